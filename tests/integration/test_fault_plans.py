"""The fault plans (issue 16) on the in-process virtual bench and on the zenoh subprocess
bench (`hil drive` as a child process, CAN and DI/DO over zenoh on loopback, RS-485 on a
pty): every step and every timing verdict (fixtures/timing/fault_*.yaml) must pass (on the
wall clock, a plan the host made late is run again on its own: REAL_TIME_ATTEMPTS)."""

from __future__ import annotations

import io

import pytest

from hil.bench.bench import load_bench
from hil.paths import fixture
from hil.plan.plan import find_plans, load_plan
from hil.plan.runner import run_plans
from hil.record import topics as T
from hil.record.reader import Recording

pytestmark = pytest.mark.integration

FAULT_PLANS = [p for p in find_plans() if p.stem.startswith("fault_")]


# A plan on the wall clock of a shared 2-core host can be late by tens of ms (the drive's
# process starved while the harness sends, docs/timing.md "Under load"): such a plan is run
# again, on its own, at most REAL_TIME_ATTEMPTS times in all. One that fails every time fails
# the test; in virtual time (deterministic) a plan runs once.
REAL_TIME_ATTEMPTS = 3


def _run_all(bench_file, tmp_path, attempts: int = 1):
    bench = load_bench(bench_file) if bench_file else load_bench()
    plans = [load_plan(p) for p in FAULT_PLANS]
    final = {}
    for n in range(attempts):
        for r in run_plans(plans, bench, tmp_path / f"try{n}", stream=io.StringIO()):
            final[r.plan] = r
        plans = [p for p in plans if not final[p.name].passed]
        if not plans:
            break
    assert len(final) == len(FAULT_PLANS)
    for r in final.values():
        assert r.passed, (r.plan, [(s.label, s.status, s.message) for s in r.steps
                                        if s.status != "pass"])
        _every_fault_starts_and_ends(r.plan, r.recording)
    return list(final.values())


def _every_fault_starts_and_ends(plan: str, path) -> None:
    """Each fault on /faults (by id): one start, then one end, not before it (issue 16)."""
    by_id: dict[int, list[tuple[int, bool]]] = {}
    for _topic, _lt, t, msg in Recording.open(path).messages(T.FAULTS):
        by_id.setdefault(msg["id"], []).append((t, msg["active"]))
    assert by_id, plan
    for fid, recs in by_id.items():
        assert [a for _, a in recs] == [True, False], (plan, fid, recs)
        assert recs[0][0] <= recs[1][0], (plan, fid, recs)


def test_fault_plans_cover_every_reaction_family():
    names = {p.stem for p in FAULT_PLANS}
    assert {"fault_heartbeat", "fault_heartbeat_moving", "fault_life_guarding", "fault_1029h",
            "fault_sdo_flood",
            "fault_duplicate_pdo", "fault_bus_error", "fault_sync_ip", "fault_rs485",
            "fault_rs485_line", "fault_di_bounce", "fault_di_stuck"} <= names


def test_fault_plans_on_the_virtual_bench(tmp_path):
    _run_all(None, tmp_path)


def test_fault_plans_on_the_zenoh_subprocess_bench(tmp_path):
    bench_file = fixture("benches", "virtual-zenoh.yaml")
    assert load_bench(bench_file).process == "subprocess"
    _run_all(bench_file, tmp_path, REAL_TIME_ATTEMPTS)


def test_burst_fault_plans_on_the_in_process_bench_in_real_time(tmp_path):
    """The in-process bench on the wall clock hands each frame over in the sender's thread
    (hil.transport.inline): a burst (an SDO flood, duplicate PDOs) must still reach the drive
    back to back, before it answers any, for AL111/AL112 (docs/clock.md)."""
    from dataclasses import replace

    bench = replace(load_bench(), clock="real")
    plans = [load_plan(p) for p in FAULT_PLANS
             if p.stem in ("fault_sdo_flood", "fault_duplicate_pdo")]
    assert len(plans) == 2
    for r in run_plans(plans, bench, tmp_path, stream=io.StringIO()):
        assert r.passed, (r.plan, [(s.label, s.status, s.message) for s in r.steps
                                        if s.status != "pass"])
        _every_fault_starts_and_ends(r.plan, r.recording)
