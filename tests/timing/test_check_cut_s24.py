"""`hil check` and `hil report` of cut, damaged and repaired recordings (helper-85's probe):

1. a repaired copy of a file with a hole mid-file was judged whole: FAIL for events in the hole;
2. a file whose run ended but whose tail was cut (its `hil.result` written, its last chunk
   lost) showed PASS, its last step SKIPPED;
3. a cut chunk starting at the very time of the plan's check records lost those records, and
   `hil check` said the file held none of its checks;
4. a damaged length in a file with its footer read as a killed run;
5. a file cut before its first channel was "not a hil recording" (exit 2), not cut (exit 4).
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import pytest
from mcap.writer import Writer

from hil.cli import main as hil
from hil.record.reader import Recording
from hil.report import data as report_data
from hil.timing.source import RecordingSource
from tests.record.rec_helpers import plan_recording
from tests.timing.test_check_incomplete import chunk_offsets, corrupt, data_end

pytestmark = pytest.mark.virtual_time


@pytest.fixture(scope="module")
def homing(tmp_path_factory) -> Path:
    return plan_recording(tmp_path_factory.mktemp("homing"), "homing_pr")


@pytest.fixture(scope="module")
def emgs(tmp_path_factory) -> Path:
    return plan_recording(tmp_path_factory.mktemp("emgs"), "emgs")


def test_a_repaired_copy_is_judged_only_up_to_its_sources_hole(homing, tmp_path, capsys):
    offs = chunk_offsets(homing.read_bytes())
    bad = tmp_path / "hole.mcap"
    corrupt(homing, bad, len(offs) // 2)  # a chunk mid-file whose CRC fails
    (hole,) = struct.unpack_from("<Q", bad.read_bytes(), offs[len(offs) // 2] + 9)
    fixed = tmp_path / "fixed.mcap"
    assert hil(["inspect", str(bad), "--repair", str(fixed)]) == 0
    capsys.readouterr()
    rep = Recording.open(fixed).metadata()["hil.repair"]
    assert rep["source_damaged"] == "true" and int(rep["source_cut_log_ns"]) == hole
    src = RecordingSource(fixed)
    assert src.cut_kind == "damage" and src.cut_ns <= hole
    assert hil(["check", str(fixed)]) == 4
    out, err = capsys.readouterr()
    assert "FAIL" not in out, out
    assert "incomplete:" in err and "repaired from a damaged" in err
    report_data.forget(fixed)
    run = report_data.load_run(fixed)
    assert run.damage and "repaired from a damaged recording" in run.damage
    assert run.status != "pass"


def _cut_in_the_last_chunk(src: Path, dst: Path) -> None:
    """`src` as a run leaves it when its writer wrote `hil.result` before a chunk still being
    filled and the file was cut inside that chunk: the chunk that holds the last step's end
    record (the chunks close on the writer's wall-clock flush, so the last chunk may hold
    only what came after every step), and all after it lost."""
    data = src.read_bytes()
    off, result = 8, b""
    while off + 9 <= len(data):
        op, ln = struct.unpack_from("<BQ", data, off)
        if op == 0x0C and b"hil.result" in data[off + 9: off + 40]:
            result = data[off: off + 9 + ln]
        if op == 0x02:
            break
        off += 9 + ln
    assert result
    t_end = max(lt for topic, lt, _pt, m in Recording.open(src).messages("/plan/steps")
                if m.get("event") == "end")
    last = next(at for at in chunk_offsets(data)  # the chunk's message_end_time
                if struct.unpack_from("<Q", data, at + 17)[0] >= t_end)
    dst.write_bytes(data[:last] + result + data[last: last + 30])


def test_a_run_that_ended_but_lost_its_tail_is_not_a_pass(emgs, tmp_path):
    cut = tmp_path / "tail.mcap"
    _cut_in_the_last_chunk(emgs, cut)
    meta = Recording.open(cut).metadata()
    assert meta["hil.result"]["status"] == "pass"
    report_data.forget(cut)
    run = report_data.load_run(cut)
    assert run.truncated and run.status == "incomplete"
    assert not [s for s in run.steps if s.status == "skipped" and s.t_start is not None]
    lost = [s for s in run.steps if "tail is lost" in s.message]
    assert lost, [(s.index, s.status, s.message) for s in run.steps]
    from hil.report.junit import junit_xml
    xml = junit_xml([cut])
    assert "<error" in xml and 'errors="1"' in xml, xml[:600]


def _one_message_a_chunk(path: Path, rows: list[tuple[str, int, bytes]]) -> None:
    """An MCAP file of (topic, log = publish time, JSON bytes) rows, a chunk each."""
    chans: dict[str, int] = {}
    with open(path, "wb") as f:
        w = Writer(f, chunk_size=1)
        w.start()
        schema = w.register_schema("hil.Any", "jsonschema", b'{"type": "object"}')
        for topic, t, data in rows:
            if topic not in chans:
                chans[topic] = w.register_channel(topic, "json", schema, {})
            w.add_message(chans[topic], log_time=t, publish_time=t, data=data)
        w.finish()


def test_check_records_at_the_cut_chunks_first_time_are_kept(tmp_path):
    """The plan's check records stand whole where they were written: read with `cut=False`
    they are all kept, though a message at that time may be in the lost chunk."""
    path = tmp_path / "c.mcap"
    _one_message_a_chunk(path, [("/x", 50, b'{"v": 0}'),
                                ("/timing/verdicts", 100, json.dumps({"v": 1}).encode()),
                                ("/x", 100, b'{"v": 2}' + b" " * 4000)])
    data = path.read_bytes()
    offs = chunk_offsets(data)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: offs[2] + 30])  # into the third chunk, which starts at 100
    kept = RecordingSource(cut, topics=["/timing/verdicts"], at_rest=True, cut=False)
    assert [m["v"] for _t, m in kept.messages("/timing/verdicts")] == [1]
    judged = RecordingSource(cut, topics=["/timing/verdicts", "/x"], at_rest=True)
    assert judged.cut_ns == 100 and judged.messages("/timing/verdicts") == []


def test_check_finds_the_steps_a_cut_file_holds(emgs, tmp_path, capsys):
    """For every cut into a chunk, and a cut just after the last chunk: when the file still
    holds the plan's check records, the checks are judged (not "holds none").

    The chunks are closed on the writer's wall-clock flush, so how many there are and where the
    check records fall varies from run to run; the cut after the last chunk always holds them
    (a run of few chunks may have no other cut that does)."""
    data = emgs.read_bytes()
    seen = 0
    for end in [off + 30 for off in chunk_offsets(data)[1:]] + [data_end(data)]:
        cut = tmp_path / "c.mcap"
        cut.write_bytes(data[:end])
        held = list(Recording.open(cut).messages("/timing/verdicts"))
        code = hil(["check", str(cut)])
        out, err = capsys.readouterr()
        assert code == 4
        if held:
            seen += 1
            assert "none of the plan's check_timing steps" not in err, (end, err)
            assert " pass," in out and "0 pass," not in out, (end, out)
    assert seen


def test_a_damaged_length_in_a_file_with_its_footer_is_damage_not_a_kill(homing, tmp_path,
                                                                        capsys):
    data = bytearray(homing.read_bytes())
    at = chunk_offsets(bytes(data))[4]
    (ln,) = struct.unpack_from("<Q", data, at + 1)
    struct.pack_into("<Q", data, at + 1, ln + 1000)  # the reader lands inside the next record
    bad = tmp_path / "len.mcap"
    bad.write_bytes(bytes(data))
    rec = Recording.open(bad)
    assert rec.corrupt and rec.cut_log_ns is not None, rec.error
    assert hil(["check", str(bad)]) == 4
    err = capsys.readouterr().err
    assert "damaged:" in err and "no footer" not in err and "killed" not in err, err


def test_a_run_killed_before_its_first_channel_is_cut_not_foreign(emgs, tmp_path, capsys):
    cut = tmp_path / "c.mcap"
    cut.write_bytes(emgs.read_bytes()[:100])
    assert hil(["check", str(cut)]) == 4
    out, err = capsys.readouterr()
    assert "cut before its first channel" in err and "not a hil recording" not in err
    assert "INCONCLUSIVE" not in out and "PASS" not in out
