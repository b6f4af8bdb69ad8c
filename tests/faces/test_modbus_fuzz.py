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
    counts = {"frames": 0, "owed": 0, "answered": 0, "units": 0}
    problems: list[str] = []
    t = 0
    with caplog.at_level(logging.ERROR):
        for unit in units(rng, list(drive.params.table), 100_000):
            t += len(unit.data) * char
            face.feed(unit.data, t)  # back to back, the last character ending at t
            t += face.silence_ns
            face.tick(t)  # the silence ends the burst
            t += face.response_delay_ns() + 1  # P3.007 (the fuzz may have written it)
            face.tick(t)
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


def test_modbus_fuzz_over_a_real_pty(tmp_path, caplog):
    link = tmp_path / "ttyA3"
    spec = DriveSpec(name="fuzz", rs485=f"pty:{link}?baud=115200", station=STATION)
    rng = random.Random(12)
    owed = answered = 0
    problems: list[str] = []
    with caplog.at_level(logging.ERROR), VirtualDriveStack(spec) as stack:
        fd = os.open(link, os.O_RDWR | os.O_NOCTTY)
        tty.setraw(fd)
        try:
            char_s = stack.serial.char_time_s
            for unit in units(rng, list(stack.drive.params.table), 2_000):
                os.write(fd, unit.data)
                wire = len(unit.data) * char_s
                if unit.replies:  # the answers come after t3.5: the line is idle again
                    sent = _read_replies(fd, len(unit.replies), wire + 2.0)
                else:  # its characters, then t3.5 (1.75 ms) with room for a late pty reader:
                    # a reader descheduled for longer (a busy machine) reads this unit and the
                    # next one as one burst, with no silence between them to end a frame
                    time.sleep(wire + 0.015)
                    sent = _read_replies(fd, 1, 0.0) if unit.silent else []
                owed += len(unit.replies)
                answered += len(sent) if unit.replies else 0
                why = check_replies(unit, sent)
                if why is not None:
                    problems.append(f"{unit.data[:40].hex()}: {why}")
            time.sleep(0.05)
            leftover = _read_replies(fd, 1, 0.0)
        finally:
            os.close(fd)
        face, runner = stack.modbus, stack.modbus_runner
        assert runner._thread.is_alive() and runner.error is None, runner.error
    assert problems == [], f"{len(problems)} bad units, first: {problems[:5]}"
    assert answered == owed > 500
    assert leftover == [] or all(not u for u in leftover)
    assert face.last_resort.count == 0, face.last_resort.last
    assert stack.host.errors == []
    assert not [r for r in caplog.records if r.levelno >= logging.ERROR]
