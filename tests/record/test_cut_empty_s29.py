"""A recording cut before its first channel (a run killed as it started: the MCAP magic, or
the magic and its header) is said to be that by every review command, never "not a hil
recording", and export does not write an empty log for it as if it had been exported."""

from __future__ import annotations

import io
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


@pytest.fixture(params=["magic", "header"])
def cut(request, tmp_path) -> Path:
    p = tmp_path / "cut.mcap"
    p.write_bytes(MAGIC if request.param == "magic" else _header_only())
    return p


def test_report_diff_and_export_say_it_was_cut_and_exit_2(cut, tmp_path, capsys) -> None:
    out = tmp_path / "x.log"
    assert hil(["report", str(cut), "-o", str(tmp_path / "r.html")]) == 2
    assert hil(["diff", str(cut), str(cut), "-o", str(tmp_path / "d.html")]) == 2
    assert hil(["export", str(cut), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("cut before its first channel: nothing was recorded") == 3, err
    assert "not a hil recording" not in err
    assert not out.exists()  # no empty log that looks exported
    assert not (tmp_path / "r.html").exists()


def test_check_calls_it_incomplete(cut, capsys) -> None:
    assert hil(["check", str(cut)]) == 4
    assert "cut before its first channel" in capsys.readouterr().err


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
