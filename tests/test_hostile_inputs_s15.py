"""Hostile bench, plan and `hil drive --params` values an outside fuzz found crashing or
misread (wave 3, session 15): each is an error naming the file, line and field, exit 2."""

from __future__ import annotations

import json

import pytest

from hil.cli import main as hil
from hil.paths import fixture

BIG = "9" * 400  # an int no float can hold: math.isfinite raised OverflowError


@pytest.mark.parametrize(("old", "new", "field"), [
    ("    options: {}", f"    options: {{sto_both_lost_ms: {BIG}}}", "sto_both_lost_ms"),
    ("      load_inertia: 1.0e-4", f"      load_inertia: {BIG}", "mechanics.load_inertia"),
    ("name: virtual", 'name: "\\ud800"', "name: not valid text"),
])
def test_a_bench_value_that_crashed_is_an_error_at_its_line(tmp_path, capsys, old, new, field):
    text = fixture("benches", "virtual.yaml").read_text()
    assert old in text, old
    bench = tmp_path / "b.yaml"
    bench.write_text(text.replace(old, new, 1))
    assert hil(["run", "--check", "--bench", str(bench), "emgs"]) == 2
    err = capsys.readouterr().err
    assert "b.yaml:" in err and field in err and "Traceback" not in err, err


def test_timing_constants_take_no_int_too_long_for_a_float(tmp_path, capsys):
    text = fixture("benches", "virtual.yaml").read_text()
    assert "\ntiming:" not in text
    bench = tmp_path / "b.yaml"
    bench.write_text(text + f"\ntiming:\n  constants: {{huge: {BIG}}}\n")
    assert hil(["run", "--check", "--bench", str(bench), "emgs"]) == 2
    assert "timing.constants.huge" in capsys.readouterr().err


def test_a_timing_constant_no_spec_defines_is_warned_of_at_its_line(tmp_path, capsys):
    """A misspelt `fw_tl` was ignored without a word: every verdict was judged with the
    spec's default. It is a warning naming the line (not an error: a constant may be for a
    project's own spec that `hil check --spec FILE` reads from the recording)."""
    text = fixture("benches", "virtual.yaml").read_text()
    bench = tmp_path / "b.yaml"
    bench.write_text(text + "\ntiming:\n  constants:\n    tol: 3\n    fw_tl: 4\n")
    line = len(text.splitlines()) + 5
    assert hil(["run", "--check", "--bench", str(bench), "emgs"]) == 0
    err = capsys.readouterr().err
    assert f"warning: {bench}:{line}: timing.constants.fw_tl" in err and "'fw_tol'" in err, err
    assert err.count("warning:") == 1, err  # `tol`, a known name, is not warned of
    bench.write_text(text + "\ntiming:\n  constants: {tol: 3, fw_tol: 4}\n")
    assert hil(["run", "--check", "--bench", str(bench), "emgs"]) == 0
    assert "warning" not in capsys.readouterr().err


@pytest.mark.parametrize("value", ["Infinity", "1.7", "true"])
def test_a_params_file_value_that_is_no_whole_number_is_refused(tmp_path, capsys, value):
    """`hil drive --params`: Infinity crashed (OverflowError), 1.7 became 1, true became 1."""
    from pathlib import Path

    from hil.virtual.cli import ParamsFileError, _load_mapping

    path = tmp_path / "p.json"
    path.write_text(f'{{"P1.042": {value}}}')
    with pytest.raises(ParamsFileError, match=r"P1\.042.*is not an integer"):
        _load_mapping(Path(path))
    path.write_text(json.dumps({"P1.042": 100}))
    assert _load_mapping(Path(path)) == {"P1.042": 100}


@pytest.mark.parametrize(("option", "value"), [("state_publish_ms", 1.0e-9),
                                               ("motion_step_ms", 1.0e-6)])
def test_a_time_option_too_fine_to_finish_is_refused(option, value):
    """state_publish_ms 1e-9 or motion_step_ms 1e-6 passed --check and the plan never ended."""
    from hil.model.options import ModelOptions

    with pytest.raises(ValueError, match=rf"{option}.*at least"):
        ModelOptions.from_dict({option: value})
    ModelOptions.from_dict({option: 1.0})


@pytest.mark.parametrize("di", ["99=1", "0=1"])
def test_hil_drive_di_outside_the_terminals_is_a_usage_error(di, capsys):
    """README: a bad `--di` exits 2; DI99 exited 1."""
    with pytest.raises(SystemExit) as e:  # as argparse exits on a usage error
        hil(["drive", "--dio", "virtual:s15-di", "--di", di])
    assert e.value.code == 2
    assert "DI1 ~ DI10" in capsys.readouterr().err


@pytest.mark.parametrize(("text", "shown"), [("P1.042: 010", "'010'"), ("P1.042: 1:40", "'1:40'")])
def test_a_yaml_1_1_octal_or_base_60_number_is_refused_not_misread(tmp_path, capsys, text,
                                                                  shown):
    """YAML 1.1 reads 010 as 8 and 1:40 as 100: a plan or bench meant something else and
    the drive got that silently (an outside fuzz)."""
    plan = tmp_path / "p.yaml"
    plan.write_text(f"name: p\nparams: {{{text}}}\nsteps:\n  - wait: 1ms\n")
    assert hil(["run", "--check", str(plan)]) == 2
    err = capsys.readouterr().err
    assert "p.yaml:2: params.P1.042: " + shown in err and "YAML 1.1" in err
    plan.write_text("name: p\nparams: {P1.042: 0x0A}\nsteps:\n  - wait: 1ms\n")
    assert hil(["run", "--check", str(plan)]) == 0  # hex stays a number


@pytest.mark.parametrize("values", [{"motor_inertia": -1e-4}, {"brake_release_ms": -5.0},
                                    {"brake_engage_ms": -1.0}, {"rated_current": 0.0},
                                    {"counts_per_rev": 1.5}, {"brake_holding_torque": -1.0}])
def test_mechanics_that_make_no_physical_sense_are_refused(values):
    """A negative inertia or brake time, a zero rated current, a fractional count per turn
    passed --check and ran (an outside fuzz)."""
    from hil.model.mechanics import Mechanics

    with pytest.raises(ValueError, match="Mechanics"):
        Mechanics.from_dict(values)


def test_an_fdbk_table_mapping_from_a_file_is_refused_at_load():
    """`fdbk_table: {a: b}` passed --check and the run failed with KeyError (True, True) and
    'SAFE STATE NOT CONFIRMED' (an outside fuzz): a file names a table."""
    from hil.model.options import ModelOptions

    with pytest.raises(ValueError, match=r"fdbk_table.*table name"):
        ModelOptions.from_dict({"fdbk_table": {"a": "b"}})
    ModelOptions.from_dict({"fdbk_table": "sto_active"})
    table = {(a, b): a and b for a in (True, False) for b in (True, False)}
    assert ModelOptions.from_dict({"fdbk_table": table}).fdbk_table == table


@pytest.mark.parametrize(("extra", "why"), [({"cia402": {"bogus": 1}}, "bogus"),
                                            ({"homing": [1]}, "a mapping"),
                                            ({"homng": {}}, "unknown room 'homng'")])
def test_extra_rooms_are_checked_at_load(extra, why):
    """`extra: {cia402: {bogus: 1}}` or `{homing: [1]}` failed the run with a bare TypeError
    and no line; a misspelled room was ignored (an outside fuzz)."""
    from hil.model.options import ModelOptions

    with pytest.raises(ValueError, match=why):
        ModelOptions.from_dict({"extra": extra})
    ModelOptions.from_dict({"extra": {"capture": {"trigger": "Z"}}})  # capture_z's


@pytest.mark.parametrize("name", ["", "a\nready", "x" * 100, "a/b"])
def test_hil_drive_name_is_a_topic_segment(name, capsys):
    """`--name` took an empty name, a newline (which split the `ready` line), 100k
    characters (an outside fuzz)."""
    with pytest.raises(SystemExit) as e:
        hil(["drive", "--dio", "virtual:s15-name", "--name", name])
    assert e.value.code == 2
    assert "--name" in capsys.readouterr().err
