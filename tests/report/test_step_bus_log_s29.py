"""The bus log of a failing step holds the frames written during that step only: not the
answer to a request made before it, nor the safe state's frames after it, though in virtual
time both are logged at the same instant as the step's start or end."""

from __future__ import annotations

import html
import io
import re
from pathlib import Path

from hil.bench.bench import load_bench
from hil.plan.plan import loads_plan
from hil.plan.runner import run_plans
from hil.report.data import bus_log, load_run

PLAN = """name: bus_log_fails
description: the read expects another value, so its step fails
steps:
  - write: {P1.042: 150, via: sdo}
  - read: {P1.042: 151, via: sdo}
"""


def test_a_failing_steps_bus_log_is_its_own_frames(tmp_path: Path) -> None:
    plan = loads_plan(PLAN, str(tmp_path / "bus_log_fails.yaml"))
    [res] = run_plans([plan], load_bench(None), tmp_path / "out", stream=io.StringIO(),
                      quiet=True)
    assert res.status == "fail" and res.steps[1].status == "fail"
    run = load_run(res.recording)
    step = next(s for s in run.steps if s.index == 1)
    rows = [text for _t, _topic, text in bus_log(run, step)]
    assert rows, "the read's frames"
    assert any("upload" in r and "index=212Ah" in r for r in rows), rows  # P1.042: 212Ah
    assert not any("index=1018h" in r for r in rows), rows  # the identity read, before
    assert not any("index=6040h" in r for r in rows), rows  # the safe state, after
    assert not any("download" in r for r in rows), rows  # step 1's write
    # the page shows the same
    page = html.unescape(re.sub("<[^>]+>", "", Path(res.html).read_text(encoding="utf-8")))
    log = page.split("Bus log of failing steps", 1)[1].split("Parameters", 1)[0]
    assert "212Ah" in log and "6040h" not in log


def test_a_flat_motion_signal_is_drawn_mid_panel_with_distinct_labels() -> None:
    """At rest the motion plot labelled each panel "0" above "0" and drew the line on its
    floor, where it read as a missing trace."""
    from hil.report.data import RunData, TruthSamples
    from hil.report.html import _plot

    samples = TruthSamples(None)
    for k in range(5):
        samples.add(k * 1_000_000, b'{"position_counts": 0, "speed_rpm": 0.0, "torque_pct": 0.0}')
    samples.finish()
    svg = _plot(RunData("x.mcap", "p", "b", "pass"), "drive1", samples)
    labels = re.findall(r'font-size="9">([^<]*)<', svg)
    assert len(labels) == 6 and all(a != b for a, b in zip(labels[::2], labels[1::2],
                                                            strict=True)), labels
    ys = {float(y) for y in re.findall(r"[\d.]+,([\d.]+)", svg.split("<polyline", 1)[1]
                                       .split("/>", 1)[0])}
    assert len(ys) == 1  # one flat line, between the panel's top (10) and floor (100)
    assert 30 < ys.pop() < 80
