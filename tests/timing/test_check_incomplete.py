"""`hil check` never passes what it did not judge (issue 12): a damaged recording, a spec that
found no data, or a file that is not a hil recording each get their own exit code and a reason.

Exit codes: 0 pass, 1 fail, 2 bad input, 3 inconclusive, 4 incomplete (nothing judged).
"""

from __future__ import annotations

import struct
from pathlib import Path

import pytest
from mcap.writer import Writer

from hil.bench.bench import load_bench
from hil.cli import main as hil
from hil.plan.plan import find_plans, load_plan
from hil.plan.runner import run_plan


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    """A real plan recording from the virtual bench (servo on/off with the brake)."""
    out = tmp_path_factory.mktemp("rec")
    result = run_plan(load_plan(find_plans(["servo_on_off_brake"])[0]), load_bench(None), out)
    assert result.passed
    return Path(result.recording)


def chunk_offsets(data: bytes) -> list[int]:
    """File offsets of the MCAP chunk records (opcode 0x06), in file order."""
    off, out = 8, []
    while off + 9 <= len(data):
        op, ln = struct.unpack_from("<BQ", data, off)
        if op == 0x06:
            out.append(off)
        if op == 0x02:  # footer
            break
        off += 9 + ln
    return out


def data_end(data: bytes) -> int:
    """File offset of the MCAP Data End record (opcode 0x0F): every chunk lies before it."""
    off = 8
    while off + 9 <= len(data):
        op, ln = struct.unpack_from("<BQ", data, off)
        if op == 0x0F:
            return off
        off += 9 + ln
    raise AssertionError("no Data End record")


def corrupt(src: Path, dst: Path, which: int) -> int:
    """Copy `src` to `dst` with ten bytes of chunk number `which` inverted; its offset."""
    data = bytearray(src.read_bytes())
    off = chunk_offsets(bytes(data))[which]
    for i in range(off + 80, off + 90):  # inside the compressed records, past the header
        data[i] ^= 0xFF
    dst.write_bytes(bytes(data))
    return off


def test_intact_recording_passes(recording, capsys):
    assert hil(["check", str(recording)]) == 0


def test_corrupt_first_chunk_judges_nothing_and_says_where(recording, tmp_path, capsys):
    bad = tmp_path / "bad.mcap"
    off = corrupt(recording, bad, 0)
    assert hil(["check", str(bad)]) == 4
    err = capsys.readouterr().err
    assert f"chunk at offset {off} unreadable" in err
    assert "nothing was judged" in err


def test_corrupt_middle_chunk_is_incomplete_not_pass(recording, tmp_path, capsys):
    """Verdicts before the damage passed, but what followed it was never read."""
    assert len(chunk_offsets(recording.read_bytes())) > 2
    bad = tmp_path / "bad.mcap"
    off = corrupt(recording, bad, 1)
    assert hil(["check", str(bad)]) == 4
    assert f"damaged: chunk at offset {off}" in capsys.readouterr().err


def test_no_damaged_chunk_turns_the_passing_run_into_a_fail_or_a_pass(recording, tmp_path,
                                                                         capsys):
    """Whichever chunk is lost (the recorder closes one every 50 ms of wall time, so which
    events share a chunk varies from run to run), what was lost is unknown, not absent: an
    event expected after the damage is inconclusive, never a FAIL, and the run incomplete."""
    n = len(chunk_offsets(recording.read_bytes()))
    codes = {}
    for which in range(n):
        bad = tmp_path / f"bad{which}.mcap"
        corrupt(recording, bad, which)
        codes[which] = hil(["check", str(bad)])
        capsys.readouterr()
    assert set(codes.values()) == {4}, codes


def test_spec_without_data_is_not_a_pass(recording, capsys):
    """The brake recording has no STO event: `--spec sto` judges nothing."""
    assert hil(["check", str(recording), "--spec", "sto"]) == 4
    err = capsys.readouterr().err
    assert "incomplete: spec sto: nothing to judge" in err


def test_spec_whose_signals_have_no_data_names_them(tmp_path, capsys):
    """A hil recording with only a CAN bus: the brake spec finds no DI/DO data at all."""
    import can

    from hil.record.recorder import Recorder

    p = tmp_path / "can_only.mcap"
    with Recorder(p) as rec:
        rec.can("can0", can.Message(arbitration_id=0x181, data=b"\0"), "rx", 1_000_000, None)
    assert hil(["check", str(p), "--spec", "servo_on_brake", "--bind", "dio=drive1"]) == 4
    err = capsys.readouterr().err
    assert "spec servo_on_brake: found no data for signal SON: no data on /dio/drive1/DI1" in err


def test_not_a_hil_recording(tmp_path, capsys):
    p = tmp_path / "other.mcap"
    with open(p, "wb") as f:
        w = Writer(f)
        w.start()
        sid = w.register_schema("geometry.Pose", "jsonschema", b"{}")
        cid = w.register_channel("/pose", "json", sid)
        w.add_message(cid, log_time=1, publish_time=1, data=b"{}")
        w.finish()
    assert hil(["check", str(p)]) == 2
    err = capsys.readouterr().err
    assert "not a hil recording: no hil.run metadata and no hil.* channels" in err
    assert "/pose" in err


def test_not_an_mcap_file(tmp_path, capsys):
    p = tmp_path / "notes.mcap"
    p.write_text("hello")
    assert hil(["check", str(p)]) == 2
    assert f"{p}: not an MCAP file" in capsys.readouterr().err


def test_cut_recording_of_a_killed_run_is_incomplete_not_pass(recording, tmp_path, capsys):
    """`kill -9` of a run leaves the chunks written so far and no summary or footer
    (docs/recording.md, crash safety). What the plan did after the cut was never recorded:
    exit 4 with the reason, as for a damaged chunk, not a silent pass."""
    data = recording.read_bytes()
    offsets = chunk_offsets(data)
    # how many chunks the writer made depends on the wall clock (its flush interval), so on
    # a loaded host there may be only one or two: cut after every chunk (the summary and
    # footer lost), and after two whole chunks where there are more
    cuts = [data_end(data)] + ([offsets[2]] if len(offsets) > 2 else [])
    assert offsets and cuts[0] > offsets[-1]
    for at in cuts:
        cut = tmp_path / "cut.mcap"
        cut.write_bytes(data[:at])
        assert hil(["check", str(cut)]) == 4
        assert "truncated (no footer" in capsys.readouterr().err


def test_a_damaged_chunk_cuts_the_source_where_messages_may_be_missing(tmp_path):
    """One message per chunk, each published 5 ms before it was logged; chunk 5 (logged at
    60 ms) unreadable: nothing published from 55 ms on is judged, as a message published
    then may have been in the lost chunk."""
    import json
    import os

    from hil.timing.source import RecordingSource

    path = tmp_path / "cut.mcap"
    with open(path, "wb") as f:
        w = Writer(f, chunk_size=1)
        w.start()
        sid = w.register_schema("hil.Any", "jsonschema", b'{"type": "object"}')
        cid = w.register_channel("/x", "json", sid, {})
        for k in range(1, 11):
            t = k * 10_000_000
            data = json.dumps({"v": k, "pad": os.urandom(120).hex()}).encode()
            w.add_message(cid, log_time=t, publish_time=t - 5_000_000, data=data)
        w.finish()
    chunks = chunk_offsets(path.read_bytes())
    assert len(chunks) == 10
    bad = tmp_path / "bad.mcap"
    corrupt(path, bad, 5)
    src = RecordingSource(bad)
    assert src.corrupt and src.cut_ns == 55_000_000
    assert [m["v"] for _t, m in src.messages("/x")] == [1, 2, 3, 4, 5]
    assert RecordingSource(path).cut_ns is None  # a whole file is not cut


def _with_message(src: Path, dst: Path, topic: str, nth: int, payload: bytes) -> None:
    """`src` copied to `dst` with the `nth` message of `topic` (1-based) replaced."""
    from mcap.reader import make_reader
    from mcap.writer import CompressionType
    from mcap.writer import Writer as McapWriter

    with open(src, "rb") as f:
        r = make_reader(f)
        summ = r.get_summary()
        msgs = [(ch.topic, m.channel_id, m.log_time, m.publish_time, m.data)
                for _s, ch, m in r.iter_messages(log_time_order=False)]
        meta = list(r.iter_metadata())
    with open(dst, "wb") as out:
        w = McapWriter(out, compression=CompressionType.ZSTD)
        w.start(profile="", library="test")
        smap = {sid: w.register_schema(s.name, s.encoding, s.data)
                for sid, s in summ.schemas.items()}
        cmap = {cid: w.register_channel(c.topic, c.message_encoding, smap.get(c.schema_id, 0),
                                        c.metadata) for cid, c in summ.channels.items()}
        for m in meta:
            w.add_metadata(m.name, m.metadata)
        k = 0
        for t, cid, lt, pt, data in msgs:
            if t == topic:
                k += 1
                if k == nth:
                    data = payload
            w.add_message(cmap[cid], lt, data, pt)
        w.finish()
    assert k >= nth


@pytest.mark.parametrize("payload", [b'{"level": fal', b"[]", b"5"])
def test_a_broken_message_on_a_judged_signal_makes_the_check_incomplete(
        recording, tmp_path, capsys, payload):
    """An outside probe (session 23): a broken DI/DO message was dropped from the signal it
    belonged to and `hil check` still passed (exit 0, nothing said), with fewer verdicts."""
    assert hil(["check", str(recording)]) == 0
    capsys.readouterr()
    bad = tmp_path / "bad.mcap"
    _with_message(recording, bad, "/dio/drive1/DI1", 2, payload)
    assert hil(["check", str(bad)]) == 4
    err = capsys.readouterr().err
    assert "1 message(s) of a wrong shape" in err and str(bad) in err
