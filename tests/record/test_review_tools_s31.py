"""What a reviewer's tools say of a recording that contradicts itself, from an outside probe
of `hil report`, `hil check`, `hil diff`, `hil inspect` and `hil export` (wave 3, session 31,
helper-137)."""

from __future__ import annotations

import os
import struct
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from rec_helpers import T0, copy_mcap, dio_mcap, first_changed, plan_recording

from hil.cli import main as hil
from hil.record.recorder import Recorder

pytestmark = pytest.mark.virtual_time


@pytest.fixture(scope="module")
def emgs(tmp_path_factory) -> Path:
    """A genuine passing recording with check steps and their verdicts."""
    return plan_recording(tmp_path_factory.mktemp("emgs"), "emgs")


@pytest.mark.parametrize("status", ["FAIL", "failed", "maybe"])
def test_a_pass_result_over_a_verdict_status_no_check_gives_is_an_error(emgs, tmp_path,
                                                                          status):
    """The page said PASS over a verdict table counting "1 FAIL"; the JUnit said pass."""
    bad = copy_mcap(emgs, tmp_path / "v.mcap", first_changed(
        "/timing/verdicts", lambda o: o | {"status": status} if o.get("status") == "pass"
        else None))
    out = tmp_path / "v.xml"
    assert hil(["report", str(bad), "-o", str(tmp_path / "v.html"), "--junit", str(out)]) == 0
    suite = ET.parse(out).getroot()
    assert suite.get("errors") == "1" and suite.get("failures") == "0"
    err = suite.find(".//testcase/error")
    assert err is not None and f"has the status {status!r}" in err.get("message")
    page = (tmp_path / "v.html").read_text(encoding="utf-8")
    assert "b-error" in page and "result says pass, but timing verdict emgs" in page


def _records(data: bytes) -> list[tuple[int, int, int]]:
    """(offset, opcode, length) of each record of an MCAP file's data section and after."""
    out, off = [], 8
    while off + 9 <= len(data) - 8:
        op, ln = struct.unpack_from("<BQ", data, off)
        out.append((off, op, ln))
        off += 9 + ln
    return out


def test_repair_reads_on_past_zeroed_records(tmp_path, capsys) -> None:
    """The message-index records after a chunk zeroed (141 bytes, no message touched):
    `--repair` kept the messages before them only, and not the result and close metadata
    written after them (helper-137)."""
    p = tmp_path / "a.mcap"
    with Recorder(p, chunk_size=2048) as rec:
        for k in range(300):
            rec.dio("io", f"DI{k % 8 + 1}", bool(k & 1), T0 + k * 1_000_000, None)
        rec.add_metadata("hil.result", {"status": "pass"})
    data = bytearray(p.read_bytes())
    recs = _records(bytes(data))
    first_chunk = next(i for i, r in enumerate(recs) if r[1] == 0x06)
    zeroed = [r for r in recs[first_chunk + 1:] if r[1] == 0x07]  # its message indexes
    k = first_chunk + 1
    while recs[k][1] == 0x07:
        off, _op, ln = recs[k]
        data[off:off + 9 + ln] = bytes(9 + ln)
        k += 1
    assert zeroed and sum(1 for r in recs if r[1] == 0x06) > 2  # chunks follow the zeros
    bad = tmp_path / "zeroed.mcap"
    bad.write_bytes(bytes(data))
    out = tmp_path / "fixed.mcap"
    assert hil(["inspect", str(bad), "--repair", str(out)]) == 0
    assert "repaired: 300 messages" in capsys.readouterr().out
    assert hil(["inspect", str(out)]) == 0
    said = capsys.readouterr().out
    assert "messages: 300" in said and "hil.result" in said


def test_check_is_incomplete_when_a_plan_check_no_longer_judges_what_the_run_did(
        tmp_path, capsys) -> None:
    """The SON input's topic gone: the run's "SON accepted after the P2.009 filter" pass
    became "not applicable" and `hil check` passed without a word (helper-137)."""
    rec = plan_recording(tmp_path, "servo_on_off_brake")
    assert hil(["check", str(rec)]) == 0
    capsys.readouterr()
    bad = copy_mcap(rec, tmp_path / "no_di1.mcap", drop={"/dio/drive1/DI1"})
    assert hil(["check", str(bad)]) == 4
    err = capsys.readouterr().err
    assert "spec servo_on_brake: the run judged 3 pass, this check 1 pass" in err
    assert "not in the recording: signal SON: no data on /dio/drive1/DI1" in err


@pytest.mark.parametrize("change", [{"measured_ms": "150"}, {"window_ms": "wide"},
                                    {"occurrence": "first"}])
def test_a_verdict_of_a_wrong_shape_is_counted_by_check_and_diff(emgs, tmp_path, capsys,
                                                                  change):
    """`hil diff` compared a measured "150" as nothing ("0 verdicts measured differently",
    exit 0) and `hil check` took such a record in silence (helper-137)."""
    bad = copy_mcap(emgs, tmp_path / "v.mcap", first_changed(
        "/timing/verdicts", lambda o: o | change if o.get("status") == "pass" else None))
    assert hil(["diff", str(emgs), str(bad), "-o", str(tmp_path / "d.html")]) == 4
    assert "wrong shape" in capsys.readouterr().err
    assert hil(["check", str(bad)]) == 4
    assert "/timing/verdicts message(s) of a wrong shape" in capsys.readouterr().err


def test_diff_takes_a_level_of_1_as_no_level(tmp_path, capsys) -> None:
    """`hil check` refuses {"level": 1} as "not a level"; `hil diff` read it as true."""
    rec = plan_recording(tmp_path, "servo_on_off_brake")
    bad = copy_mcap(rec, tmp_path / "b.mcap", first_changed(
        "/dio/drive1/DO6", lambda o: o | {"level": 1} if o.get("level") is True else None))
    assert hil(["diff", str(rec), str(bad), "-o", str(tmp_path / "d.html")]) == 4
    assert "wrong shape" in capsys.readouterr().err


def test_the_page_shows_a_long_text_clipped(emgs, tmp_path) -> None:
    """A 2 MB step message (zstd keeps it in a few kB) was put whole on the page: a 79 kB
    file gave a 140 MB page and 600 MB of memory (helper-137)."""
    huge = "x" * 2_000_000
    bad = copy_mcap(emgs, tmp_path / "big.mcap", first_changed(
        "/plan/steps", lambda o: o | {"message": huge} if o.get("event") == "end" else None))
    assert bad.stat().st_size < 200_000
    out = tmp_path / "big.html"
    assert hil(["report", str(bad), "-o", str(out)]) == 0
    page = out.read_text(encoding="utf-8")
    assert len(page) < 500_000
    assert "1,995,904 more characters not shown" in page


def test_inspect_says_when_the_summary_points_elsewhere(emgs, tmp_path, capsys) -> None:
    """A footer whose summary offset is wrong, or a chunk index pointing where no chunk
    starts: `hil inspect` said "complete" of files an indexed reader fails on (helper-137)."""
    data = emgs.read_bytes()
    foot = len(data) - 8 - 20  # footer body: summary_start, summary_offset_start, crc
    bad = tmp_path / "footer.mcap"
    bad.write_bytes(data[:foot] + (12345).to_bytes(8, "little") + data[foot + 8:])
    assert hil(["inspect", str(bad)]) == 0
    assert "INDEX DAMAGED: the footer says the summary starts at offset 12345" in (
        capsys.readouterr().out)
    ci = next(off for off, op, _ln in _records(data) if op == 0x08)  # a chunk index
    bad2 = tmp_path / "chunkidx.mcap"
    at = ci + 9 + 16  # its chunk_start_offset
    bad2.write_bytes(data[:at] + (999_999).to_bytes(8, "little") + data[at + 8:])
    assert hil(["inspect", str(bad2)]) == 0
    assert "points to offset 999999, where no chunk starts" in capsys.readouterr().out
    fixed = tmp_path / "fixed.mcap"
    assert hil(["inspect", str(bad), "--repair", str(fixed)]) == 0
    capsys.readouterr()
    assert hil(["inspect", str(fixed)]) == 0
    assert "complete: footer and summary present" in capsys.readouterr().out
    assert hil(["inspect", str(emgs)]) == 0
    assert "complete: footer and summary present" in capsys.readouterr().out


def test_report_of_one_recording_given_twice_says_so(emgs, tmp_path, capsys) -> None:
    """It said "-o x.html: is also the -o output" where no -o was given (helper-137)."""
    assert hil(["report", str(emgs), str(emgs)]) == 2
    err = capsys.readouterr().err
    assert " -o " not in err and "the page of two recordings given" in err
    assert "one file twice?" in err
    assert hil(["report", str(emgs), "--index", str(emgs.with_suffix(".html"))]) == 2
    assert f"is also the page of {emgs}" in capsys.readouterr().err


def test_inspect_counts_a_topic_of_two_channels_once(tmp_path, capsys) -> None:
    """Another writer's two channels of one topic, one of them empty, were each listed with
    the topic's whole count (helper-137)."""
    p = dio_mcap(tmp_path / "dup.mcap", channels=2)
    assert hil(["inspect", str(p)]) == 0
    rows = [ln for ln in capsys.readouterr().out.splitlines() if "/dio/io/DI1" in ln]
    assert len(rows) == 1 and " 3  " in rows[0] and "(2 channels of this topic)" in rows[0]


@pytest.mark.parametrize("options", [{}, {"use_summary_offsets": False},
                                     {"use_chunking": False, "use_summary_offsets": False},
                                     {"use_statistics": False, "repeat_channels": False}])
def test_inspect_calls_the_mcap_writers_own_files_complete(tmp_path, capsys, options) -> None:
    """A summary with no offset section (its footer offset 0, as the MCAP spec allows) was
    called INDEX DAMAGED (helper-138)."""
    p = dio_mcap(tmp_path / "w.mcap", **options)
    assert hil(["inspect", str(p)]) == 0
    assert "complete: footer and summary present" in capsys.readouterr().out


def test_check_with_an_override_is_not_incomplete_for_judging_otherwise(tmp_path,
                                                                        capsys) -> None:
    """A --param asks for other verdicts on purpose: the new "as the run judged" rule made
    `hil check --param P2.009=2` of a run that failed at P2.009 = 5 incomplete (exit 4)
    where every verdict passed (helper-138)."""
    from hil.bench.bench import load_bench
    from hil.paths import plans_dir
    from hil.plan.plan import load_plan
    from hil.plan.runner import run_plan

    text = (plans_dir() / "emgs.yaml").read_text(encoding="utf-8")
    plan = tmp_path / "emgs_strict.yaml"
    plan.write_text(text.replace("name: emgs", "name: emgs_strict").replace(
        "  - check_timing: emgs", "  - check_timing: {spec: emgs, params: {P2.009: 5}}"),
        encoding="utf-8")
    res = run_plan(load_plan(plan), load_bench(None), tmp_path, reports=False)
    assert res.status == "fail"
    assert hil(["check", res.recording]) == 1
    capsys.readouterr()
    assert hil(["check", res.recording, "--param", "P2.009=2"]) == 0
    assert "incomplete" not in capsys.readouterr().err


def test_diff_compares_the_active_alarms(emgs, tmp_path, capsys) -> None:
    """An alarm in one run only gave "0 state sequence(s) differ" (helper-137)."""
    bad = copy_mcap(emgs, tmp_path / "al.mcap", first_changed(
        "/drive/drive1/state", lambda o: o | {"alarms": ["AL500"]} if o.get("alarms") == []
        else None))
    assert hil(["diff", str(emgs), str(bad), "-o", str(tmp_path / "d.html")]) == 0
    out = capsys.readouterr().out
    assert "1 state sequence(s) differ" in out
    page = (tmp_path / "d.html").read_text(encoding="utf-8")
    assert "drive1 alarms" in page and "AL500" in page


def test_report_of_a_stream_asks_for_o_and_writes_nothing_in_dev(emgs, tmp_path) -> None:
    """`hil report /dev/stdin < a.mcap` wrote its page as /dev/stdin.html (helper-137): the
    default page goes beside the recording, and /dev is no recording's folder."""
    import subprocess
    import sys

    def report(*extra: str) -> subprocess.CompletedProcess:
        with emgs.open("rb") as f:
            return subprocess.run([sys.executable, "-m", "hil.cli", "report", "/dev/stdin",
                                   *extra], stdin=f, capture_output=True, text=True,
                                  timeout=120)

    Path("/dev/stdin.html").unlink(missing_ok=True)
    try:
        out = report()
        assert out.returncode == 2 and "give -o FILE.html" in out.stderr, out.stderr
        assert not Path("/dev/stdin.html").exists()
    finally:
        Path("/dev/stdin.html").unlink(missing_ok=True)
    # a file in /dev/shm (a tmpfs) is a file in a folder: its page goes beside it
    # (helper-141: everything under /dev had been called a stream)
    shm = Path("/dev/shm")
    if shm.is_dir() and os.access(shm, os.W_OK):
        mine = shm / f"hil-test-{os.getpid()}.mcap"
        try:
            mine.write_bytes(emgs.read_bytes())
            assert hil(["report", str(mine)]) == 0
            assert mine.with_suffix(".html").exists()
        finally:
            mine.unlink(missing_ok=True)
            mine.with_suffix(".html").unlink(missing_ok=True)
    page = tmp_path / "s.html"
    out = report("-o", str(page))
    assert out.returncode == 0, out.stderr
    assert "emgs" in page.read_text(encoding="utf-8")


def test_a_time_past_2_63_is_named_as_such_when_skipped(emgs, tmp_path, caplog) -> None:
    """A publish time of 2^63 + 5 was skipped by `hil check` with Python's "int too big to
    convert" as the reason (helper-137)."""
    n = {"left": 2}

    def huge(topic: str, pt: int) -> int:
        if topic == "/dio/drive1/DO6" and n["left"]:
            n["left"] -= 1
            return pt if n["left"] else 2**63 + 5
        return pt

    bad = copy_mcap(emgs, tmp_path / "h.mcap", publish=huge)
    assert n["left"] == 0
    with caplog.at_level("WARNING"):
        hil(["check", str(bad)])
    text = caplog.text
    assert "a publish time of 9223372036854775813 ns, past the 2^63 - 1 ns" in text, text
    assert "int too big" not in text
