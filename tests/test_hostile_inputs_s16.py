"""Bad input found in wave 3, session 16: each gets a clear error and the usage exit code."""

from __future__ import annotations

import pytest

from hil.cli import main as hil


def test_hil_drive_state_naming_a_file_is_a_usage_error(tmp_path, capsys):
    """`--state` names a directory; a file there had exited 1 with "[Errno 17] File exists"
    after the drive began to start."""
    f = tmp_path / "state.json"
    f.write_text("{}")
    assert hil(["drive", "--dio", "virtual:s16-state", "--state", str(f)]) == 2
    err = capsys.readouterr().err
    assert f"--state {f}: not a directory" in err and "Errno" not in err
    assert f.read_text() == "{}"  # nothing lost


def test_a_subprocess_drive_that_dies_at_start_is_said_with_its_own_words():
    """`hil drive` ending before "ready": the runner had gone on and reported a timeout or
    "no zenoh peer" later; it now says the exit code and the drive's last lines at once."""
    import subprocess
    import sys

    import pytest

    from hil.virtual.world import SubprocessWorld

    w = SubprocessWorld.__new__(SubprocessWorld)  # only its start-up wait
    w._out = {}
    p = subprocess.Popen([sys.executable, "-c", "print('hil drive: --can x: refused'); "
                          "raise SystemExit(2)"], stdin=subprocess.PIPE,
                         stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        with pytest.raises(RuntimeError, match=r"exited with code 2; output: hil drive: "
                                                r"--can x: refused"):
            w._wait_ready("drive1", p, 20.0)
    finally:
        p.kill()
        p.wait()


BIG = "9" * 400  # no float holds it: float() raised OverflowError inside the check

PLC = """name: t
bench_requires: [virtual, motion, pulse, dio]
steps:
  - plc_program:
      axis: {axis}
      program:
        - {{SPD: {spd}, DRV: "ADR,+,100,Ps", EXT: {ext}}}
        - MD
      expect: {{position: {pos}}}
"""
GOOD = {"axis": "{max_speed: 100000, dog: X0, clr: Y8}", "spd": "1000", "ext": "X1",
        "pos": "100"}


def _check(tmp_path, text: str, capsys, bench: str | None = None) -> tuple[int, str]:
    plan = tmp_path / "p.yaml"
    plan.write_text(text)
    args = ["run", "--check", str(plan)] + (["--bench", bench] if bench else [])
    code = hil(args)
    return code, capsys.readouterr().err


@pytest.mark.parametrize(("field", "value", "said"), [
    ("axis", f"{{max_speed: {BIG}}}", "plc_program.axis.max_speed: 9999"),
    ("spd", BIG, "program[0].SPD: 9999"),
    ("pos", BIG, "plc_program.expect.position: 9999"),
    ("ext", "X00", "program[0].EXT: 'X00': a PLC line"),
    ("axis", "{max_speed: 100000, dog: X00}", "plc_program.axis.dog: error 51"),
    ("axis", "{max_speed: 100000, clr: Y08}", "plc_program.axis.clr: error 53"),
])
def test_hostile_plc_program_values_are_refused_by_the_check(tmp_path, capsys, field,
                                                             value, said):
    """An outside fuzz (session 16): a 400-digit number in a PLC program was a traceback
    (exit 1) from `--check`; X00 / Y08 passed and then named no line the bench drives."""
    assert _check(tmp_path, PLC.format(**GOOD), capsys)[0] == 0
    code, err = _check(tmp_path, PLC.format(**(GOOD | {field: value})), capsys)
    assert code == 2 and "p.yaml:" in err and said in err and "Traceback" not in err


def test_a_mark_on_a_line_with_a_leading_zero_is_refused_by_the_check(tmp_path, capsys):
    """`mark: {line: DI07}` passed the check and the step ended in a raw ValueError."""
    text = ("name: t\nbench_requires: [virtual, motion]\nsteps:\n"
            "  - mark: {width: 3ms, line: DI07}\n")
    code, err = _check(tmp_path, text, capsys)
    assert code == 2 and "p.yaml:4: steps[0].mark.line: 'DI07'" in err


def test_a_gear_ratio_past_a_float_is_refused_by_the_check(tmp_path, capsys):
    """In 1e9 / Out 1e-300 passed the check and the cycle loop raised OverflowError."""
    from hil.paths import fixture

    text = ("name: t\nbench_requires: [virtual, can, motion]\nsteps:\n"
            "  - group: {axes: [axis1, axis2], cycle: 2ms}\n"
            "  - group_gear: {axis: axis2, master: axis1, in: 1000000000, out: 1.0e-300}\n")
    code, err = _check(tmp_path, text, capsys, str(fixture("benches", "virtual-group.yaml")))
    assert code == 2 and "p.yaml:5: steps[1].group_gear.out: ratio In/Out" in err


def test_a_plc_programs_timeout_stops_a_move_that_runs_past_it(tmp_path, capsys):
    """docs/pulse.md: the step fails when the program's time runs out. A 50 s DRV had
    passed a `timeout: 5s` (the time was looked at only between steps)."""
    text = """name: t
bench_requires: [virtual, motion, pulse, dio]
params:
  P1.001: 0x0000
steps:
  - power_cycle: {battery: true}
  - di: {SON: on}
  - wait_until: {do: {BRKR: on}, timeout: 1s}
  - plc_program:
      axis: {max_speed: 100000, start_speed: 500, accel_ms: 50}
      program:
        - {SPD: 10000, DRV: "ADR,+,500000,Ps"}
        - MD
      timeout: 5s
"""
    plan = tmp_path / "p.yaml"
    plan.write_text(text)
    assert hil(["run", "-j", "1", "--out", str(tmp_path / "out"), str(plan)]) == 1
    err = capsys.readouterr().err
    assert "a move ran past the program's time (5 s left at its start)" in err
    # a move inside its time still passes
    plan.write_text(text.replace("500000", "20000"))
    assert hil(["run", "-q", "-j", "1", "--out", str(tmp_path / "out"), str(plan)]) == 0
    # a 32-bit stroke (legal, 001:38) lasts 3 h at 200 kHz: it was planned a ms at a time up
    # front (27 s, 455 MB) and then refused as error 40 "speed too low"; planned up to the
    # program's time, it is the same timeout as any move that runs past it
    plan.write_text(text.replace('{SPD: 10000, DRV: "ADR,+,500000,Ps"}',
                                 '{SPD: 100000, DRV: "ADR,+,2147483647,Ps"}'))
    assert hil(["run", "-j", "1", "--out", str(tmp_path / "out"), str(plan)]) == 1
    err = capsys.readouterr().err
    assert "a move ran past the program's time (5 s left at its start)" in err
    assert "error 40" not in err


def test_a_drive_process_line_reaches_only_the_ground_truth_records():
    """`hil-ctl {"truth": ...}` lines from a `hil drive` process call the recorder's four
    ground-truth methods only: a line naming `close` (or any other method, or not a name) is
    dropped, and so is a line that is not a JSON object, without an exception that would end
    the thread reading the process's output."""
    import json
    import threading

    from hil.virtual.world import TRUTH_METHODS, SubprocessWorld

    calls: list[tuple[str, tuple, dict]] = []

    class Rec:
        def __getattr__(self, name):
            return lambda *a, **kw: calls.append((name, a, kw))

    w = SubprocessWorld.__new__(SubprocessWorld)
    w.rec, w._lock, w._waiting = Rec(), threading.Lock(), {}
    for name in ("close", "flush", "keep_messages", "__class__", "log", [], {"a": 1}, None,
                 "drive_state"):
        w._control_line("drive1", json.dumps({"truth": name, "args": ["drive1", {"t": 1}],
                                              "kw": {"source_t": 5}}))
    for line in ("[1]", "7", '"drive_state"', "null", '{"truth": "drive_state", "args": 5}',
                 '{"truth": "drive_event", "kw": []}', '{"reply": [1]}'):
        w._control_line("drive1", line)  # dropped, the reader goes on
    assert [c[0] for c in calls] == ["drive_state"]
    assert calls[0][1:] == (("drive1", {"t": 1}), {"source_t": 5})
    assert sorted(TRUTH_METHODS) == ["drive_event", "drive_params", "drive_state",
                                     "input_delivery"]


@pytest.mark.parametrize("out", ["Y08", "Y008", "y8", "Y256"])
def test_plc_output_refuses_a_name_the_program_refuses(tmp_path, capsys, out):
    """An outside probe (session 22): `plc_output: {Y08: on}` passed the check and drove a
    line nothing is wired to, while the program and `axis.clr` refuse Y08 (docs/pulse.md)."""
    text = ("name: t\nbench_requires: [virtual, motion, pulse, dio]\nsteps:\n"
            f"  - plc_output: {{{out}: on}}\n")
    code, err = _check(tmp_path, text, capsys)
    assert code == 2 and f"p.yaml:4: steps[0].plc_output.{out}: '{out}': a PLC output" in err
    assert _check(tmp_path, text.replace(out, "Y8"), capsys)[0] == 0


def test_a_negative_data_register_stroke_with_a_direction_is_error_33(tmp_path, capsys):
    """docs/pulse.md: registers are judged with the codes a constant gets; `ADR,+,-1000` is
    33, and `ADR,+,D100` with D100 = -2000 passed the check and ran +2000 (session 22)."""
    text = ("name: t\nbench_requires: [virtual, motion, pulse, dio]\nsteps:\n"
            "  - plc_program:\n      axis: {max_speed: 100000}\n"
            "      program: [{SPD: 20000, DRV: 'ADR,+,D100,Ps'}, MD]\n"
            "      registers: {D100: %d}\n")
    code, err = _check(tmp_path, text % -2000, capsys)
    assert code == 2 and "error 33" in err and "stroke D100 = -2000: a direction +" in err
    assert _check(tmp_path, text % 2000, capsys)[0] == 0


def test_a_line_name_with_a_trailing_newline_is_refused(tmp_path, capsys):
    """A review (session 22): `$` matches before a final newline, so `"Y8\\n"` passed as Y8
    and the run drove a line named "Y8\\n" that nothing is wired to."""
    text = ("name: t\nbench_requires: [virtual, motion, pulse, dio]\nsteps:\n"
            '  - plc_output: {"Y8\\n": on}\n')
    code, err = _check(tmp_path, text, capsys)
    assert code == 2 and "a PLC output" in err
