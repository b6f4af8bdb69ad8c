"""`hil inspect`, `hil export` and the python-can `.mcap` plugin."""

from __future__ import annotations

import os
import subprocess
import sys

import can
import pytest
from rec_helpers import make

from hil.cli import main as hil
from hil.record.canio import McapCanReader, McapCanWriter
from hil.record.export_cli import candump_line
from hil.record.reader import Recording


def test_inspect_prints_summary(tmp_path, capsys):
    p = make(tmp_path / "a.mcap")
    assert hil(["inspect", str(p)]) == 0
    out = capsys.readouterr().out
    assert "complete: footer and summary present" in out
    assert "/can/can0/raw" in out and "hil.CanFrame" in out
    assert "largest gaps: 497.000 ms" in out
    assert "drops: 0" in out


def test_inspect_truncated_and_repair(tmp_path, capsys):
    p = make(tmp_path / "a.mcap")
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(p.read_bytes()[: p.stat().st_size - 200])
    out_p = tmp_path / "fixed.mcap"
    assert hil(["inspect", str(cut), "--repair", str(out_p)]) == 0
    out = capsys.readouterr().out
    n = sum(Recording.open(p).counts().values())
    assert "TRUNCATED" in out and f"repaired: {n} messages" in out
    r = Recording.open(out_p)
    assert not r.truncated and sum(r.counts().values()) == n


def test_repair_onto_its_input_is_refused_before_anything_is_read(tmp_path, capsys):
    """An output that names the input is refused before the file is read (it printed the
    whole summary first), in any spelling: here a link."""
    p = make(tmp_path / "a.mcap")
    link = tmp_path / "link.mcap"
    link.symlink_to(p)
    before = p.read_bytes()
    assert hil(["inspect", str(p), "--repair", str(link)]) == 2
    cap = capsys.readouterr()
    assert "is the input" in cap.err and "complete:" not in cap.out
    assert p.read_bytes() == before


def test_inspect_and_repair_read_a_message_at_a_time(tmp_path, monkeypatch, capsys):
    """`hil inspect` and `--repair` never hold the recording whole (a killed run of hours):
    the summary is the one a whole read gives, and the repaired file has every readable
    message, channel by channel."""
    from hil.record.cli import summarise

    p = make(tmp_path / "a.mcap")
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(p.read_bytes()[: p.stat().st_size - 200])
    want = {f: summarise(Recording.open(f)) for f in (p, cut)}
    whole = [(t, lt, pt, bytes(d)) for t, lt, pt, d in Recording.open(cut).raw_messages()]

    def banned(*_a, **_k):
        raise AssertionError("read whole")

    with monkeypatch.context() as m:
        m.setattr(Recording, "open", classmethod(banned))
        for f in (p, cut):
            assert hil(["inspect", str(f)]) == 0
            assert capsys.readouterr().out.strip() == want[f]
        fixed = tmp_path / "fixed.mcap"
        assert hil(["inspect", str(cut), "--repair", str(fixed)]) == 0
    assert f"repaired: {len(whole)} messages" in capsys.readouterr().out
    back = Recording.open(fixed)
    assert not back.truncated
    assert [(t, lt, pt, bytes(d)) for t, lt, pt, d in back.raw_messages()] == whole


def test_inspect_unreadable_names_the_file(tmp_path, capsys):
    bad = tmp_path / "notes.txt"
    bad.write_text("hello")
    assert hil(["inspect", str(bad)]) == 2
    assert f"{bad}: not an MCAP file" in capsys.readouterr().err
    assert hil(["inspect", str(tmp_path / "missing.mcap")]) == 2
    assert "missing.mcap: cannot read" in capsys.readouterr().err


def test_export_candump(tmp_path, capsys):
    p = make(tmp_path / "a.mcap")
    out = tmp_path / "a.log"
    assert hil(["export", str(p), "--format", "candump", "-o", str(out)]) == 0
    assert out.read_text().splitlines() == [
        "(1700000000.123456) can0 123#DEADBEEF",
        "(1700000000.124456) can0 1ABCDEF0#01",
        "(1700000000.125456) can1 701#R",
        "(1700000000.126456) can0 181##10011",
        "(1700000000.623456) can0 181#",
    ]
    assert hil(["export", str(p), "-f", "candump", "-o", str(out), "--bus", "can1"]) == 0
    assert out.read_text() == "(1700000000.125456) can1 701#R\n"
    assert hil(["export", str(p), "-f", "candump", "-o", str(out), "--bus", "can9"]) == 2
    assert "bus 'can9'" in capsys.readouterr().err


def test_export_reads_the_recording_a_message_at_a_time(tmp_path, monkeypatch, capsys):
    """`hil export` never holds a recording whole (an hour of a saturated bus is 32 M frames):
    what it writes is what the whole read (`can_messages`) gives, a cut file is exported as far
    as it reads, and a bad `--bus` still leaves no output."""
    from hil.record.canio import can_messages
    from hil.record.export_cli import candump_line as line

    p = make(tmp_path / "a.mcap")
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(p.read_bytes()[: p.stat().st_size - 200])
    want = {f: [line(b, m) for b, m in can_messages(Recording.open(f))] for f in (p, cut)}

    def banned(*_a, **_k):
        raise AssertionError("read whole")

    monkeypatch.setattr(Recording, "open", classmethod(banned))
    for f in (p, cut):
        out = tmp_path / "out.log"
        assert hil(["export", str(f), "-f", "candump", "-o", str(out)]) == 0
        assert out.read_text().splitlines() == want[f] and want[f]
    assert "is truncated" in capsys.readouterr().err  # said of the cut file
    out = tmp_path / "none.log"
    assert hil(["export", str(p), "-f", "candump", "-o", str(out), "--bus", "can9"]) == 2
    assert not out.exists()


def test_candump_error_frame():
    m = can.Message(arbitration_id=0x4, is_error_frame=True, data=bytes(8), timestamp=1.5)
    assert candump_line("can0", m) == "(1.500000) can0 20000004#0000000000000000"


def test_export_python_can_formats_read_back(tmp_path):
    p = make(tmp_path / "a.mcap")
    for fmt in ("asc", "blf", "csv"):
        out = tmp_path / f"a.{fmt}"
        assert hil(["export", str(p), "-f", fmt, "-o", str(out)]) == 0
        back = list(can.LogReader(out))
        assert [m.arbitration_id for m in back] == [0x123, 0x1ABCDEF0, 0x701, 0x181, 0x181], fmt
        assert bytes(back[0].data) == bytes.fromhex("DEADBEEF")


def test_python_can_logger_and_logreader(tmp_path, canio_entry_points):
    p = tmp_path / "pc.mcap"
    writer = can.Logger(p)
    assert isinstance(writer, McapCanWriter)
    sent = [
        can.Message(
            timestamp=1700000000.0 + i / 1000,
            arbitration_id=0x181 + i,
            is_extended_id=False,
            data=bytes([i] * (i % 9)),
            channel="vcan0",
        )
        for i in range(20)
    ]
    with writer:
        for m in sent:
            writer(m)
    reader = can.LogReader(p)
    assert isinstance(reader, McapCanReader)
    back = list(reader)
    assert len(back) == len(sent)
    for a, b in zip(sent, back, strict=True):
        assert a.equals(b, timestamp_delta=1e-6), (a, b)
    assert Recording.open(p).topics()[0] == "/can/vcan0/raw"


def test_logreader_reads_a_frame_at_a_time_and_stops_with_its_caller(tmp_path, monkeypatch):
    """`can.LogReader("x.mcap")` never holds the recording whole: it reads ahead at most a few
    thousand frames on a thread of its own, gives what a whole read gives, and a caller that
    stops early ends that thread."""
    import threading

    from hil.record import canio
    from hil.record.canio import can_messages

    p = tmp_path / "many.mcap"
    with McapCanWriter(p) as w:
        for i in range(3 * canio._AHEAD):
            w(can.Message(timestamp=1700000000.0 + i / 1e4, arbitration_id=0x181 + i % 4,
                          is_extended_id=False, data=i.to_bytes(4, "little"), channel="can0"))
    want = [m for _b, m in can_messages(Recording.open(p))]

    def banned(*_a, **_k):
        raise AssertionError("read whole")

    monkeypatch.setattr(Recording, "open", classmethod(banned))
    got = list(McapCanReader(p))
    assert len(got) == len(want) == 3 * canio._AHEAD
    assert all(a.equals(b, timestamp_delta=1e-9) for a, b in zip(got, want, strict=True))
    it = iter(McapCanReader(p))
    first = [next(it) for _ in range(10)]
    assert first[0].equals(want[0], timestamp_delta=1e-9)
    it.close()  # the caller stops early
    assert not [t for t in threading.enumerate() if t.name == "mcap-can-reader"]
    reader = McapCanReader(p)  # stop() from elsewhere ends the iteration, it never hangs
    it = iter(reader)
    next(it)
    reader.stop()
    rest = list(it)
    assert len(rest) < len(want) - 1
    assert not [t for t in threading.enumerate() if t.name == "mcap-can-reader"]
    with pytest.raises(ValueError, match="can9"):  # a bus not in the file, said at once
        McapCanReader(p, bus="can9")


def test_can_player_replays_an_mcap(tmp_path, canio_entry_points):
    p = make(tmp_path / "a.mcap")
    env = dict(os.environ)
    if canio_entry_points is not None:
        env["PYTHONPATH"] = os.pathsep.join([str(canio_entry_points), env.get("PYTHONPATH", "")])
    res = subprocess.run(
        [
            sys.executable,
            "-m",
            "can.player",
            "-i",
            "virtual",
            "-c",
            "replay",
            "-v",
            "--ignore-timestamps",
            str(p),
        ],
        capture_output=True,
        text=True,
        timeout=60,
        env=env,
        check=False,
    )
    assert res.returncode == 0, res.stderr
    assert "1abcdef0" in res.stdout.lower() and "deadbeef" in res.stdout.lower().replace(" ", "")


def test_repair_makes_its_missing_folders(tmp_path, capsys):
    """As `hil report`, `diff` and `export` do for their outputs (it failed: no such file)."""
    p = make(tmp_path / "a.mcap")
    out = tmp_path / "new" / "dir" / "fixed.mcap"
    assert hil(["inspect", str(p), "--repair", str(out)]) == 0
    assert sum(Recording.open(out).counts().values()) == sum(Recording.open(p).counts().values())
