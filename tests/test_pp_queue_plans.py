"""PP set-points given while a move runs (bit 5 = 0), end to end through the harness's CiA 402
driver on the virtual bench: L17172-17174 "只有在當前命令執行完成後，新的命令伺服才會被承認並執行"
(acknowledged and run only once the current move completes). helper-88 found the second
acknowledged at once and a third never run."""

from __future__ import annotations

import dataclasses
import json

import pytest
from mcap.reader import make_reader

from hil.bench.bench import load_bench
from hil.plan.plan import loads_plan
from hil.plan.runner import run_plan
from hil.units import S

BUILTIN = load_bench(None)

THREE = """\
name: pp_three
steps:
  - state: OPERATION ENABLED
  - move: {mode: PP, target: 500000, velocity: 200000, wait: false}
  - move: {mode: PP, target: 400000, velocity: 200000, wait: false}
  - move: {mode: PP, target: 100000, velocity: 200000, wait: true}
"""


@pytest.mark.virtual_time
def test_each_set_point_given_during_a_move_is_acknowledged_when_it_completes(tmp_path) -> None:
    """500000 PUU at 200000 PUU/s takes about 2.5 s: the second set-point's step waits that
    long for its acknowledge, the third the 0.5 s of the second move (500000 -> 400000), and
    the axis ends on the third target."""
    bench = dataclasses.replace(BUILTIN, timeouts=BUILTIN.timeouts | {"setpoint_ack": 10 * S})
    res = run_plan(loads_plan(THREE, str(tmp_path / "pp_three.yaml")), bench, tmp_path,
                   reports=False)
    assert res.status == "pass", [(s.index, s.status, s.message) for s in res.steps]
    second, third = res.steps[2].duration_ns / 1e9, res.steps[3].duration_ns / 1e9
    assert 2.3 < second < 2.8, second
    assert 0.4 < third < 3.0, third  # its acknowledge, then its move to the target
    with open(res.recording, "rb") as f:
        last = [json.loads(m.data) for _, ch, m in make_reader(f).iter_messages(
            log_time_order=True) if ch.topic.endswith("/state")][-1]
    assert abs(last["position_puu"] - 100000) < 1000  # the third target (bit 10: 6067h)


@pytest.mark.virtual_time
def test_an_acknowledge_timeout_during_a_move_says_why(tmp_path) -> None:
    res = run_plan(loads_plan(THREE, str(tmp_path / "pp_three.yaml")), BUILTIN, tmp_path,
                   reports=False)
    step = res.steps[2]
    assert step.status == "error"
    assert "set-point acknowledge (bit 12) within 1.000 s" in step.message
    assert "acknowledged only when that move completes" in step.message
    assert "L17172-17174" in step.message
