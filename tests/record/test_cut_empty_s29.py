"""A recording cut before its first channel (a run killed as it started: the MCAP magic, the
magic and its header, or what the recorder writes first, the run's metadata) is said to be
that by every review command, never "not a hil recording" nor judged or reported as a run,
and export does not write an empty log for it as if it had been exported."""

from __future__ import annotations

import io
import os
import subprocess
import sys
from pathlib import Path

import pytest
from mcap.writer import Writer

from hil.cli import main as hil

MAGIC = b"\x89MCAP0\r\n"


def _header_only() -> bytes:
    buf = io.BytesIO()
    w = Writer(buf)
    w.start(profile="", library="hil")
    return buf.getvalue()  # no channel, no footer: what a kill right after open leaves


def _recorder_killed_at_start(p: Path) -> None:
    """A process that opened a Recorder (its hil.run metadata flushed) and died at once."""
    code = ("import os, sys; from hil.record.recorder import Recorder; "
            "Recorder(sys.argv[1], metadata={'hil.plan': 'x'}); os._exit(9)")
    subprocess.run([sys.executable, "-c", code, str(p)], check=False, timeout=60,
                   env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2])})
    assert p.stat().st_size > len(MAGIC)


@pytest.fixture(params=["magic", "header", "recorder"])
def cut(request, tmp_path) -> Path:
    p = tmp_path / "cut.mcap"
    if request.param == "recorder":
        _recorder_killed_at_start(p)
    else:
        p.write_bytes(MAGIC if request.param == "magic" else _header_only())
    return p


@pytest.fixture(params=["magic", "header"])
def bare(request, tmp_path) -> Path:
    p = tmp_path / "cut.mcap"
    p.write_bytes(MAGIC if request.param == "magic" else _header_only())
    return p


def test_report_diff_and_export_say_it_was_cut_and_exit_2(bare, tmp_path, capsys) -> None:
    """Not even the run's metadata: nothing to show."""
    cut, out = bare, tmp_path / "x.log"
    assert hil(["report", str(cut), "-o", str(tmp_path / "r.html")]) == 2
    assert hil(["diff", str(cut), str(cut), "-o", str(tmp_path / "d.html")]) == 2
    assert hil(["export", str(cut), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("cut before its first channel: nothing was recorded") == 3, err
    assert "not a hil recording" not in err
    assert not out.exists()  # no empty log that looks exported
    assert not (tmp_path / "r.html").exists() and not (tmp_path / "d.html").exists()


def test_a_run_killed_after_its_metadata_is_shown_incomplete(tmp_path, capsys) -> None:
    """The recorder's first records (hil.run, hil.versions) and no channel: the page shows
    the run as incomplete, diff says it is cut (4), export has nothing to export (2)."""
    cut = tmp_path / "cut.mcap"
    _recorder_killed_at_start(cut)
    assert hil(["report", str(cut), "-o", str(tmp_path / "r.html")]) == 0
    page = (tmp_path / "r.html").read_text(encoding="utf-8")
    assert "recording truncated" in page and "b-pass'" not in page.split("</style>")[1]
    assert hil(["diff", str(cut), str(cut), "-o", str(tmp_path / "d.html")]) == 4
    assert hil(["export", str(cut), "-o", str(tmp_path / "x.log")]) == 2
    assert not (tmp_path / "x.log").exists()
    assert "cut before its first channel" in capsys.readouterr().err


def test_check_calls_it_incomplete(cut, capsys) -> None:
    assert hil(["check", str(cut), "--json"]) == 4
    out = capsys.readouterr()
    assert "cut before its first channel" in out.err
    assert out.out.strip() == "[]"  # nothing judged, not the specs' defaults inconclusive


def test_a_foreign_mcap_is_still_not_a_hil_recording(tmp_path, capsys) -> None:
    """A whole MCAP file (with its footer) of someone else's channels stays foreign."""
    p = tmp_path / "other.mcap"
    with open(p, "wb") as f:
        w = Writer(f)
        w.start(profile="", library="other")
        sid = w.register_schema("s", "jsonschema", b"{}")
        cid = w.register_channel("/other", "json", sid)
        w.add_message(cid, log_time=1, publish_time=1, data=b"{}")
        w.finish()
    assert hil(["report", str(p), "-o", str(tmp_path / "r.html")]) == 2
    assert "not a hil recording" in capsys.readouterr().err


def _first_chunk_damaged(p: Path) -> None:
    """A recorder's file (its metadata, then one chunk of log lines) killed, with a byte of
    its first chunk flipped: no channel of it can be read."""
    import struct

    code = ("import os, sys; from hil.record.recorder import Recorder; "
            "r = Recorder(sys.argv[1], metadata={'hil.plan': 'x'})\n"
            "for i in range(50): r.log('info', f'hello {i}', name='t')\n"
            "r.flush(); os._exit(9)")
    subprocess.run([sys.executable, "-c", code, str(p)], check=False, timeout=60,
                   env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2])})
    b = bytearray(p.read_bytes())
    pos = len(MAGIC)
    while pos < len(b):
        op, n = b[pos], struct.unpack_from("<Q", b, pos + 1)[0]
        if op == 0x06:  # the chunk: a byte in the middle of its records
            b[pos + 9 + n // 2] ^= 0xFF
            break
        pos += 9 + n
    else:
        raise AssertionError("no chunk")
    p.write_bytes(bytes(b))


def test_a_first_chunk_damaged_is_judged_and_exported_as_nothing(tmp_path, capsys) -> None:
    """helper-123: check judged it with every spec's defaults (206 verdicts, 20 of them
    inconclusive) and export wrote an empty log (exit 0)."""
    bad = tmp_path / "bad.mcap"
    _first_chunk_damaged(bad)
    assert hil(["check", str(bad), "--json"]) == 4
    out = capsys.readouterr()
    assert out.out.strip() == "[]" and "damaged before its first channel" in out.err
    assert hil(["export", str(bad), "-o", str(tmp_path / "x.log")]) == 2
    assert "damaged before its first channel" in capsys.readouterr().err
    assert not (tmp_path / "x.log").exists()


def test_a_damaged_recording_without_a_result_is_incomplete_not_aborted(tmp_path) -> None:
    """With its first chunk unreadable, how the run ended is unknown: the page said
    ABORTED, which nothing in the file supports (helper-125)."""
    from hil.report.data import load_run

    bad = tmp_path / "bad.mcap"
    _first_chunk_damaged(bad)
    assert load_run(bad).status == "incomplete"
