"""A WAIT that is a move's transition has what the move left of the program's time, and a
program that runs out of its time fails as the PLC's failure, not at the step's watchdog
(helper-139: the WAIT compared with the time left before the move, so a 5 s program failed
after 5.64 s; with the default 60 s the bench's 60 s step timeout fired first, an ERROR)."""

from __future__ import annotations

import pytest

from hil.bench.bench import load_bench
from hil.plan.plan import load_plan
from hil.plan.runner import run_plan

pytestmark = pytest.mark.virtual_time

PLAN = """name: wait_left
bench_requires: [virtual, motion, pulse, dio]
params:
  P1.001: 0x0000
steps:
  - power_cycle: {{battery: true}}
  - di: {{SON: on}}
  - wait_until: {{do: {{BRKR: on}}, timeout: 1s}}
  - plc_program:
      axis: {{max_speed: 100000, start_speed: 500, accel_ms: 100}}
      program: [{{SPD: 50000, DRV: "ADR,+,30000,Ps", WAIT: 100s}}, MD]{timeout}
"""


@pytest.mark.parametrize("timeout, limit_ms", [("\n      timeout: 2s", 2000),
                                              ("", 60_000)])
def test_a_wait_after_a_move_fails_at_the_programs_time(tmp_path, timeout, limit_ms) -> None:
    path = tmp_path / "wait_left.yaml"
    path.write_text(PLAN.format(timeout=timeout), encoding="utf-8")
    res = run_plan(load_plan(path), load_bench(None), tmp_path, reports=False)
    step = res.steps[-1]
    assert step.status == "fail", (step.status, step.message)  # not "error" (the watchdog)
    assert "WAIT 100 s: longer than the program's time left" in step.message
    left = float(step.message.rsplit("(", 1)[1].split(" s)")[0])
    assert 0 < left < limit_ms / 1000 - 0.3  # the move's ~0.64 s are not left any more
    assert step.duration_ns / 1e6 == pytest.approx(limit_ms, abs=5)
