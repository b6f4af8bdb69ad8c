"""`fault:` steps and the `faults_allowed` bench key (issue 16, docs/faults.md)."""

from __future__ import annotations

import pytest

from hil.bench.bench import load_bench
from hil.bench.yamlio import PlanFileError
from hil.paths import fixture
from hil.plan.plan import check_plan, load_plan

PLAN = "plans/fault_heartbeat.yaml"


def test_fault_step_refused_on_real_bench_by_default():
    bench = load_bench(fixture("benches", "example-asda-a3-socketcan.yaml"))
    assert bench.faults_allowed is False
    with pytest.raises(PlanFileError, match="faults_allowed: false"):
        check_plan(load_plan(PLAN), bench)


def test_fault_step_allowed_on_virtual_bench():
    bench = load_bench(fixture("benches", "virtual.yaml"))
    assert bench.faults_allowed is True
    check_plan(load_plan(PLAN), bench)


def test_real_bench_may_allow_faults(tmp_path):
    text = fixture("benches", "example-asda-a3-socketcan.yaml").read_text()
    p = tmp_path / "b.yaml"
    p.write_text(text + "\nfaults_allowed: true\n")
    check_plan(load_plan(PLAN), load_bench(p))


@pytest.mark.parametrize(("step", "problem"), [
    ("{can: explode}", "one of drop"),
    ("{can: drop, match: {function: foo}}", "one of nmt"),
    ("{can: drop, rate: 2}", "fraction"),
    ("{can: duplicate_pdo}", "cob_id"),
    ("{dio: stuck, line: DO3}", "harness-driven line"),
    ("{can: drop, every: 0}", "integer 1..1000"),
    ("{can: drop, every: 2, rate: 0.5}", "not both"),
    ("{rs485: reply_slow}", "one of crc"),
])
def test_malformed_fault_step(tmp_path, step, problem):
    p = tmp_path / "p.yaml"
    p.write_text(f"name: p\nsteps:\n  - fault: {step}\n")
    with pytest.raises(PlanFileError, match=problem) as e:
        load_plan(p)
    assert "p.yaml:3" in str(e.value)


def test_hil_run_check_refuses_every_fault_plan_on_a_bench_without_faults_allowed(
        capsys, tmp_path):
    """`hil run --check` (nothing moves) on the real-bench example: every shipped plan with a
    `fault:` step is refused, naming the file:line of the step and the bench key. (Motion is
    allowed in this copy, so a plan that also moves is refused for its faults alone.)"""
    from hil.cli import main
    from hil.plan.plan import find_plans

    example = fixture("benches", "example-asda-a3-socketcan.yaml").read_text()
    assert "motion_allowed: false" in example
    bench_file = tmp_path / "example-asda-a3-socketcan.yaml"
    bench_file.write_text(example.replace("motion_allowed: false", "motion_allowed: true"))
    bench = str(bench_file)
    with_faults = [p for p in find_plans() if "\n  - fault:" in p.read_text()]
    assert len(with_faults) >= 8
    for plan in with_faults:
        assert main(["run", "--check", "--bench", bench, str(plan)]) == 2
        err = capsys.readouterr().err
        assert f"{plan.name}:" in err and "faults_allowed: false" in err, err
    assert main(["run", "--check", str(with_faults[0])]) == 0  # the virtual bench allows them


@pytest.mark.parametrize(("step", "problem"), [
    ("{P3.004: null, via: modbus, expect_error: lost}", "one of timeout, bad_reply"),
    ("{P3.004: null, via: sdo, expect_error: timeout}", "via: modbus"),
])
def test_malformed_read_expecting_a_line_error(tmp_path, step, problem):
    p = tmp_path / "p.yaml"
    p.write_text(f"name: p\nsteps:\n  - read: {step}\n")
    with pytest.raises(PlanFileError, match=problem) as e:
        load_plan(p)
    assert "p.yaml:3" in str(e.value)


def test_every_rs485_fault_kind_parses():
    from hil.plan.plan import loads_plan
    from hil.transport.faults import SERIAL_FAULTS

    steps = "".join(f"  - fault: {{rs485: {k}, for: 1s}}\n" for k in SERIAL_FAULTS)
    plan = loads_plan(f"name: p\nsteps:\n{steps}")
    assert [s.args.kind for s in plan.steps] == list(SERIAL_FAULTS)


def test_a_burst_the_host_stretched_past_1ms_is_sent_again():
    """duplicate_pdo / sdo_flood need their frames within 1 ms (L19933, L19941): a burst
    a loaded host stretched is recorded `tight: false` and sent again; the message says so.
    A host that never manages it fails the step instead of claiming a fault it did not make."""
    from hil.plan.kinds.comm import BURST_ATTEMPTS, _burst
    from hil.transport.faults import FaultyCanBus
    from tests.transport.test_faults import Sink, SlowBus, frame

    sink = Sink()
    bus = FaultyCanBus(SlowBus([0, 0.003, 0, 0]), "can0", sink=sink)
    msg = _burst(bus, "duplicate_pdo", [frame(0x201)] * 2)
    assert "2 frames back to back" in msg and "sent again" in msg and "over the 1 ms" in msg
    starts = [r[4]["tight"] for r in sink.records if r[2]]
    assert starts[0] is False and starts[-1] is True and not any(starts[1:-1])  # retried
    slow = FaultyCanBus(SlowBus([0, 0.0015] * BURST_ATTEMPTS), "can0", sink=Sink())
    with pytest.raises(RuntimeError, match=r"could not send 2 frames within 1 ms in 5 tries"):
        _burst(slow, "sdo_flood", [frame(0x601)] * 2)
    assert "sent again" not in _burst(FaultyCanBus(SlowBus([0.002] * 3), "can0"),
                                      "bus_error", [frame(0)] * 3)  # no window


def test_a_flood_needs_two_frames():
    """"More than one" SDO / PDO (L19933, L19941): a burst of one cannot be the fault (it
    passed `--check`, went out "tight", and the plan then waited for an alarm in vain)."""
    from hil.plan.plan import loads_plan

    for kind in ("sdo_flood", "duplicate_pdo, cob_id: 0x201"):
        with pytest.raises(PlanFileError, match=r"count.*1: an integer 2\.\.1000"):
            loads_plan(f"name: p\nsteps:\n  - fault: {{can: {kind}, count: 1}}\n", "p.yaml")
    loads_plan("name: p\nsteps:\n  - fault: {can: bus_error, count: 1}\n", "p.yaml")


def test_a_burst_the_wire_cannot_carry_within_1ms_is_refused_at_check():
    """9 SDO requests are 9 x 124 bits: 1.1 ms at 1 Mbit/s, never within AL111's 1 ms
    (L19933): `--check` says so, naming the count (an execution fuzz found it failing at run
    time as "host under load")."""
    from hil.plan.plan import loads_plan

    bench = load_bench(fixture("benches", "virtual.yaml"))
    check_plan(loads_plan("name: p\nsteps:\n  - fault: {can: sdo_flood, count: 8}\n"), bench)
    with pytest.raises(PlanFileError, match=r"count: 9 frames take 1116 µs on the wire at "
                                            r"1000 kbit/s"):
        check_plan(loads_plan("name: p\nsteps:\n  - fault: {can: sdo_flood, count: 9}\n"), bench)


def test_in_virtual_time_a_burst_over_1ms_says_the_bus_is_full_not_the_host(tmp_path):
    """7 requests with the drive's answers between them take 1.8 ms of wire: in virtual time
    that is the same on every try, so the step ends at once and says why."""
    import dataclasses

    from hil.plan.plan import loads_plan
    from hil.plan.runner import run_plan

    bench = dataclasses.replace(load_bench(fixture("benches", "virtual.yaml")), clock="virtual")
    plan = loads_plan("name: p\nsteps:\n  - fault: {can: sdo_flood, count: 7}\n")
    r = run_plan(plan, bench, tmp_path, reports=False)
    [step] = r.steps
    assert step.status == "error" and "send fewer" in step.message, step.message
    assert "host under load" not in step.message


def test_produce_off_stops_every_cyclic_frame():
    """docs/faults.md lists `produce: off`; YAML reads `off` as false, and the step refused
    it ("must be a mapping", an outside review)."""
    from hil.plan.plan import loads_plan

    for text in ("off", "'off'"):
        plan = loads_plan(f"name: p\nsteps:\n  - produce: {{sync: 10ms}}\n  - produce: {text}\n",
                          "p.yaml")
        a = plan.steps[1].args
        assert (a.heartbeat, a.sync, a.guard) == (0, 0, 0)
        assert plan.steps[1].label == "produce heartbeat off, sync off, guard off"
