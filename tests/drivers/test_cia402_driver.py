"""Cia402Driver against the CANopen slave + fake drive on a virtual bus."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "faces"))
from fake_drive import Bench

from hil.drivers.cia402 import (
    Cia402Driver,
    Cia402Fault,
    Cia402ModeError,
    Cia402Timeout,
    ObjectValueError,
    SdoError,
    decode_state,
)

NODE = 7


@pytest.fixture
def rig():
    b = Bench(NODE)
    drv = Cia402Driver(b.network(), NODE, timeouts={"state": 0.3, "fault_reset": 0.2})
    yield b, drv
    b.close()


def test_decode_state_masks():
    # L18321-L18331
    assert decode_state(0x0250) == "SWITCH ON DISABLED"
    assert decode_state(0x0231) == "READY TO SWITCH ON"
    assert decode_state(0x0237) == "OPERATION ENABLED"
    assert decode_state(0x0217) == "QUICK STOP ACTIVE"
    assert decode_state(0x0218) == "FAULT"


def test_power_states(rig):
    b, drv = rig
    drv.enable_operation()
    assert b.drive.state == "OPERATION ENABLED"
    assert [w[2] for w in b.drive.writes if w[0] == 0x6040] == [0x06, 0x07, 0x0F]  # L17150
    drv.quick_stop()
    assert drv.state == "QUICK STOP ACTIVE"
    drv.enable_operation()
    drv.shutdown()
    assert drv.state == "READY TO SWITCH ON"
    drv.disable_voltage()
    assert drv.state == "SWITCH ON DISABLED"


def test_pp_move_and_homing(rig):
    b, drv = rig
    drv.move_to(100_000, velocity=10_000, accel=200, decel=200)
    assert b.drive.objects[(0x6064, 0)] == 100_000
    assert b.drive.objects[(0x6061, 0)] == 1
    sw = drv.home(35, speeds=(100, 20), accel=100)
    assert sw & 0x1000 and b.drive.objects[(0x6098, 0)] == 35


def test_fault_reset(rig):
    b, drv = rig
    drv.enable_operation()
    with b.lock:
        b.drive.alarm("AL009", 0x8611, True)
    with pytest.raises(Cia402Fault, match="saw FAULT"):
        drv.enable_operation()
    with b.lock:
        b.drive.alarm("AL009", 0, False)
    drv.fault_reset()
    assert drv.state == "SWITCH ON DISABLED"


def test_timeout_message_says_expected_and_seen(rig):
    b, drv = rig
    with b.lock:
        b.drive.alarm("AL011", 0x7305, True)  # the cause stays: reset cannot clear it
    with pytest.raises(Cia402Timeout) as info:
        drv.fault_reset()
    msg = str(info.value)
    assert "expected SWITCH ON DISABLED after fault reset" in msg
    assert "timeouts['fault_reset']" in msg and "saw state FAULT (statusword 0x0018)" in msg
    assert info.value.elapsed >= 0.2 and info.value.state == "FAULT"


def test_set_mode_never_swallows(rig):
    b, drv = rig
    with pytest.raises(Cia402ModeError, match="unknown mode 'CSP'"):
        drv.set_mode("CSP")
    b.drive.write_object = _no_echo(b.drive.write_object)
    with pytest.raises(Cia402ModeError, match=r"expected 6061h = 3 \(PV\).*saw 0"):
        drv.set_mode("PV")


def _no_echo(write):
    def w(index, sub, value):
        if index == 0x6060:
            return
        write(index, sub, value)

    return w


def test_sdo_error_names_abort(rig):
    _, drv = rig
    with pytest.raises(SdoError, match=r"3000h sub 0: abort 0x06020000 \(Object does not exist"):
        drv.read(0x3000, 0)
    with pytest.raises(ValueError, match="unknown names"):
        Cia402Driver(None, 1, timeouts={"nope": 1})


def test_writes_go_by_the_eds_type_or_as_32_bits_when_it_lacks_the_object(rig):
    """CiA 301: an object the dictionary lacks is answered with abort 0602 0000; the driver
    sends it (32 bits) instead of failing in canopen's lookup. A value its EDS type cannot
    carry (6060h is INTEGER8, 1017h UNSIGNED16) is refused before anything is sent."""
    b, drv = rig
    with pytest.raises(SdoError, match=r"3000h sub 0: abort 0x06020000"):
        drv.write(0x3000, 0, 1)
    for index, value in ((0x6060, 200), (0x1017, -1), (0x6040, 0x10000)):
        sent = b.slave.stats["rx"]
        with pytest.raises(ObjectValueError, match=f"{index:04X}h sub 0 takes"):
            drv.write(index, 0, value)
        assert b.slave.stats["rx"] == sent  # nothing on the bus
    drv.write(0x1017, 0, 250)  # in range: written, and read back by its type
    assert drv.read(0x1017, 0) == 250


def test_two_threads_share_one_sdo_client(rig):
    """A step thread polling 6041h while the safe-state routine writes 6040h (issue 12): with
    one SDO client, every transaction must still pair with its own reply (no 0x4B mix-ups)."""
    import threading

    _, drv = rig
    errors: list[BaseException] = []
    stop = threading.Event()

    def poll() -> None:
        try:
            while not stop.is_set():
                drv.statusword  # noqa: B018
        except BaseException as e:
            errors.append(e)

    t = threading.Thread(target=poll)
    t.start()
    try:
        for _ in range(200):
            drv.write(0x6040, 0, 0x06)
            drv.write(0x6040, 0, 0x00)
    except BaseException as e:
        errors.append(e)
    finally:
        stop.set()
        t.join(5)
    assert not errors, errors[:3]


def test_cancel_ends_a_wait_at_once(rig):
    """The runner's cancel event ends a driver wait within one poll, not at its timeout."""
    import threading
    import time

    from hil.drivers.cia402 import Cia402Cancelled

    _, drv = rig
    drv.cancel = threading.Event()
    threading.Timer(0.05, drv.cancel.set).start()
    t0 = time.monotonic()
    with pytest.raises(Cia402Cancelled):
        drv.wait_state("OPERATION ENABLED", timeout=5.0)
    assert time.monotonic() - t0 < 1.0


def test_fault_reset_outside_fault_sends_the_edge_and_keeps_the_state(rig):
    """AL111/AL112/AL3E3 keep the servo on (no FAULT) yet clear with "NMT reset or 0x6040
    reset" (L19937, L19945, L20169): the bit 7 edge goes out on top of the present
    controlword, which is restored, so OPERATION ENABLED stays."""
    b, drv = rig
    drv.enable_operation()
    n = len(b.drive.writes)
    drv.fault_reset()
    assert [w[2] for w in b.drive.writes[n:] if w[0] == 0x6040] == [0x8F, 0x0F]
    assert drv.state == "OPERATION ENABLED"


def test_a_set_point_whose_acknowledge_timed_out_is_taken_back_and_never_runs() -> None:
    """A set-point given while a move runs is acknowledged only when that move completes
    (A3 L17172-17174). When the driver gives up waiting (timeouts.setpoint_ack) it drops bit 4
    before raising, so the drive withdraws the set-point: the move the caller was told had
    failed does not run later (helper-89). The driver is wired to the CiA 402 model."""
    from hil.drivers.cia402 import DEFAULT_TIMEOUTS, Cia402Driver, Cia402Timeout
    from tests.model.test_cia402 import Rig

    rig = Rig()
    rig.pp_setup()
    drv = object.__new__(Cia402Driver)
    drv.timeouts = {**DEFAULT_TIMEOUTS, "setpoint_ack": 0.2}
    drv.node_id, drv.recorder, drv.cancel, drv._controlword = 7, None, None, 0
    drv.clock = lambda: rig.t / 1e9
    drv.read = lambda i, s=0: rig.r(i, s)
    drv.write = lambda i, s, v: rig.w(i, v, s)
    drv._pause = lambda at_most=None: rig.step(1)
    drv.set_mode = lambda m: None
    drv.enable_operation = lambda: None
    drv.move_to(500000, 500000, 200, 200, wait=False)
    with pytest.raises(Cia402Timeout, match="acknowledged only when that move completes"):
        drv.move_to(-400000, 500000, 200, 200)
    assert not rig.r(0x6040) & 0x10
    rig.until(lambda: rig.sw & 0x400 and not rig.axis.moving)
    rig.step(3000)
    assert rig.r(0x6064) == 500000


def test_a_wait_takes_its_last_look_at_its_timeout_not_a_poll_past_it():
    """helper-131 (the same rule as wait_until's): the 2 ms poll slept past the timeout and
    a state reached after it still passed. A statusword that turns at 3 ms: met with a
    3 ms timeout (the last look is at it), a timeout at 2.5 ms is a timeout."""
    from hil import clock
    from hil.clock import VirtualClock
    from hil.units import MS

    class Drv(Cia402Driver):
        def __init__(self, timeout_s: float) -> None:  # the poll loop alone, no bus
            self.timeouts = {"poll": 0.002, "state": timeout_s}
            self.node_id, self.cancel = NODE, None
            self.clock = clock.monotonic

        @property
        def statusword(self) -> int:
            return 0x0237 if clock.monotonic_ns() >= 3 * MS else 0x0250

    for timeout_s, met in ((0.003, True), (0.0025, False)):
        c = VirtualClock(epoch_ns=0)
        with clock.use(c):
            drv = Drv(timeout_s)
            if met:
                assert drv._wait("OPERATION ENABLED", "state", lambda sw: sw == 0x0237) == 0x0237
                assert c.time_ns() == 3 * MS
            else:
                with pytest.raises(Cia402Timeout):
                    drv._wait("OPERATION ENABLED", "state", lambda sw: sw == 0x0237)
                assert c.time_ns() == 2.5 * MS  # reported at the timeout, not a poll later
