"""Recorder throughput vs the bare `mcap` Writer, same CAN frames, same run.

    .venv/bin/python benchmarks/bench_record.py [N]

Recorder: `Recorder.can()` from the calling thread (as a bus thread would), then `close()`;
the time includes the writer thread draining the queue, raw JSON, decoded CANopen
(`hil.protocol.canopen.describe_frame` if present), SDO pairing and zstd chunks of 64 KiB.
Bare: `mcap.writer.Writer.add_message` with the raw JSON pre-encoded (no decoding), 1 MiB
chunks (its default). Also a Recorder run without decoding (`decode=False`) and the reader.
Then the issue's baseline: the bare Writer on exactly the messages each recorder run wrote
(read back from its file, already encoded, 64 KiB chunks like the recorder's), best of three
runs of each against best of three of the recorder.
"""

from __future__ import annotations

import os
import sys
import tempfile
import time

import can
from mcap.reader import make_reader
from mcap.writer import Writer

from hil.record.reader import Recording
from hil.record.recorder import Recorder

BUS_FPS = 9000  # saturated 1 Mbit/s CAN, 8-byte frames (~111 bits each)


def frames(n: int) -> list[can.Message]:
    out = []
    for i in range(n):
        node = 1 + i % 4
        k = i % 10
        if k < 6:  # TPDO/RPDO traffic with changing data
            cid = (0x180, 0x200, 0x280, 0x300, 0x380, 0x400)[k] + node
            data = (i & 0xFFFFFFFF).to_bytes(4, "little") + bytes([0x37, 0x06, k, 0])
        elif k == 6:
            cid, data = 0x80, b""  # SYNC
        elif k == 7:
            cid, data = 0x700 + node, b"\x05"  # heartbeat
        elif k == 8:
            cid, data = 0x600 + node, bytes([0x40, 0x41, 0x60, 0, 0, 0, 0, 0])
        else:
            cid, data = 0x580 + node, bytes([0x4B, 0x41, 0x60, 0, 0x37, 0x06, 0, 0])
        out.append(can.Message(arbitration_id=cid, data=data, is_extended_id=False))
    return out


def run_recorder(path: str, msgs: list[can.Message], decode: bool) -> tuple[float, Recorder]:
    t0 = time.perf_counter()
    rec = Recorder(path, decode=decode, max_queue=len(msgs) + 10)
    base = time.time_ns()
    can_ = rec.can
    for i, m in enumerate(msgs):
        can_("can0", m, "rx" if i & 1 else "tx", base + i * 1000, None)
    rec.close()
    return time.perf_counter() - t0, rec


def run_bare(path: str, msgs: list[can.Message]) -> float:
    t0 = time.perf_counter()
    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        sid = w.register_schema("hil.CanFrame", "jsonschema", b"{}")
        cid = w.register_channel("/can/can0/raw", "json", sid)
        base = time.time_ns()
        for i, m in enumerate(msgs):
            data = (
                f'{{"id":{m.arbitration_id},"ext":false,"rtr":false,"err":false,"fd":false,'
                f'"brs":false,"esi":false,"dlc":{m.dlc},"data":"{m.data.hex()}",'
                f'"dir":"{"rx" if i & 1 else "tx"}"}}'
            ).encode()
            t = base + i * 1000
            w.add_message(cid, t, data, t)
        w.finish()
    return time.perf_counter() - t0


def recorded(path: str) -> tuple[list, list]:
    """(channels as (topic, schema name, schema bytes), messages as (channel index, log time,
    publish time, bytes)) of a recording, in file order: what a bare writer writes again."""
    with open(path, "rb") as f:
        chans: dict[int, int] = {}
        channels: list = []
        out = []
        for schema, channel, m in make_reader(f).iter_messages(log_time_order=False):
            k = chans.get(channel.id)
            if k is None:
                k = chans[channel.id] = len(channels)
                channels.append((channel.topic, schema.name, schema.data))
            out.append((k, m.log_time, m.publish_time, bytes(m.data)))
    return channels, out


def run_bare_same(path: str, channels: list, messages: list) -> float:
    """The bare `mcap` Writer writing exactly the messages the recorder wrote, already
    encoded (the issue's baseline: "a bare mcap writer on the same messages")."""
    t0 = time.perf_counter()
    with open(path, "wb") as f:
        w = Writer(f, chunk_size=64 * 1024)  # the recorder's chunk size
        w.start()
        ids = []
        for topic, name, data in channels:
            sid = w.register_schema(name, "jsonschema", data)
            ids.append(w.register_channel(topic, "json", sid))
        for k, lt, pt, data in messages:
            w.add_message(ids[k], lt, data, pt)
        w.finish()
    return time.perf_counter() - t0


def main() -> int:
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 200_000
    msgs = frames(n)
    with tempfile.TemporaryDirectory() as tmp:
        p_rec, p_raw, p_bare = (os.path.join(tmp, x) for x in ("rec.mcap", "raw.mcap", "b.mcap"))
        dt_rec, rec = run_recorder(p_rec, msgs, decode=True)
        dt_raw, rec_raw = run_recorder(p_raw, msgs, decode=False)
        dt_bare = run_bare(p_bare, msgs)
        same = {}  # the bare writer on the very messages each recorder run wrote
        for name, p in (("decode", p_rec), ("no decode", p_raw)):
            channels, written = recorded(p)
            same[name] = (len(written), min(run_bare_same(os.path.join(tmp, "s.mcap"),
                                                          channels, written)
                                            for _ in range(3)))
        # the recorder again, best of three each, against the bare writer's best of three
        dt_rec = min([dt_rec] + [run_recorder(p_rec, msgs, decode=True)[0] for _ in range(2)])
        dt_raw = min([dt_raw] + [run_recorder(p_raw, msgs, decode=False)[0] for _ in range(2)])
        t0 = time.perf_counter()
        r = Recording.open(p_rec)
        n_read = sum(1 for _ in r.messages())
        dt_read = time.perf_counter() - t0
        total = r.counts()
        size_rec, size_raw, size_bare = (os.path.getsize(p) for p in (p_rec, p_raw, p_bare))
    fps_rec, fps_raw, fps_bare = n / dt_rec, n / dt_raw, n / dt_bare
    print(f"frames: {n:,}   decoders: {r.metadata().get('hil.close', {}).get('decoders')}")
    print(f"messages written per frame (recorder, decoding): {n_read / n:.2f}  {total}")
    print(
        f"recorder (decode)   : {fps_rec:>10,.0f} frames/s  {size_rec / n:6.1f} B/frame  "
        f"{fps_rec / BUS_FPS:5.1f}x of a saturated 1 Mbit/s bus ({BUS_FPS} frames/s)  "
        f"drops={rec.drops} errors={rec.errors}"
    )
    print(
        f"recorder (no decode): {fps_raw:>10,.0f} frames/s  {size_raw / n:6.1f} B/frame  "
        f"{fps_raw / BUS_FPS:5.1f}x of a saturated 1 Mbit/s bus ({BUS_FPS} frames/s)  "
        f"drops={rec_raw.drops}"
    )
    print(
        f"bare mcap Writer    : {fps_bare:>10,.0f} frames/s  {size_bare / n:6.1f} B/frame  "
        f"{fps_bare / BUS_FPS:5.1f}x of a saturated 1 Mbit/s bus"
    )
    print(
        f"ratio recorder(no decode)/bare: {fps_raw / fps_bare:.2f}   "
        f"recorder(decode)/bare: {fps_rec / fps_bare:.2f}"
    )
    print("the issue's baseline, the bare mcap Writer on the same messages (already encoded):")
    for name, dt in (("decode", dt_rec), ("no decode", dt_raw)):
        k, dt_same = same[name]
        print(f"  recorder ({name:9s}): {k / dt:>10,.0f} msg/s   bare on its {k:,} messages: "
              f"{k / dt_same:>10,.0f} msg/s   ratio {dt_same / dt:.2f}")
    print(f"reader (Recording.messages, json decoded): {n_read / dt_read:,.0f} msgs/s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
