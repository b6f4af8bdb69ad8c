"""`hil run` output: plan N of M with elapsed time and ETA by default, a line per step with
-v, nothing but the summary with -q, log records with --log-level (issue 18 item 3)."""

from __future__ import annotations

import io
import os
import re
import subprocess
import sys
import time
from types import SimpleNamespace

from hil.plan.events import PlanEnded, PlanStarted, StepEnded, StepStarted
from hil.plan.progress import RunProgress

TWO = ["alarm_reset", "cia402_power_states"]  # short plans


def _run(tmp_path, *args):
    return subprocess.run([sys.executable, "-m", "hil.cli", "run", *TWO, "--out",
                           str(tmp_path / "out"), *args], capture_output=True, text=True,
                          timeout=300, env=dict(os.environ))


def test_default_output_is_plan_n_of_m_with_elapsed_and_eta(tmp_path):
    r = _run(tmp_path)
    assert r.returncode == 0, r.stderr
    # counted as plans complete: in virtual time the two run side by side (one per CPU), so
    # either may be the first to finish
    plans = "(alarm_reset|cia402_power_states)"
    first = re.search(rf"^\[1/2\] {plans} +PASS .*\(elapsed [^,]+, ETA .+\)$", r.stderr, re.M)
    last = re.search(rf"^\[2/2\] {plans} +PASS .*\(elapsed [^,)]+\)$", r.stderr, re.M)
    assert first and last and first.group(1) != last.group(1), r.stderr
    assert "[ 1/16]" not in r.stderr  # no step lines without -v
    assert "2/2 plans passed" in r.stdout


def test_verbose_prints_each_step_and_quiet_prints_no_progress(tmp_path):
    r = _run(tmp_path, "-v")
    assert r.stderr.count("PASS") >= 30 and "[ 1/16]" in r.stderr, r.stderr
    q = _run(tmp_path, "-q")
    assert q.returncode == 0
    assert "[1/2]" not in q.stderr and "PASS" not in q.stderr and "plans:" not in q.stderr
    assert "2/2 plans passed" in q.stdout


def test_log_level_debug_shows_the_harness_logs(tmp_path):
    r = _run(tmp_path, "-q", "--log-level", "debug")
    assert re.search(r"^(DEBUG|INFO) hil\.", r.stderr, re.M), r.stderr[-2000:]
    r = _run(tmp_path, "-q", "--log-level", "loud")
    assert r.returncode == 2 and "invalid choice: 'loud'" in r.stderr


def _events(n_plans: int, steps: int):
    for i in range(1, n_plans + 1):
        plan = SimpleNamespace(name=f"p{i}", steps=[None] * steps)
        yield PlanStarted(plan, SimpleNamespace(name="b"), i, n_plans)
        for k in range(steps):
            r = SimpleNamespace(label=f"step {k}", index=k, status="pass", duration_ns=0)
            yield StepStarted(plan, None, r, "d")
            yield StepEnded(plan, None, r, "d")
        yield PlanEnded(plan, SimpleNamespace(plan=plan.name, status="pass", duration_ns=1),
                        i, n_plans)


def test_eta_counts_the_steps_still_to_run():
    p = RunProgress(total_steps=40, total_plans=4, stream=io.StringIO(), live=False)
    p.t0 -= 10.0  # 10 s so far
    for e in list(_events(1, 10)):
        p.on_event(e)
    assert p.done_steps == 10
    assert abs(p.eta_s() - 30.0) < 1.0  # 1 s per step, 30 steps to go


def test_live_display_on_a_terminal_draws_and_ends_with_the_plan_lines():
    out = io.StringIO()
    p = RunProgress(total_steps=6, total_plans=2, stream=out, live=True)
    for e in _events(2, 3):
        p.on_event(e)
        time.sleep(0.001)
    text = out.getvalue()
    assert "[1/2] p1" in text and "[2/2] p2" in text
    assert p._progress is None  # stopped after the last plan
