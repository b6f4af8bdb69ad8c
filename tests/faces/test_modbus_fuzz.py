"""Modbus RTU face fuzz (issue 12): zero unanswered valid requests, zero drive exceptions.

Traffic (tests/faces/modbus_fuzz.py, fixed seeds): valid requests to station 1 and 0xFF
(03h/06h/10h on real parameter addresses and values, plus ones the face must refuse:
unknown functions, word counts over the A3's 10 / 8 limits L15634 / L15781, lying byte
counts, undefined addresses and out-of-range values the model refuses), requests glued
without a silence, foreign stations, broadcasts, truncated and bit-flipped frames,
overlong bursts (257, 514, 515, 771 ... bytes), random noise. Each unit is followed by at
least t3.5 of silence, so every valid request in it must be answered.

- `test_modbus_fuzz_100k_frames`: 100 000 frames against a real `Drive`'s parameter store
  through `ModbusSlave.feed` / `tick` with injected time: the byte-level entry point the
  runner feeds from the line (framing, silence, resync, dispatch are all exercised). The
  model's clock does not run here: it is the face and the store under test.
- `test_modbus_fuzz_over_a_real_pty`: a 2 000-frame share as `hil drive` runs it: a
  `VirtualDriveStack` (Drive + DriveHost ticking in real time + ModbusSlaveRunner) on a
  pty line (hil.transport.serial_line.PtyLine, 115200 baud emulated), the master on the
  pty's far end. A pty is too slow for 100k frames within the CI minute.
"""

from __future__ import annotations

import logging
import os
import random
import select
import threading
import time
import tty

import pytest
from modbus_fuzz import STATION, check_replies, units

from hil.faces.modbus_slave import ModbusSlave
from hil.model.drive import Drive
from hil.protocol import modbus as mb
from hil.virtual.stack import DriveSpec, VirtualDriveStack

MS = 1_000_000
S = 1_000_000_000


def test_modbus_fuzz_100k_frames(caplog):
    drive = Drive()
    alarms: list[int] = []
    sent: list[bytes] = []
    face = ModbusSlave(
        drive.params,
        station=STATION,
        send=sent.append,
        lock=threading.RLock(),
        on_timeout=lambda t: (alarms.append(t), drive.raise_alarm("AL020")),  # as the stack
    )
    char = face.line.char_time_ns
    rng = random.Random(20250112)
    counts = {"frames": 0, "owed": 0, "answered": 0, "units": 0, "bytes": 0}
    problems: list[str] = []
    t = 0
    with caplog.at_level(logging.ERROR):
        for unit in units(rng, list(drive.params.table), 100_000):
            t += len(unit.data) * char
            face.feed(unit.data, t)  # back to back, the last character ending at t
            counts["bytes"] += len(unit.data)
            t += face.silence_ns
            face.tick(t)  # the silence ends the burst
            t += face.response_delay_ns() + 1  # P3.007 (the fuzz may have written it)
            face.tick(t)
            assert face.settled, unit  # judged, and any reply sent
            counts["units"] += 1
            counts["frames"] += unit.frames
            counts["owed"] += len(unit.replies)
            counts["answered"] += sum(1 for _ in sent) if unit.replies else 0
            why = check_replies(unit, sent)
            if why is not None:
                problems.append(f"unit {counts['units']} ({unit.data[:40].hex()}): {why}")
            sent.clear()
            t += rng.choice([0, 10_000, 1 * MS, 20 * MS])  # more idle line
    assert counts["frames"] >= 100_000
    assert problems == [], f"{len(problems)} bad units, first: {problems[:5]}"
    assert counts["answered"] == counts["owed"] > 30_000, counts
    assert face.last_resort.count == 0, face.last_resort.last  # zero drive exceptions
    assert not [r for r in caplog.records if r.levelno >= logging.ERROR]
    assert face.stats["frames"] >= counts["owed"]  # every owed request reached the store
    assert face.stats["bytes"] == counts["bytes"]


def _exchange(fd: int, unit, face: ModbusSlave, line: dict[str, int]) -> list[bytes]:
    """Write one unit; its replies (after t3.5 the line is idle again), or for a unit owed
    none, wait until the drive has read every byte written so far and judged them (its
    silence ended, no reply pending: `ModbusSlave.settled`). A drive-side reader descheduled
    between two reads can still see a unit and the next as one burst: a unit whose replies
    are wrong is sent once more after 100 ms of silence, and must then be right (a face bug
    fails both)."""
    os.write(fd, unit.data)
    line["written"] += len(unit.data)
    wire = len(unit.data) * face.line.char_time_ns / 1e9
    if unit.replies:
        return _read_replies(fd, len(unit.replies), wire + 2.0)
    end = time.monotonic() + wire + 2.0
    while not (face.stats["bytes"] >= line["written"] and face.settled) and time.monotonic() < end:
        time.sleep(0.0005)
    return _read_replies(fd, 1, 0.001) if unit.silent else []


def _read_replies(fd: int, count: int, timeout: float) -> list[bytes]:
    """`count` RTU responses from the pty's far end (or fewer on timeout)."""
    buf = bytearray()
    out: list[bytes] = []
    end = time.monotonic() + timeout
    while len(out) < count and (left := end - time.monotonic()) > 0:
        ready, _, _ = select.select([fd], [], [], left)
        if ready:
            buf += os.read(fd, 512)
        while (n := mb.rtu_response_length(bytes(buf))) is not None and len(buf) >= n:
            out.append(bytes(buf[:n]))
            del buf[:n]
    return out


@pytest.mark.integration  # real pty, the drive host ticking in real time
def test_modbus_fuzz_over_a_real_pty(tmp_path, caplog):
    link = tmp_path / "ttyA3"
    spec = DriveSpec(name="fuzz", rs485=f"pty:{link}?baud=115200", station=STATION)
    rng = random.Random(12)
    owed = answered = 0
    problems: list[str] = []
    retried: list[str] = []
    with caplog.at_level(logging.ERROR), VirtualDriveStack(spec) as stack:
        fd = os.open(link, os.O_RDWR | os.O_NOCTTY)
        tty.setraw(fd)
        face, line = stack.modbus, {"written": 0}
        try:
            for unit in units(rng, list(stack.drive.params.table), 2_000):
                sent = _exchange(fd, unit, face, line)
                why = check_replies(unit, sent)
                if why is not None:  # sent again after a long silence (see _exchange)
                    retried.append(f"{unit.data[:40].hex()}: {why}")
                    time.sleep(0.1)
                    _read_replies(fd, 64, 0.0)  # whatever the merged burst produced
                    sent = _exchange(fd, unit, face, line)
                    why = check_replies(unit, sent)
                owed += len(unit.replies)
                answered += len(sent) if unit.replies else 0
                if why is not None:
                    problems.append(f"{unit.data[:40].hex()}: {why}")
            time.sleep(0.05)
            leftover = _read_replies(fd, 1, 0.0)
        finally:
            os.close(fd)
        runner = stack.modbus_runner
        assert runner._thread.is_alive() and runner.error is None, runner.error
    assert problems == [], f"{len(problems)} bad units, first: {problems[:5]}"
    assert len(retried) <= 20, f"{len(retried)} units needed a second try: {retried[:5]}"
    assert answered == owed > 500
    assert leftover == [] or all(not u for u in leftover)
    assert face.last_resort.count == 0, face.last_resort.last
    assert stack.host.errors == []
    assert not [r for r in caplog.records if r.levelno >= logging.ERROR]


# ---------------------------------------------------------------- PR-mode surfaces, clock on

PR_BENCH = {"P1.001": 0x0001, "P2.010": 0x0101, "P2.011": 0x0108, "P2.012": 0x0111,
            "P2.013": 0x0112, "P2.014": 0x0146, "P2.015": 0x0139, "P2.016": 0, "P2.036": 0}
# the surfaces of PR mode, capture and compare (A3 ch. 7), jog (P4.005) and DI mapping
PR_SURFACE = (["P5.007"] * 8 + ["P4.005"] * 3 + ["P0.001"] + [f"P5.{n:03d}" for n in (
    8, 9, 10, 11, 12, 13, 15, 16, 20, 35, 36, 37, 38, 39, 56, 57, 58, 59, 60, 64, 76, 98, 99,
    100, 101, 102, 103)] + [f"P2.{n:03d}" for n in (*range(11, 18), *range(36, 41))])
TRIGGERS = [0, 1, 99, 100, 999, 1000, 1001, 9999, 10000, 10001, 20050, 65535, -1, -100]


def _pr_value(rng: random.Random, name: str, spec) -> int:
    if name == "P5.007":
        return rng.choice([*TRIGGERS, rng.randint(1, 99)])
    if name == "P0.001":
        return 0  # alarm reset (L7079-7083): the PR engine keeps running
    if name == "P4.005":
        return rng.choice([0, 4998, 4999, 1, 100, 5000, 5001, -1])
    if name.startswith("P2."):
        return rng.choice([0, 0x100, 0x200, 0x1000]) | rng.randrange(0x100)  # a/b digit, code
    if rng.random() < 0.5:
        return rng.choice([0, 1, -1, 99, 100, 799, 800, 0x7FFFFFFF, -2**31, 0xFFFF, 0x10000])
    return rng.randint(spec.min, spec.max)


def _pr_path(rng: random.Random) -> tuple[int, int]:
    """A PR definition and data word: mostly defined TYPEs with random fields, some garbage."""
    typ = rng.choice([1, 2, 3, 7, 8, 0xA, 0xB, 0, 4, 5, 9, 0xC, 0xF])
    definition = rng.randrange(1 << 28) << 4 | typ
    data = rng.choice([0, 1, 99, 100, 799, 800, -1, 0x0107, 0x0507, rng.randint(-200000, 200000),
                       rng.randint(-2**31, 2**31 - 1)])
    return definition, data


def test_modbus_fuzz_pr_surfaces_with_the_model_running(caplog):
    """PR mode with the servo on and the model's clock running: random PR tables (P6.000-
    P7.099, every TYPE, garbage fields) written by 10h, then P5.007 triggers (0 homing, 1-99,
    100-999 refused L11176, 1000 stop L11183, 10000+ and negative out of range), P4.005 jog
    commands (4998/4999/0, L10863-10866), the data array (P5.010-P5.013, P5.100-P5.103),
    capture / compare (P5.036-P5.039, P5.056-P5.059), DI mapping codes 0x00-0xFF with the
    contact digit, 03h reads of odd ranges and single 32-bit halves, while DIs toggle. Every
    request is answered (a reply or an exception), the model never raises, the face's
    last-resort counter stays 0, and the drive still answers afterwards."""
    drive = Drive(inputs={8: True}, params=PR_BENCH, sensors={})
    drive.set_di(1, True)
    drive.advance(400 * MS)
    assert drive.servo_on
    face = ModbusSlave(drive.params, station=STATION, send=lambda _a: None,
                       lock=threading.RLock())
    table = drive.params.table
    rng = random.Random(7007)
    owed = answered = refused = on = 0
    with caplog.at_level(logging.ERROR):
        for _ in range(80):
            for name, value in PR_BENCH.items():  # the fuzz may have mapped EMGS, NL, PL...
                if name.startswith("P2."):
                    drive.params.write(name, value)
            drive.params.write("P0.001", 0)  # alarm reset (L7079-7083)
            drive.advance(10 * MS)
            if not drive.servo_on:  # AL809 (a statement PR) clears by power cycle only (L20232)
                drive.power_cycle()
                drive.advance(400 * MS)
            for n in rng.sample(range(1, 100), 8):
                base = table.spec(f"P6.{2 * n:03d}" if n < 50 else f"P7.{2 * n - 100:03d}")
                d, v = (x & 0xFFFFFFFF for x in _pr_path(rng))
                pdu = mb.write_multiple_request(base.modbus_address,
                                                [d & 0xFFFF, d >> 16, v & 0xFFFF, v >> 16])
                owed += 1
                answered += face._process(pdu, broadcast=False) is not None
            for _ in range(40):
                name = rng.choice(PR_SURFACE)
                spec = table.spec(name)
                value = _pr_value(rng, name, spec) & 0xFFFFFFFF
                a = spec.modbus_address
                pdu = rng.choice([
                    mb.write_multiple_request(a, [value & 0xFFFF, value >> 16]),
                    mb.write_single_request(a, value & 0xFFFF),
                    mb.write_single_request(a + 1, value >> 16),
                    mb.read_request(a + rng.randrange(2), rng.randint(1, 10))])
                reply = face._process(pdu, broadcast=False)
                owed += 1
                answered += reply is not None
                refused += bool(reply and reply[0] & 0x80)
                if rng.random() < 0.15:
                    drive.set_di(rng.choice([2, 3, 4, 5, 6, 7]), rng.random() < 0.5)
                drive.advance(rng.choice([1, 1, 5, 20]) * MS)
                on += drive.servo_on
        assert face._process(mb.read_request(0x0000, 2), broadcast=False)[0] == 0x03
    assert answered == owed > 3000 and refused > 300, (answered, owed, refused)
    assert on > 2000 and len(drive.pr.trace) > 300, (on, len(drive.pr.trace))  # PR ran
    assert face.last_resort.count == 0, face.last_resort.last
    assert not [r for r in caplog.records if r.levelno >= logging.ERROR]
