"""Brake (§2.9) and STO (§3.10) components on the injected clock, with the manual's numbers."""

from __future__ import annotations

import pytest

from hil.model.brake import Brake, HoldingBrake
from hil.model.options import FDBK_AS_PRINTED, ModelOptions
from hil.model.sto import Sto
from hil.model.timebase import Scheduler
from hil.units import MS


class Rig:
    def __init__(self, options: ModelOptions | None = None, **params: int) -> None:
        self.sched = Scheduler()
        self.params = {"P1.042": 0, "P1.043": 0, "P1.038": 100} | params
        self.speed = 0.0
        self.brkr_edges: list[tuple[int, bool]] = []
        self.clamp_edges: list[tuple[int, bool]] = []
        # the brake coil wired straight to BRKR's DO line
        clamp = self.clamp_edges
        self.holding = HoldingBrake(self.sched, lambda v: clamp.append((self.sched.now, v)))
        self.brake = Brake(
            self.sched,
            self.params.__getitem__,
            lambda: self.speed,
            self._brkr,
            options or ModelOptions(),
        )

    def _brkr(self, v: bool) -> None:
        self.brkr_edges.append((self.sched.now, v))
        self.holding.coil(v)

    def run_until(self, t: int, step: int = MS) -> None:
        while self.sched.now < t:
            self.sched.advance_to(min(t, self.sched.now + step))
            self.brake.after_step()


def test_brkr_rises_p1042_after_servo_on() -> None:
    # L8499: P1.042 = delay from servo on to BRKR On. Issue example: 150 ms.
    rig = Rig(**{"P1.042": 150})
    rig.brake.servo_on()
    rig.run_until(149 * MS)
    assert rig.brkr_edges == []
    rig.run_until(150 * MS)
    assert rig.brkr_edges == [(150 * MS, True)]
    rig.run_until(400 * MS)
    assert rig.clamp_edges == [(170 * MS, False)]  # mechanical release 20 ms later


def test_brkr_off_after_p1043_when_still_fast() -> None:
    # L1361: P1.043 elapsed while the speed is still above P1.038 -> BRKR Off.
    rig = Rig(**{"P1.043": 200})
    rig.brake.servo_on()
    rig.run_until(10 * MS)
    rig.speed = 500.0
    rig.brake.servo_off()
    rig.run_until(209 * MS)
    assert rig.brkr_edges[-1] == (0, True)
    rig.run_until(211 * MS)
    assert rig.brkr_edges[-1] == (210 * MS, False)


def test_brkr_off_early_when_speed_below_p1038() -> None:
    # L1362: speed below P1.038 (100 = 10.0 rpm) before P1.043 -> BRKR Off at that moment.
    rig = Rig(**{"P1.043": 500})
    rig.brake.servo_on()
    rig.run_until(1 * MS)
    rig.speed = 300.0
    rig.brake.servo_off()
    rig.run_until(50 * MS)
    rig.speed = 9.9
    rig.run_until(51 * MS)
    assert rig.brkr_edges[-1] == (51 * MS, False)


def test_standstill_engages_at_once_and_negative_p1043_rules() -> None:
    rig = Rig(**{"P1.043": 300})
    rig.brake.servo_on()
    rig.run_until(1 * MS)
    assert rig.brake.servo_off() == 0
    assert rig.brkr_edges[-1] == (1 * MS, False)  # level test: already below P1.038
    # Negative P1.043 on an alarm stop acts as 0 (L8516) ...
    rig = Rig(**{"P1.043": -100})
    rig.brake.servo_on()
    rig.run_until(1 * MS)
    rig.speed = 1000.0
    assert rig.brake.servo_off("alarm", "AL009") == 0
    assert rig.brkr_edges[-1] == (1 * MS, False)
    # ... and on a normal stop (option brake_first) clamps first, holds torque 100 ms.
    rig = Rig(**{"P1.043": -100})
    rig.brake.servo_on()
    rig.run_until(1 * MS)
    rig.speed = 1000.0
    assert rig.brake.servo_off("normal") == 100 * MS
    assert rig.brkr_edges[-1] == (1 * MS, False)


def test_deviation_knob_shifts_brake_release() -> None:
    rig = Rig(ModelOptions(dev_brake_on_delay_ms=5), **{"P1.042": 150})
    rig.brake.servo_on()
    rig.run_until(300 * MS)
    assert rig.brkr_edges == [(155 * MS, True)]


class StoRig:
    def __init__(self, options: ModelOptions | None = None) -> None:
        self.sched = Scheduler()
        self.alarms: list[tuple[int, str]] = []
        self.causes: dict[str, bool] = {}
        self.cuts: list[tuple[int, bool]] = []
        self.fdbk: list[bool] = []
        self.sto = Sto(
            self.sched,
            self._cause,
            lambda v: self.cuts.append((self.sched.now, v)),
            self.fdbk.append,
            options or ModelOptions(),
        )

    def _cause(self, code: str, present: bool) -> None:
        if present and not self.causes.get(code):
            self.alarms.append((self.sched.now, code))
        self.causes[code] = present

    def at(self, t: int) -> None:
        self.sched.advance_to(t)


@pytest.mark.parametrize(("held_ms", "alarmed"), [(9, False), (10, True)])
def test_both_channels_lost_10ms_gives_al500(held_ms: int, alarmed: bool) -> None:
    # L2478: both safety signals lost 10 ms -> AL500. 9 ms: nothing.
    rig = StoRig()
    rig.sto.set_channel("A", False)
    rig.sto.set_channel("B", False)
    rig.at(held_ms * MS - 1)
    assert rig.alarms == []
    rig.at(held_ms * MS)
    if not alarmed:
        rig.sto.set_channel("A", True)
        rig.sto.set_channel("B", True)
        rig.at(2000 * MS)
    assert rig.alarms == ([(10 * MS, "AL500")] if alarmed else [])
    assert rig.cuts[0] == (1 * MS, True)  # torque cut within 20 ms (L2474)


@pytest.mark.parametrize(("channel", "code"), [("A", "AL501"), ("B", "AL502")])
def test_one_channel_lost_1s(channel: str, code: str) -> None:
    # L2482/L2487: one channel lost 1 s -> AL501 (A) / AL502 (B); 999 ms -> nothing.
    rig = StoRig()
    rig.sto.set_channel(channel, False)
    rig.at(999 * MS)
    assert rig.alarms == []
    rig.at(1000 * MS)
    assert rig.alarms == [(1000 * MS, code)]


def test_restored_channels_end_the_cause_but_raise_nothing() -> None:
    rig = StoRig()
    rig.sto.set_channel("A", False)
    rig.sto.set_channel("B", False)
    rig.at(20 * MS)
    assert rig.causes["AL500"] is True
    rig.sto.set_channel("A", True)
    rig.sto.set_channel("B", True)
    assert rig.causes["AL500"] is False
    assert rig.alarms == [(10 * MS, "AL500")]


def test_fdbk_follows_the_configured_table() -> None:
    rig = StoRig()
    rig.sto.set_channel("B", False)  # (A on, B off): "Close" as printed (L2466)
    assert rig.fdbk == [FDBK_AS_PRINTED[(True, False)]] == [True]


def test_sto_deviation_acknowledges_late() -> None:
    rig = StoRig(ModelOptions(dev_sto_both_lost_ms=15))
    rig.sto.set_channel("A", False)
    rig.sto.set_channel("B", False)
    rig.at(14 * MS)
    assert rig.alarms == []
    rig.at(15 * MS)
    assert rig.alarms == [(15 * MS, "AL500")]


def test_bad_channel_name_is_refused() -> None:
    with pytest.raises(ValueError, match="unknown STO channel"):
        StoRig().sto.set_channel("C", True)
