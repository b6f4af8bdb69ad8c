"""The absolute encoder against section 10.3 and chapter 13, written from the manual (an
outside review found these departures). A whole `Drive` on its injected clock; ABSE on DI2,
ABSC on DI3, ABSW on DO4, DI4/DO2/DO3 left free for the handshake (L16504)."""

from __future__ import annotations

from hil.drivers.abs_reader import AbsPositionReader
from hil.model.drive import Drive
from hil.units import MS, S
from hil.virtual.model_lines import ModelLines

ABS = {"P2.069": 1, "P2.011": 0x11D, "P2.012": 0x11F, "P2.021": 0x10D,  # ABSE, ABSC, ABSW
       "P2.013": 0, "P2.019": 0, "P2.020": 0}  # DI4 / DO2 / DO3 idle (L16504)


def drive(**params: int) -> Drive:
    """A drive with its absolute origin set (P2.071 after the P2.008 = 271 key, L10081)."""
    d = Drive(inputs={8: True}, params=ABS | params)
    d.params.write("P2.008", 271)
    d.params.write("P2.071", 1)
    assert d.absolute.mem.coordinate == "valid"
    return d


def switched(d: Drive) -> Drive:
    """ABSQ (DI4) idles high, then ABSE on: after T_S the pins switch (L16503-L16504)."""
    d.set_di(4, True)
    d.set_di(2, True)
    d.advance(20 * MS)
    assert d.absolute.state == "ready"
    return d


def test_dropping_abse_with_the_pins_switched_ends_the_cycle_without_an_alarm():
    """The host drops ABSE: the drive ends the cycle and ABSW goes off (L16514-L16515). AL068
    is for a host that breaks the ABSQ/ABSR order or T_R (L19787-L19790), not for this."""
    d = switched(drive())
    d.set_di(2, False)
    d.advance(300 * MS)  # past T_R (200 ms, L16497)
    assert "AL068" not in d.alarms.active
    assert not d.do(4) and d.absolute.state == "idle"


def test_dropping_abse_after_the_hosts_ack_raises_nothing():
    """ABSE off right after ABSQ went on for a bit (ABSR still on): the cycle just ends."""
    d = switched(drive())
    d.set_di(4, False)  # request bit 0 (L16505)
    d.advance(10 * MS)
    assert d.do(2)  # ABSR: the bit is ready (L16506)
    d.set_di(4, True)  # the host took it (L16507)
    d.advance(3 * MS)
    d.set_di(2, False)
    d.advance(300 * MS)
    assert "AL068" not in d.alarms.active and not d.do(4)


def test_the_reader_sets_the_origin_twice_and_then_reads():
    """The harness's reader re-origins an axis that has one already (ABSE, ABSC, ABSE off)
    and then reads it: no AL068, and the read succeeds (the first attempt)."""
    d = drive()
    d.advance(20 * MS)
    lines = ModelLines(now=lambda: d.now, advance_to=d.advance_to,
                       write=lambda line, v: d.set_di(int(line[2:]), v),
                       read=lambda line: d.do(int(line[2:])), next_deadline=d.sched.next_deadline)
    reader = AbsPositionReader(lines, abse="DI2", absc="DI3", absw="DO4", clock=lines.clock)
    reader.set_origin()
    reader.set_origin()
    d.advance(300 * MS)
    assert "AL068" not in d.alarms.active and not d.do(4)
    got = reader.read()
    assert got.attempts == 1 and got.status == 0


def test_an_absc_pulse_shorter_than_t_q_sets_no_origin():
    """ABSC must be held T_Q, at least P2.009 + 2 ms (L16441, L16448-L16450): with P2.009 =
    2 ms a 3 ms pulse passes the input filter but is too short, a 4.5 ms one is enough."""
    for pulse_ms, coordinate in ((2.1, "unset"), (3.0, "unset"), (4.5, "valid")):
        d = Drive(inputs={8: True}, params=ABS | {"P2.009": 2})
        d.set_di(2, True)
        d.advance(20 * MS)  # ABSE on, past T_S
        d.set_di(3, True)
        d.advance(round(pulse_ms * MS))
        d.set_di(3, False)
        d.advance(50 * MS)
        assert d.absolute.mem.coordinate == coordinate, pulse_ms


def test_a_normal_clear_at_rest_releases_al07c():
    """AL07C: a clear above 200 rpm; "run the normal clear of the absolute position to
    release it by itself" (L19855-L19857)."""
    d = drive()
    d.set_di(1, True)  # SON
    d.advance(5 * MS)
    d.axis.run_velocity(500, 50, 50)
    d.advance(S)
    d.params.write("P2.071", 1)  # at 500 rpm: refused (L19855)
    assert "AL07C" in d.alarms.active
    d.axis.run_velocity(0, 50, 50)
    d.advance(S)
    d.params.write("P2.071", 1)  # at rest: the normal clear
    d.advance(MS)
    assert "AL07C" not in d.alarms.active


def test_al028_clears_by_itself_once_the_battery_is_back_in_range():
    """AL028 (battery over 3.8 V) "clears by itself" once the cause is removed (L19639,
    L19641)."""
    d = drive()
    d.absolute.set_battery_voltage(3.9)
    d.advance(MS)
    assert "AL028" in d.alarms.active
    d.absolute.set_battery_voltage(3.6)
    d.advance(MS)
    assert "AL028" not in d.alarms.active


def test_monitor_038_is_the_battery_voltage():
    """Monitor 038 (26h) is the battery voltage, with the absolute function on (L15477); 31
    means below 3.1 V (L16379), so the unit is 0.1 V. With P2.069 off it has no value."""
    d = drive()
    d.params.write("P0.017", 38)  # P0.009 shows the code P0.017 selects (L7147)
    d.absolute.set_battery_voltage(3.6)
    assert d.params.get("P0.009") == 36
    d.absolute.set_battery_voltage(3.04)
    assert d.params.get("P0.009") == 30
    off = Drive(inputs={8: True})
    off.params.write("P0.017", 38)
    assert off.params.get("P0.009") == 0
