"""One plan gives the same messages whether it is named by a relative or an absolute path
(helper-86 #4: `/plan/steps` and `/log` carried the path as typed, so the recordings of one
plan differed though docs/clock.md says only metadata such as the start time does)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
from mcap.reader import make_reader

from hil.bench.bench import load_bench
from hil.plan.plan import load_plan
from hil.plan.runner import run_plan

pytestmark = pytest.mark.virtual_time

PLAN = """name: paths
params:
  P1.043: 10
steps:
  - di: {SON: on}
  - wait_until: {do: {BRKR: on}, timeout: 1s}
  - wait_until: {do: {BRKR: off}, timeout: 10ms}   # fails: logged on /log with its file
"""


def _messages(path: str) -> list[tuple[str, int, bytes]]:
    with open(path, "rb") as f:
        return [(ch.topic, m.log_time, m.data)
                for _s, ch, m in make_reader(f).iter_messages(log_time_order=False)]


def test_a_plan_by_relative_and_absolute_path_records_the_same(tmp_path, monkeypatch):
    (tmp_path / "p").mkdir()
    (tmp_path / "p" / "paths.yaml").write_text(PLAN, encoding="utf-8")
    monkeypatch.chdir(tmp_path)
    runs = [run_plan(load_plan(Path(p)), load_bench(None), tmp_path / out, reports=False)
            for p, out in (("p/paths.yaml", "rel"), (str(tmp_path / "p/paths.yaml"), "abs"))]
    assert [r.status for r in runs] == ["fail", "fail"]
    rel, ab = (_messages(r.recording) for r in runs)
    assert rel == ab
    named = [json.loads(m).get("file") for t, _lt, m in rel if t in ("/plan/steps", "/log")]
    named = [f for f in named if f]
    assert len(named) >= 4 and set(named) == {os.path.abspath("p/paths.yaml")}
