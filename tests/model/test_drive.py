"""The composed virtual drive on the injected clock, with the manual's own numbers."""

from __future__ import annotations

import pytest

from hil.model.drive import Drive
from hil.model.errors import ObjectError, OutOfRange, ReadOnly, UnknownFunction, UnknownParameter
from hil.model.events import AlarmChanged, DoChanged
from hil.model.options import ModelOptions
from hil.units import MS, S

# Virtual bench wiring: EMGS (DI8, b-contact) closed = no emergency; BRKR on DO6.
BENCH = {"P2.041": 0x0108}


def make(options: ModelOptions | None = None, **params: int) -> tuple[Drive, list]:
    drive = Drive(options=options, inputs={8: True}, params=BENCH | params)
    events: list = []
    drive.subscribe(events.append)
    return drive, events


def do_edges(events: list, function: str) -> list[tuple[int, bool]]:
    return [(e.t, e.level) for e in events if isinstance(e, DoChanged) and e.function == function]


def alarms_raised(events: list) -> list[tuple[int, str]]:
    return [(e.t, e.code) for e in events if isinstance(e, AlarmChanged) and e.active]


def servo_on_by_di(drive: Drive) -> int:
    """Close SON (DI1) and return when the drive accepted it (after the P2.009 filter)."""
    t = drive.now
    drive.set_di(1, True)
    drive.advance(drive.params.get("P2.009") * MS)
    assert drive.servo_on
    return t + drive.params.get("P2.009") * MS


def test_factory_outputs_at_power_up() -> None:
    drive, _ = make()
    drive.advance(10 * MS)
    # DO1 SRDY (a) on, DO5 ALRM b-contact conducts while there is no alarm (L1900-1907).
    assert drive.do(1) and drive.do(5)
    assert drive.snapshot()["state"] == "SWITCH ON DISABLED"
    assert not drive.servo_on and not drive.do(6)


def test_brkr_rises_p1042_after_servo_on() -> None:
    # Issue example: P1.042 = 150 ms -> BRKR rises 150 ms after servo on (L8499).
    drive, events = make(**{"P1.042": 150})
    drive.advance(5 * MS)
    t_on = servo_on_by_di(drive)
    assert t_on == 7 * MS  # DI filter P2.009 = 2 ms (L9229)
    drive.advance(400 * MS)
    assert do_edges(events, "BRKR") == [(t_on + 150 * MS, True)]
    assert drive.snapshot()["brake_released"]


def test_brkr_drops_when_speed_below_p1038_before_p1043() -> None:
    # L1359-1362: BRKR off at the earlier of P1.043 and |v| < P1.038.
    drive, events = make(**{"P1.043": 1000, "P1.032": 0x0000})  # dynamic brake stop
    servo_on_by_di(drive)
    drive.axis.run_velocity(300.0, 100.0, 100.0)
    drive.advance(300 * MS)
    assert drive.axis.velocity_rpm > 250
    drive.set_di(1, False)
    drive.advance(1200 * MS)
    off = [t for t, lvl in do_edges(events, "BRKR") if not lvl]
    assert len(off) == 1
    t_off_request = 300 * MS + 2 * MS + 2 * MS
    assert off[0] - t_off_request < 1000 * MS  # engaged by the speed rule, before P1.043
    snap = drive.snapshot()
    assert not snap["brkr"] and abs(snap["speed_rpm"]) < 10.0


@pytest.mark.parametrize(("held_ms", "alarm"), [(9, False), (10, True)])
def test_sto_both_channels(held_ms: int, alarm: bool) -> None:
    # L2478: both lost 10 ms -> servo off + AL500; 9 ms -> nothing (issue example).
    drive, events = make()
    servo_on_by_di(drive)
    t0 = drive.now
    drive.set_sto("A", False)
    drive.set_sto("B", False)
    drive.advance(held_ms * MS)
    drive.set_sto("A", True)
    drive.set_sto("B", True)
    drive.advance(100 * MS)
    if alarm:
        assert alarms_raised(events) == [(t0 + 10 * MS, "AL500")]
        assert not drive.servo_on and "AL500" in drive.alarms.active
    else:
        assert alarms_raised(events) == []
        assert drive.servo_on and drive.axis.power  # torque came back


def test_al500_cleared_by_arst_rising_edge_only_after_restore() -> None:
    drive, _ = make()
    servo_on_by_di(drive)
    drive.set_sto("A", False)
    drive.set_sto("B", False)
    drive.advance(20 * MS)
    drive.set_di(5, True)  # ARST while STO still lost: cause present, stays (L2493)
    drive.advance(5 * MS)
    assert "AL500" in drive.alarms.active
    drive.set_di(5, False)
    drive.set_sto("A", True)
    drive.set_sto("B", True)
    drive.advance(5 * MS)
    assert "AL500" in drive.alarms.active  # restored signals never clear it
    drive.set_di(5, True)
    drive.advance(5 * MS)
    assert drive.alarms.active == ()
    assert drive.servo_on  # SON still held: level-triggered (options.son_level_reenables)


@pytest.mark.parametrize(("channel", "code"), [("A", "AL501"), ("B", "AL502")])
def test_sto_one_channel_999_vs_1000ms(channel: str, code: str) -> None:
    drive, events = make()
    servo_on_by_di(drive)
    t0 = drive.now
    drive.set_sto(channel, False)
    drive.advance(999 * MS)
    assert alarms_raised(events) == []
    drive.advance(1 * MS)
    assert alarms_raised(events) == [(t0 + 1000 * MS, code)]
    drive.set_sto(channel, True)
    drive.set_di(5, True)  # ARST does not clear AL501/AL502 (L20205, L20211)
    drive.advance(10 * MS)
    assert code in drive.alarms.active
    drive.power_cycle()
    assert code not in drive.alarms.active


def test_deviation_al501_cleared_by_arst() -> None:
    drive, _ = make(ModelOptions(dev_al501_cleared_by_arst=True))
    drive.set_sto("A", False)
    drive.advance(1000 * MS)
    drive.set_sto("A", True)
    drive.set_di(5, True)
    drive.advance(5 * MS)
    assert "AL501" not in drive.alarms.active


def test_emgs_stop_and_auto_clear() -> None:
    # DI8 EMGS b-contact (P2.017 = 0x0021): opening the contact = emergency (L15184, L19338).
    drive, _ = make(**{"P1.043": -200})
    servo_on_by_di(drive)
    drive.advance(10 * MS)
    drive.set_di(8, False)
    drive.advance(3 * MS)
    assert "AL013" in drive.alarms.active and not drive.servo_on
    # negative P1.043 ignored on an EMGS stop (L8516): BRKR already off
    assert not drive.snapshot()["brkr"]
    drive.set_di(8, True)
    drive.advance(3 * MS)
    assert drive.alarms.active == ()
    assert drive.servo_on


def test_positive_limit_stops_motion_and_warns() -> None:
    drive, _ = make()
    servo_on_by_di(drive)
    drive.axis.run_velocity(3000.0, 50.0, 50.0)
    drive.advance(int(1.5 * S))  # 45 rev at 3000 rpm = 0.9 s: the PL switch is reached
    assert "AL015" in drive.alarms.active
    assert drive.servo_on  # WARN class, servo stays on (L19340)
    drive.advance(200 * MS)
    assert abs(drive.axis.velocity_rpm) < 1.0


def test_cia402_route_enables_servo_and_brake() -> None:
    drive, events = make(**{"P1.042": 50})
    for cw in (0x06, 0x07, 0x0F):
        drive.write_object(0x6040, 0, cw)
        drive.advance(1 * MS)
    assert drive.snapshot()["state"] == "OPERATION ENABLED"
    assert drive.read_object(0x6041) & 0x6F == 0x27
    assert drive.servo_on
    drive.advance(60 * MS)
    assert do_edges(events, "BRKR")[0][1] is True


def test_pp_move_over_objects() -> None:
    drive, _ = make()
    drive.write_object(0x6060, 0, 1)
    for cw in (0x06, 0x07, 0x0F):
        drive.write_object(0x6040, 0, cw)
    drive.write_object(0x607A, 0, 100_000)  # PUU (P1.044 = 16777216, P1.045 = 100000: 1 rev)
    drive.write_object(0x6081, 0, 200_000)
    drive.write_object(0x6040, 0, 0x1F)
    drive.advance(2 * S)
    assert drive.read_object(0x6041) & (1 << 10)
    assert abs(drive.read_object(0x6064) - 100_000) <= drive.read_object(0x6067)


def test_bad_input_is_refused_precisely() -> None:
    drive, _ = make()
    with pytest.raises(UnknownParameter, match=r"P9\.001"):
        drive.params.write("P9.001", 1)
    with pytest.raises(OutOfRange, match=r"P1\.042.*1000"):
        drive.params.write("P1.042", 1001)
    with pytest.raises(ReadOnly, match=r"P0\.046"):
        drive.params.write("P0.046", 1)
    with pytest.raises(UnknownFunction, match=r"P2\.010"):
        drive.params.write("P2.010", 0x0107)  # DI code 0x07 does not exist (table 8.1)
    with pytest.raises(ObjectError) as info:
        drive.write_object(0x212A, 0, 5000)  # P1.042 over SDO: range
    assert info.value.abort_code == 0x06090030
    with pytest.raises(ObjectError) as info:
        drive.write_object(0x6060, 0, 8)  # CSP is not supported (6502h = 0x6D)
    assert info.value.abort_code == 0x06090030


def test_retained_parameters_survive_power_cycle(tmp_path) -> None:
    drive = Drive(state_path=tmp_path, inputs={8: True})
    drive.params.write("P1.042", 321)
    drive.params.write("P1.001", 0x000C)  # ● power-cycle parameter: pending until then
    assert drive.params.get("P1.001") == 0
    drive.power_cycle()
    assert drive.params.get("P1.001") == 0x0C
    drive.close()
    again = Drive(state_path=tmp_path, inputs={8: True})
    assert again.params.read("P1.042") == 321


def test_result_does_not_depend_on_how_time_is_sliced() -> None:
    def run(chunk: int) -> dict:
        drive, _ = make()
        servo_on_by_di(drive)
        drive.axis.run_velocity(1000.0, 200.0, 200.0)
        for _ in range(0, 500 * MS, chunk):
            drive.advance(chunk)
        snap = drive.snapshot()
        snap.pop("t")
        return snap

    assert run(1 * MS) == run(50 * MS) == run(500 * MS)


def test_6064h_follows_the_absolute_coordinate(tmp_path) -> None:
    # Chapter 10: origin by P2.071 (after P2.008 = 271, L10074-10081) puts PUU = P6.001 there;
    # the coordinate survives a restart of the process (battery-backed, L16391-16397).
    drive = Drive(state_path=tmp_path, inputs={8: True}, params={"P2.069": 1, "P6.001": 500})
    drive.params.write("P2.008", 271)
    drive.params.write("P2.071", 1)
    assert drive.read_object(0x6064) == 500
    servo_on_by_di(drive)
    drive.axis.move_to(drive.axis.position + 3 * 16777216, 600.0, 100.0, 100.0)
    drive.advance(2 * S)
    before = drive.read_object(0x6064)
    assert abs(before - (500 + 300_000)) <= 2  # 3 rev at P1.045 = 100000 PUU/rev
    drive.set_di(1, False)
    drive.advance(10 * MS)
    drive.close()
    again = Drive(state_path=tmp_path, inputs={8: True})
    assert abs(again.read_object(0x6064) - before) <= 1
    assert again.absolute.coordinate_valid


def test_arst_keeps_al500_while_one_channel_is_still_lost() -> None:
    # L2493, L20199: AL500 can be reset only after both safety signals are back.
    drive, _ = make()
    drive.set_sto("A", False)
    drive.set_sto("B", False)
    drive.advance(20 * MS)
    drive.set_sto("A", True)
    drive.set_di(5, True)
    drive.advance(5 * MS)
    assert "AL500" in drive.alarms.active
    drive.set_di(5, False)
    drive.set_sto("B", True)
    drive.advance(5 * MS)
    drive.set_di(5, True)
    drive.advance(5 * MS)
    assert "AL500" not in drive.alarms.active
