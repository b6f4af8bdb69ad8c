"""`Recording.stream` (what `hil check` reads with) gives what `Recording.open` gives, one
record at a time: the same messages of the wanted topics, the same verdict on a truncated or
damaged file, and no message of a chunk it could not read whole."""

from __future__ import annotations

import io
import random

import pytest

from hil.record.mcapio import McapWriter
from hil.record.reader import Recording, RecordingError


def _file(tmp_path, n: int = 3000):
    buf = io.BytesIO()
    w = McapWriter(buf, chunk_size=4096)
    sid = w.add_schema("hil.Any", "jsonschema", b"{}")
    a = w.add_channel("/a", "json", sid, {})
    b = w.add_channel("/b", "json", sid, {})
    for i in range(n):
        w.add_message(a if i % 3 else b, i * 1000, i * 1000 + 7, b'{"i": %d}' % i)
        if i % 500 == 0:
            w.flush()
    w.add_metadata("hil.run", {"k": "v"})
    w.finish()
    path = tmp_path / "r.mcap"
    path.write_bytes(buf.getvalue())
    return path


def _streamed(path, topics):
    got = []
    rec = Recording.stream(path, topics, lambda *m: got.append(m))
    return rec, got


@pytest.mark.parametrize("topics", [None, ["/a"], ["/b", "/none"], []])
def test_stream_gives_what_open_gives(tmp_path, topics) -> None:
    path = _file(tmp_path)
    rec, got = _streamed(path, topics)
    whole = Recording.open(path)
    assert got == list(whole.raw_messages(topics if topics is not None else None))
    assert rec.metadata() == whole.metadata() == {"hil.run": {"k": "v"}}
    assert rec.message_topics == ["/a", "/b"]
    assert not rec.truncated and rec.error is None


def test_truncated_and_damaged_files_read_alike(tmp_path) -> None:
    path = _file(tmp_path)
    data = path.read_bytes()
    rng = random.Random(7)
    cut = tmp_path / "cut.mcap"
    for size in sorted(rng.sample(range(9, len(data)), 25)):
        cut.write_bytes(data[:size])
        rec, got = _streamed(cut, None)
        whole = Recording.open(cut)
        assert got == list(whole.raw_messages()), size
        assert (rec.truncated, rec.corrupt, rec.error) == (whole.truncated, whole.corrupt,
                                                          whole.error)
    for _ in range(10):  # a flipped byte mid-file: the chunk's CRC or its records break
        pos = rng.randrange(200, len(data) - 200)
        bad = bytearray(data)
        bad[pos] ^= 0x5A
        cut.write_bytes(bytes(bad))
        rec, got = _streamed(cut, None)
        whole = Recording.open(cut)
        assert got == list(whole.raw_messages()), pos
        assert (rec.corrupt, rec.error, rec.cut_log_ns) == (whole.corrupt, whole.error,
                                                           whole.cut_log_ns)


def test_not_a_recording_is_named(tmp_path) -> None:
    p = tmp_path / "x.mcap"
    p.write_bytes(b"not mcap at all")
    with pytest.raises(RecordingError, match=r"x\.mcap"):
        Recording.stream(p, None, lambda *m: None)
    with pytest.raises(RecordingError, match="not a regular"):
        Recording.stream(tmp_path, None, lambda *m: None)


def test_hostile_bytes_never_crash_the_stream_and_read_as_open_reads(tmp_path) -> None:
    """Fuzz: byte flips, bursts of junk, huge record lengths and cuts anywhere, in chunks
    and between them. Every outcome is what `Recording.open` says of the same bytes: the
    same messages or the same `RecordingError`."""
    data = _file(tmp_path, 1200).read_bytes()
    rng = random.Random(2026)
    bad = tmp_path / "bad.mcap"
    for k in range(300):
        b = bytearray(data)
        for _ in range(rng.randint(1, 4)):
            pos = rng.randrange(len(b))
            kind = rng.random()
            if kind < 0.4:
                b[pos] ^= 1 << rng.randrange(8)
            elif kind < 0.7:  # a record length field made huge or tiny
                b[pos:pos + 8] = rng.choice((b"\xff" * 8, b"\x00" * 8,
                                            rng.randbytes(8)))
            elif kind < 0.9:
                b[pos:pos] = rng.randbytes(rng.randint(1, 64))
            else:
                del b[pos:]
                break
        bad.write_bytes(bytes(b))
        try:
            whole = Recording.open(bad)
            want: object = (list(whole.raw_messages()), whole.error, whole.corrupt,
                            whole.metadata())
        except RecordingError as e:
            want = ("error", str(e))
        try:
            rec, got_msgs = _streamed(bad, None)
            got: object = (got_msgs, rec.error, rec.corrupt, rec.metadata())
        except RecordingError as e:
            got = ("error", str(e))
        assert got == want, k
        try:  # the head steps over the chunks: it never crashes, and knows no message
            head = Recording.head(bad)
            assert list(head.raw_messages()) == []
        except RecordingError:
            pass


def test_head_reads_what_a_recording_says_of_itself_without_its_chunks(tmp_path) -> None:
    """`Recording.head`: the metadata and attachments of a whole read and whether the file
    ends whole, with the chunks stepped over unread (no message; the channels only as the
    file's summary lists them)."""
    from hil.record import mcapio

    path = _file(tmp_path, 500)
    whole = Recording.open(path)
    opened: list[int] = []
    real = mcapio.decompress
    mcapio.decompress = lambda *a: (opened.append(1), real(*a))[1]
    try:
        head = Recording.head(path)
    finally:
        mcapio.decompress = real
    assert opened == []  # no chunk opened
    assert head.metadata() == whole.metadata() and head.metadata()
    assert [a.name for a in head.attachments()] == [a.name for a in whole.attachments()]
    assert not head.truncated and list(head.raw_messages()) == []
    assert head.topics() == whole.topics()  # from the summary of a whole file
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    assert Recording.head(cut).truncated


def test_a_callback_error_is_the_callers_not_damage(tmp_path) -> None:
    """An error raised by the caller's `on_message` (a bug, a payload it cannot take) comes
    out as that error: the file is not called damaged and the read does not end quietly."""
    path = _file(tmp_path, 500)

    def picky(topic, _lt, _pt, data):
        if b'"i": 250}' in data:
            raise KeyError("payload the caller cannot take")

    with pytest.raises(KeyError, match="cannot take"):
        Recording.stream(path, None, picky)

