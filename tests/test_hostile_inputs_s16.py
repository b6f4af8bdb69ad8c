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
