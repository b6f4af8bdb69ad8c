"""Gateways in front of virtual drives, runners with leases (all in-process, loopback)."""

from __future__ import annotations

import json
import time

import can
import pytest
import zenoh

from hil.gateway.client import LeaseRefused, acquire, status
from hil.record.reader import Recording
from hil.record.recorder import Recorder
from hil.transport.can_bus import open_can
from hil.transport.dio import open_dio
from hil.transport.zenoh_can import pack
from hil.transport.zenoh_net import close_session, make_config, open_session, wait_connected
from hil.virtual.stack import VirtualDriveStack
from tests.gateway.conftest import sdo_read_statusword


def wait(pred, timeout_s: float = 5.0, what: str = "condition"):
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        v = pred()
        if v:
            return v
        time.sleep(0.005)
    raise AssertionError(f"{what} not reached within {timeout_s} s")


def test_two_gateways_two_runners_leases_honoured(make_rig):
    b1, b2 = make_rig("bench1"), make_rig("bench2")
    with acquire("lab", "bench1", holder="alice", connect=[b1.endpoint]) as a1, \
            acquire("lab", "bench2", holder="bob", connect=[b2.endpoint]):
        with pytest.raises(LeaseRefused) as refused:
            acquire("lab", "bench1", holder="bob", connect=[b1.endpoint])
        e = refused.value
        assert e.holder == "alice" and e.since_ns == a1.since_ns
        assert "leased by alice since" in str(e)
        assert status("lab", "bench1", connect=[b1.endpoint])["holder"] == "alice"
        # bob, without bench1's lease (another process: here a bare session), is heard by
        # nobody there, with no token or with a forged one
        request = can.Message(arbitration_id=0x601, is_extended_id=False,
                              data=bytes([0x40, 0x41, 0x60, 0, 0, 0, 0, 0]))
        s = open_session(make_config("peer", connect=[b1.endpoint]))
        try:
            answers: list = []
            sub = s.declare_subscriber("lab/bench1/can/can0", lambda smp: answers.append(smp),
                                       allowed_origin=zenoh.Locality.REMOTE)
            wait_connected(s, 5, what="intruder")

            def intrude() -> bool:
                s.put("lab/bench1/can/can0", pack(request, time.time_ns()))
                s.put("lab/bench1/can/can0", pack(request, time.time_ns()), attachment=b"X" * 16)
                time.sleep(0.02)
                return b1.gateway.can["can0"].health.refused >= 2

            wait(intrude, what="refusals")
            time.sleep(0.1)
            assert answers == []  # the drive never saw the requests
            sub.undeclare()
        finally:
            close_session(s)
        # alice drives bench1 and bob drives bench2 at the same time
        alice_bus = open_can(a1.can_url("can0"))
        bob_bus = open_can(f"zenoh:lab/bench2/can/can0?connect={b2.endpoint}")
        try:
            assert sdo_read_statusword(alice_bus).data[0] == 0x4B
            assert sdo_read_statusword(bob_bus).data[0] == 0x4B
        finally:
            alice_bus.shutdown()
            bob_bus.shutdown()
    # the gateway drives the safe state on its own thread after a release: wait for its report
    wait(lambda: len(b1.gateway.safe_reports) >= 1 and not b1.gateway.lease.safing,
         what="safe state after alice's release")
    with acquire("lab", "bench1", holder="bob", connect=[b1.endpoint]) as again:
        assert again.since_ns > a1.since_ns
    wait(lambda: len(b1.gateway.safe_reports) >= 2, what="safe state after bob's release")
    assert [r["reason"] for r in b1.gateway.safe_reports] == ["released by alice",
                                                              "released by bob"]


def test_one_runner_holds_several_benches(make_rig):
    b1, b2 = make_rig("bench1"), make_rig("bench2")
    with acquire("lab", "bench1", holder="ci", connect=[b1.endpoint]) as l1, \
            acquire("lab", "bench2", holder="ci", connect=[b2.endpoint]) as l2:
        buses = [open_can(l1.can_url("can0")), open_can(l2.can_url("can0"))]
        try:
            for bus in buses:
                assert sdo_read_statusword(bus).arbitration_id == 0x581
        finally:
            for bus in buses:
                bus.shutdown()
        assert l1.info()["can"] == {"can0": "lab/bench1/can/can0"}


@pytest.mark.integration
def test_killed_runner_leads_to_safe_state_in_recording(make_rig, runner_child):
    rig = make_rig("bench1", lease_timeout_s=1.0)
    child = runner_child("lab", "bench1", rig.endpoint, "ci-runner-7")
    assert child.lines[-1] == "ready", child.lines
    assert rig.state() == "READY TO SWITCH ON"  # Shutdown 0x0006 went through the gateway
    t_kill = time.time_ns()
    child.proc.kill()
    # the report is appended once the whole safe state is done; when it began is its t_ns
    wait(lambda: rig.gateway.safe_reports, timeout_s=5.0, what="safe state after the kill")
    rep = rig.gateway.safe_reports[0]
    assert rep["t_ns"] - t_kill < 1_000_000_000  # begun within the 1 s lease timeout
    assert rep["ok"] and "ci-runner-7 disappeared" in rep["reason"]
    assert wait(lambda: rig.state() == "SWITCH ON DISABLED", what="Disable Voltage applied")
    rig.gateway.stop()
    rec = Recording.open(rig.record)
    safety = [m for _t, _l, _p, m in rec.messages("/safety")]
    actions = [m["action"] for m in safety]
    assert actions[0] == "safe state start" and actions[-1] == "safe state done"
    cw = next(m for m in safety if m["action"].startswith("controlword"))
    assert cw["ok"] and cw["detail"] == "acknowledged" and cw["source"] == "gateway"
    assert any(m["action"] == "DI SON off" and m["ok"] for m in safety)
    frames = [m for _t, _l, _p, m in rec.messages("/can/can0/raw")]
    # Disable Voltage: controlword 0x0000 written to 6040h:00 of node 1 (L18272-18281)
    assert {"id": 0x601, "data": "2b40600000000000", "dir": "tx"}.items() <= next(
        f for f in frames if f["id"] == 0x601 and f["data"].startswith("2b406000000000")).items()
    leases = [m["event"] for _t, _l, _p, m in rec.messages("/gateway/lease")]
    assert leases[:2] == ["granted", "ended"]


def test_hung_runner_expires_after_lease_timeout(make_rig):
    rig = make_rig("bench1", lease_timeout_s=0.3)
    lease = acquire("lab", "bench1", holder="frozen", connect=[rig.endpoint])
    try:
        lease._stop.set()  # keep-alives stop, the session (and liveliness) stays
        lease._thread.join(2)
        t0 = time.time_ns()
        wait(lambda: rig.gateway.safe_reports, timeout_s=5.0, what="expiry")
        began = (rig.gateway.safe_reports[0]["t_ns"] - t0) / 1e9  # when the safe state began
        assert 0.15 < began < 1.0
        assert "no keep-alive within 0.3 s" in rig.gateway.safe_reports[0]["reason"]
        assert not rig.gateway.lease.allows(lease.token)
    finally:
        lease.release()


def test_source_timestamps_survive_the_hop(make_rig, tmp_path):
    """The adapter's capture time (here 250 ms before the gateway reads the frame) is what
    the runner gets as sender_time_ns and what its recorder writes as publish_time."""
    lag_s = 0.25
    stamped: list[float] = []

    class HardwareStamped(can.BusABC):
        def __init__(self, url: str) -> None:
            self.inner = open_can(url)
            super().__init__(channel=url)

        def send(self, msg, timeout=None):
            self.inner.send(msg, timeout)

        def _recv_internal(self, timeout):
            msg = self.inner.recv(timeout)
            if msg is not None:
                msg.timestamp = time.time() - lag_s
                stamped.append(msg.timestamp)
            return msg, False

        def shutdown(self):
            super().shutdown()
            self.inner.shutdown()

    rig = make_rig("bench1", can_factory=lambda _n, url: HardwareStamped(url))
    rec_path = tmp_path / "runner.mcap"
    with acquire("lab", "bench1", holder="t", connect=[rig.endpoint]) as lease, \
            Recorder(rec_path) as rec:
        bus = open_can(lease.can_url("can0"), tap=rec, name="can0")
        try:
            ans = sdo_read_statusword(bus)
        finally:
            bus.shutdown()
        assert abs(ans.sender_time_ns - round(stamped[-1] * 1e9)) < 2_000
        assert ans.timestamp - ans.sender_time_ns / 1e9 > lag_s * 0.9
        # DI/DO: the drive's output edge keeps the gateway's capture time
        dio = open_dio(lease.dio_url("drive1"), role="harness", tap=rec, name="drive1")
        try:
            seen: list[tuple] = []
            dio.subscribe(lambda line, level, t: seen.append((line, level, t)))
            captured: list[tuple] = []
            rig.gateway.dio["drive1"].port.subscribe(lambda *edge: captured.append(edge))
            # DO6 has no function (P2.041 = 0): only this test drives it, on the drive side
            rig.stack.dio_port.set("DO6", True)
            assert dio.wait_for("DO6", True, 2.0)
            t_src = next(t for line, level, t in captured if line == "DO6" and level)
        finally:
            dio.close()
    r = Recording.open(rec_path)
    rx = [(lt, pt) for _t, lt, pt, m in r.messages("/can/can0/raw") if m["dir"] == "rx"]
    assert rx and all(lt - pt > lag_s * 0.9e9 for lt, pt in rx)
    do6 = [(lt, pt) for _t, lt, pt, m in r.messages("/dio/drive1/DO6") if m["level"]]
    assert do6 and do6[0][1] == t_src


def test_health_queryable_and_periodic(make_rig):
    rig = make_rig("bench1")
    s = open_session(make_config("peer", connect=[rig.endpoint]))
    try:
        got: list[dict] = []
        sub = s.declare_subscriber("lab/bench1/health",
                                   lambda smp: got.append(json.loads(smp.payload.to_bytes())))
        wait(lambda: len(got) >= 2, timeout_s=3, what="two periodic health reports")
        sub.undeclare()
        reply = next(iter(s.get("lab/bench1/health", timeout=2))).ok
        doc = json.loads(reply.payload.to_bytes())
    finally:
        close_session(s)
    can0 = doc["buses"]["can/can0"]
    assert can0["link"] == "up" and can0["state"] == "active" and not can0["bus_off"]
    assert doc["buses"]["dio/drive1"]["link"] == "up"
    assert doc["lease"] == {"held": False, "safing": None}


def test_bus_off_error_frame_is_reported(make_rig):
    rig = make_rig("bench1")
    # SocketCAN error frame: CAN_ERR_BUSOFF | CAN_ERR_CRTL | CAN_ERR_CNT, counters 248/127
    rig.stack.can_bus.send(can.Message(arbitration_id=0x40 | 0x04 | 0x200, is_error_frame=True,
                                       data=bytes([0, 0x20, 0, 0, 0, 0, 248, 127])))
    h = rig.gateway.can["can0"].health
    # a snapshot is taken under the health's lock: the frame's whole update or none of it
    snap = wait(lambda: (s := h.snapshot())["bus_off"] and s, what="bus-off")
    assert snap["state"] == "bus-off"
    assert (snap["tx_error_counter"], snap["rx_error_counter"]) == (248, 127)


class Unpluggable(can.BusABC):
    """A virtual bus whose adapter can be pulled: send/recv/open raise OSError meanwhile."""

    plugged = True
    opened = 0

    def __init__(self, url: str) -> None:
        if not Unpluggable.plugged:
            raise OSError(19, "No such device")
        Unpluggable.opened += 1
        self.inner = open_can(url)
        super().__init__(channel=url)

    def send(self, msg, timeout=None):
        if not Unpluggable.plugged:
            raise OSError(19, "No such device")
        self.inner.send(msg, timeout)

    def _recv_internal(self, timeout):
        if not Unpluggable.plugged:
            raise OSError(100, "Network is down")
        return self.inner.recv(timeout), False

    def shutdown(self):
        super().shutdown()
        self.inner.shutdown()


def test_unplug_replug_recovers_without_restart(make_rig):
    Unpluggable.plugged, Unpluggable.opened = True, 0
    rig = make_rig("bench1", can_factory=lambda _n, url: Unpluggable(url))
    export = rig.gateway.can["can0"]
    with acquire("lab", "bench1", holder="t", connect=[rig.endpoint]) as lease:
        bus = open_can(lease.can_url("can0"))
        try:
            sdo_read_statusword(bus)
            Unpluggable.plugged = False
            wait(lambda: export.health.link == "down", what="link down")
            assert "OSError" in export.health.last_error
            time.sleep(0.1)  # a few failed reopen attempts with backoff
            assert lease.health()["buses"]["can/can0"]["link"] == "down"
            Unpluggable.plugged = True
            wait(lambda: export.health.link == "up", what="link up again")
            assert export.health.reopens == 1 and Unpluggable.opened == 2
            assert sdo_read_statusword(bus).arbitration_id == 0x581
        finally:
            bus.shutdown()


@pytest.mark.integration  # a real pty and zenoh in real time: t3.5 is 1.75 ms at 115200
def test_rs485_modbus_through_the_gateway(make_rig, tmp_path):
    from hil.protocol.modbus import crc16, read_request, rtu_decode, rtu_encode
    from hil.transport.serial_line import open_serial

    link = tmp_path / "ttyA3"
    rig = make_rig("bench1", rs485=(f"pty:{link}?baud=115200", f"serial:{link}?baud=115200"))
    assert isinstance(rig.stack, VirtualDriveStack)
    with acquire("lab", "bench1", holder="t", connect=[rig.endpoint]) as lease:
        line = open_serial(lease.serial_url("rs485", 115200))
        try:
            req = rtu_encode(1, read_request(0x0000, 2))  # P0.000, two words
            line.write(req)
            frame = line.read_frame(timeout=2.0)
        finally:
            line.close()
    assert frame is not None, "no Modbus answer through the gateway"
    station, pdu = rtu_decode(frame.data)
    assert station == 1 and pdu[0] == 0x03 and crc16(frame.data) == 0
    assert frame.source_t is not None  # the gateway's capture time of the first character
    # characters keep their line spacing: one character time at 115200 8N2 (11 bits)
    c = frame.char_time_ns
    steps = [b - a for a, b in zip(frame.times_ns, frame.times_ns[1:], strict=False)]
    assert all(s >= c for s in steps)
