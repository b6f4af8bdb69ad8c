"""`hil check` on a recording from an earlier run gives the same verdicts as the live run."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from hil.bench.bench import load_bench
from hil.plan.plan import find_plans, load_plan
from hil.plan.runner import run_plan
from hil.record import topics
from hil.record.reader import Recording

# the built-in virtual bench in virtual time: deterministic, never rerun (conftest.py)
pytestmark = [pytest.mark.integration, pytest.mark.virtual_time]


@pytest.mark.parametrize("plan_name", ["servo_on_off_brake", "sto_both", "emgs",
                                       "absolute_power_cycle", "homing_pr"])
def test_offline_check_matches_live_verdicts(tmp_path, plan_name: str) -> None:
    result = run_plan(load_plan(find_plans([plan_name])[0]), load_bench(None), tmp_path)
    assert result.passed
    live = [m for _t, _l, _p, m in Recording.open(result.recording).messages(
        [topics.TIMING_VERDICTS])]
    assert live, "the plan checked no timing spec"
    # no --spec: a plan recording is re-checked step by step, as the run checked it
    args = [sys.executable, "-m", "hil.cli", "check", result.recording, "--json"]
    out = subprocess.run(args, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stdout + out.stderr
    offline = json.loads(out.stdout)

    def key(v: dict) -> tuple:
        return (v["spec"], v["constraint"], v["status"],
                None if v.get("measured_ms") is None else round(v["measured_ms"], 3))

    judged_live = sorted(key(v) for v in live if v["status"] != "skipped")
    judged_offline = sorted(key(v) for v in offline if v["status"] != "skipped")
    assert judged_live == judged_offline
