"""The shipped plans on the built-in virtual bench (real model, faces, pty, virtual buses)."""

from __future__ import annotations

import io

import pytest

from hil.bench.bench import load_bench
from hil.plan.plan import find_plans, load_plan, loads_plan
from hil.plan.runner import run_plans
from hil.record import topics as T
from hil.record.reader import Recording

# the built-in virtual bench in virtual time: deterministic, never rerun (conftest.py)
pytestmark = [pytest.mark.integration, pytest.mark.virtual_time]

PASSING = ["servo_on_off_brake", "param_access", "sto_both", "sto_short_dropout", "pp_move",
           "cia402_power_states", "servo_brake_settings", "alarm_reset", "limit_switches",
           "pv_move", "sto_single_channel"]


@pytest.mark.parametrize("name", PASSING)
def test_shipped_plan_passes(tmp_path, name):
    # inconclusive allowed, as on a real bench (this runs in virtual time: none is expected);
    # a fail is never allowed
    [r] = run_plans([load_plan(p) for p in find_plans([name])], load_bench(), tmp_path,
                    stream=io.StringIO(), allow_inconclusive=True)
    assert r.passed, [(s.label, s.status, s.message) for s in r.steps if s.status != "pass"]
    rec = Recording.open(r.recording)
    assert rec.counts().get(T.drive_state("drive1"), 0) > 0  # ground truth recorded


def test_failing_plan_on_the_model_records_the_safe_state(tmp_path):
    plan = loads_plan("name: broken\nparams: {P1.042: 100}\nsteps:\n  - di: {SON: on}\n"
                      "  - wait_until: {do: {BRKR: on}, timeout: 30ms}\n  - wait: 1s\n",
                      str(tmp_path / "broken.yaml"))
    [r] = run_plans([plan], load_bench(), tmp_path, stream=io.StringIO())
    assert r.status == "fail" and r.steps[1].status == "fail"
    assert r.steps[2].status == "skipped"
    rec = Recording.open(r.recording)
    safety = [m for _, _, _, m in rec.messages(T.SAFETY)]
    assert {"controlword disable_voltage (0x00)", "DI SON off"} <= {m["action"] for m in safety}
    assert safety[-1]["action"] == "safe_state_reached"
    # the model confirms: servo off and brake engaged at the end
    last = [m for _, _, _, m in rec.messages(T.drive_state("drive1"))][-1]
    assert last["servo_on"] is False and last["brkr"] is False


def test_the_drive_under_test_is_recorded_and_reported(tmp_path):
    """OpenHTF's dut_id: the bench's name for the drive, P0.000 firmware (the virtual drive
    reports 100, not 0) and the 1018h identity, in the metadata, the report and the index."""
    from hil.report.html import write_html
    from hil.report.index import write_index

    plan = load_plan(find_plans(["servo_on_off_brake"])[0])
    [r] = run_plans([plan], load_bench(None), tmp_path, stream=io.StringIO())
    dut = Recording.open(r.recording).metadata()["hil.dut"]
    assert dut["drive1.firmware"] == "100"
    assert dut["drive1.vendor_id"] == "0x000001DD"  # Delta (1018h sub 1, L17778-17784)
    assert dut["drive1.product_code"] == "0x00006000"
    html = write_html(r.recording, tmp_path / "p.html").read_text()
    assert "drive1 fw 100 1018h 000001DD/00006000" in html
    index = write_index([r.recording], tmp_path / "index.html").read_text()
    assert "drive1 fw 100" in index


def test_a_failed_timing_check_is_an_error_on_the_log_with_its_line(tmp_path):
    """A check_timing step's failure reaches /log (Foxglove's Log panel) at error level with
    the plan's file and line, as a failing expect does, though the plan goes on after it
    (an outside review found only safety lines there)."""
    text = (find_plans(["servo_on_off_brake"])[0].read_text()
            .replace("steps:\n", "options: {dev_brake_on_delay_ms: 5}\nsteps:\n", 1))
    plan = loads_plan(text, str(tmp_path / "brake.yaml"))
    [r] = run_plans([plan], load_bench(None), tmp_path, stream=io.StringIO())
    assert not r.passed
    errors = [m for *_t, m in Recording.open(r.recording).messages([T.LOG])
              if m["level"] >= 4]
    assert any("check_timing servo_on_brake" in m["message"] and m["line"] == 19
               and m["file"].endswith("brake.yaml") for m in errors), errors


def test_the_safe_state_reads_the_statusword_back_and_a_check_judges_it(tmp_path):
    """The safe state wrote disable voltage (6040h = 0) and read nothing back, so on the
    recording of a run that enabled the drive `cia402_transitions` judged "never reached
    SWITCH ON DISABLED": the last 6041h on the wire said OPERATION ENABLED (an outside
    probe). It now reads 6041h until the power stage is off and says what it read."""
    from hil.paths import fixture
    from hil.timing.checker import check
    from hil.timing.source import RecordingSource
    from hil.timing.spec import load_spec

    plan = loads_plan("name: enabled\nsteps:\n  - state: OPERATION ENABLED\n  - wait: 50ms\n",
                      str(tmp_path / "enabled.yaml"))
    [r] = run_plans([plan], load_bench(), tmp_path, stream=io.StringIO())
    assert r.passed
    rec = Recording.open(r.recording)
    safety = [m for _, _, _, m in rec.messages(T.SAFETY)]
    [read] = [m for m in safety if m["action"] == "statusword: power stage off"]
    assert read["ok"] and read["detail"].endswith("SWITCH ON DISABLED"), read
    spec = load_spec(fixture("timing", "cia402_transitions.yaml"))
    verdicts = check(spec, RecordingSource(r.recording), binding={"bus": "can0"})
    disable = [v for v in verdicts if v.constraint.startswith("transitions 7/9/10/12")]
    assert [v.status for v in disable] == ["pass"], [(v.status, v.message) for v in disable]


def test_a_plan_that_leaves_the_bench_unsafe_does_not_pass(tmp_path):
    """Every step passed, but the safe state could not be confirmed (DO6 no longer carries
    BRKR: the brake wait times out): the plan said PASS and `hil run` exited 0 (an outside
    probe). A plan passes only if it leaves the bench in its safe state."""
    plan = loads_plan("name: remap\nsteps:\n  - write: {P2.041: 0x0101}\n  - di: {SON: on}\n"
                      "  - wait: 200ms\n", str(tmp_path / "remap.yaml"))
    [r] = run_plans([plan], load_bench(), tmp_path, stream=io.StringIO())
    assert all(s.status == "pass" for s in r.steps)
    assert r.status == "error" and "safe state not confirmed" in r.error, r.error
    meta = Recording.open(r.recording).metadata()["hil.result"]
    assert meta["status"] == "error" and meta["safe_state_ok"] == "false", meta


def test_a_quick_stop_safe_state_ramps_then_disables_voltage(tmp_path):
    """`safe_state.controlword: quick_stop` on a drive that stays in QUICK STOP ACTIVE after
    its ramp (the A3: transition 12 is a command, L18262): the safe state waits for the ramp,
    then writes disable voltage, and confirms the power stage off and the brake engaged."""
    from hil.paths import fixture

    text = fixture("benches", "virtual.yaml").read_text(encoding="utf-8")
    bench_file = tmp_path / "qs.yaml"
    bench_file.write_text(text.replace("  controlword: disable_voltage\n",
                                       "  controlword: quick_stop\n", 1), encoding="utf-8")
    plan = loads_plan("name: spinning\nsteps:\n  - state: OPERATION ENABLED\n"
                      "  - move: {mode: PV, velocity: 10000}\n  - wait: 300ms\n",
                      str(tmp_path / "spinning.yaml"))
    [r] = run_plans([plan], load_bench(bench_file), tmp_path, stream=io.StringIO())
    assert r.passed, (r.status, r.error)
    rec = Recording.open(r.recording)
    safety = [(t, m) for _, t, _, m in rec.messages(T.SAFETY)]
    actions = [m["action"] for _, m in safety]
    i = actions.index("controlword quick_stop (0x02)")
    assert actions[i + 1:i + 4] == [
        "quick stop ramp ended", "controlword disable_voltage (0x00) after the quick stop "
        "(transition 12)", "statusword: power stage off"]
    assert actions[-1] == "safe_state_reached"
    # the ramp was waited for: the motor ran down from 1000 rpm with the servo on, and was
    # at rest, the servo still on, when the disable voltage went out
    t_qs, t_end = safety[i][0], safety[i + 1][0]
    states = [(t, m) for _, t, _, m in rec.messages(T.drive_state("drive1"))]
    during = [m for t, m in states if t_qs <= t <= t_end]
    assert any(abs(m["speed_rpm"]) > 100 and m["servo_on"] for m in during)
    at_end = [m for t, m in states if t <= t_end][-1]
    assert abs(at_end["speed_rpm"]) <= 10 and at_end["servo_on"]
    last = [m for _, _, _, m in rec.messages(T.drive_state("drive1"))][-1]
    assert last["servo_on"] is False and last["brkr"] is False
