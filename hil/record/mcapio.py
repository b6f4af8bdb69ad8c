"""A lean MCAP writer and a tolerant record scanner (MCAP spec, as `mcap` 1.6.0 writes it).

Why not `mcap.writer.Writer` on the hot path: its `add_message` builds a dataclass and a
`BytesIO` record per message (~4.5 µs, docs/dev/feasibility.md §5), which eats most of the
budget of a saturated CAN bus plus its decoded twin. Here a message is one `struct.pack` and
two list appends; everything that is not per message (schema, channel, chunk, indexes, summary,
footer) reuses `mcap.records`, so the bytes are those of the official writer.

Crash safety: `flush()` closes the open chunk early and writes it, so every message added
before a `flush()` survives a `kill -9` (the file then lacks only its summary and footer).
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from io import BytesIO
from typing import IO, Any

from mcap.data_stream import ReadDataStream, RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    Attachment,
    AttachmentIndex,
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)

try:
    import zstandard
except ImportError:  # pragma: no cover - zstandard ships with our mcap install
    zstandard = None
try:
    import lz4.frame as lz4frame
except ImportError:  # pragma: no cover
    lz4frame = None

MAGIC = b"\x89MCAP0\r\n"
_MSG = struct.Struct("<BQHIQQ").pack  # opcode, record length, channel, sequence, log, publish
_MSG_OVERHEAD = 31  # bytes of a Message record before its data
_REC = struct.Struct("<BQ")
_MSG_BODY = struct.Struct("<HIQQ")
_CHUNK_HEAD = struct.Struct("<QQQI")


class McapWriter:
    """Minimal chunked MCAP writer. Not thread-safe: one owner thread calls it."""

    def __init__(
        self,
        stream: IO[bytes],
        *,
        chunk_size: int = 64 * 1024,
        compression: str = "zstd",
        library: str = "hil",
        profile: str = "",
    ) -> None:
        if compression == "zstd" and zstandard is None:
            compression = "lz4" if lz4frame is not None else ""
        if compression == "lz4" and lz4frame is None:
            compression = ""
        if compression not in ("zstd", "lz4", "", "none"):
            raise ValueError(f"compression {compression!r}: must be 'zstd', 'lz4' or 'none'")
        self.compression = "" if compression == "none" else compression
        self._zstd = zstandard.ZstdCompressor(level=3) if self.compression == "zstd" else None
        self._f = stream
        self.chunk_size = chunk_size
        self._schemas: list[Schema] = []
        self._channels: list[Channel] = []
        self._chunk_indexes: list[ChunkIndex] = []
        self._attachment_indexes: list[AttachmentIndex] = []
        self._metadata_indexes: list[MetadataIndex] = []
        self._counts: dict[int, int] = {}
        self.message_count = 0
        self._t_min = 0
        self._t_max = 0
        self._metadata_count = 0
        self._attachment_count = 0
        self._reset_chunk()
        self._pos = 0
        self._write(MAGIC)
        rb = RecordBuilder()
        Header(profile=profile, library=library).write(rb)
        self._write(rb.end())
        self._finished = False

    # -- internals -------------------------------------------------------------------------
    def _write(self, data: bytes) -> None:
        self._f.write(data)
        self._pos += len(data)

    def _reset_chunk(self) -> None:
        self._parts: list[bytes] = []
        self._size = 0
        self._n = 0
        self._c_min = 1 << 64
        self._c_max = 0
        self._index: dict[int, list[int]] = {}

    def _chunk_record(self, data: bytes) -> None:
        self._parts.append(data)
        self._size += len(data)

    # -- records -----------------------------------------------------------------------------
    def add_schema(self, name: str, encoding: str, data: bytes) -> int:
        schema = Schema(id=len(self._schemas) + 1, data=data, encoding=encoding, name=name)
        self._schemas.append(schema)
        rb = RecordBuilder()
        schema.write(rb)
        self._chunk_record(rb.end())
        return schema.id

    def add_channel(
        self, topic: str, message_encoding: str, schema_id: int, metadata: dict[str, str]
    ) -> int:
        channel = Channel(
            id=len(self._channels) + 1,
            topic=topic,
            message_encoding=message_encoding,
            metadata=dict(metadata),
            schema_id=schema_id,
        )
        self._channels.append(channel)
        self._counts[channel.id] = 0
        rb = RecordBuilder()
        channel.write(rb)
        self._chunk_record(rb.end())
        return channel.id

    def add_message(
        self, channel_id: int, log_time: int, publish_time: int, data: bytes, sequence: int = 0
    ) -> None:
        """Append one message to the open chunk (closes the chunk when it is full)."""
        n = len(data)
        offset = self._size
        self._parts.append(_MSG(5, 22 + n, channel_id, sequence, log_time, publish_time))
        self._parts.append(data)
        self._size = offset + _MSG_OVERHEAD + n
        self._n += 1
        idx = self._index.get(channel_id)
        if idx is None:
            idx = self._index[channel_id] = []
        idx.append(log_time)
        idx.append(offset)
        if log_time < self._c_min:
            self._c_min = log_time
        if log_time > self._c_max:
            self._c_max = log_time
        if self._size >= self.chunk_size:
            self.close_chunk()

    def close_chunk(self) -> None:
        """Write the open chunk and its message indexes (no-op without messages)."""
        if self._n == 0:
            return
        raw = b"".join(self._parts)
        if self.compression == "zstd":
            data = self._zstd.compress(raw)
        elif self.compression == "lz4":
            data = lz4frame.compress(raw)
        else:
            data = raw
        chunk = Chunk(
            compression=self.compression,
            data=data,
            message_start_time=self._c_min,
            message_end_time=self._c_max,
            uncompressed_crc=zlib.crc32(raw),
            uncompressed_size=len(raw),
        )
        rb = RecordBuilder()
        chunk.write(rb)
        chunk_bytes = rb.end()
        start = self._pos
        self._write(chunk_bytes)
        index_start = self._pos
        offsets: dict[int, int] = {}
        parts = []
        pos = index_start
        for cid, flat in self._index.items():
            k = len(flat)
            rec = struct.pack(f"<BQHI{k}Q", Opcode.MESSAGE_INDEX, 6 + 8 * k, cid, 8 * k, *flat)
            offsets[cid] = pos
            pos += len(rec)
            parts.append(rec)
            self._counts[cid] += k // 2
        index_bytes = b"".join(parts)
        self._write(index_bytes)
        self._chunk_indexes.append(
            ChunkIndex(
                message_start_time=self._c_min,
                message_end_time=self._c_max,
                chunk_start_offset=start,
                chunk_length=len(chunk_bytes),
                message_index_offsets=offsets,
                message_index_length=len(index_bytes),
                compression=self.compression,
                compressed_size=len(data),
                uncompressed_size=len(raw),
            )
        )
        if self.message_count == 0:
            self._t_min = self._c_min
        else:
            self._t_min = min(self._t_min, self._c_min)
        self._t_max = max(self._t_max, self._c_max)
        self.message_count += self._n
        self._reset_chunk()

    def flush(self) -> None:
        """Close the open chunk and push everything to the OS (survives kill -9)."""
        self.close_chunk()
        self._f.flush()

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        rb = RecordBuilder()
        Metadata(name=name, metadata=dict(data)).write(rb)
        rec = rb.end()
        self._metadata_indexes.append(MetadataIndex(offset=self._pos, length=len(rec), name=name))
        self._metadata_count += 1
        self._write(rec)

    def add_attachment(
        self, name: str, media_type: str, data: bytes, log_time: int, create_time: int = 0
    ) -> None:
        rb = RecordBuilder()
        Attachment(
            create_time=create_time,
            log_time=log_time,
            name=name,
            media_type=media_type,
            data=data,
        ).write(rb)
        rec = rb.end()
        self._attachment_indexes.append(
            AttachmentIndex(
                offset=self._pos,
                length=len(rec),
                log_time=log_time,
                create_time=create_time,
                data_size=len(data),
                name=name,
                media_type=media_type,
            )
        )
        self._attachment_count += 1
        self._write(rec)

    def finish(self) -> None:
        """Write data end, summary (schemas, channels, statistics, indexes) and footer."""
        if self._finished:
            return
        self._finished = True
        # Schemas/channels registered after the last message still belong in the data section.
        if self._n == 0 and self._parts:
            self._write(b"".join(self._parts))
            self._reset_chunk()
        self.close_chunk()
        rb = RecordBuilder()
        DataEnd(data_section_crc=0).write(rb)
        self._write(rb.end())
        summary_start = self._pos
        sb = RecordBuilder()
        offsets: list[SummaryOffset] = []

        def group(opcode: Opcode, records: list[Any]) -> None:
            if not records:
                return
            begin = sb.count
            for r in records:
                r.write(sb)
            offsets.append(SummaryOffset(opcode, summary_start + begin, sb.count - begin))

        group(Opcode.SCHEMA, self._schemas)
        group(Opcode.CHANNEL, self._channels)
        stats = Statistics(
            message_count=self.message_count,
            schema_count=len(self._schemas),
            channel_count=len(self._channels),
            attachment_count=self._attachment_count,
            metadata_count=self._metadata_count,
            chunk_count=len(self._chunk_indexes),
            message_start_time=self._t_min,
            message_end_time=self._t_max,
            channel_message_counts=dict(self._counts),
        )
        group(Opcode.STATISTICS, [stats])
        group(Opcode.CHUNK_INDEX, self._chunk_indexes)
        group(Opcode.ATTACHMENT_INDEX, self._attachment_indexes)
        group(Opcode.METADATA_INDEX, self._metadata_indexes)
        offset_start = summary_start + sb.count
        for o in offsets:
            o.write(sb)
        summary = sb.end()
        crc = zlib.crc32(summary)
        crc = zlib.crc32(struct.pack("<BQQQ", Opcode.FOOTER, 20, summary_start, offset_start), crc)
        self._write(summary)
        fb = RecordBuilder()
        Footer(
            summary_start=summary_start, summary_offset_start=offset_start, summary_crc=crc
        ).write(fb)
        self._write(fb.end())
        self._write(MAGIC)
        self._f.flush()


# -- tolerant scanning -----------------------------------------------------------------------
@dataclass
class Scan:
    """Everything readable in a (possibly truncated) MCAP byte string."""

    schemas: dict[int, Schema]
    channels: dict[int, Channel]
    chunks: list[bytes]  # uncompressed chunk payloads, file order
    loose: list[tuple[int, int, int, bytes]]  # messages outside chunks (cid, log, pub, data)
    metadata: list[Metadata]
    attachments: list[Attachment]
    has_footer: bool
    has_data_end: bool
    error: str | None  # first broken record, or None
    error_offset: int | None
    size: int
    corrupt: bool = False  # the broken record was whole but unreadable (not merely cut short)
    # damage: an unreadable chunk's first log time (its header was readable), else just after
    # the last message read before it: every message logged before it was read
    cut_log_ns: int | None = None
    chunk_count: int = 0  # chunk records met (read or stepped over)
    #: why each whole record that could not be read was stepped over (`past_damage`)
    skipped: list[str] = field(default_factory=list)
    stated_chunks: int | None = None  # what the summary's Statistics record says
    #: attachments whose CRC failed (name, offset): left out of `attachments`
    bad_attachments: list[str] = field(default_factory=list)
    #: the latest log time of any message read (chunk headers' end times, loose messages)
    last_log_ns: int | None = None
    #: why the summary's pointers (the footer's summary offsets, a chunk index's chunk
    #: offset) do not point where they say, in a file otherwise whole: its messages read in
    #: order, but an indexed reader (Foxglove, `mcap` with its index) fails on it
    index_error: str | None = None
    #: a file cut short with no damage (a killed run): the cut chunk's first log time, when
    #: its header was there to read, else just after the last message read (every message
    #: logged before it was read)
    tail_log_ns: int | None = None


def _parse(cls: Any, body: bytes) -> Any:
    return cls.read(ReadDataStream(BytesIO(body)))


# the most a chunk may hold, uncompressed: hil writes 64 KiB chunks, other writers a few MiB;
# a chunk stating more is damaged or a bomb (one lz4 chunk of 1 GB of zeros fits in 4.7 MB)
MAX_CHUNK_BYTES = 256 * 1024 * 1024


def decompress(compression: str, data: bytes, size: int) -> bytes:
    """A chunk's records: exactly the `size` bytes it states, or ValueError (damage). Never
    more than `size` + 1 bytes are made, whatever the compressed data declares (a 98 KB zstd
    frame declaring 3 GiB had been decompressed whole)."""
    if compression == "":
        out = data
    elif size > MAX_CHUNK_BYTES:
        raise ValueError(f"chunk states {size:,} bytes uncompressed, more than a reader takes "
                         f"({MAX_CHUNK_BYTES:,})")
    elif compression == "zstd":
        if zstandard is None:
            raise ValueError("chunk is zstd-compressed but zstandard is not installed")
        reader = zstandard.ZstdDecompressor().stream_reader(data)
        parts, got = [], 0
        while got <= size:
            part = reader.read(size + 1 - got)
            if not part:
                break
            parts.append(part)
            got += len(part)
        out = b"".join(parts)
    elif compression == "lz4":
        if lz4frame is None:
            raise ValueError("chunk is lz4-compressed but lz4 is not installed")
        # never more than the chunk says it holds (a 4.7 MB file of one lz4 chunk of 1 GB
        # of zeros took 2 GB)
        out = lz4frame.LZ4FrameDecompressor().decompress(data, max_length=size + 1)
    else:
        raise ValueError(f"unknown chunk compression {compression!r}")
    if len(out) > size:
        raise ValueError(f"{compression or 'uncompressed'} chunk holds more than its stated "
                         f"{size:,} bytes")
    if len(out) < size:
        raise ValueError(f"{compression or 'uncompressed'} chunk holds {len(out):,} bytes, "
                         f"not its stated {size:,}")
    return out


def iter_chunk(buf: bytes, schemas: dict, channels: dict,
               keep: Callable[[int], bool] | None = None, kept: dict[int, bool] | None = None
               ) -> Iterator[tuple[int, int, int, bytes]]:
    """Messages of one uncompressed chunk; schema and channel records update the dicts.
    `keep(channel id)`: only those messages are yielded (the others are walked, not copied);
    `kept` caches its answers (asked first)."""
    off = 0
    n = len(buf)
    unpack_rec = _REC.unpack_from
    unpack_msg = _MSG_BODY.unpack_from
    while off + 9 <= n:
        op, ln = unpack_rec(buf, off)
        if op == 0:  # no MCAP record has opcode 0 (a zeroed chunk was walked 9 bytes a step)
            raise ValueError(f"record with opcode 0x00 (invalid) at chunk offset {off}")
        body = off + 9
        end = body + ln
        if end > n:
            raise ValueError(f"record at chunk offset {off} runs past the chunk end")
        if op == 5:
            cid, _seq, lt, pt = unpack_msg(buf, body)
            if keep is not None:
                k = kept.get(cid) if kept is not None else None
                if not (k if k is not None else keep(cid)):
                    off = end
                    continue
            yield cid, lt, pt, buf[body + 22 : end]
        elif op == 3:
            s = _parse(Schema, buf[body:end])
            schemas[s.id] = s
        elif op == 4:
            c = _parse(Channel, buf[body:end])
            channels[c.id] = c
        off = end


class FileBytes:
    """The slices of an open file that `scan` asks for, read when asked: a recording is
    scanned without holding the whole file in memory."""

    def __init__(self, f: IO[bytes], size: int,
                 on_read: Callable[[int], None] | None = None) -> None:
        self._f = f
        self._size = size
        self._on_read = on_read  # told the offset each read ended at (progress)

    def __len__(self) -> int:
        return self._size

    def __getitem__(self, s: slice) -> bytes:
        start = s.start or 0
        stop = self._size if s.stop is None else min(s.stop, self._size)
        if stop <= start:
            return b""
        self._f.seek(start)
        data = self._f.read(stop - start)
        if self._on_read is not None:
            self._on_read(stop)
        return data


#: what `scan` hands each readable chunk instead of keeping it: (uncompressed payload,
#: schemas, channels); it walks the chunk itself and raises on a broken record
ChunkSink = Callable[[bytes, dict, dict], None]


_IN_CHUNKS = frozenset((Opcode.CHUNK, Opcode.MESSAGE_INDEX))  # what `chunks=False` steps over


_COMPRESSIONS = (b"", b"zstd", b"lz4")


def _after_read(out: Scan) -> int:
    """Where damage that gives no time of its own cuts: just after the last message read."""
    return out.last_log_ns + 1 if out.last_log_ns is not None else 0


def _resync(data: bytes | FileBytes, start: int, n: int) -> int | None:
    """The offset of the next whole chunk record at or after `start` whose header holds
    together (times in order, a known compression, its records' length the rest of the
    record): where reading goes on past a record whose length was damaged. None if none."""
    window = 1 << 20
    pos = start
    while pos < n:
        buf = data[pos : pos + window + 64]
        i = buf.find(b"\x06")
        while i != -1 and i < window:
            at = pos + i
            head = data[at : at + 9 + 40]
            if len(head) >= 9 + 36:
                ln = int.from_bytes(head[1:9], "little")
                c_min, c_max, usize, _crc = _CHUNK_HEAD.unpack_from(head, 9)
                clen = int.from_bytes(head[37:41], "little")
                if (at + 9 + ln <= n and c_min <= c_max and usize <= MAX_CHUNK_BYTES
                        and clen <= 4):
                    tail = data[at + 41 : at + 41 + clen + 8]
                    if (len(tail) == clen + 8 and tail[:clen] in _COMPRESSIONS
                            and int.from_bytes(tail[clen:], "little") == ln - 40 - clen):
                        return at
            i = buf.find(b"\x06", i + 1)
        pos += window
    return None


def _starts_record(data: bytes | FileBytes, at: int, n: int) -> int | None:
    """The end of a record that could start at `at` (a known opcode, its length within the
    file), else None."""
    head = data[at : at + 9]
    if len(head) < 9:
        return None
    op, ln = _REC.unpack_from(head, 0)
    end = at + 9 + ln
    return end if 0 < op <= max(Opcode) and end <= n else None


def _after_zeros(data: bytes | FileBytes, off: int, n: int) -> int | None:
    """Where reading goes on past a run of zeroed bytes at `off` inside a file (a block the
    disk lost, index records zeroed): the first non-zero byte when a record starts there and
    another (or the file's closing magic) right after it, so that the metadata and chunks
    after the zeros are kept (helper-137: a repair kept none of them); else the next whole
    chunk record (`_resync`). None when nothing whole follows."""
    z = off
    while z < n:
        buf = data[z : z + 65536]
        rest = buf.lstrip(b"\0")
        z += len(buf) - len(rest)
        if rest:
            break
    if z < n:
        end = _starts_record(data, z, n)
        if end is not None and (data[end : end + 8] == MAGIC
                                or _starts_record(data, end, n) is not None):
            return z
    return _resync(data, off + 1, n)


def scan(data: bytes | FileBytes, sink: ChunkSink | None = None, *,
         chunks: bool = True, past_damage: bool = False) -> Scan:
    """Read every complete record of `data`; stop at the first broken one and say where.
    With `sink`, each chunk goes to it (after its CRC check) and is not kept; the sink's
    walk is the chunk's structural check, so it must keep nothing of a chunk it could not
    walk to the end. `chunks=False`: chunks are stepped over unread (what the file says of
    itself outside them: metadata, attachments, its end). `past_damage`: a whole record
    that cannot be read (a chunk whose CRC fails, say) is stepped over and the scan goes on
    with the next (`Scan.skipped`); `error`, `corrupt` and `cut_log_ns` still say the first
    (what `hil inspect --repair` recovers; a checker stops at the first)."""
    out = Scan({}, {}, [], [], [], [], False, False, None, None, len(data))
    if data[:8] != MAGIC:
        raise ValueError("not an MCAP file (bad magic at offset 0)")
    off = 8
    n = len(data)
    summary_at: int | None = None
    chunk_at: set[int] = set()  # where each chunk record starts (a chunk index points there)
    while off < n:
        head = data[off : off + 9]
        if len(head) < 9:
            out.error, out.error_offset = f"truncated record header at offset {off}", off
            break
        op, ln = _REC.unpack_from(head, 0)
        if op == 0:  # no MCAP record has opcode 0: zeroed or foreign bytes
            text = f"record with opcode 0x00 (invalid) at offset {off}"
            # zeros to the end (as far as looked) are a tail the file system never filled
            # after a crash, a cut like a killed run's; anything else is damage
            corrupt = any(data[off : off + 65536])
            if out.error is None:  # the first damage is the one said (`error`)
                out.error, out.error_offset, out.corrupt = text, off, corrupt
                if corrupt:
                    out.cut_log_ns = _after_read(out)
            nxt = _after_zeros(data, off, n) if past_damage and corrupt else None
            if nxt is not None:  # zeroed bytes inside the file: whole records follow
                out.skipped.append(f"{text}; whole records follow at offset {nxt}")
                off = nxt
                continue
            break
        end = off + 9 + ln
        if end > n:
            nxt = _resync(data, off + 1, n) if past_damage else None
            if nxt is not None:  # its length was damaged: whole chunks follow it
                text = (f"record (opcode 0x{op:02x}) at offset {off} unreadable: its length "
                        f"({ln:,} bytes) runs past the file's end; whole records follow at "
                        f"offset {nxt}")
                if out.error is None:
                    out.error, out.error_offset, out.corrupt = text, off, True
                    out.cut_log_ns = _after_read(out)
                out.skipped.append(text)
                off = nxt
                continue
            if n - off > 8 + 9 and data[n - 8 : n] == MAGIC:  # the file's own end is there:
                # not a killed run's last record, but a length that was damaged
                out.error = (f"record (opcode 0x{op:02x}) at offset {off} unreadable: its "
                             f"length ({ln:,} bytes) runs past the file's end, which has its "
                             "closing magic")
                out.error_offset, out.corrupt = off, True
                out.cut_log_ns = _after_read(out)
                break
            out.error = f"record (opcode 0x{op:02x}) at offset {off} truncated: needs {ln} bytes"
            out.error_offset = off
            if op == Opcode.CHUNK and off + 17 <= n:  # its message_start_time is there
                (out.tail_log_ns,) = struct.unpack("<Q", data[off + 9 : off + 17])
            break
        if op == Opcode.CHUNK:
            out.chunk_count += 1
            chunk_at.add(off)
        if not chunks and op in _IN_CHUNKS:
            off = end
            continue
        rec = data[off + 9 : end]
        c_min: int | None = None
        try:
            if op == Opcode.CHUNK:
                c_min, c_max, usize, ucrc = _CHUNK_HEAD.unpack_from(rec, 0)
                p = 28
                (clen,) = struct.unpack_from("<I", rec, p)
                comp = rec[p + 4 : p + 4 + clen].decode()
                p += 4 + clen
                (dlen,) = struct.unpack_from("<Q", rec, p)
                if p + 8 + dlen > len(rec):
                    raise ValueError(f"chunk's records ({dlen:,} bytes) run past its end")
                raw = decompress(comp, rec[p + 8 : p + 8 + dlen], usize)
                if ucrc and zlib.crc32(raw) != ucrc:
                    raise ValueError("chunk CRC mismatch")
                if sink is not None:
                    sink(raw, out.schemas, out.channels)
                else:
                    # validate structure now so a bad chunk is reported as the broken record
                    for _ in iter_chunk(raw, out.schemas, out.channels):
                        pass
                    out.chunks.append(raw)
                if out.last_log_ns is None or c_max > out.last_log_ns:
                    out.last_log_ns = c_max
            elif op == Opcode.MESSAGE:
                cid, _seq, lt, pt = _MSG_BODY.unpack_from(rec, 0)
                out.loose.append((cid, lt, pt, rec[22:]))
                if out.last_log_ns is None or lt > out.last_log_ns:
                    out.last_log_ns = lt
            elif op == Opcode.SCHEMA:
                s = _parse(Schema, rec)
                out.schemas[s.id] = s
            elif op == Opcode.CHANNEL:
                c = _parse(Channel, rec)
                out.channels[c.id] = c
            elif op == Opcode.METADATA:
                out.metadata.append(_parse(Metadata, rec))
            elif op == Opcode.ATTACHMENT:
                a = _parse(Attachment, rec)
                # MCAP: a CRC-32 of the record's preceding fields, 0 = none. A damaged one
                # is left out, said (`bad_attachments`), and the messages read on
                (crc,) = struct.unpack_from("<I", rec, len(rec) - 4)
                if crc and zlib.crc32(rec[:-4]) != crc:
                    out.bad_attachments.append(f"{a.name!r} at offset {off}: CRC mismatch")
                else:
                    out.attachments.append(a)
            elif op == Opcode.DATA_END:
                out.has_data_end = True
                summary_at = end  # the summary, if any, starts right after data end
            elif op == Opcode.CHUNK_INDEX and out.index_error is None:
                (at,) = struct.unpack_from("<Q", rec, 16)  # message start/end time first
                if at not in chunk_at:  # (not read from the file: the reading stays in order)
                    out.index_error = (f"the chunk index at offset {off} points to offset "
                                       f"{at}, where no chunk starts")
            elif op == Opcode.STATISTICS:  # chunk_count after message, schema, channel,
                (out.stated_chunks,) = struct.unpack_from("<I", rec, 22)  # attachment and
                # metadata counts (MCAP spec, Statistics)
            elif op == Opcode.FOOTER:
                if data[end : end + 8] != MAGIC:
                    out.error = f"closing magic missing after the footer at offset {off}"
                    out.error_offset = end
                elif n > end + 8:  # `cat a.mcap b.mcap`: what follows is unread
                    out.error = (f"{n - end - 8:,} bytes after the closing magic at offset "
                                 f"{end}: not part of this recording (files joined?)")
                    out.error_offset = end + 8
                    out.corrupt = True
                out.has_footer = True
                s_start, s_offsets = struct.unpack_from("<QQ", rec, 0)
                if out.index_error is None and s_start and (  # 0: none (MCAP spec)
                        s_start != summary_at or (s_offsets and not s_start <= s_offsets <= off)):
                    out.index_error = (
                        f"the footer says the summary starts at offset {s_start} and its "
                        f"offsets at {s_offsets}; the summary starts at "
                        f"{summary_at if summary_at is not None else '?'}")
                break
        except Exception as exc:  # a broken record ends the readable part
            what = "chunk" if op == Opcode.CHUNK else f"record (opcode 0x{op:02x})"
            why = str(exc) or type(exc).__name__  # a MemoryError says nothing of itself
            text = f"{what} at offset {off} unreadable: {why}"
            if out.error is None:
                out.error, out.error_offset = text, off
                out.corrupt = True
                out.cut_log_ns = c_min if c_min is not None else _after_read(out)
            if not past_damage:
                break
            out.skipped.append(text)
        off = end
    if (out.error is None and out.has_footer and out.stated_chunks is not None
            and out.stated_chunks != out.chunk_count):  # a chunk cut out of a whole file
        out.error = (f"the summary counts {out.stated_chunks} chunk(s) but the file holds "
                     f"{out.chunk_count}: part of the recording is missing")
        out.error_offset = None
        out.corrupt = True
    # where what was read ends, when nothing said it sooner: after the last message read
    if out.corrupt and out.cut_log_ns is None:
        out.cut_log_ns = _after_read(out)
    elif not out.corrupt and (out.error or not out.has_footer) and out.tail_log_ns is None:
        out.tail_log_ns = _after_read(out)
    return out
