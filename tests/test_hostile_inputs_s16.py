"""Bad input found in wave 3, session 16: each gets a clear error and the usage exit code."""

from __future__ import annotations

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
