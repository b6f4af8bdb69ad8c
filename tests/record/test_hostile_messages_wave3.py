"""Recordings with messages of a hostile shape, from an outside fuzz of the readers
(helper-45): JSON nested past the stack, NaN and Infinity where integers belong, lists and
texts where objects belong, CAN frames without an id, log times at 2^64 - 1, a damaged
`bench.yaml` attachment (an alias bomb) and a chunk stating 1 TB. Every command answers with
its documented exit code, never a traceback, and says what it skipped."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import pytest
from mcap.writer import CompressionType, Writer
from rec_helpers import copy_mcap

from hil.bench.bench import load_bench
from hil.cli import main as hil
from hil.paths import plans_dir
from hil.plan.plan import load_plan
from hil.plan.runner import run_plan

pytestmark = pytest.mark.virtual_time

BOMB = "a: &a [x, x, x, x, x, x, x, x, x]\n" + "".join(
    f"{c}: &{c} [*{p}, *{p}, *{p}, *{p}, *{p}, *{p}, *{p}, *{p}, *{p}]\n"
    for p, c in zip("abcdefgh", "bcdefghi", strict=True)) + "drives: {d: {wiring: *i}}\n"


@pytest.fixture(scope="module")
def genuine(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("genuine")
    res = run_plan(load_plan(plans_dir() / "servo_on_off_brake.yaml"), load_bench(None), out,
                   reports=False)
    assert res.passed
    return Path(res.recording)


def _rewrite(src: Path, dst: Path, payload, every: int = 7, *, log_time=None,
             attachment: tuple[str, bytes] | None = None,
             compression: CompressionType = CompressionType.ZSTD) -> Path:
    """`src` again with every `every`-th message of each topic replaced by `payload`."""
    seen: dict[str, int] = {}

    def message(topic: str, data: bytes, lt: int) -> tuple[bytes, int]:
        n = seen[topic] = seen.get(topic, 0) + 1
        if n % every:
            return data, lt
        return (payload if isinstance(payload, bytes) else payload.encode(),
                log_time if log_time is not None else lt)

    return copy_mcap(src, dst, message, attachment=attachment, compression=compression)


HOSTILE = {
    "deep": "[" * 100_000 + "]" * 100_000,
    "nan": '{"index": NaN, "line": Infinity, "id": Infinity, "sent_ns": NaN, "values": 1}',
    "list": "[1, 2, 3]",
    "text": '"text"',
    "types": '{"index": "x", "values": "str", "id": "str", "data": 5, "level": {}}',
}


@pytest.mark.parametrize("kind", sorted(HOSTILE))
def test_every_reader_takes_messages_of_a_hostile_shape(genuine, tmp_path, capsys, kind):
    bad = _rewrite(genuine, tmp_path / f"{kind}.mcap", HOSTILE[kind])
    runs = {
        "report": ["report", str(bad), "-o", str(tmp_path / "r.html"), "--junit",
                   str(tmp_path / "r.xml")],
        "diff": ["diff", str(genuine), str(bad), "-o", str(tmp_path / "d.html"),
                 "--json", str(tmp_path / "d.json")],
        "export": ["export", str(bad), "-o", str(tmp_path / "x.log")],
        "inspect": ["inspect", str(bad)],
        "check": ["check", str(bad)],
    }
    for name, argv in runs.items():
        code = hil(argv)  # a traceback would raise here
        assert code in (0, 1, 3, 4), (name, code, capsys.readouterr().err[-500:])


def test_a_damaged_bench_attachment_and_far_log_times(genuine, tmp_path):
    bomb = _rewrite(genuine, tmp_path / "bomb.mcap", "{}", every=10**9,
                    attachment=("bench.yaml", BOMB.encode()))
    assert hil(["diff", str(genuine), str(bomb), "-o", str(tmp_path / "d.html"),
                "--json", str(tmp_path / "d.json")]) == 0
    far = _rewrite(genuine, tmp_path / "far.mcap", "{}", every=50, log_time=2**64 - 1)
    assert hil(["inspect", str(far)]) == 0  # MCAP log times are unsigned 64-bit


def test_a_chunk_stating_a_terabyte_is_damage_not_an_allocation(genuine, tmp_path, capsys):
    lz4 = _rewrite(genuine, tmp_path / "lz4.mcap", "{}", every=10**9,
                   compression=CompressionType.LZ4)
    data = bytearray(lz4.read_bytes())
    off = 8
    while data[off] != 0x06:  # the first chunk record
        off += 9 + struct.unpack_from("<Q", data, off + 1)[0]
    struct.pack_into("<Q", data, off + 9 + 16, 2**40)  # uncompressed_size
    bomb = tmp_path / "claim.mcap"
    bomb.write_bytes(bytes(data))
    capsys.readouterr()
    assert hil(["check", str(bomb)]) == 4
    assert "more than a reader takes" in capsys.readouterr().err


def test_inspect_shows_no_escape_sequence_from_a_recording(genuine, tmp_path, capsys):
    evil = tmp_path / "evil.mcap"
    with open(evil, "wb") as g:
        w = Writer(g)
        w.start(profile="", library="test")
        sid = w.register_schema("hil.Json\x1b]0;T\x07", "jsonschema", b"{}")
        cid = w.register_channel("/x\x1b[2J\x1b[H", "json", sid, {})
        w.add_message(cid, log_time=1, publish_time=1, data=json.dumps({}).encode())
        w.add_metadata("hil.run", {"plan": "p\x1b[31m"})
        w.finish()
    capsys.readouterr()
    hil(["inspect", str(evil)])
    out = capsys.readouterr()
    assert "\x1b" not in out.out and "\x07" not in out.out
    assert "\\x1b[2J" in out.out
