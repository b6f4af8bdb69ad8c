"""Hostile pulse-line traffic against the drive's pulse face (issue 26): random segments,
absurd totals and frequencies, malformed bodies, level spam. The face and the model never
raise; refusals are on record; afterwards a clean segment still moves the motor exactly."""

from __future__ import annotations

import random

import pytest

from hil import clock
from hil.model.mechanics import COUNTS_PER_REV
from hil.transport.pulse import PulseError, open_pulse
from hil.virtual.stack import DriveSpec, VirtualDriveStack

pytestmark = pytest.mark.virtual_time


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_random_traffic_never_breaks_the_drive(seed: int) -> None:
    rnd = random.Random(seed)
    line = f"virtual:pulse-fuzz-{seed}"
    with clock.use(clock.VirtualClock()):
        stack = VirtualDriveStack(DriveSpec(
            name="d", pulse=line, inputs={8: True},
            params={"P2.041": 0x0108, "P1.045": 10000, "P1.044": 16777216})).start()
        plc = open_pulse(line, role="master", name="d")
        try:
            stack.host.call(stack.drive.set_di, 1, True)
            clock.sleep(0.05)
            refused = 0
            for _ in range(300):
                body = {
                    "freq": rnd.choice([0, 1, 999.5, 5e5, 4e6, 9e7, -1, float("nan"), "x"]),
                    "direction": rnd.choice([1, -1, 1, 0]),
                    "count": rnd.choice([0, 1, 10, 2**40, -1]),
                    "form": rnd.choice(["pulse_sign", "ab", "cw_ccw", "pulse_sign", "?"]),
                    "total": rnd.choice([None, 0, 12345, -(2**50), 2**61]),
                }
                if body["total"] is None:
                    del body["total"]
                try:
                    plc.send("seg", body)
                except PulseError:
                    refused += 1
                if rnd.random() < 0.2:
                    plc.set(f"Y{rnd.randint(0, 20)}", rnd.random() < 0.5)
                clock.sleep(rnd.choice([0.0, 0.0005, 0.003, 0.02]))
            assert refused > 0
            snap = stack.host.call(stack.drive.snapshot)  # the model still answers
            assert isinstance(snap["pt_count"], int)
            # whatever happened: reset alarms by a power cycle, then a clean move is exact
            plc.send("seg", {"freq": 0.0})
            plc.set("Y8", False)
            stack.host.call(stack.drive.power_cycle)
            stack.host.call(stack.drive.set_di, 1, True)
            clock.sleep(0.1)
            assert stack.drive.servo_on, stack.drive.alarms.active
            start = stack.drive.axis.position
            plc.send("seg", {"freq": 20_000, "direction": 1, "count": 10_000})
            clock.sleep(1.0)
            assert stack.drive.axis.position - start == pytest.approx(COUNTS_PER_REV, abs=2)
            assert not stack.pulse_face.errors or all(isinstance(e, str)
                                                      for e in stack.pulse_face.errors)
        finally:
            plc.close()
            stack.stop()


def test_the_face_keeps_only_the_last_refusals() -> None:
    """A review (helper-136): every segment the model refused was kept, so a flood grew the
    drive's memory without end; the face keeps the last 20, as the Modbus face does."""
    with clock.use(clock.VirtualClock()):
        stack = VirtualDriveStack(DriveSpec(name="d", pulse="virtual:pulse-face-flood",
                                            inputs={8: True})).start()
        try:
            face = stack.pulse_face
            for i in range(500):  # a form the model does not know: refused by the model
                stack.host.call(face._segment, {"freq": 1000.0 + i, "direction": 1,
                                                "count": 1, "form": "zigzag", "logic": 0})
            assert 0 < len(face.errors) <= 20 and "zigzag" in face.errors[-1]
        finally:
            stack.stop()


def test_the_dio_face_keeps_only_the_last_refusals() -> None:
    """The same for the DI/DO face: DI lines the drive has no terminal for (DI11 and up)."""
    with clock.use(clock.VirtualClock()):
        stack = VirtualDriveStack(DriveSpec(name="d", dio="virtual:dio-face-flood",
                                            inputs={8: True})).start()
        try:
            face = stack.dio_face
            for i in range(500):
                stack.host.call(face._apply, f"DI{11 + i % 50}", bool(i % 2))
            assert 0 < len(face.errors) <= 20
        finally:
            stack.stop()
