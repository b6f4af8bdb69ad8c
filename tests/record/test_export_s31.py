"""`hil export` says what it did not write (helper-137, session 31): a frame the format
cannot carry is counted, never reported as written; a field of the wrong type is a frame
of the wrong shape, not another kind of frame; a recording without CAN traffic writes no
empty file."""

from __future__ import annotations

import json

import can
from rec_helpers import T0, copy_mcap, frame, make

from hil.cli import main as hil
from hil.record.recorder import Recorder


def test_trc_counts_the_remote_and_fd_frames_it_cannot_write(tmp_path, capsys) -> None:
    p = make(tmp_path / "a.mcap")  # 5 frames: std, ext, RTR (guarding), FD, empty
    out = tmp_path / "x.trc"
    assert hil(["export", str(p), "-o", str(out)]) == 0
    io = capsys.readouterr()
    assert "3 frames -> " in io.out
    assert "1 frame(s) not exported: python-can's TRC writer cannot carry remote frames" in io.err
    assert "1 frame(s) not exported: python-can's TRC writer cannot carry CAN FD frames" in io.err
    assert [m.arbitration_id for m in can.LogReader(out)] == [0x123, 0x1ABCDEF0, 0x181]


def test_blf_leaves_out_a_frame_whose_time_it_cannot_encode(tmp_path, capsys) -> None:
    p = tmp_path / "t.mcap"
    with Recorder(p) as rec:
        rec.can("can0", frame(0x180, "00"), "rx", 0, None)  # legal uint64 log times, both
        rec.can("can0", frame(0x181, "01"), "rx", T0, None)
        rec.can("can0", frame(0x182, "02"), "rx", 2**64 - 1, None)  # 2**64 ns after the first
        rec.can("can0", frame(0x183, "03"), "rx", T0 + 1_000_000, None)
    out = tmp_path / "t.blf"
    assert hil(["export", str(p), "-o", str(out)]) == 0  # was: struct.error, a traceback
    io = capsys.readouterr()
    assert "3 frames -> " in io.out
    assert "1 frame(s) not exported: the BLF format cannot carry their times" in io.err
    back = list(can.BLFReader(out))
    assert [m.arbitration_id for m in back] == [0x180, 0x181, 0x183]
    assert abs(back[2].timestamp - (T0 + 1_000_000) / 1e9) < 1e-3


def test_a_flag_recorded_as_text_is_a_frame_of_the_wrong_shape(tmp_path, caplog) -> None:
    """"ext": "false" had been exported as an extended frame, "rtr": "false" as an RTR,
    "id": 1.5 as 001."""
    src = make(tmp_path / "a.mcap")
    bad = {0x123: ("ext", "false"), 0x701: ("rtr", "false"), 0x181: ("id", 1.5)}

    def spoil(topic, data, lt):
        if topic.startswith("/can/"):
            obj = json.loads(data)
            key_value = bad.get(obj["id"])
            if key_value is not None and lt != T0 + 3_000_000:  # the FD 0x181 stays whole
                obj[key_value[0]] = key_value[1]
                data = json.dumps(obj).encode()
        return data, lt

    p = copy_mcap(src, tmp_path / "b.mcap", spoil) or tmp_path / "b.mcap"
    out = tmp_path / "b.log"
    assert hil(["export", str(p), "-o", str(out)]) == 0
    assert "3 message(s) of a wrong shape skipped" in caplog.text
    assert "not true or false" in caplog.text
    lines = out.read_text().splitlines()
    assert [ln.split()[2] for ln in lines] == ["1ABCDEF0#01", "181##10011"]


def test_no_can_traffic_writes_no_empty_file(tmp_path, capsys) -> None:
    p = tmp_path / "io.mcap"
    with Recorder(p) as rec:
        rec.dio("io", "DI1", True, T0, None)
    out = tmp_path / "io.log"
    assert hil(["export", str(p), "-o", str(out)]) == 2
    assert "no CAN bus recorded: nothing to export" in capsys.readouterr().err
    assert not out.exists()
