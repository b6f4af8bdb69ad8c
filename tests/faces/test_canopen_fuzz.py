"""CANopen face fuzz (issue 12): no SDO request unanswered, zero drive exceptions.

The face runs as `hil drive` runs it: `CanopenSlave` in its own receive thread on one end
of a python-can virtual bus, in front of a real `Drive`, `own_timer=False` (the host ticks
it); the master is a raw python-can bus on another end of the same channel. Time is
injected: the model is advanced under the face's lock by the test (1 ms every 50 frames)
and the face's clock is the model clock. The face's timers (heartbeat, guarding, SDO
timeout) are not ticked here, so the NMT state is exactly what the fuzz's NMT frames make
it; they are covered by tests/faces/test_canopen_slave.py.

"Owed an answer" (CiA 301): a standard data frame on the SDO request COB-ID (605h) while
the node is PRE-OPERATIONAL or OPERATIONAL, other than a client abort (80h). The face
answers each with the response or an abort; `last_resort.count == 0` means the model
raised nothing the face could only answer with the general abort 0800 0000.
"""

from __future__ import annotations

import logging
import random
import struct
import threading
import time

import can
import pytest

from hil.faces.canopen_slave import CanopenSlave
from hil.model.drive import Drive
from hil.profile.od import Entry, ObjectDictionary
from hil.protocol import canopen as P

NODE = 5
SDO_REQ, SDO_RSP = 0x600 + NODE, 0x580 + NODE
MS = 1_000_000


class Rig:
    def __init__(self, channel: str) -> None:
        self.drive = Drive()
        self.lock = threading.RLock()
        self.slave_bus = can.Bus(interface="virtual", channel=channel)
        self.master = can.Bus(interface="virtual", channel=channel)
        self.slave = CanopenSlave(self.slave_bus, self.drive, node_id=NODE, lock=self.lock,
                                  own_timer=False, clock=lambda: self.drive.now)
        self.slave.start()
        self.other: list[int] = []  # COB-IDs of frames seen while waiting for SDO answers

    def send(self, cid: int, data: bytes = b"", *, remote: bool = False,
             extended: bool = False) -> None:
        self.master.send(can.Message(arbitration_id=cid, data=data, is_remote_frame=remote,
                                     is_extended_id=extended))

    def answer(self, timeout: float = 2.0) -> bytes | None:
        end = time.monotonic() + timeout
        while (left := end - time.monotonic()) > 0:
            msg = self.master.recv(timeout=left)
            if msg is None:
                break
            if msg.arbitration_id == SDO_RSP and not msg.is_extended_id:
                return bytes(msg.data)
            self.other.append(msg.arbitration_id)
        return None

    def advance(self, dt: int) -> None:
        with self.lock:
            self.drive.advance(dt)

    def close(self) -> None:
        self.slave.close()
        self.slave_bus.shutdown()
        self.master.shutdown()


@pytest.fixture
def rig(request):
    r = Rig(f"fuzz-{request.node.name}")
    yield r
    r.close()


def _pairs(request: bytes, answer: bytes) -> bool:
    """An answer to an initiate request names its index and sub-index (CiA 301 §7.2.4.3)."""
    if len(request) == 8 and request[0] >> 5 in (P.CCS_INITIATE_DOWNLOAD,
                                                 P.CCS_INITIATE_UPLOAD):
        return answer[1:4] == request[1:4]
    return True


# ---------------------------------------------------------------- every writable object


def _values(e: Entry, rng: random.Random) -> list[int]:
    lo = e.min if e.min is not None else e.type_min()
    hi = e.max if e.max is not None else e.type_max()
    picks = {0, lo, hi, lo - 1, hi + 1, e.default or 0, e.type_max(), -1,
             rng.randint(lo, hi) if lo <= hi else 0, rng.randint(e.type_min(), e.type_max())}
    return sorted(picks)


def test_sdo_download_fuzz_over_every_writable_object(rig, caplog):
    """Every writable object of the A3 dictionary (1xxx, 2xxx parameters, 6xxx), with the
    range edges, one past them, all-ones, random values, and wrong sizes: each download is
    answered (60h or an abort), none with the general abort of the last-resort handler."""
    rng = random.Random(301)
    od: ObjectDictionary = rig.slave.od
    writable = [e for e in od.entries.values() if e.writable and e.size]
    assert len(writable) > 600
    owed = answered = 0
    refused: dict[int, int] = {}
    problems: list[str] = []
    with caplog.at_level(logging.ERROR):
        for e in writable:
            frames = []
            for value in _values(e, rng):
                raw = (value & ((1 << (8 * e.size)) - 1)).to_bytes(e.size, "little")
                n = 4 - e.size
                frames.append(bytes([0x23 | n << 2]) + struct.pack("<HB", e.index, e.sub)
                              + raw + bytes(n))
            for size in {1, 2, 4} - {e.size}:  # the wrong size (06070010h family)
                frames.append(bytes([0x23 | (4 - size) << 2]) + struct.pack("<HB", e.index, e.sub)
                              + rng.randbytes(4))
            frames.append(bytes([0x22]) + struct.pack("<HB", e.index, e.sub)
                          + rng.randbytes(4))  # expedited, size not indicated
            for frame in frames:
                rig.send(SDO_REQ, frame)
                owed += 1
                got = rig.answer()
                if got is None or got[0] not in (0x60, 0x80) or not _pairs(frame, got):
                    problems.append(f"{frame.hex()} -> {got.hex() if got else None}")
                    continue
                answered += 1
                if got[0] == 0x80:
                    code = struct.unpack_from("<I", got, 4)[0]
                    refused[code] = refused.get(code, 0) + 1
            rig.advance(MS)
    assert problems == [], f"{len(problems)} unanswered/wrong, first: {problems[:5]}"
    assert answered == owed > 6000
    assert 0x08000000 not in refused, refused  # no last-resort answer
    assert rig.slave.last_resort.count == 0, rig.slave.last_resort.last
    assert not [r for r in caplog.records if r.levelno >= logging.ERROR]


# ---------------------------------------------------------------- 20k mixed frames


def _sdo(rng: random.Random, od: ObjectDictionary) -> bytes:
    cs = rng.choice([0x40, 0x40, 0x2F, 0x2B, 0x27, 0x23, 0x23, 0x22, 0x21, 0x20,
                     0x00, 0x10, 0x01, 0x11, 0x60, 0x70, 0x80, 0xA0, 0xC0, 0xE0,
                     rng.randrange(256)])
    if rng.random() < 0.8:
        index, sub = rng.choice(list(od.entries))
    else:
        index, sub = rng.randrange(0x10000), rng.randrange(256)
    data = bytes([cs]) + struct.pack("<HB", index, sub) + rng.randbytes(4)
    if rng.random() < 0.08:
        data = data[: rng.randrange(8)] if rng.random() < 0.8 else data + b"\x00"
    return data[:8]


def test_canopen_fuzz_20k_frames(rig, caplog):
    """Random SDO (every command specifier, real and random objects, wrong lengths), NMT
    (every command, to us, to all, to others, wrong lengths), wrong-length PDOs, SYNC
    storms, guarding RTRs, extended and random COB-IDs. Every SDO request owed an answer
    gets exactly one, paired by index/sub-index."""
    rng = random.Random(17)
    od: ObjectDictionary = rig.slave.od
    state = "PRE-OPERATIONAL"
    counts = {"frames": 0, "owed": 0, "answered": 0, "sync": 0, "nmt": 0, "pdo": 0}
    problems: list[str] = []
    with caplog.at_level(logging.ERROR):
        while counts["frames"] < 20_000:
            r = rng.random()
            if r < 0.45:
                data = _sdo(rng, od)
                rig.send(SDO_REQ, data)
                counts["frames"] += 1
                owed = state != "STOPPED" and (len(data) != 8 or data[0] >> 5 != P.CCS_ABORT)
                if owed:
                    counts["owed"] += 1
                    got = rig.answer()
                    if got is None or not _pairs(data, got):
                        problems.append(f"{state} {data.hex()} -> {got.hex() if got else None}")
                    else:
                        counts["answered"] += 1
            elif r < 0.60:
                cs = rng.choice([0x01, 0x02, 0x80, 0x81, 0x82, rng.randrange(256)])
                node = rng.choice([0, NODE, NODE, 3, rng.randrange(128)])
                data = bytes([cs, node])
                if rng.random() < 0.1:
                    data = data[: rng.randrange(2)] + rng.randbytes(rng.choice([0, 1, 3]))
                rig.send(P.NMT, data)
                counts["frames"] += 1
                counts["nmt"] += 1
                if len(data) == 2 and data[1] in (0, NODE):
                    state = {0x01: "OPERATIONAL", 0x02: "STOPPED", 0x80: "PRE-OPERATIONAL",
                             0x81: "PRE-OPERATIONAL", 0x82: "PRE-OPERATIONAL"}.get(cs, state)
            elif r < 0.75:  # PDOs of every length, mostly wrong for their mapping
                cid = rng.choice([0x200, 0x300, 0x400, 0x500]) + NODE
                rig.send(cid, rng.randbytes(rng.randrange(9)))
                counts["frames"] += 1
                counts["pdo"] += 1
            elif r < 0.754:  # a SYNC storm
                for _ in range(rng.randint(20, 100)):
                    rig.send(P.SYNC, rng.randbytes(rng.choice([0, 0, 1, 2, 8])))
                    counts["frames"] += 1
                    counts["sync"] += 1
            elif r < 0.80:  # node guarding RTR, heartbeats of others
                if rng.random() < 0.5:
                    rig.send(P.HEARTBEAT + NODE, remote=True)
                else:
                    rig.send(P.HEARTBEAT + rng.randrange(1, 128), bytes([rng.choice([0, 5, 127])]))
                counts["frames"] += 1
            else:  # anything: random COB-ID (some 605h), extended IDs, RTRs
                cid = rng.choice([rng.randrange(0x800), SDO_REQ, 0x080, 0x000])
                extended = rng.random() < 0.2
                remote = rng.random() < 0.1
                data = b"" if remote else rng.randbytes(rng.randrange(9))
                if extended:
                    cid |= rng.randrange(1 << 29) & ~0x7FF
                rig.send(cid, data, remote=remote, extended=extended)
                counts["frames"] += 1
                if cid == SDO_REQ and not extended and not remote and state != "STOPPED" and (
                    len(data) != 8 or data[0] >> 5 != P.CCS_ABORT
                ):
                    counts["owed"] += 1
                    got = rig.answer()
                    if got is None:
                        problems.append(f"{state} random {data.hex()} -> None")
                    else:
                        counts["answered"] += 1
                if cid == P.NMT and not extended and not remote and len(data) == 2 and (
                    data[1] in (0, NODE)
                ):
                    state = {0x01: "OPERATIONAL", 0x02: "STOPPED", 0x80: "PRE-OPERATIONAL",
                             0x81: "PRE-OPERATIONAL", 0x82: "PRE-OPERATIONAL"}.get(data[0], state)
            if counts["frames"] % 50 < 1:
                rig.advance(MS)
        # the face still serves after all that: reset communication, read 1000h
        rig.send(P.NMT, bytes([P.NMT_RESET_COMMUNICATION, NODE]))
        upload = bytes([0x40, 0x00, 0x10, 0x00]) + bytes(4)
        rig.send(SDO_REQ, upload)
        last = rig.answer(5.0)
    assert problems == [], f"{len(problems)} unanswered, first: {problems[:5]}; {counts}"
    assert counts["answered"] == counts["owed"] > 5000, counts
    assert counts["sync"] > 1000 and counts["nmt"] > 1000 and counts["pdo"] > 1000, counts
    assert last is not None and last[:4] == bytes.fromhex("43001000"), last
    assert rig.slave._thread.is_alive()
    assert rig.slave.last_resort.count == 0, rig.slave.last_resort.last  # no drive exception
    assert not [r for r in caplog.records if r.levelno >= logging.ERROR]


# ---------------------------------------------------------------- PR-mode surfaces, clock on


class _ListBus:
    """A bus that keeps what the slave sends; frames go in through `handle_frame`."""

    def __init__(self) -> None:
        self.sent: list[can.Message] = []

    def send(self, msg: can.Message) -> None:
        self.sent.append(msg)

    def recv(self, timeout: float | None = None) -> None:
        time.sleep(timeout or 0)


def test_sdo_fuzz_pr_surfaces_with_the_model_running(caplog):
    """The SDO side of tests/faces/test_modbus_fuzz.py's PR fuzz: PR mode, servo on, the
    model's clock running; expedited (1/2/4 bytes, size given or not) and segmented downloads
    and uploads of 2xxxh objects: the PR table (2600h-2763h), P5.007 triggers (0, 1-99,
    100-999, 1000, 10000+, negative, L11174-11183), P4.005 jog (4998/4999/0), the data array
    and capture / compare (P5.010-P5.013, P5.036-P5.039, P5.056-P5.059), DI mapping codes
    0x00-0xFF with the contact digit. Every request gets one answer paired by index/sub (60h,
    43h-4Fh, 41h + segments, or an abort that is never the last-resort 0800 0000)."""
    from hil.units import MS as MS_

    bench = {"P1.001": 0x0001, "P2.010": 0x0101, "P2.011": 0x0108, "P2.012": 0x0111,
             "P2.013": 0x0112, "P2.014": 0x0146, "P2.015": 0x0139, "P2.016": 0, "P2.036": 0}
    drive = Drive(inputs={8: True}, params=bench, sensors={})
    drive.set_di(1, True)
    drive.advance(400 * MS_)
    bus = _ListBus()
    slave = CanopenSlave(bus, drive, node_id=NODE, own_timer=False, clock=lambda: drive.now)
    objs = ([0x2600 + i for i in range(100)] + [0x2700 + i for i in range(100)]
            + [0x2507] * 40 + [0x2405] * 10 + [0x2500 + n for n in (8, 9, 10, 11, 12, 13, 36,
                                                                     37, 38, 39, 56, 57, 58, 59)]
            + [0x2200 + n for n in (*range(11, 18), *range(36, 41))] * 2)
    rng = random.Random(3011)
    problems: list[str] = []
    owed = aborts = 0

    def ask(data: bytes) -> bytes | None:
        bus.sent.clear()
        with slave.lock:
            slave.handle_frame(can.Message(arbitration_id=SDO_REQ, data=data,
                                           is_extended_id=False))
        got = [bytes(m.data) for m in bus.sent if m.arbitration_id == SDO_RSP]
        return got[0] if len(got) == 1 else None

    with caplog.at_level(logging.ERROR), slave:
        for _ in range(3000):
            index = rng.choice(objs)
            value = rng.choice([0, 1, 99, 100, 999, 1000, 4998, 4999, 10000, 20050, -1, -100,
                                0x7FFFFFFF, -2**31, rng.randrange(0x200),
                                rng.randrange(1 << 32)])
            size = rng.choice([4, 4, 2, 1])
            raw = (value & ((1 << 8 * size) - 1)).to_bytes(size, "little")
            head = struct.pack("<HB", index, 0)
            r = rng.random()
            if r < 0.6:  # expedited, size given (or not: 22h)
                cs = 0x23 | (4 - size) << 2 if rng.random() < 0.9 else 0x22
                frames = [bytes([cs]) + head + raw + bytes(4 - size)]
            elif r < 0.8:  # segmented: initiate with the size, then 7-byte segments
                body = raw if rng.random() < 0.7 else rng.randbytes(rng.choice([5, 8]))
                frames = [bytes([0x21]) + head + struct.pack("<I", len(body))]
                for k, pos in enumerate(range(0, len(body), 7)):
                    chunk = body[pos:pos + 7]
                    last = pos + 7 >= len(body)
                    frames.append(bytes([(k & 1) << 4 | (7 - len(chunk)) << 1 | last])
                                  + chunk + bytes(7 - len(chunk)))
            else:
                frames = [bytes([0x40]) + head + bytes(4)]
            for f in frames:
                owed += 1
                got = ask(f)
                if got is None or (f[0] >> 5 in (1, 2) and got[0] != 0x80
                                   and got[1:4] != f[1:4]):
                    problems.append(f"{f.hex()} -> {got.hex() if got else None}")
                    break
                if got[0] == 0x80:
                    aborts += 1
                    assert struct.unpack_from("<I", got, 4)[0] != 0x08000000, f.hex()
                    break  # an aborted transfer ends: no more segments
            if rng.random() < 0.1:
                drive.set_di(rng.choice([2, 3, 4, 5, 6, 7]), rng.random() < 0.5)
            with slave.lock:
                drive.advance(rng.choice([1, 1, 5, 20]) * MS_)
        assert ask(bytes([0x40, 0x00, 0x10, 0x00]) + bytes(4))[:4] == bytes.fromhex("43001000")
    assert problems == [], problems[:5]
    assert owed > 3000 and aborts > 400, (owed, aborts)
    assert slave.last_resort.count == 0, slave.last_resort.last
    assert not [r for r in caplog.records if r.levelno >= logging.ERROR]
