"""`hil export`: the format comes from the -o extension, as python-can reads files by it
(issue 12); `-f` must agree with it; `-o -` is stdout for the text formats."""

from __future__ import annotations

import subprocess
import sys

import can
from rec_helpers import make

from hil.cli import main as hil

IDS = [0x123, 0x1ABCDEF0, 0x701, 0x181, 0x181]


def test_blf_extension_without_format_writes_blf(tmp_path):
    p = make(tmp_path / "a.mcap")
    out = tmp_path / "x.blf"
    assert hil(["export", str(p), "-o", str(out)]) == 0
    back = list(can.BLFReader(out))
    assert [m.arbitration_id for m in back] == IDS
    assert bytes(back[0].data) == bytes.fromhex("DEADBEEF")


def test_each_extension_is_read_back_by_python_can(tmp_path):
    p = make(tmp_path / "a.mcap")
    for ext in ("log", "asc", "blf", "csv"):
        out = tmp_path / f"x.{ext}"
        assert hil(["export", str(p), "-o", str(out)]) == 0, ext
        assert [m.arbitration_id for m in can.LogReader(out)] == IDS, ext
    assert (tmp_path / "x.log").read_text().startswith("(1700000000.123456) can0 123#DEADBEEF\n")


def test_format_and_extension_disagree_or_unknown(tmp_path, capsys):
    p = make(tmp_path / "a.mcap")
    assert hil(["export", str(p), "-f", "candump", "-o", str(tmp_path / "x.blf")]) == 2
    assert "names a blf file but -f is candump" in capsys.readouterr().err
    assert hil(["export", str(p), "-o", str(tmp_path / "x.txt")]) == 2
    assert "cannot tell the format from '.txt'" in capsys.readouterr().err
    assert not (tmp_path / "x.blf").exists() and not (tmp_path / "x.txt").exists()
    # -f names the format where the extension says nothing
    assert hil(["export", str(p), "-f", "candump", "-o", str(tmp_path / "x.txt")]) == 0
    assert (tmp_path / "x.txt").read_text().count("\n") == len(IDS)


def test_dash_is_stdout(tmp_path, monkeypatch):
    p = make(tmp_path / "a.mcap")
    monkeypatch.chdir(tmp_path)
    res = subprocess.run([sys.executable, "-m", "hil.cli", "export", str(p), "-o", "-"],
                         capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    assert res.stdout.splitlines()[0] == "(1700000000.123456) can0 123#DEADBEEF"
    assert len(res.stdout.splitlines()) == len(IDS)
    assert "5 frames -> stdout (candump)" in res.stderr
    assert not (tmp_path / "-").exists()
    res = subprocess.run([sys.executable, "-m", "hil.cli", "export", str(p), "-o", "-",
                          "-f", "asc"], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    assert "123" in res.stdout and "Begin Triggerblock" in res.stdout
    res = subprocess.run([sys.executable, "-m", "hil.cli", "export", str(p), "-o", "-",
                          "-f", "blf"], capture_output=True, timeout=60)
    assert res.returncode == 2 and res.stdout == b""
    assert b"BLF is binary" in res.stderr


def test_trc_is_written_and_read_back(tmp_path):
    """PCAN .trc, which python-can reads and writes (TRCReader / TRCWriter)."""
    p = make(tmp_path / "a.mcap")
    out = tmp_path / "x.trc"
    assert hil(["export", str(p), "-o", str(out)]) == 0
    back = list(can.LogReader(out))  # TRC has no remote or error frames: the data frames
    assert [m.arbitration_id for m in back] == [0x123, 0x1ABCDEF0, 0x181]
    assert bytes(back[0].data) == bytes.fromhex("DEADBEEF")


def test_mf4_names_its_missing_package_or_is_written(tmp_path, capsys):
    p = make(tmp_path / "a.mcap")
    code = hil(["export", str(p), "-o", str(tmp_path / "x.mf4")])
    try:
        import asammdf  # noqa: F401
    except ImportError:
        assert code == 2
        assert "pip install 'hil[mf4]'" in capsys.readouterr().err
    else:
        assert code == 0
    assert hil(["export", str(p), "-f", "mf4", "-o", "-"]) == 2


def test_a_frame_at_time_zero_keeps_its_time(tmp_path):
    """The .mcap writer: 0.0 is a time (a converted log's start), not "now"."""
    out = tmp_path / "zero.mcap"
    with can.Logger(str(out)) as log:
        log.on_message_received(can.Message(arbitration_id=0x181, data=b"\x01", timestamp=0.0))
        log.on_message_received(can.Message(arbitration_id=0x181, data=b"\x02", timestamp=1.5))
    stamps = [m.timestamp for m in can.LogReader(str(out))]
    assert stamps == [0.0, 1.5]


def test_a_hostile_bus_name_stays_one_candump_token():
    """A recording's bus name reaches `candump -L` lines (and a terminal with `-o -`): a
    space would split the line, an escape sequence would act on the terminal."""
    import can

    from hil.record.export_cli import candump_line

    msg = can.Message(timestamp=1.5, arbitration_id=0x123, data=b"\x01", is_extended_id=False)
    assert candump_line("can0", msg) == "(1.500000) can0 123#01"
    line = candump_line("a b\x1b[2J\n", msg)
    assert line == "(1.500000) a_b__2J_ 123#01" and "\x1b" not in line
    assert candump_line("", msg) == "(1.500000) _ 123#01"
