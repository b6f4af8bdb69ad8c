"""Recordings that end wrongly but not by a kill (helper-84 #7): two files joined with `cat`,
and a footer without its closing magic. Neither is a killed run, and neither is whole."""

from __future__ import annotations

from pathlib import Path

import pytest
from rec_helpers import plan_recording

from hil.cli import main as hil
from hil.record.reader import Recording

pytestmark = pytest.mark.virtual_time


@pytest.fixture(scope="module")
def emgs(tmp_path_factory) -> Path:
    return plan_recording(tmp_path_factory.mktemp("emgs"), "emgs")


def test_two_recordings_joined_are_not_read_as_one_complete_file(emgs, tmp_path, capsys):
    """`cat a.mcap b.mcap`: the scan stopped at a's footer and called the file complete;
    b's 40 kB were never mentioned."""
    joined = tmp_path / "joined.mcap"
    joined.write_bytes(emgs.read_bytes() * 2)
    rec = Recording.open(joined)
    assert rec.corrupt and "after the closing magic" in rec.error
    assert hil(["inspect", str(joined)]) == 0
    out = capsys.readouterr().out
    assert "complete:" not in out
    assert f"DAMAGED: {emgs.stat().st_size:,} bytes after the closing magic" in out
    assert "files joined?" in out
    assert hil(["check", str(joined)]) == 4
    err = capsys.readouterr().err
    assert "damaged:" in err and "after the closing magic" in err


def test_a_footer_without_its_closing_magic_is_cut_short_not_killed(emgs, tmp_path, capsys):
    """The footer is there (the writer finished): "no footer: the run was killed" was wrong."""
    cut = tmp_path / "nomagic.mcap"
    cut.write_bytes(emgs.read_bytes()[:-8])
    assert hil(["check", str(cut)]) == 4
    err = capsys.readouterr().err
    assert "cut short: closing magic missing after the footer" in err, err
    assert "no footer" not in err and "killed" not in err, err


def _flip_in_attachment(src: Path, dst: Path, name: bytes) -> int:
    """`src` copied to `dst` with one byte of the attachment `name`'s data flipped; its offset."""
    import struct

    data = bytearray(src.read_bytes())
    off = 8
    while off + 9 <= len(data):
        op, ln = struct.unpack_from("<BQ", data, off)
        if op == 0x09 and name in data[off + 9: off + 9 + ln]:
            data[off + 9 + ln - 20] ^= 0x20  # inside the data, before the CRC
            dst.write_bytes(bytes(data))
            return off
        off += 9 + ln
    raise AssertionError(f"no attachment {name!r}")


def test_a_damaged_attachment_is_said_and_left_out(emgs, tmp_path, capsys):
    """Attachment CRCs were not checked (helper-84 #6): a flipped byte in the plan file the
    run attached was shown as the plan. It is left out and said; the messages are whole, so
    the checks are judged as before."""
    from hil.report import data as report_data

    bad = tmp_path / "att.mcap"
    off = _flip_in_attachment(emgs, bad, b"plan.yaml")
    rec = Recording.open(bad)
    assert rec.bad_attachments == [f"'plan.yaml' at offset {off}: CRC mismatch"]
    assert "plan.yaml" not in [a.name for a in rec.attachments()]
    assert "bench.yaml" in [a.name for a in rec.attachments()]
    assert hil(["inspect", str(bad)]) == 0
    assert f"DAMAGED attachment 'plan.yaml' at offset {off}: CRC mismatch" in \
        capsys.readouterr().out
    report_data.forget(bad)
    run = report_data.load_run(bad)
    assert run.attachments["plan.yaml"] == f"<damaged at offset {off}: CRC mismatch; not shown>"
    assert hil(["check", str(bad)]) == hil(["check", str(emgs)]) == 0


def test_confusing_flag_values_are_named_before_any_work(emgs, tmp_path, capsys):
    """helper-84 #8: `--spec ''` was read as the current directory (".:0: (file): a
    directory"); `--repair DIR` failed only after the whole summary was printed."""
    assert hil(["check", str(emgs), "--spec", ""]) == 2
    err = capsys.readouterr().err
    assert "--spec '': empty" in err and "directory" not in err
    d = tmp_path / "outdir"
    d.mkdir()
    assert hil(["inspect", str(emgs), "--repair", str(d)]) == 2
    out, err = capsys.readouterr()
    assert out == "" and f"--repair {d}: a directory" in err


@pytest.fixture(scope="module")
def homing(tmp_path_factory) -> Path:
    """0.6 MB in some ten 64 KiB chunks."""
    return plan_recording(tmp_path_factory.mktemp("homing"), "homing_pr")


@pytest.mark.parametrize("how", ["past the end", "short"])
def test_repair_goes_on_past_a_chunk_whose_length_was_damaged(homing, tmp_path, capsys, how):
    """helper-84 #4: a chunk whose length field was damaged (a huge one runs past the file's
    end; a short one leaves the reader inside the chunk) ended `--repair` there, though
    whole chunks follow. The scan finds the next whole chunk and reads on."""
    import struct

    from tests.timing.test_check_incomplete import chunk_offsets

    data = bytearray(homing.read_bytes())
    offs = chunk_offsets(bytes(data))
    assert len(offs) >= 6
    at = offs[3]
    (ln,) = struct.unpack_from("<Q", data, at + 1)
    struct.pack_into("<Q", data, at + 1, ln | (0x7F << 56) if how == "past the end" else ln - 100)
    bad = tmp_path / "len.mcap"
    bad.write_bytes(bytes(data))
    (after,) = struct.unpack_from("<Q", data, offs[4] + 9)  # the next chunk's first log time
    fixed = tmp_path / "fixed.mcap"
    assert hil(["inspect", str(bad), "--repair", str(fixed)]) == 0
    out = capsys.readouterr().out
    assert f"whole records follow at offset {offs[4]}" in out
    total = sum(1 for _ in Recording.open(homing).raw_messages())
    got = [lt for _tp, lt, _pt, _d in Recording.open(fixed).raw_messages()]
    assert max(got) >= after and len(got) < total  # read past it, and not the damaged chunk
    assert hil(["check", str(bad)]) == 4  # a checker still stops at the first damage


def test_export_says_damaged_not_truncated(homing, tmp_path, capsys):
    """helper-85: `hil export` of a file whose chunk CRC fails called it truncated."""
    from tests.timing.test_check_incomplete import corrupt

    bad = tmp_path / "bad.mcap"
    corrupt(homing, bad, 3)
    assert hil(["export", str(bad), "-o", str(tmp_path / "o.log")]) == 0
    err = capsys.readouterr().err
    assert f"{bad} is damaged (chunk at offset" in err and "truncated" not in err, err
