"""Plans in virtual time (docs/clock.md): the same verdicts as in real time, step timeouts in
virtual time, a wall-clock watchdog, and `--clock` / `clock:` refusals."""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import pytest
from mcap.reader import make_reader

from hil import clock
from hil.bench.bench import load_bench, loads_bench, with_clock
from hil.bench.yamlio import PlanFileError
from hil.paths import fixture
from hil.plan.plan import find_plans, load_plan, loads_plan
from hil.plan.runner import run_plan

BUILTIN = load_bench(None)


def _verdicts(res) -> list[tuple]:
    return [(s.index, s.status,
             tuple((v["spec"], v["constraint"], v["status"]) for v in s.verdicts))
            for s in res.steps]


def test_the_builtin_bench_runs_in_virtual_time_and_names_its_clock(tmp_path) -> None:
    assert BUILTIN.clock == "virtual"
    res = run_plan(load_plan(find_plans(["servo_on_off_brake"])[0]), BUILTIN, tmp_path)
    assert res.passed
    with open(res.recording, "rb") as f:
        reader = make_reader(f)
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
        first = next(reader.iter_messages(log_time_order=True))[2].log_time
    assert meta["hil.clock"]["clock"] == "virtual"
    assert first >= clock.VIRTUAL_EPOCH_NS
    assert first - clock.VIRTUAL_EPOCH_NS < 10**9  # stamped on the virtual clock
    assert clock.current() is clock.REAL  # the run's clock is gone after it


@pytest.mark.integration
@pytest.mark.parametrize("name", ["servo_on_off_brake", "sto_single_channel", "pr_delay",
                                  "fault_heartbeat", "homing_pr",
                                  "sto_short_dropout"])  # once 12 verdicts real, 9 virtual
def test_virtual_and_real_time_give_the_same_verdicts(name, tmp_path) -> None:
    plan = load_plan(find_plans([name])[0])
    # the verdicts are the result's: no HTML/JUnit needed (they read the same recording)
    virtual = run_plan(plan, BUILTIN, tmp_path / "v", reports=False)
    real = run_plan(plan, with_clock(BUILTIN, "real"), tmp_path / "r", reports=False)
    assert virtual.status == real.status == "pass"
    assert _verdicts(virtual) == _verdicts(real)


STUCK = """\
name: stuck
steps:
  - state: OPERATION ENABLED
  - move: {mode: PP, target: 50000000, velocity: 20000, accel: 200, decel: 200}
    timeout: 30s
"""


@pytest.mark.virtual_time
def test_a_step_timeout_passes_in_virtual_time_and_the_bench_goes_safe(tmp_path) -> None:
    plan = loads_plan(STUCK, str(tmp_path / "stuck.yaml"))
    t0 = time.monotonic()
    res = run_plan(plan, BUILTIN, tmp_path)
    wall = time.monotonic() - t0
    assert res.status == "error"
    step = res.steps[1]
    assert "step timeout 30 s of virtual time" in step.message, step.message
    assert step.duration_ns == 30 * 10**9  # exactly the timeout, in bench time
    assert wall < 20, f"30 s of virtual time took {wall:.1f} s of wall time"
    assert res.safe is not None and res.safe.ok


@pytest.mark.virtual_time
def test_the_wall_clock_watchdog_stops_a_step_that_never_waits(tmp_path, monkeypatch) -> None:
    from hil.plan import context
    from hil.plan.context import StepThread
    from hil.units import MS

    monkeypatch.setattr(context, "WATCHDOG_GRACE_NS", 200 * MS)
    monkeypatch.setattr(context, "WATCHDOG_FACTOR", 3)  # 300 ms: the grace is longer
    cancel = __import__("threading").Event()
    stop = __import__("threading").Event()
    with clock.use(clock.VirtualClock()):
        t0 = time.monotonic()
        with pytest.raises(TimeoutError, match="wall-clock watchdog"):
            StepThread().run(lambda: stop.wait(5), 100 * MS, cancel)
        assert 0.3 <= time.monotonic() - t0 < 2  # the grace, not 3 x the timeout
        t0 = time.monotonic()
        cancel.clear()
        with pytest.raises(TimeoutError, match="wall-clock watchdog"):  # 3 x 200 ms > 400 ms
            StepThread().run(lambda: stop.wait(5), 200 * MS, cancel)
        assert 0.6 <= time.monotonic() - t0 < 2
        assert cancel.is_set()
        stop.set()


def test_a_step_hung_inside_a_clock_event_still_ends_the_plan_with_a_readable_recording(
        tmp_path, monkeypatch) -> None:
    """An outside audit: a clock event that never returns held the clock's lock, so after the
    watchdog the safe state waited for it for ever and the recording was never closed. The
    other threads now give up on the clock after HELD_WAIT_S: the safe state is recorded as
    not confirmed, with why, the plan ends as an error and its recording is readable."""
    import threading

    from hil.plan import context
    from hil.plan.kinds.waits import Wait
    from hil.record.reader import Recording
    from hil.units import MS

    monkeypatch.setattr(context, "WATCHDOG_GRACE_NS", 300 * MS)
    monkeypatch.setattr(context, "WATCHDOG_FACTOR", 1)
    monkeypatch.setattr(clock, "HELD_WAIT_S", 0.5)
    release = threading.Event()

    def hang(self, ctx, step, d):
        def forever() -> None:  # a model bug: an event that loops (released at the end)
            while not release.is_set():
                time.sleep(0.001)
        clock.call_later(0.001, forever)
        clock.sleep(0.5)

    monkeypatch.setattr(Wait, "run", hang)
    plan = loads_plan("name: wd\nsteps:\n  - state: OPERATION ENABLED\n  - wait: 1s\n"
                      "    timeout: 1s\n", "wd.yaml")
    try:
        res = run_plan(plan, load_bench(None), tmp_path, reports=False)
    finally:
        release.set()
    assert res.status == "error" and "wall-clock watchdog" in res.steps[1].message
    assert res.safe is not None and not res.safe.ok
    assert any("ClockHung" in a["detail"] for a in res.safe.actions if not a["ok"])
    rec = Recording.open(res.recording)
    assert not rec.truncated and "hil.close" in rec.metadata()


def test_clock_virtual_is_refused_where_the_bench_cannot(tmp_path) -> None:
    zenoh = load_bench(fixture("benches", "virtual-zenoh.yaml"))
    assert zenoh.clock == "real"
    with pytest.raises(ValueError, match="subprocess"):
        with_clock(zenoh, "virtual")
    text = Path(fixture("benches", "virtual.yaml")).read_text()
    named = text.replace('"pty:auto?baud=38400"', '"pty:/tmp/ttyA3?baud=38400"')
    assert loads_bench(named).clock == "real"
    with pytest.raises(PlanFileError, match=r":\d+: clock: virtual: RS-485 line rs485"):
        loads_bench("clock: virtual\n" + named, "b.yaml")
    with pytest.raises(PlanFileError, match="clock: 'fast'"):
        loads_bench("clock: fast\n" + text, "b.yaml")
    with pytest.raises(PlanFileError, match=r"b.yaml:1: clock: must not be empty"):
        loads_bench("clock: ''\n" + text, "b.yaml")  # said so, not "must be text, got text"
    with pytest.raises(PlanFileError, match=r"b.yaml:1: clock: must be text, got a list"):
        loads_bench("clock: [virtual]\n" + text, "b.yaml")
    assert loads_bench("clock: real\n" + text).clock == "real"
    assert dataclasses.replace(BUILTIN).clock == "virtual"


def test_schemes_are_read_in_any_case_as_parse_url_reads_them(tmp_path) -> None:
    """`VIRTUAL:auto` and `PTY:auto` are the in-process bus and the auto pty (`parse_url`
    lower-cases a scheme): virtual time by default, and `clock: virtual` is no error naming
    them "not in-process". On the wall clock the harness opens the pty's far end (it used to
    open a second pty of its own: no reply to any Modbus request)."""
    text = Path(fixture("benches", "virtual.yaml")).read_text()
    upper = (text.replace('"virtual:auto"', '"VIRTUAL:auto"')
             .replace('"pty:auto?baud=38400"', '" PTY:auto?baud=38400"'))
    assert upper != text and '"virtual:' not in upper and '"pty:' not in upper
    assert loads_bench(upper).clock == "virtual"
    assert loads_bench("clock: virtual\n" + upper).clock == "virtual"
    (tmp_path / "upper.yaml").write_text(upper)
    bench = load_bench(tmp_path / "upper.yaml")
    plan = load_plan(find_plans(["param_access"])[0])
    for clk in ("virtual", "real"):
        res = run_plan(plan, with_clock(bench, clk), tmp_path / clk)
        assert res.status == "pass", (clk, res.error, [s.message for s in res.steps])


def test_a_named_virtual_can_channel_keeps_the_wall_clock_unless_asked(tmp_path) -> None:
    """A named `virtual:<channel>` is there for another bus of the process to open (a python-can
    sniffer, which hears only the wall clock's bus): the wall clock by default, as a named
    pty; `clock: virtual` (or `--clock virtual`) still runs it in virtual time."""
    text = Path(fixture("benches", "virtual.yaml")).read_text()
    named = text.replace('can0: "virtual:auto"', 'can0: "virtual:sniffed"')
    assert named != text
    assert loads_bench(named).clock == "real"
    assert loads_bench("clock: virtual\n" + named).clock == "virtual"
    assert with_clock(loads_bench(named), "virtual").clock == "virtual"
    # `auto` with parameters is still nobody else's
    rate = text.replace('can0: "virtual:auto"', 'can0: "virtual:auto?bitrate=500000"')
    assert rate != text and loads_bench(rate).clock == "virtual"


def test_a_tagged_clock_and_a_merge_key_are_named_for_what_they_are() -> None:
    """`!!binary` is not "text" (it said "must be text, got text"); a YAML merge key is
    refused by its line (it was "could not determine a constructor", no field)."""
    text = Path(fixture("benches", "virtual.yaml")).read_text()
    with pytest.raises(PlanFileError, match=r"b.yaml:1: clock: must be text, got binary data"):
        loads_bench("clock: !!binary dmlydHVhbA==\n" + text, "b.yaml")
    with pytest.raises(PlanFileError, match=r"b.yaml:1: <<: a YAML merge key is not supported"):
        loads_bench("<<: {clock: virtual}\n" + text, "b.yaml")


def test_cli_clock_flag_refusals(tmp_path, capsys) -> None:
    from hil.cli import main

    zenoh = str(fixture("benches", "virtual-zenoh.yaml"))
    assert main(["run", "pp_move", "--bench", zenoh, "--clock", "virtual", "--out",
                 str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "--clock" in err and "cannot run on the virtual clock" in err and "subprocess" in err
    with pytest.raises(SystemExit) as e:
        main(["run", "pp_move", "--clock", "fast"])
    assert e.value.code == 2


@pytest.mark.parametrize("rate", ["0", "abc", "2000000", "-5"])
def test_a_bad_virtual_bitrate_is_named(rate, tmp_path) -> None:
    """Refused when the bench is read, at its line (it was an error only once the plan ran)."""
    text = Path(fixture("benches", "virtual.yaml")).read_text().replace(
        '"virtual:auto"\nrs485', f'"virtual:auto?bitrate={rate}"\nrs485')
    assert f"bitrate={rate}" in text
    with pytest.raises(PlanFileError) as e:
        loads_bench(text, "b.yaml")
    assert "b.yaml:" in str(e.value) and f"bitrate={rate}" in str(e.value).replace("'", "")


def test_a_virtual_time_plan_collects_the_older_gc_generations_seldom(tmp_path,
                                                                      monkeypatch) -> None:
    """While a plan runs in virtual time, the collector's older generations wait for
    `VIRTUAL_GC_OLDER` collections of the younger; the thresholds come back after it, also
    when it fails, and a wall-clock plan keeps them as they are (docs/performance.md)."""
    import gc

    from hil.plan import runner

    seen: list[tuple[int, int, int]] = []

    def fake(plan, bench, out_dir, **kw):
        seen.append(gc.get_threshold())
        if kw.get("boom"):
            raise RuntimeError("boom")
        return "done"

    monkeypatch.setattr(runner, "_run_plan", fake)
    before = gc.get_threshold()
    try:
        gc.set_threshold(700, 10, 10)
        plan = load_plan(find_plans(["servo_on_off_brake"])[0])
        assert run_plan(plan, BUILTIN, tmp_path) == "done"
        assert seen[-1] == (700, *runner.VIRTUAL_GC_OLDER)
        assert gc.get_threshold() == (700, 10, 10)
        with pytest.raises(RuntimeError):
            run_plan(plan, BUILTIN, tmp_path, boom=True)
        assert gc.get_threshold() == (700, 10, 10)
        assert run_plan(plan, with_clock(BUILTIN, "real"), tmp_path) == "done"
        assert seen[-1] == (700, 10, 10)
        assert clock.current() is clock.REAL
    finally:
        gc.set_threshold(*before)


def test_another_process_with_another_hash_seed_records_the_same_messages(tmp_path) -> None:
    # the determinism of tests/test_plans_hil.py runs both runs in one process, so one hash
    # seed: a set of names iterated into a message would agree with itself there. Here the
    # same plans run in a child `hil run` with another PYTHONHASHSEED (plans that touch the
    # PLC's pulse train, the PR engine, the absolute encoder, capture, SYNC and STO)
    import os
    import subprocess
    import sys

    from tests.test_plans_hil import messages

    names = ["plc_home_md1", "pr_jump_chain", "absolute_overflow", "capture_z",
             "fault_sync_ip", "sto_both"]
    seed = "1" if os.environ.get("PYTHONHASHSEED") != "1" else "2"
    out = tmp_path / "child"
    paths = [str(find_plans([n])[0]) for n in names]  # the same files as here (by name, a
    # child outside the checkout would take the installed plans: another `file` on record)
    cmd = [sys.executable, "-m", "hil.cli", "run", "-q", "-j", "1", "--out", str(out), *paths]
    done = subprocess.run(cmd, env={**os.environ, "PYTHONHASHSEED": seed}, timeout=300,
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]
    for name in names:
        here = run_plan(load_plan(find_plans([name])[0]), BUILTIN, tmp_path / name,
                        reports=False)
        first, second = messages(here.recording), messages(str(out / f"{name}.mcap"))
        assert len(first) == len(second), name
        diff = next((i for i, (a, b) in enumerate(zip(first, second, strict=True)) if a != b),
                    None)
        assert diff is None, f"{name}: message {diff} differs: {first[diff]} vs {second[diff]}"


def _brkr_edge_after_son_ns(res) -> int:
    """From the recording: the DI1 (SON) rise to the DO6 (BRKR) rise, in bench ns."""
    rises: dict[str, int] = {}
    with open(res.recording, "rb") as f:
        for _, ch, m in make_reader(f).iter_messages():
            line = ch.topic.rsplit("/", 1)[-1]
            if ch.topic.startswith("/dio/") and line in ("DI1", "DO6") \
                    and json.loads(m.data).get("level"):
                rises.setdefault(line, m.log_time)
    return rises["DO6"] - rises["DI1"]


def test_wait_until_takes_its_last_look_at_the_deadline_not_after(tmp_path) -> None:
    """helper-131: `wait_until` slept a whole poll (1 ms) past its timeout and then passed
    on a condition met after it: BRKR at 2 ms passed a 1.5 ms timeout. Met before the
    timeout it passes; met after it, it fails, whatever the poll period."""
    def run(timeout_us: int, out: str):
        plan = loads_plan("name: wu\nsteps:\n  - di: {SON: on}\n"
                          f"  - wait_until: {{do: {{BRKR: on}}, timeout: {timeout_us}us}}\n",
                          "wu.yaml")
        return run_plan(plan, BUILTIN, tmp_path / out, reports=False)

    edge_ns = _brkr_edge_after_son_ns(run(50_000, "long"))
    assert edge_ns > 1_000_000  # past the first 1 ms poll, so a poll can overshoot it
    late = run(edge_ns // 1000 - 500, "late")  # the timeout 0.5 ms before the edge
    assert late.steps[1].status == "fail" and "timeout" in late.steps[1].message
    on_time = run(edge_ns // 1000 + 200, "on_time")
    assert on_time.steps[1].status == "pass"


def test_the_safe_state_looks_at_the_brake_at_its_timeout(tmp_path) -> None:
    from hil.units import S

    """helper-131: the brake wait polled every 2 ms and never looked at its deadline, so a
    BRKR that went off exactly at the safe state's timeout was recorded as "still on"; a
    shorter timeout was reported a poll late. Timed from the record of SON off."""
    plan = loads_plan("name: son\nsteps:\n  - di: {SON: on}\n"
                      "  - wait_until: {do: {BRKR: on}, timeout: 1s}\n", "son.yaml")

    def safety(timeout_ns: int, out: str) -> dict[str, tuple[int, dict]]:
        bench = dataclasses.replace(BUILTIN, safe_state=dataclasses.replace(
            BUILTIN.safe_state, timeout_ns=timeout_ns))
        res = run_plan(plan, bench, tmp_path / out, reports=False)
        with open(res.recording, "rb") as f:
            return {json.loads(m.data)["action"].split(" (")[0]: (m.log_time, json.loads(m.data))
                    for _, ch, m in make_reader(f).iter_messages(topics=["/safety"])}

    roomy = safety(3 * S, "roomy")
    t_off = roomy["wait BRKR off"][0] - roomy["DI SON off"][0]
    assert roomy["wait BRKR off"][1]["ok"] and t_off > 500_000
    exact = safety(t_off, "exact")  # the brake engages at the timeout itself: confirmed
    assert exact["wait BRKR off"][1]["ok"], exact["wait BRKR off"][1]
    short = safety(t_off - 500_000, "short")  # 0.5 ms short: reported at the timeout
    assert not short["wait BRKR off"][1]["ok"]
    assert short["wait BRKR off"][0] - short["DI SON off"][0] == t_off - 500_000


def test_a_clock_event_that_hangs_the_safe_state_is_stopped_by_its_watchdog(
        tmp_path, monkeypatch) -> None:
    """helper-131: a step timed out before its event fired; the safe state then ran that
    event, which never returned, in the run's own thread: no watchdog, Ctrl-C and SIGTERM
    ignored (the safe state is shielded), the recording never closed. The safe state now
    runs under a wall-clock watchdog: not confirmed, with why, and a readable recording."""
    from hil.plan import context
    from hil.plan.kinds.waits import Wait
    from hil.record.reader import Recording
    from hil.units import MS

    monkeypatch.setattr(context, "WATCHDOG_GRACE_NS", 500 * MS)
    monkeypatch.setattr(context, "WATCHDOG_FACTOR", 0)

    def hang(self, ctx, step, d):
        def forever() -> None:  # a model bug: an event that never returns
            while True:
                time.sleep(0.001)
        clock.call_later(1e-6, forever)  # due after the step's 1 ns timeout: the safe
        clock.sleep(0.01)                 # state's first SDO runs it

    monkeypatch.setattr(Wait, "run", hang)
    plan = loads_plan("name: hung\nsteps:\n  - wait: 10ms\n    timeout: 1ns\n", "hung.yaml")
    t0 = time.monotonic()
    res = run_plan(plan, BUILTIN, tmp_path, reports=False)
    assert time.monotonic() - t0 < 30
    assert res.status == "error" and res.safe is not None and not res.safe.ok
    rec = Recording.open(res.recording)
    assert rec.metadata()["hil.result"]["safe_state_ok"] == "false"
    safety = [m for _, _, _, m in rec.messages("/safety")]
    assert safety[-1]["action"] == "safe_state_not_confirmed"
    assert any("wall-clock watchdog" in m.get("detail", "") for m in safety)
    # which drive's action hung is on the record (a review, helper-134)
    assert [m["action"] for m in safety if m.get("drive") == "drive1" and not m["ok"]] == [
        "controlword disable_voltage (0x00)"]


@pytest.mark.parametrize("due_s, action", [(0.010001, "safe_state_not_confirmed"),
                                           (0.15, "safe_tail_hung")])
def test_a_passed_plan_whose_safe_state_hung_says_so(tmp_path, monkeypatch, due_s,
                                                     action) -> None:
    """A review (helper-134): a plan that passed and then hung in its safe state said
    "end of plan" as its result's reason (the JUnit's message); and a hang in the 200 ms
    after a safe state that was reached read as the safe state not confirmed."""
    from hil.plan import context
    from hil.plan.context import Outcome
    from hil.plan.kinds.waits import Wait
    from hil.record.reader import Recording
    from hil.units import MS

    monkeypatch.setattr(context, "WATCHDOG_GRACE_NS", 500 * MS)
    monkeypatch.setattr(context, "WATCHDOG_FACTOR", 0)

    def hang(self, ctx, step, d):
        def forever() -> None:
            while True:
                time.sleep(0.001)
        clock.call_later(due_s, forever)  # after the step: it passes
        clock.sleep(0.01)
        return Outcome("ok")

    monkeypatch.setattr(Wait, "run", hang)
    res = run_plan(loads_plan("name: hung\nsteps:\n  - wait: 10ms\n", "hung.yaml"), BUILTIN,
                   tmp_path, reports=False)
    assert res.status == "error" and res.steps[0].status == "pass"
    rec = Recording.open(res.recording)
    result = rec.metadata()["hil.result"]
    assert result["reason"].startswith("safe state not confirmed") and action in result["reason"]
    actions = [m["action"] for _, _, _, m in rec.messages("/safety")]
    assert actions[-1] == action
    assert ("safe_state_reached" in actions) == (action == "safe_tail_hung")
