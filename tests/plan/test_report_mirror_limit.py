"""A plan without `check_timing` steps keeps its messages in memory for its reports only up to
`REPORT_MIRROR_LIMIT`; past it the reports read the file (helper-86: a 30-minute wait in
virtual time peaked at 499 MB for a 5 MB recording, about 2.4 KB a message, without bound)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from hil.bench.bench import load_bench
from hil.plan import runner
from hil.plan.plan import load_plan
from hil.plan.runner import run_plan
from hil.record.reader import Recording
from hil.record.recorder import Recorder

pytestmark = pytest.mark.virtual_time

PLAN = """name: soak
steps:
  - di: {SON: on}
  - wait: 3s
"""


def test_the_recorders_mirror_is_dropped_at_its_limit(tmp_path) -> None:
    rec = Recorder(tmp_path / "m.mcap")
    mirror = rec.keep_messages(limit=5)
    assert rec.keep_messages(limit=5) is mirror
    with pytest.raises(ValueError, match="limit 5"):
        rec.keep_messages()
    for i in range(3):
        rec.drive_state("d", {"t": i}, t=i + 1)
    rec.flush()
    assert len(mirror) == 3 and rec.mirror is mirror and not rec.mirror_dropped
    for i in range(3, 12):
        rec.drive_state("d", {"t": i}, t=i + 1)
    rec.flush()
    assert rec.mirror is None and rec.mirror_dropped and mirror == []
    with pytest.raises(RuntimeError, match="dropped at its limit of 5"):
        rec.keep_messages(limit=5)
    rec.close()
    # the file lost nothing
    got = [m["t"] for *_h, m in Recording.open(tmp_path / "m.mcap").messages("/drive/d/state")]
    assert got == list(range(12))


def _page(path: Path) -> str:
    text = path.read_text(encoding="utf-8")
    text = re.sub(r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d UTC", "DATE", text)
    return text.replace(str(path.parent), "OUT")


def test_a_plan_past_the_limit_reports_from_the_file_the_same_page(tmp_path, monkeypatch):
    (tmp_path / "soak.yaml").write_text(PLAN, encoding="utf-8")
    plan = load_plan(tmp_path / "soak.yaml")
    seen = []
    real = Recorder.keep_messages

    def spy(self, limit=None):
        seen.append(self)
        return real(self, limit)

    monkeypatch.setattr(Recorder, "keep_messages", spy)
    whole = run_plan(plan, load_bench(None), tmp_path / "a")
    assert whole.passed and not seen[-1].mirror_dropped
    monkeypatch.setattr(runner, "REPORT_MIRROR_LIMIT", 100)
    cut = run_plan(plan, load_bench(None), tmp_path / "b")
    assert cut.passed and seen[-1].mirror_dropped and seen[-1].mirror_limit == 100
    assert _page(Path(cut.html)) == _page(Path(whole.html))
    assert "drive1" in _page(Path(cut.html))
