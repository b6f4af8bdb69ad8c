"""Damaged and hostile recordings from an outside fuzz of the offline tools (wave 3, session
16, helper-59): a zstd bomb, zeroed and oversized chunks, a chunk cut out of a whole file, a
repaired cut run, a repair that fails half-way, spec names that are paths, and records whose
fields have the wrong types. Each gets the documented answer (exit code, a message naming
the problem, what was skipped), never a traceback, an allocation the file does not hold, or
a cut run reported as a clean pass."""

from __future__ import annotations

import json
import struct
import tracemalloc
from collections.abc import Callable
from pathlib import Path

import pytest
import zstandard
from rec_helpers import copy_mcap

from hil.bench.bench import load_bench
from hil.cli import main as hil
from hil.paths import plans_dir
from hil.plan.plan import load_plan
from hil.plan.runner import run_plan
from hil.record import mcapio
from hil.record.reader import Recording
from hil.report import data as report_data

pytestmark = pytest.mark.virtual_time


@pytest.fixture(scope="module")
def emgs(tmp_path_factory) -> Path:
    """A genuine recording with checks: the emgs plan (timing verdicts on the record)."""
    out = tmp_path_factory.mktemp("emgs")
    res = run_plan(load_plan(plans_dir() / "emgs.yaml"), load_bench(None), out, reports=False)
    assert res.passed
    return Path(res.recording)


def _rewrite(src: Path, dst: Path, change: Callable[[str, dict], dict | None] | None = None,
             meta: dict[str, dict[str, str]] | None = None) -> Path:
    """`src` again, each JSON message passed through `change(topic, obj)` (None: unchanged),
    the metadata `meta` added (a name given replaces the original's record)."""
    def message(topic: str, data: bytes, lt: int) -> tuple[bytes, int]:
        new = change(topic, json.loads(data)) if change is not None else None
        return (data if new is None else json.dumps(new).encode()), lt

    return copy_mcap(src, dst, message, metadata=meta)


def _records(data: bytes) -> list[tuple[int, int, int]]:
    """(offset, opcode, length) of each record of an MCAP file."""
    out, off = [], 8
    while off + 9 <= len(data):
        op, ln = data[off], struct.unpack_from("<Q", data, off + 1)[0]
        out.append((off, op, ln))
        off += 9 + ln
    return out


# --- chunks ---------------------------------------------------------------------------------


def test_a_zstd_frame_declaring_more_than_its_chunk_is_refused_without_making_it():
    """A chunk stating 100 bytes whose zstd frame declares 64 MiB: `max_output_size` does not
    cap a frame that declares its size (a 98 KB file made 3 GiB)."""
    frame = zstandard.ZstdCompressor().compress(b"\0" * (64 << 20))
    tracemalloc.start()
    try:
        with pytest.raises(ValueError, match="more than its stated 100 bytes"):
            mcapio.decompress("zstd", frame, 100)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 1 << 20
    exact = zstandard.ZstdCompressor().compress(b"x" * 1000)
    assert mcapio.decompress("zstd", exact, 1000) == b"x" * 1000
    with pytest.raises(ValueError, match="holds 1,000 bytes, not its stated 1,001"):
        mcapio.decompress("zstd", exact, 1001)


def test_an_uncompressed_chunk_must_hold_what_it_states():
    with pytest.raises(ValueError, match="holds 5 bytes, not its stated 1,000,000,000,000"):
        mcapio.decompress("", b"12345", 10**12)


def test_a_zeroed_chunk_is_damage_not_millions_of_empty_records():
    """A legal 250 MiB chunk of zero bytes was walked 9 bytes a record (29 M records)."""
    with pytest.raises(ValueError, match="opcode 0x00"):
        list(mcapio.iter_chunk(b"\0" * 4096, {}, {}))


def test_a_chunk_whose_records_run_past_it_is_damage(emgs, tmp_path, capsys):
    data = bytearray(emgs.read_bytes())
    off = next(o for o, op, _ln in _records(bytes(data)) if op == 0x06)
    body = off + 9
    clen = struct.unpack_from("<I", data, body + 28)[0]
    struct.pack_into("<Q", data, body + 32 + clen, 2**63 - 1)  # the records' length
    bad = tmp_path / "dlen.mcap"
    bad.write_bytes(bytes(data))
    assert hil(["check", str(bad)]) == 4
    assert "run past its end" in capsys.readouterr().err


def test_a_chunk_cut_out_of_a_whole_file_is_damage(emgs, tmp_path, capsys):
    """The summary counts the chunks: one cut out (footer and summary kept) had been read as
    a complete recording, and checked and reported as a pass."""
    data = emgs.read_bytes()
    recs = _records(data)
    chunks = [i for i, (_o, op, _ln) in enumerate(recs) if op == 0x06]
    assert len(chunks) >= 2
    i = chunks[-1]  # the last chunk and its message indexes
    j = i + 1
    while recs[j][1] == 0x07:
        j += 1
    start, end = recs[i][0], recs[j][0]
    cut = tmp_path / "nochunk.mcap"
    cut.write_bytes(data[:start] + data[end:])
    assert hil(["inspect", str(cut)]) == 0
    out = capsys.readouterr().out
    assert "part of the recording is missing" in out and "complete:" not in out
    assert hil(["check", str(cut)]) == 4
    assert "part of the recording is missing" in capsys.readouterr().err


# --- repair ---------------------------------------------------------------------------------


def test_a_repaired_cut_run_is_still_cut_for_check_and_report(emgs, tmp_path, capsys):
    """`inspect --repair` writes a footer; the run it copies was still killed: `check` had
    exited 0 and the report said PASS."""
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(emgs.read_bytes()[: emgs.stat().st_size // 3])  # before hil.result
    assert "hil.result" not in Recording.open(cut).metadata()
    fixed = tmp_path / "fixed.mcap"
    assert hil(["inspect", str(cut), "--repair", str(fixed)]) == 0
    capsys.readouterr()
    assert hil(["check", str(fixed)]) == 4
    assert "repaired from a" in capsys.readouterr().err
    report_data._RUNS.clear()
    report_data._SUMMARIES.clear()
    assert report_data.load_run(cut).status == "aborted"
    run = report_data.load_run(fixed)
    assert run.truncated and run.status == "aborted"
    # a whole recording repaired stays whole
    whole = tmp_path / "whole.mcap"
    assert hil(["inspect", str(emgs), "--repair", str(whole)]) == 0
    assert hil(["check", str(whole)]) == 0


def test_a_repair_that_fails_leaves_an_existing_output_as_it_was(emgs, tmp_path, monkeypatch,
                                                                 capsys):
    out = tmp_path / "out.mcap"
    out.write_bytes(b"keep me")

    def full(self):
        raise OSError(27, "File too large")

    monkeypatch.setattr(mcapio.McapWriter, "finish", full)
    assert hil(["inspect", str(emgs), "--repair", str(out)]) == 2
    assert "File too large" in capsys.readouterr().err
    assert out.read_bytes() == b"keep me"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.mcap"]


# --- what a recording names -----------------------------------------------------------------


@pytest.mark.parametrize("specs", [["/etc/passwd"], ["../../etc/hostname"]])
def test_a_recording_cannot_make_check_open_a_file_it_names(emgs, tmp_path, capsys, specs):
    """The plan's spec ids on the record are ids, never paths: `timing.specs =
    ["/etc/passwd"]` had printed the start of /etc/passwd."""
    meta = dict(Recording.open(emgs).metadata()["timing"])
    bad = _rewrite(emgs, tmp_path / "p.mcap", meta={"timing": meta | {
        "specs": json.dumps(specs)}})
    assert hil(["check", str(bad), "--whole"]) == 2
    err = capsys.readouterr().err
    assert "not a shipped spec id" in err and "root:" not in err
    text = _rewrite(emgs, tmp_path / "t.mcap", meta={"timing": meta | {
        "specs": json.dumps("emgs")}})  # a text, not a list: none recorded (was e, m, g, s)
    assert hil(["check", str(text), "--whole"]) in (0, 1)
    assert "no shipped spec" not in capsys.readouterr().err


# --- fields of the wrong type ---------------------------------------------------------------


def _verdict(change: Callable[[dict], None]) -> Callable[[str, dict], dict | None]:
    def f(topic: str, obj: dict) -> dict | None:
        if topic == "/timing/verdicts" and "constraint" in obj:
            change(obj)
            return obj
        return None
    return f


@pytest.mark.parametrize(("name", "change"), [
    ("window", lambda v: v.update(window_ms=5, uncertainty_ms=5)),
    ("spec_list", lambda v: v.update(spec=["emgs"], occurrence={"a": 1})),
    ("no_status", lambda v: v.pop("status")),
])
def test_a_verdict_record_of_the_wrong_shape_is_skipped_and_said(emgs, tmp_path, caplog,
                                                                 name, change):
    bad = _rewrite(emgs, tmp_path / f"{name}.mcap", _verdict(change))
    assert hil(["report", str(bad), "-o", str(tmp_path / "r.html")]) == 0
    assert "wrong shape skipped (the first: /timing/verdicts" in caplog.text
    assert (tmp_path / "r.html").is_file()


def test_a_step_record_whose_status_is_not_text_is_skipped(emgs, tmp_path, caplog):
    def f(topic: str, obj: dict) -> dict | None:
        if topic == "/plan/steps" and obj.get("event") != "start":
            obj["status"] = 3
            return obj
        return None

    bad = _rewrite(emgs, tmp_path / "s.mcap", f)
    assert hil(["report", str(bad), "-o", str(tmp_path / "r.html")]) == 0
    assert "/plan/steps field 'status' is int, not text" in caplog.text


def test_hostile_metadata_and_records_give_no_traceback(emgs, tmp_path, capsys):
    meta = Recording.open(emgs).metadata()
    deep = _rewrite(emgs, tmp_path / "deep.mcap", meta={"hil.plan": dict(meta["hil.plan"]) | {
        "tags": "[" * 100_000 + "]" * 100_000}})
    assert hil(["report", str(deep), "-o", str(tmp_path / "r.html"), "--index",
                str(tmp_path / "i.html")]) == 0
    big = _rewrite(emgs, tmp_path / "big.mcap", meta={"timing": dict(meta["timing"]) | {
        "constants": json.dumps({"tol": 10**400})}})
    assert hil(["check", str(big), "--whole"]) in (0, 1)

    def binding(v: dict) -> None:
        v["binding"] = {"drive": 5}

    bind = _rewrite(emgs, tmp_path / "bind.mcap", _verdict(binding))
    assert hil(["check", str(bind)]) in (0, 1, 4)

    def values(topic: str, obj: dict) -> dict | None:
        if topic.endswith("/params"):
            obj["values"] = "P1.043"
            return obj
        return None

    vals = _rewrite(emgs, tmp_path / "vals.mcap", values)
    assert hil(["check", str(vals), "--whole"]) in (0, 1, 3, 4)


def test_export_skips_frames_no_can_bus_carries(emgs, tmp_path, caplog):
    """An identifier past 29 bits or negative became candump `-01#00` / `10000000000#00`
    and a BLF writer's struct.error traceback."""
    ids = iter([-1, 2**40, 2**31])

    def frame(topic: str, obj: dict) -> dict | None:
        if topic.startswith("/can/") and (new := next(ids, None)) is not None:
            obj["id"], obj["ext"] = new, True
            return obj
        return None

    bad = _rewrite(emgs, tmp_path / "ids.mcap", frame)
    assert hil(["export", str(bad), "-o", str(tmp_path / "x.log")]) == 0
    assert "3 message(s) of a wrong shape skipped" in caplog.text
    for line in (tmp_path / "x.log").read_text().splitlines():
        ident = line.split()[2].split("#")[0]
        assert len(ident) in (3, 8) and int(ident, 16) < 2**29, line
    assert hil(["export", str(bad), "-o", str(tmp_path / "x.blf")]) == 0


@pytest.mark.parametrize(("topic_end", "field", "value", "what"), [
    ("/DO6", "level", "false", "is not a level"),        # BRKR: the text read as true
    ("/state", "servo_on", [], "is not a single value"),  # a list read as false
])
def test_a_signal_recorded_with_the_wrong_type_cannot_be_judged(emgs, tmp_path, capsys,
                                                                topic_end, field, value, what):
    """Judged as it was, "false" had been a level that never fell (a fail) and [] a servo
    that never switched (constraints skipped, exit 0)."""
    def f(topic: str, obj: dict) -> dict | None:
        if topic.endswith(topic_end) and field in obj:
            obj[field] = value
            return obj
        return None

    bad = _rewrite(emgs, tmp_path / "typed.mcap", f)
    assert hil(["check", str(bad), "--whole", "--spec", "emgs", "-v"]) == 3
    out = capsys.readouterr().out
    assert "INCONCLUSIVE" in out and what in out and "FAIL " not in out


def test_diff_json_is_strict_json_with_a_nan_parameter(emgs, tmp_path):
    """A recorded parameter NaN or Infinity came out as a bare NaN token in `--json`, which
    strict JSON readers refuse."""
    def f(topic: str, obj: dict) -> dict | None:
        if topic.endswith("/params") and isinstance(obj.get("values"), dict):
            obj["values"] = {k: float("nan") for k in obj["values"]} | {"P9.999": float("inf")}
            return obj
        return None

    bad = _rewrite(emgs, tmp_path / "nan.mcap", f)
    out = tmp_path / "d.json"
    assert hil(["diff", str(emgs), str(bad), "-o", str(tmp_path / "d.html"), "--json",
                str(out)]) in (0, 1, 4)

    def refuse(token: str) -> None:
        raise ValueError(f"not strict JSON: {token}")

    text = out.read_text()
    json.loads(text, parse_constant=refuse)
    assert '"NaN"' in text


def test_inspect_and_repair_read_past_a_damaged_chunk(emgs, tmp_path, capsys):
    """One flipped bit in the first chunk: `inspect` said nothing after it was readable and
    `--repair` wrote 0 messages, though the later chunks were whole. Now both step over it;
    `check` of the damaged file still stops there (exit 4), and of the repair too."""
    data = bytearray(emgs.read_bytes())
    chunks = [o for o, op, _ln in _records(bytes(data)) if op == 0x06]
    assert len(chunks) >= 2
    data[chunks[0] + 9 + 60] ^= 0x01  # inside the first chunk's compressed records
    bad = tmp_path / "crc.mcap"
    bad.write_bytes(bytes(data))
    whole = sum(1 for _ in Recording.open(emgs).raw_messages())
    assert hil(["inspect", str(bad)]) == 0
    out = capsys.readouterr().out
    assert "DAMAGED: 1 unreadable record(s) stepped over" in out
    fixed = tmp_path / "fixed.mcap"
    assert hil(["inspect", str(bad), "--repair", str(fixed)]) == 0
    got = Recording.open(fixed)
    n = sum(1 for _ in got.raw_messages())
    assert 0 < n < whole
    assert got.metadata()["hil.repair"]["skipped_records"] == "1"
    capsys.readouterr()
    assert hil(["check", str(bad)]) == 4
    assert hil(["check", str(fixed)]) == 4
    assert "repaired from a damaged" in capsys.readouterr().err


def test_review_a_repair_of_a_repair_and_diff_keep_the_cut(emgs, tmp_path, capsys):
    """A second repair had written `source_truncated: false` over the first's record, and
    `hil diff` took a repaired cut run as whole (a review of this session's change)."""
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(emgs.read_bytes()[: emgs.stat().st_size // 3])
    once, twice = tmp_path / "once.mcap", tmp_path / "twice.mcap"
    assert hil(["inspect", str(cut), "--repair", str(once)]) == 0
    assert hil(["inspect", str(once), "--repair", str(twice)]) == 0
    capsys.readouterr()
    assert hil(["check", str(twice)]) == 4
    assert "repaired from a" in capsys.readouterr().err
    assert hil(["diff", str(emgs), str(once), "-o", str(tmp_path / "d.html")]) == 4
    assert "repaired from a" in capsys.readouterr().err


def test_review_a_verdict_without_spec_or_constraint_is_still_shown(emgs, tmp_path, caplog):
    """hil.TimingVerdict makes spec and constraint optional; the shape check had dropped
    such a verdict (a failing one disappeared from the page)."""
    def f(v: dict) -> None:
        v.pop("spec")
        v.pop("constraint")

    bad = _rewrite(emgs, tmp_path / "nospec.mcap", _verdict(f))
    report_data._RUNS.clear()
    report_data._SUMMARIES.clear()
    run = report_data.load_run(bad)
    assert run.verdicts and "wrong shape" not in caplog.text


def test_review_recorded_spec_ids_never_reach_the_report_as_paths(emgs, tmp_path,
                                                                  monkeypatch):
    """`truth_fields` built fixture("timing", f"{id}.yaml") from the recording's ids: a
    `../` id opened any YAML file."""
    evil = tmp_path / "evil.yaml"
    evil.write_text("id: evil\n")
    meta = dict(Recording.open(emgs).metadata()["timing"])
    rel = "../" * 12 + str(evil.with_suffix(""))[1:]
    bad = _rewrite(emgs, tmp_path / "t.mcap", meta={"timing": meta | {
        "specs": json.dumps([rel])}})
    opened: list[str] = []
    from hil.timing import registry

    real = registry.load_spec_cached
    monkeypatch.setattr(registry, "load_spec_cached",
                        lambda p: (opened.append(str(p)), real(p))[1])
    report_data._RUNS.clear()
    report_data._SUMMARIES.clear()
    report_data.load_run(bad)
    assert not any("evil" in p for p in opened)
