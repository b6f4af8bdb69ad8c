"""When the firmware enters Servo Off on an STO loss (issue 13 item 4).

L2474: either channel lost -> the hardware cuts the motor current within 20 ms.
L2478: both lost for 10 ms -> the firmware acknowledges: Servo Off + AL500.
L2482: one lost for 1 s -> the firmware acknowledges: Servo Off + AL501 / AL502.
Default `ModelOptions.sto_servo_off = "acknowledged"`: a shorter glitch only cuts torque;
DO.SON, BRKR and the CiA 402 state stay. "at_loss" is the old reading (servo off at once).
"""

from __future__ import annotations

import pytest

from hil.model.drive import Drive
from hil.model.events import DoChanged
from hil.model.options import ModelOptions
from hil.units import MS

# BRKR on DO6 (released 50 ms after servo on), DO.SON on DO2
BENCH = {"P2.041": 0x0108, "P2.019": 0x0102, "P1.042": 50}


def make(**opts) -> tuple[Drive, list]:
    drive = Drive(options=ModelOptions(**opts), inputs={8: True}, params=BENCH)
    events: list = []
    drive.subscribe(events.append)
    return drive, events


def enabled(drive: Drive) -> None:
    """Servo on through CiA 402 (6040h 6 -> 7 -> F), brake released."""
    for cw in (0x06, 0x07, 0x0F):
        drive.write_object(0x6040, 0, cw)
        drive.advance(10 * MS)
    drive.advance(100 * MS)
    assert drive.servo_on and drive.brake.brkr
    assert drive.cia402.state == "OPERATION ENABLED"


def do_edges(events: list, t0: int) -> list[tuple[str, bool]]:
    return [(e.function, e.level) for e in events if isinstance(e, DoChanged) and e.t >= t0]


@pytest.mark.parametrize(("channels", "glitch_ms"), [("AB", 9), ("A", 999), ("B", 999)])
def test_glitch_shorter_than_acknowledgement_keeps_servo_on(channels: str, glitch_ms: int):
    """L2474 vs L2478/L2482: torque cut by hardware, DO.SON / BRKR / 402 state unchanged."""
    drive, events = make()
    enabled(drive)
    t0 = drive.now
    for ch in channels:
        drive.set_sto(ch, False)
    drive.advance(2 * MS)  # past sto_torque_cut_ms (1 ms, "within 20 ms", L2474)
    assert not drive.axis.power  # current cut in hardware
    assert drive.servo_on and drive.do(6)  # firmware: still Servo On, brake released
    drive.advance((glitch_ms - 2) * MS)
    assert drive.cia402.state == "OPERATION ENABLED"
    for ch in channels:
        drive.set_sto(ch, True)
    drive.advance(10 * MS)
    assert do_edges(events, t0) == []  # neither SON nor BRKR moved
    assert drive.alarms.active == ()
    assert drive.servo_on and drive.axis.power  # torque back (sto_resume_after_dropout)


@pytest.mark.parametrize(
    ("channels", "ack_ms", "code"), [("AB", 10, "AL500"), ("A", 1000, "AL501")]
)
def test_loss_enters_servo_off_when_acknowledged(channels: str, ack_ms: int, code: str):
    """L2478/L2482: Servo Off (DO.SON off, BRKR timing, FAULT) at the acknowledgement."""
    drive, events = make()
    enabled(drive)
    t0 = drive.now
    for ch in channels:
        drive.set_sto(ch, False)
    drive.advance((ack_ms - 1) * MS)
    assert drive.servo_on and do_edges(events, t0) == []
    drive.advance(1 * MS)
    assert not drive.servo_on and code in drive.alarms.active
    son = [e.t for e in events if isinstance(e, DoChanged) and e.function == "SON"]
    son_off = [t for t in son if t >= t0]
    assert son_off == [t0 + ack_ms * MS]
    assert drive.cia402.state == "FAULT"
    drive.advance(10 * MS)
    assert not drive.brake.brkr  # at standstill BRKR engages at once (L1362)


def test_at_loss_option_turns_servo_off_on_a_glitch():
    """The other reading (sto_servo_off = "at_loss"): a 5 ms glitch drops DO.SON and BRKR."""
    drive, events = make(sto_servo_off="at_loss")
    enabled(drive)
    t0 = drive.now
    drive.set_sto("A", False)
    drive.advance(5 * MS)
    drive.set_sto("A", True)
    assert ("SON", False) in do_edges(events, t0)
    assert ("BRKR", False) in do_edges(events, t0)


def test_servo_on_refused_while_a_channel_is_lost():
    """Ready (準備完成) needs both channels (L2454-2468): no servo on during a glitch."""
    drive, _ = make()
    drive.set_sto("B", False)
    drive.set_di(1, True)
    drive.advance(5 * MS)
    assert not drive.servo_on
    drive.set_sto("B", True)
    drive.advance(1 * MS)
    assert drive.servo_on


def test_bad_option_value_is_refused():
    with pytest.raises(ValueError, match="sto_servo_off"):
        ModelOptions.from_dict({"sto_servo_off": "never"})


def _alarms_after_skew(skew_ms: int, back_ms: int | None = None) -> tuple[str, ...]:
    """STO_B lost, STO_A lost `skew_ms` later; STO_A back `back_ms` after its loss (None:
    stays lost); the alarms 1.1 s after STO_B's loss."""
    drive, _ = make()
    enabled(drive)
    drive.set_sto("B", False)
    drive.advance(skew_ms * MS)
    drive.set_sto("A", False)
    if back_ms is not None:
        drive.advance(back_ms * MS)
        drive.set_sto("A", True)
    drive.advance((1100 - skew_ms - (back_ms or 0)) * MS)
    return drive.alarms.active


@pytest.mark.parametrize("skew_ms", [500, 989, 990, 995, 999])
def test_both_lost_within_the_second_is_al500_alone(skew_ms: int):
    """AL502: "STO_B 失去致能訊號或 STO_A 訊號沒有與 STO_B 訊號同步且差距達 1 秒以上" (L20209):
    both channels lost less than 1 s apart were never out of step for a second; both lost
    for 10 ms is AL500 (L2478). A skew of 990-999 ms had raised AL502 (power cycle only,
    L20211) with AL500 (helper-105)."""
    assert _alarms_after_skew(skew_ms) == ("AL500",)


def test_a_skew_of_more_than_a_second_is_al502_then_al500():
    assert _alarms_after_skew(1005) == ("AL502", "AL500")


def test_the_other_channel_back_within_10_ms_leaves_the_lost_ones_second_up():
    """STO_B lost; STO_A lost 995 ms later and back 8 ms after (no AL500: L2478): STO_B has
    been lost alone for more than its second, counted from its own loss: AL502 (L2482)."""
    assert _alarms_after_skew(995, back_ms=8) == ("AL502",)


@pytest.mark.parametrize("order", ["AB", "BA"])
def test_an_estop_released_a_few_ms_apart_gives_al500_alone(order: str):
    """Both channels cut 3 s (AL500), back 5 ms apart: each channel's own second ran out
    while both were lost, but they were never out of step for one (L20203, L20209); AL501/
    AL502 need a power cycle (L20205), AL500 an alarm reset (helper-110)."""
    drive, _ = make()
    enabled(drive)
    drive.set_sto("A", False)
    drive.set_sto("B", False)
    drive.advance(3000 * MS)
    drive.set_sto(order[0], True)
    drive.advance(5 * MS)
    drive.set_sto(order[1], True)
    drive.advance(2000 * MS)
    assert drive.alarms.active == ("AL500",)
