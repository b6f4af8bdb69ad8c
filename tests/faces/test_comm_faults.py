"""The drive's reactions to a misbehaving master or bus (issue 16), on the injected clock.

A real `Drive` behind a `CanopenSlave`; frames are handed to `handle_frame` with explicit
sender timestamps and the timers run from `Drive.advance` (no wall-clock sleeps). What the
drive sends (EMCY, state) is read off a second bus on the same virtual channel.
Lines: AL180 L17097-17126 / L20021-20025, 1029h L17806-17838, AL111 L19933-19937,
AL112 L19941-19945, AL185 L20027-20031, AL301 L20123-20127, AL3E2 L20159-20163,
AL3E3 L20165-20169, AL019 L19592-19596, AL020 L19598-19602, EMCY L17061-17069.
"""

from __future__ import annotations

import struct
import time
import uuid

import can
import pytest

from hil.faces.canopen_slave import CanopenSlave
from hil.model.drive import Drive
from hil.model.options import ModelOptions
from hil.units import MS

NODE = 5
MASTER = 0x7F
US = 1_000


class Rig:
    def __init__(self, **opts) -> None:
        self.drive = Drive(options=ModelOptions(**opts), inputs={8: True})
        ch = f"cf-{uuid.uuid4().hex}"
        self.bus = can.Bus(interface="virtual", channel=ch, ignore_config=True)
        self.out = can.Bus(interface="virtual", channel=ch, ignore_config=True)
        self.slave = CanopenSlave(self.bus, self.drive, node_id=NODE, own_timer=False,
                                  clock=lambda: self.drive.now)
        self.slave.start()
        self.t0 = time.time()

    def close(self) -> None:
        self.slave.close()
        self.bus.shutdown()
        self.out.shutdown()

    def feed(self, cid: int, data: bytes = b"", *, at_ms: float | None = None,
             remote: bool = False, error: bool = False) -> None:
        """Hand one frame to the slave; `at_ms` = its sender time after t0 (default now)."""
        sent = time.time() if at_ms is None else self.t0 + at_ms / 1000
        msg = can.Message(arbitration_id=cid, data=data, is_extended_id=False,
                          is_remote_frame=remote, is_error_frame=error, timestamp=sent)
        with self.slave.lock:
            self.slave.handle_frame(msg)

    def run(self, ms: float) -> None:
        """Let `ms` pass on the model clock, ticking the face every millisecond."""
        end = self.drive.now + round(ms * MS)
        while self.drive.now < end:
            self.drive.advance(min(MS, end - self.drive.now))
            self.slave.tick(self.drive.now)

    def sdo_write(self, index: int, sub: int, value: int, size: int = 4) -> None:
        cs = 0x23 | (4 - size) << 2
        self.feed(0x600 + NODE, struct.pack("<BHB", cs, index, sub)
                  + value.to_bytes(size, "little").ljust(4, b"\0"))

    def start(self) -> None:
        self.feed(0x000, bytes([0x01, NODE]))  # NMT start

    def emcys(self) -> list[bytes]:
        out = []
        while (m := self.out.recv(0.01)) is not None:
            if m.arbitration_id == 0x80 + NODE:
                out.append(bytes(m.data))
        return out

    def enable(self) -> None:
        for cw in (0x06, 0x07, 0x0F):
            self.drive.write_object(0x6040, 0, cw)
            self.run(10)
        assert self.drive.cia402.state == "OPERATION ENABLED"

    @property
    def alarms(self) -> tuple[str, ...]:
        return self.drive.alarms.active


@pytest.fixture
def rig():
    r = Rig()
    yield r
    r.close()


def heartbeat_rig(r: Rig, consumer_ms: int = 100) -> None:
    r.start()
    r.sdo_write(0x1016, 1, MASTER << 16 | consumer_ms)  # node bits 23..16, ms (L17743)
    r.feed(0x700 + MASTER, bytes([0x05]))  # first heartbeat starts the monitoring


def test_heartbeat_loss_al180_emcy_preop_and_fault_reaction(rig):
    """1016h consumer 100 ms: AL180 just after 100 ms of silence (L17097-17115), EMCY 8130h
    with 1001h bit 4 "communication" and the Delta code 0x0180 (L17061-17069), 1029h = 0 ->
    PRE-OPERATIONAL, and the servo-off alarm runs the 605Eh = 0 reaction: FAULT at once."""
    rig.enable()
    heartbeat_rig(rig)
    rig.emcys()
    rig.run(99)
    rig.feed(0x700 + MASTER, bytes([0x05]))  # in time: re-armed
    rig.run(100)
    assert "AL180" not in rig.alarms
    rig.run(2)
    assert "AL180" in rig.alarms
    assert rig.slave.state == "PRE-OPERATIONAL"
    assert rig.drive.cia402.state == "FAULT" and not rig.drive.servo_on
    emcy = rig.emcys()[0]
    assert emcy[:2] == b"\x30\x81" and emcy[2] & 0x11 == 0x11 and emcy[3:5] == b"\x80\x01"


def test_heartbeat_deviation_knob_makes_al180_late():
    r = Rig(dev_heartbeat_extra_ms=30)
    try:
        heartbeat_rig(r)
        r.run(110)
        assert "AL180" not in r.alarms
        r.run(25)
        assert "AL180" in r.alarms
    finally:
        r.close()


@pytest.mark.parametrize(("behaviour", "state"), [(0, "PRE-OPERATIONAL"), (1, "OPERATIONAL"),
                                                  (2, "STOPPED")])
def test_life_guarding_al180_and_1029h(rig, behaviour, state):
    """100Ch 10 ms x 100Dh 3 = 30 ms life time (L17117-17126); 1029h sub1 (L17823-17838)."""
    rig.start()
    rig.sdo_write(0x100C, 0, 10, 2)
    rig.sdo_write(0x100D, 0, 3, 1)
    rig.sdo_write(0x1029, 1, behaviour, 1)
    rig.feed(0x700 + NODE, remote=True)  # guard request starts the life time
    rig.run(30)
    assert "AL180" not in rig.alarms
    rig.run(2)
    assert "AL180" in rig.alarms and rig.slave.state == state


@pytest.mark.parametrize("option", ["heartbeat", "both"])
def test_guarding_while_the_heartbeat_runs(option):
    """CiA 301 uses the heartbeat when 1017h != 0 (as drives do: both share 700h + node): no
    guard answer and no life time then, so a master that guarded and then turned the
    heartbeat on gets no AL180 when its guard requests stop. Option `both`: answered and
    watched as before (the A3 manual, L17097-L17126, says nothing of the two together)."""
    r = Rig(guarding_with_heartbeat=option)
    try:
        r.start()
        r.sdo_write(0x100C, 0, 10, 2)
        r.sdo_write(0x100D, 0, 3, 1)
        r.feed(0x700 + NODE, remote=True)  # life guarding runs: 30 ms
        r.run(5)
        r.sdo_write(0x1017, 0, 100, 2)  # heartbeat producer 100 ms
        while r.out.recv(0.01) is not None:
            pass
        r.feed(0x700 + NODE, remote=True)
        answers = []
        while (m := r.out.recv(0.05)) is not None:
            if m.arbitration_id == 0x700 + NODE and not m.is_remote_frame:
                answers.append(bytes(m.data))
        r.run(60)  # past the 30 ms life time
        if option == "heartbeat":
            assert answers == [] and "AL180" not in r.alarms, (answers, r.alarms)
        else:
            assert answers and "AL180" in r.alarms, (answers, r.alarms)
    finally:
        r.close()


def test_sdo_flood_al111(rig):
    """Two SDO requests sent 0.2 ms apart, before the drive answered the first: AL111
    (L19933-19937). EMCY 8110h."""
    rig.start()
    rig.emcys()
    up = struct.pack("<BHBI", 0x40, 0x1000, 0, 0)
    rig.feed(0x600 + NODE, up, at_ms=-0.4)
    rig.feed(0x600 + NODE, up, at_ms=-0.2)
    assert "AL111" in rig.alarms
    assert any(e[:2] == b"\x10\x81" for e in rig.emcys())


def test_sdo_one_at_a_time_is_no_flood():
    """A master that waits for each answer never overflows, however fast it is."""
    r = Rig()
    try:
        up = struct.pack("<BHBI", 0x40, 0x1000, 0, 0)
        for _ in range(20):
            r.feed(0x600 + NODE, up)  # each sent after the previous answer left
        assert "AL111" not in r.alarms
        r.close()
        r = Rig(dev_ignore_sdo_flood=True)
        r.feed(0x600 + NODE, up, at_ms=-0.4)
        r.feed(0x600 + NODE, up, at_ms=-0.2)
        assert "AL111" not in r.alarms
    finally:
        r.close()


def test_duplicate_pdo_al112(rig):
    """RPDO1 (200h + node, harness mapping 6040h + 6060h) twice within 1 ms, the second sent
    before the first was processed: AL112 (L19941-19945); 2 ms apart, or sent after the drive
    took the previous one (a fast master waiting for the statusword): nothing."""
    rig.start()
    rig.feed(0x200 + NODE, b"\x06\x00\x01", at_ms=-4)
    rig.feed(0x200 + NODE, b"\x06\x00\x01", at_ms=-2)
    for _ in range(5):  # a master that sends each PDO after the drive took the previous
        rig.feed(0x200 + NODE, b"\x06\x00\x01")
    assert "AL112" not in rig.alarms
    rig.feed(0x200 + NODE, b"\x06\x00\x01", at_ms=-1)  # sent before the last was processed
    rig.feed(0x200 + NODE, b"\x06\x00\x01", at_ms=-0.5)
    assert "AL112" in rig.alarms


def test_error_frames_al185():
    """Error frames add 8 to the receive error counter, valid frames take 1; > 128 raises
    AL185 (L20027-20031): 16 frames = 128 is not enough, the 17th is."""
    r = Rig()
    try:
        for _ in range(16):
            r.feed(0x000, error=True)
        assert r.slave.rx_error_counter == 128 and "AL185" not in r.alarms
        r.feed(0x123, b"\x00")  # a valid frame: 127
        r.feed(0x000, error=True)
        assert "AL185" in r.alarms
        r.close()
        r = Rig(dev_bus_error_limit=200)
        for _ in range(17):
            r.feed(0x000, error=True)
        assert "AL185" not in r.alarms
    finally:
        r.close()


def ip_rig(r: Rig, period_ms: int = 10) -> None:
    r.start()
    r.sdo_write(0x1006, 0, period_ms * 1000)  # µs (L17590-17630)
    r.drive.write_object(0x6060, 0, 7)  # IP mode (L17211)
    r.run(5)


def test_sync_timeout_al3e3(rig):
    """SYNC every 10 ms, then none: AL3E3 after 3 x 1006h (option sync_timeout_cycles)."""
    ip_rig(rig)
    for k in range(5):
        rig.feed(0x80, at_ms=10 * k)
        rig.run(10)
    rig.run(20)
    assert rig.alarms == ()
    rig.run(2)
    assert "AL3E3" in rig.alarms


def test_sync_not_monitored_outside_ip_mode(rig):
    rig.start()
    rig.sdo_write(0x1006, 0, 10_000)
    rig.feed(0x80, at_ms=0)
    rig.feed(0x80, at_ms=1)  # early, but the drive is not in IP mode
    rig.run(100)
    assert rig.alarms == ()


def test_early_sync_al3e2(rig):
    ip_rig(rig)
    rig.feed(0x80, at_ms=0)
    rig.feed(0x80, at_ms=6)  # 6 ms >= 0.5 x 10 ms: fine
    assert rig.alarms == ()
    rig.feed(0x80, at_ms=10)  # 4 ms after the previous one: too early
    assert "AL3E2" in rig.alarms


def test_sync_cycle_mismatch_al301(rig):
    """A master whose cycle is 12 ms while 1006h says 10 ms: AL301 after 8 intervals."""
    ip_rig(rig)
    for k in range(8):
        rig.feed(0x80, at_ms=12 * k)
    assert rig.alarms == ()
    rig.feed(0x80, at_ms=96)
    assert "AL301" in rig.alarms


def test_sync_timeout_deviation_knob():
    r = Rig(dev_sync_timeout_extra_ms=15)
    try:
        ip_rig(r)
        r.feed(0x80, at_ms=0)
        r.run(32)
        assert "AL3E3" not in r.alarms
        r.run(15)
        assert "AL3E3" in r.alarms
    finally:
        r.close()


@pytest.mark.parametrize(("code", "raised"), [(1, False), (2, True), (3, True), (4, False)])
def test_modbus_exception_al019(code, raised):
    """AL019: "communication address / value incorrect" (L19592-19596) = exceptions 02, 03."""
    drive = Drive(inputs={8: True})
    drive.modbus_comm_error(code)
    assert ("AL019" in drive.alarms.active) is raised


def test_modbus_al019_option_off():
    drive = Drive(options=ModelOptions(modbus_al019_exceptions=()), inputs={8: True})
    drive.modbus_comm_error(2)
    assert drive.alarms.active == ()


def test_comm_timeout_deviation_makes_al020_late():
    drive = Drive(options=ModelOptions(dev_comm_timeout_extra_ms=50), inputs={8: True})
    drive.raise_alarm("AL020")
    drive.advance(49 * MS)
    assert "AL020" not in drive.alarms.active
    drive.advance(2 * MS)
    assert "AL020" in drive.alarms.active


@pytest.mark.parametrize("alarm", ["AL111", "AL112", "AL3E3"])
@pytest.mark.parametrize("clear", ["6040h", "nmt"])
def test_servo_on_comm_alarms_clear_by_6040h_or_nmt(rig, alarm, clear):
    """"Clear: NMT reset or 0x6040 reset" (AL111 L19937, AL112 L19945, AL3E3 L20169): with
    the servo on (these alarms keep it on, so CiA 402 is not in FAULT) the bit 7 edge on top
    of controlword 0Fh clears them and the servo stays on; an NMT reset clears them too."""
    rig.enable()
    rig.drive.raise_alarm(alarm)
    assert alarm in rig.alarms and rig.drive.servo_on
    if clear == "6040h":
        rig.drive.write_object(0x6040, 0, 0x8F)
        rig.run(2)
        rig.drive.write_object(0x6040, 0, 0x0F)
        rig.run(2)
        assert rig.drive.cia402.state == "OPERATION ENABLED"
    else:
        rig.feed(0x000, bytes([0x82, NODE]))  # NMT reset communication
        rig.run(2)
    assert alarm not in rig.alarms


def test_sdo_request_sent_after_the_answer_left_is_no_flood():
    """A master that waits for each answer never overflows (L19933-19937, choice
    `sdo_flood_window_us`), even when it is faster than the drive's own bookkeeping: here the
    drive's thread is held up 3 ms right after its answer left, and the next request is sent
    0.1 ms after that answer (a zenoh bench under load does this)."""
    r = Rig()
    try:
        left: list[float] = []
        real_send = r.bus.send

        def send(msg, timeout=None):
            real_send(msg, timeout)
            if msg.arbitration_id == 0x580 + NODE:
                left.append(time.time())
                time.sleep(0.003)  # preempted between sending and anything after it

        r.bus.send = send
        up = struct.pack("<BHBI", 0x40, 0x1000, 0, 0)
        r.feed(0x600 + NODE, up)
        assert left
        nxt = can.Message(arbitration_id=0x600 + NODE, data=up, is_extended_id=False,
                          timestamp=left[0] + 0.0001)
        with r.slave.lock:
            r.slave.handle_frame(nxt)
        assert "AL111" not in r.alarms
    finally:
        r.close()


def test_sync_resumed_after_timeout_restarts_the_monitoring(rig):
    """SYNC lost (AL3E3, L20165-20169), then back at the right cycle: the gap is not a SYNC
    interval, so no AL301 (L20123-20127) follows from it (choice, docs/manual-choices.md)."""
    ip_rig(rig)
    for k in range(5):
        rig.feed(0x80, at_ms=10 * k)
        rig.run(10)
    rig.run(100)
    assert rig.alarms == ("AL3E3",)
    for k in range(12):
        rig.feed(0x80, at_ms=200 + 10 * k)
        rig.run(10)
    assert rig.alarms == ("AL3E3",)
