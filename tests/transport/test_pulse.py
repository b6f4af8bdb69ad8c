"""Pulse lines (issue 26, docs/pulse.md): segments, never one message per pulse; virtual and
zenoh; hostile messages are refused with the field named and never stop the line."""

from __future__ import annotations

import json
import random
import threading
import time

import pytest

from hil.transport.pulse import PulseAdapter, PulseError, check_segment, open_pulse
from hil.transport.urls import TransportUrlError, parse_url
from hil.transport.zenoh_net import (
    close_session,
    config_from,
    open_session,
    wait_connected,
    wait_matching,
)

pytestmark = pytest.mark.timeout(30)


def test_virtual_segments_and_levels_both_ways(tap):
    plc = open_pulse("virtual:tp1", role="master", tap=tap, name="drive1")
    drv = open_pulse("virtual:tp1", role="drive")
    try:
        at_drive, at_plc = [], []
        drv.subscribe(lambda k, d, t, s: at_drive.append((k, d)))
        plc.subscribe(lambda k, d, t, s: at_plc.append((k, d)))
        plc.send("seg", {"freq": 50_000, "direction": -1, "count": 1000, "total": 7})
        plc.set("Y8", True)
        drv.send("oab", {"freq": 4000.0, "direction": 1, "count": 40})
        drv.send("oz", {"width_ns": 1000})
        drv.set("X0", True)
        assert at_drive == [
            ("seg", {"freq": 50_000.0, "direction": -1, "count": 1000, "total": 7,
                     "form": "pulse_sign", "logic": 0}),
            ("level", {"line": "Y8", "level": True})]
        assert [k for k, _ in at_plc] == ["oab", "oz", "level"]
        assert plc.get("X0") and drv.get("Y8")
        # the tap (the harness side) records what it sent and what it saw
        assert [(r[1]) for r in tap.pulse_messages] == ["seg", "oab", "oz"]
        assert [(r[1], r[2]) for r in tap.dio_levels] == [("Y8", True), ("X0", True)]
    finally:
        plc.close()
        drv.close()


def test_each_side_sends_only_its_own():
    plc = open_pulse("virtual:tp2", role="master")
    drv = open_pulse("virtual:tp2", role="drive")
    try:
        with pytest.raises(PulseError, match="cannot send 'oab'"):
            plc.send("oab", {"freq": 1, "count": 1})
        with pytest.raises(PulseError, match="cannot set line 'X0'"):
            plc.set("X0", True)
        with pytest.raises(PulseError, match="cannot send 'seg'"):
            drv.send("seg", {"freq": 1})
        with pytest.raises(PulseError, match="cannot set line 'Y8'"):
            drv.set("Y8", True)
    finally:
        plc.close()
        drv.close()
    with pytest.raises(RuntimeError, match="closed"):
        plc.send("seg", {"freq": 1})


@pytest.mark.parametrize("kind, body, field", [
    ("seg", {"freq": -1}, "seg.freq"),
    ("seg", {"freq": float("nan")}, "seg.freq"),
    ("seg", {"freq": 1e12}, "seg.freq"),
    ("seg", {"freq": "fast"}, "seg.freq"),
    ("seg", {"freq": True}, "seg.freq"),
    ("seg", {"freq": 10, "direction": 0}, "seg.direction"),
    ("seg", {"freq": 10, "count": -3}, "seg.count"),
    ("seg", {"freq": 10, "count": 1.5}, "seg.count"),
    ("seg", {"freq": 10, "form": "quad"}, "seg.form"),
    ("seg", {"freq": 10, "logic": 2}, "seg.logic"),
    ("seg", {"freq": 10, "total": 2**70}, "seg.total"),
    ("oz", {"width_ns": -1}, "oz.width_ns"),
    ("oz", [], "oz: body"),
    ("jump", {}, "kind 'jump'"),
])
def test_malformed_messages_name_their_field(kind, body, field):
    with pytest.raises(PulseError, match=field.replace(".", r"\.")):
        check_segment(kind, body)


def test_urls():
    for bad, why in (("udp:x", "not a pulse transport"), ("pty:auto", "not a pulse"),
                     ("virtual:", "needs a target"), ("virtual:a?baud=9600", "unknown param")):
        with pytest.raises(TransportUrlError, match=why):
            open_pulse(bad, role="master")
    with pytest.raises(ValueError, match="role"):
        open_pulse("virtual:x", role="harness")  # type: ignore[arg-type]


def test_zenoh_line_between_two_sessions(port, tap):
    ep = f"tcp/127.0.0.1:{port}"
    drv = open_pulse(f"zenoh:tzp/drive1/pulse?listen={ep}", role="drive")
    drv.set("X0", True)  # before the PLC exists: learnt by query
    plc = open_pulse(f"zenoh:tzp/drive1/pulse?connect={ep}", role="master", tap=tap,
                     name="drive1")
    try:
        assert plc.get("X0") is True
        got: list = []
        drv.subscribe(lambda k, d, t, s: got.append((k, d, s)))
        t0 = time.time_ns()
        plc.send("seg", {"freq": 1000, "direction": 1, "count": 10, "total": 0})
        plc.set("Y8", True)
        deadline = time.monotonic() + 5
        while len(got) < 2 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert [g[0] for g in got] == ["seg", "level"]
        assert got[0][1]["count"] == 10 and got[0][2] >= t0  # the sender's time attached
        seen: list = []
        plc.subscribe(lambda k, d, t, s: seen.append(k))
        drv.send("oz", {"width_ns": 5})
        deadline = time.monotonic() + 5
        while not seen and time.monotonic() < deadline:
            time.sleep(0.01)
        assert seen == ["oz"]
    finally:
        plc.close()
        drv.close()


def test_zenoh_levels_heard_on_two_threads_are_told_in_the_order_stored(port):
    """As on the DI/DO port: a query's answer (its own thread) does not tell a level while
    the subscriber's thread has stored one and not yet told it."""
    from types import SimpleNamespace

    def sample(line: str):
        return SimpleNamespace(key_expr=f"tzo/pulse/{line}", attachment=None,
                               payload=SimpleNamespace(to_bytes=lambda: b"1"))

    heard: list[str] = []
    answering_done = threading.Event()

    class Tap:
        def dio(self, name, line, level, t, source_t):
            if line == "Y1" and not answering_done.is_set():
                threading.Thread(target=lambda: (drv._learn_levels(0.1, if_unknown=True),
                                                 answering_done.set()), daemon=True).start()
                answering_done.wait(0.3)

        def pulse(self, *a):
            pass

    drv = open_pulse(f"zenoh:tzo/pulse?listen=tcp/127.0.0.1:{port}", role="drive", tap=Tap())
    session = drv.session
    try:
        drv.session = SimpleNamespace(get=lambda key, timeout: [
            SimpleNamespace(ok=sample("Y1")), SimpleNamespace(ok=sample("Y2"))])
        drv.subscribe(lambda kind, body, t, s: heard.append(body.get("line", kind)))
        drv._on_sample(sample("Y1"))  # as the subscriber's thread hears it
        assert answering_done.wait(2.0)
        assert heard == ["Y1", "Y2"]
    finally:
        drv.session = session
        drv.close()


def test_zenoh_level_missed_at_connect_is_asked_for_again(port, monkeypatch):
    """The drive's X level was set before the PLC could hear it and its first answer was
    lost: the PLC asks again when it reads a level it never heard of (at most every 100 ms)."""
    ep = f"tcp/127.0.0.1:{port}"
    drv = open_pulse(f"zenoh:tzl/drive1/pulse?listen={ep}", role="drive")
    drv.set("X2", True)
    answered = drv._on_query
    queries = []

    def late(query):
        queries.append(1)
        if len(queries) > 1:
            answered(query)

    monkeypatch.setattr(drv, "_on_query", late)
    drv._queryable.undeclare()
    drv._queryable = drv.session.declare_queryable("tzl/drive1/pulse/**", drv._on_query)
    plc = open_pulse(f"zenoh:tzl/drive1/pulse?connect={ep}", role="master", name="drive1")
    try:
        assert len(queries) == 1 and plc.levels() == {}
        assert plc.get("X2") is False  # not known: asked in the background, no wait
        deadline = time.monotonic() + 2
        while not plc.get("X2") and time.monotonic() < deadline:
            time.sleep(0.01)
        assert plc.get("X2") is True and len(queries) == 2  # learnt by asking again
        assert plc.get("X2") is True and len(queries) == 2  # known: nothing asked
        for _ in range(20):  # never set by the drive: asked at most every 100 ms
            assert plc.get("X5") is False
        time.sleep(0.3)
        assert len(queries) <= 3
    finally:
        plc.close()
        drv.close()


def test_zenoh_hostile_payloads_never_stop_the_line(port):
    """Random bytes, broken JSON and wrong fields on every key: each is refused (kept in
    `errors` where it was a message), and a good segment after them still arrives."""
    ep = f"tcp/127.0.0.1:{port}"
    drv = open_pulse(f"zenoh:tzh/pulse?listen={ep}", role="drive")
    u = parse_url(f"zenoh:tzh/pulse?connect={ep}", "pulse")
    session = open_session(config_from(u.zenoh()), what="fuzzer")
    try:
        got: list = []
        drv.subscribe(lambda k, d, t, s: got.append((k, d)))
        rnd = random.Random(26)
        wait_connected(session, 5, what="fuzzer")
        probe = session.declare_publisher("tzh/pulse/seg")
        assert wait_matching(probe, 5)  # the drive's subscriber is known: nothing is lost
        probe.undeclare()
        for i in range(200):
            key = rnd.choice(["seg", "Y8", "oab", "oz", "X0", "seg"])
            raw = rnd.choice([
                bytes(rnd.getrandbits(8) for _ in range(rnd.randint(0, 40))),
                b'{"freq":',
                json.dumps({"freq": rnd.choice([-1, 1e30, "x", None, [1]]), "count": i}).encode(),
                json.dumps({"freq": 10, "direction": rnd.choice([0, 2, "up"])}).encode(),
                b"2", b"",
            ])
            session.put(f"tzh/pulse/{key}", raw)
        session.put("tzh/pulse/seg", json.dumps({"freq": 500, "count": 5}).encode())
        deadline = time.monotonic() + 5
        while not got and time.monotonic() < deadline:
            time.sleep(0.01)
        assert got and got[-1] == ("seg", {"freq": 500.0, "direction": 1, "count": 5,
                                            "form": "pulse_sign", "logic": 0})
        assert len(got) == 1  # nothing malformed got through
        assert drv.errors  # and what was refused is on record
    finally:
        close_session(session)
        drv.close()


class _BenchGenerator(PulseAdapter):
    """A stand-in for a real pulse generator + counter behind `PulseAdapter`: its "hardware"
    is a virtual line's PLC end (the virtual drive on the other side)."""

    def __init__(self, wire: str) -> None:
        super().__init__(f"bench-generator:{wire}", "master", name="d")
        self.hw = open_pulse(wire, role="master")
        self.hw.subscribe(self._from_hardware)
        for line, level in self.hw.levels().items():  # read the inputs once at start
            self._received_level(line, level, None)

    def _from_hardware(self, kind, data, t, source_t):
        if kind == "level":
            self._received_level(data["line"], data["level"], source_t)
        else:
            self._received(kind, data, source_t)

    def _publish(self, kind, body, t):  # load a segment into the generator
        self.hw.send(kind, body)

    def _publish_level(self, line, level, t):  # set an output (CLR)
        self.hw.set(line, level)

    def _close_backend(self):
        self.hw.close()


def test_an_adapter_behind_the_interface_drives_the_virtual_drive():
    from hil import clock
    from hil.drivers.plc_pulse import AxisParams, Drv, Program, PulseMaster, Step
    from hil.model.mechanics import COUNTS_PER_REV
    from hil.virtual.stack import DriveSpec, VirtualDriveStack

    with clock.use(clock.VirtualClock()):
        stack = VirtualDriveStack(DriveSpec(
            name="d", pulse="virtual:adapter-wire", inputs={8: True},
            params={"P2.041": 0x0108, "P1.045": 10000, "P1.044": 16777216})).start()
        gen = _BenchGenerator("virtual:adapter-wire")
        try:
            stack.host.call(stack.drive.set_di, 1, True)
            clock.sleep(0.05)
            assert gen.get("X0")  # the DOG level came through the adapter
            plc = PulseMaster(gen, AxisParams(max_speed=100_000, start_speed=500,
                                              accel_ms=100))
            st = plc.run(Program([Step(spd=20_000, drive=Drv("ADR", "+", 10_000),
                                       wait_time=0.2)]))
            assert st.feedback == pytest.approx(10_000, abs=3)  # the counter, via _received
            assert stack.drive.axis.position == pytest.approx(COUNTS_PER_REV, abs=2)
        finally:
            gen.close()
            stack.stop()


def test_a_flood_of_malformed_messages_keeps_only_the_last_reasons():
    """A review (helper-136): every refused message's reason was kept, so a hostile flood
    grew the port's memory without end. The last few are kept, and all are counted."""
    plc = open_pulse("virtual:tp-flood", role="master")
    drv = open_pulse("virtual:tp-flood", role="drive")
    try:
        for i in range(5000):
            drv._received("seg", {"freq": -i - 1}, None)
        assert drv.refused == 5000 and 0 < len(drv.errors) <= 20
        assert "-5000" in drv.errors[-1]  # the newest reason is there
    finally:
        plc.close()
        drv.close()
