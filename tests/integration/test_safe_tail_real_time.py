"""A real-time run records the drive's reaction to the safe state, as a virtual-time run does
(helper-86: the wall-clock recording closed about 2 ms after `safe_state_reached`, before the
motor's brake clamped, so `hil diff` of the two clocks showed a brake edge that only the
harness had made differ)."""

from __future__ import annotations

import json
from dataclasses import replace

import pytest
from mcap.reader import make_reader

from hil.bench.bench import load_bench
from hil.plan.plan import find_plans, load_plan
from hil.plan.runner import SAFE_TAIL_NS, run_plan

pytestmark = pytest.mark.integration


def test_the_brake_clamping_after_the_safe_state_is_on_a_real_time_record(tmp_path) -> None:
    plan = load_plan(find_plans(["servo_on_off_brake"])[0])
    res = run_plan(plan, replace(load_bench(None), clock="real"), tmp_path, reports=False)
    assert res.passed, [(s.label, s.message) for s in res.steps if s.status != "pass"]
    safe_t, clamped, last = None, [], 0
    with open(res.recording, "rb") as f:
        for _s, ch, m in make_reader(f).iter_messages(log_time_order=False):
            last = max(last, m.log_time)
            d = json.loads(m.data)
            if ch.topic == "/safety" and d.get("action") == "safe_state_reached":
                safe_t = m.log_time
            elif ch.topic == "/drive/drive1/events" and d.get("type") == "BrakeChanged" \
                    and d.get("clamped"):
                clamped.append(m.log_time)
    assert safe_t is not None
    # the motor's spring brake clamps its engage time (the bench's brake, 50 ms) after BRKR
    # went off
    assert any(t > safe_t for t in clamped), (safe_t, clamped)
    assert last >= safe_t + SAFE_TAIL_NS * 0.9  # the wall clock's sleep, not the model's
