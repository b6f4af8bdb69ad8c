"""CiA 402 state machine and 6xxx objects of the A3 (a3-comms.md §2.10-2.13), injected time."""

from __future__ import annotations

import pytest

from hil.model.cia402 import (
    FAULT,
    FAULT_REACTION_ACTIVE,
    NOT_READY,
    OPERATION_ENABLED,
    QUICK_STOP_ACTIVE,
    READY,
    SWITCH_ON_DISABLED,
    SWITCHED_ON,
    Cia402,
    Cia402Options,
)
from hil.model.errors import ObjectError
from hil.model.events import StateChanged
from hil.model.motion import Axis
from hil.protocol.canopen import (
    ABORT_DATA_STATE,
    ABORT_NO_OBJECT,
    ABORT_NO_SUBINDEX,
    ABORT_READ_ONLY,
    ABORT_VALUE_HIGH,
    ABORT_VALUE_LOW,
    ABORT_VALUE_RANGE,
)
from hil.units import MS

GEAR_100K = (16777216, 100000)  # factory e-gear: 100000 PUU per rev (L6879-6880)


class Rig:
    """Axis + CiA 402 on an injected clock, stepped 1 ms at a time like the drive does."""

    def __init__(self, **options) -> None:
        self.t = 0
        self.events: list[StateChanged] = []
        self.homing_starts = 0
        self.homing_stops = 0
        self.axis = Axis()
        self.cia = Cia402(
            self.axis,
            clock=lambda: self.t,
            emit=self.events.append,
            options=Cia402Options(**options),
            start_homing=self._start_homing,
            stop_homing=self._stop_homing,
        )
        self.cia.power_on()

    def _start_homing(self) -> None:
        self.homing_starts += 1

    def _stop_homing(self) -> None:
        self.homing_stops += 1

    def step(self, ms: int = 1) -> None:
        for _ in range(ms):
            self.t += MS
            self.axis.step(MS)
            self.cia.after_step()

    def until(self, cond, limit_ms: int = 10_000) -> int:
        for _ in range(limit_ms):
            if cond():
                return self.t
            self.step()
        raise AssertionError("condition not reached")

    def cw(self, value: int) -> None:
        self.cia.write(0x6040, 0, value)

    def w(self, index: int, value: int, sub: int = 0) -> None:
        self.cia.write(index, sub, value)

    def r(self, index: int, sub: int = 0) -> int:
        return self.cia.read(index, sub)

    @property
    def sw(self) -> int:
        return self.r(0x6041)

    def enable(self, mode: int | None = None) -> None:
        if mode is not None:
            self.w(0x6060, mode)
        for value in (0x06, 0x07, 0x0F):  # L17135-17141
            self.cw(value)
        assert self.cia.state == OPERATION_ENABLED

    def pp_setup(self, speed_puu_s: int = 500000) -> None:
        self.w(0x6093, GEAR_100K[0], 1)
        self.w(0x6093, GEAR_100K[1], 2)
        self.w(0x6081, speed_puu_s)  # 500000 PUU/s = 300 rpm
        self.enable(1)

    def pp_pulse(self, target: int, relative: bool = False) -> None:
        """607Ah, then a bit 4 pulse (0x1F, 0x0F; bit 6 when relative) without waiting."""
        rel = 0x40 if relative else 0
        self.w(0x607A, target)
        self.cw(0x1F | rel)
        self.cw(0x0F | rel)

    def pp_handshake(self, target: int, relative: bool = False) -> None:
        """607Ah, bit 4 up, wait for bit 12 (the CiA 402 handshake), bit 4 down."""
        rel = 0x40 if relative else 0
        self.w(0x607A, target)
        self.cw(0x1F | rel)
        self.until(lambda: self.sw & 0x1000)
        self.cw(0x0F | rel)

    def settle(self) -> None:
        """Until target reached (bit 10) and the axis at rest."""
        self.until(lambda: self.sw & 0x0400 and not self.axis.moving)


def abort_of(fn, *args) -> int:
    with pytest.raises(ObjectError) as info:
        fn(*args)
    return info.value.abort_code


# ---- state machine ------------------------------------------------------------------------


def test_boot_is_switch_on_disabled():
    rig = Rig()
    assert [(e.old, e.new) for e in rig.events] == [(NOT_READY, SWITCH_ON_DISABLED)]
    assert rig.sw & 0x4F == 0x40  # L18324
    assert rig.sw == 0x0250  # + bit 4 voltage enabled, bit 9 remote
    assert rig.r(0x6040) == 0x0004  # printed default (L18212)


def test_enable_sequence_statusword_patterns():
    rig = Rig()
    rig.cw(0x06)
    assert rig.cia.state == READY and rig.sw & 0x6F == 0x21 and rig.sw == 0x0231  # L18325
    rig.cw(0x07)
    assert rig.cia.state == SWITCHED_ON and rig.sw & 0x6F == 0x23 and rig.sw == 0x0233
    assert not rig.cia.servo_enable_requested  # 3 = servo-on preparation only (L18251)
    rig.cw(0x0F)
    assert rig.cia.state == OPERATION_ENABLED and rig.sw & 0x6F == 0x27
    assert rig.sw == 0x0637  # standing still: target reached (bit 10)
    assert rig.cia.servo_enable_requested and rig.axis.power
    assert [e.new for e in rig.events][1:] == [READY, SWITCHED_ON, OPERATION_ENABLED]
    assert all(e.t == 0 for e in rig.events)


def test_enable_from_switch_on_disabled_needs_shutdown_first():
    rig = Rig()
    rig.cw(0x0F)
    assert rig.cia.state == SWITCH_ON_DISABLED
    rig.cw(0x06)
    rig.cw(0x0F)  # "Switch on + Enable Operation" = 3 + 4 (L18276)
    assert rig.cia.state == OPERATION_ENABLED
    assert [e.new for e in rig.events][-2:] == [SWITCHED_ON, OPERATION_ENABLED]


@pytest.mark.parametrize(
    ("value", "state", "servo"),
    [(0x07, SWITCHED_ON, False), (0x06, READY, False), (0x00, SWITCH_ON_DISABLED, False)],
)
def test_leaving_operation_enabled(value, state, servo):
    # 5 disable operation, 8 shutdown, 9 disable voltage: servo off (L18253-18257)
    rig = Rig()
    rig.enable()
    rig.cw(value)
    assert rig.cia.state == state and rig.cia.servo_enable_requested is servo
    assert not rig.axis.power


def test_quick_stop_from_ready_goes_to_switch_on_disabled():
    rig = Rig()
    rig.cw(0x06)
    rig.cw(0x02)  # transition 7 (L18255)
    assert rig.cia.state == SWITCH_ON_DISABLED


def test_quick_stop_ramps_with_6085h_then_stays_until_disable_voltage():
    """Transition 11 "Quick Stop 功能啟動"; the only ways out of QUICK STOP ACTIVE are
    commands: 12 "Command Disable Voltage" (servo off) and 16 Enable Operation (L18260-18266).
    Until session 28 the model went to SWITCH ON DISABLED by itself after the ramp (605Ah
    option 2; helpers 88, 105)."""
    rig = Rig()
    rig.w(0x6085, 100)  # ms for 3000 -> 0 rpm (L18787-18801)
    rig.w(0x60FF, 15000)  # 1500 rpm
    rig.enable(3)
    rig.until(lambda: rig.r(0x606C) == 15000)
    rig.cw(0x0B)  # bit 2 = 0: quick stop (L18278), transition 11
    assert rig.cia.state == QUICK_STOP_ACTIVE
    assert rig.sw & 0x6F == 0x07  # L18328
    assert rig.cia.servo_enable_requested
    rig.step(49)
    assert rig.axis.demand_rpm > 0
    rig.step(1)
    assert rig.axis.demand_rpm == 0  # 1500 rpm at 100 ms/3000 rpm: 50 ms (L4164)
    rig.step(500)
    assert rig.cia.state == QUICK_STOP_ACTIVE and rig.cia.servo_enable_requested
    rig.cw(0x00)  # transition 12: Disable Voltage
    assert rig.cia.state == SWITCH_ON_DISABLED and not rig.cia.servo_enable_requested


def test_quick_stop_option_2_still_ends_in_switch_on_disabled():
    rig = Rig(quick_stop_option=2)
    rig.w(0x6085, 100)
    rig.w(0x60FF, 15000)
    rig.enable(3)
    rig.until(lambda: rig.r(0x606C) == 15000)
    rig.cw(0x0B)
    t0 = rig.t
    t_sod = rig.until(lambda: rig.cia.state == SWITCH_ON_DISABLED)
    assert t_sod - t0 < 200 * MS
    assert not rig.cia.servo_enable_requested


def test_quick_stop_option_6_stays_and_restarts_with_transition_16():
    rig = Rig(quick_stop_option=6)
    rig.w(0x60FF, 10000)
    rig.enable(3)
    rig.step(100)
    rig.cw(0x0B)
    rig.until(lambda: not rig.axis.moving)
    rig.step(10)
    assert rig.cia.state == QUICK_STOP_ACTIVE and rig.sw & 0x0400  # stopped: bit 10
    rig.cw(0x0F)  # transition 16: PV restarts at 60FFh (L18266)
    assert rig.cia.state == OPERATION_ENABLED
    rig.step(100)
    assert rig.r(0x606C) > 9000


def test_fault_and_fault_reset_on_rising_edge_only():
    rig = Rig()
    rig.enable()
    rig.cia.set_fault(True)
    assert [e.new for e in rig.events][-2:] == [FAULT_REACTION_ACTIVE, FAULT]  # 13, 14
    assert rig.sw & 0x4F == 0x08  # L18331
    assert not rig.cia.servo_enable_requested
    rig.cw(0x80)  # alarm still present: stays (L18265)
    assert rig.cia.state == FAULT
    rig.cia.set_fault(False)
    rig.cw(0x80)  # bit 7 still 1: no rising edge
    assert rig.cia.state == FAULT
    rig.cw(0x00)
    assert rig.cia.state == FAULT  # falling edge does nothing
    rig.cw(0x80)
    assert rig.cia.state == SWITCH_ON_DISABLED  # 15
    rig.cw(0x06)
    assert rig.cia.state == READY


def test_fault_reset_uses_the_drive_hook():
    remaining = [True]
    axis = Axis()
    cia = Cia402(axis, clock=lambda: 0, fault_reset=lambda: not remaining[0])
    cia.power_on()
    cia.set_fault(True)
    cia.write(0x6040, 0, 0x80)
    assert cia.state == FAULT
    remaining[0] = False
    cia.write(0x6040, 0, 0x00)
    cia.write(0x6040, 0, 0x80)
    assert cia.state == SWITCH_ON_DISABLED


def test_fault_reaction_option_ramps_before_fault():
    rig = Rig(fault_reaction_option=2)
    rig.w(0x60FF, 30000)
    rig.enable(3)
    rig.step(300)
    rig.cia.set_fault(True)
    assert rig.cia.state == FAULT_REACTION_ACTIVE and rig.sw & 0x4F == 0x0F  # L18330
    assert rig.cia.servo_enable_requested
    rig.until(lambda: rig.cia.state == FAULT)
    assert not rig.axis.power


def test_disable_operation_option_1_ramps_then_servo_off():
    rig = Rig(disable_operation_option=1)
    rig.w(0x60FF, 30000)
    rig.enable(3)
    rig.step(300)
    rig.cw(0x07)
    assert rig.cia.state == SWITCHED_ON and rig.cia.servo_enable_requested
    rig.until(lambda: not rig.cia.servo_enable_requested)
    assert rig.axis.velocity == 0


def test_warning_voltage_and_shutdown_option():
    rig = Rig()
    rig.cia.set_warning(True)
    rig.cia.set_voltage(False)
    assert rig.sw & 0x90 == 0x80
    assert rig.cia.shutdown_stop_mode == 1  # 605Bh 0 = free run (L18356) = P1.032.Y 1
    rig.w(0x605B, 1)
    assert rig.cia.shutdown_stop_mode == 0  # dynamic brake (L18358)
    assert abort_of(rig.w, 0x605B, 2) == ABORT_VALUE_HIGH


# ---- objects -------------------------------------------------------------------------------


def test_defaults_as_printed():
    rig = Rig()
    expected = {
        (0x6065, 0): 3840000,
        (0x6067, 0): 100,
        (0x6068, 0): 0,
        (0x6081, 0): 10000,
        (0x6083, 0): 200,
        (0x6084, 0): 200,
        (0x6085, 0): 200,
        (0x6087, 0): 200,
        (0x6093, 0): 2,
        (0x6093, 1): 1,
        (0x6093, 2): 1,
        (0x6099, 1): 100,
        (0x6099, 2): 20,
        (0x609A, 0): 100,
        (0x6502, 0): 0x6D,
        (0x60E0, 0): 3000,
        (0x60E1, 0): 3000,
        (0x606D, 0): 100,
        (0x606F, 0): 100,
        (0x60C2, 1): 1,
        (0x60C2, 2): -3,
        (0x6060, 0): 0,
        (0x6061, 0): 0,
    }
    assert {key: rig.r(*key) for key in expected} == expected


@pytest.mark.parametrize("mode", [2, 5, 8, 9, 10, -1])
def test_unsupported_modes_refused(mode):
    rig = Rig()
    assert abort_of(rig.w, 0x6060, mode) == ABORT_VALUE_RANGE  # 6502h = 0x6D (L19250)
    assert rig.r(0x6060) == 0


def test_object_access_errors():
    rig = Rig()
    assert abort_of(rig.w, 0x6061, 1) == ABORT_READ_ONLY
    assert abort_of(rig.w, 0x6064, 1) == ABORT_READ_ONLY
    assert abort_of(rig.r, 0x6066) == ABORT_NO_OBJECT  # not in the A3 list
    assert abort_of(rig.r, 0x605A) == ABORT_NO_OBJECT  # option codes absent (default)
    assert abort_of(rig.r, 0x6093, 3) == ABORT_NO_SUBINDEX
    assert abort_of(rig.w, 0x6083, 0) == ABORT_VALUE_LOW  # 1 ~ 65500 (L18755-18769)
    assert abort_of(rig.w, 0x6083, 65501) == ABORT_VALUE_HIGH
    assert abort_of(rig.w, 0x6071, 3001) == ABORT_VALUE_HIGH  # -3000 ~ 3000 (L18568)
    assert abort_of(rig.w, 0x6098, 36) == ABORT_VALUE_HIGH  # 0 ~ 35 (L18856)
    assert abort_of(rig.w, 0x6099, 0, 1) == ABORT_VALUE_LOW  # 1 ~ 2000
    assert abort_of(rig.w, 0x6040, 0x10000) == ABORT_VALUE_RANGE  # not a U16
    assert abort_of(rig.w, 0x6093, 0, 1) == ABORT_VALUE_LOW


def test_option_code_objects_when_enabled():
    rig = Rig(option_objects=True)
    assert rig.r(0x605A) == 6 and rig.r(0x605D) == 1 and rig.r(0x605E) == 0
    rig.w(0x605A, 2)
    assert abort_of(rig.w, 0x605D, 0) == ABORT_VALUE_RANGE


def test_gear_not_writable_while_servo_on():
    rig = Rig()
    rig.enable()
    assert abort_of(rig.w, 0x6093, 5, 1) == ABORT_DATA_STATE  # P1.044 ▲ (L6879)


def test_mode_change_while_enabled_option():
    rig = Rig(mode_change_while_enabled="refuse")
    rig.enable(1)
    assert abort_of(rig.w, 0x6060, 3) == ABORT_DATA_STATE
    rig2 = Rig()
    rig2.w(0x60FF, 5000)
    rig2.enable(1)
    rig2.w(0x6060, 3)  # accepted: PV runs at 60FFh at once
    assert rig2.r(0x6061) == 3
    rig2.step(200)
    assert rig2.r(0x606C) == pytest.approx(5000, abs=5)


# ---- profile position ----------------------------------------------------------------------


def test_pp_move_target_reached_after_window_time():
    rig = Rig()
    rig.w(0x6068, 10)  # position window time, ms (L18472-18486)
    rig.pp_setup()
    rig.w(0x607A, 100000)  # one revolution
    rig.cw(0x1F)  # bit 4 rising edge (L17143-17206)
    assert rig.sw & 0x1000  # set-point acknowledge
    assert not rig.sw & 0x0400
    rig.cw(0x0F)
    assert not rig.sw & 0x1000  # ack follows bit 4 down

    def inside() -> bool:  # 607Ah minus 6064h inside 6067h (L18469)
        return abs(rig.r(0x6064) - 100000) < rig.r(0x6067)

    t_in = rig.until(inside)
    assert rig.cia.next_deadline() == t_in + 10 * MS
    rig.until(lambda: rig.sw & 0x0400)
    assert rig.t == t_in + 10 * MS  # held for 6068h (L18469-18486)
    assert rig.sw == 0x0637  # OE, voltage, remote, target reached
    rig.until(lambda: not rig.axis.moving)
    assert rig.r(0x6064) == 100000 and rig.r(0x6063) == 16777216 and rig.r(0x60F4) == 0


def test_pp_relative_moves_add_to_the_previous_target():
    """Each set-point given at bit 10 (the profile may have a ms or two left: it is then
    acknowledged when it ends, L17172-17174), bit 4 held until bit 12 as CiA 402's
    handshake has it."""
    rig = Rig()
    rig.pp_setup()
    rig.w(0x607A, 20000)
    rig.cw(0x5F)  # bit 6: relative (L18241)
    rig.cw(0x4F)
    rig.until(lambda: rig.sw & 0x0400)
    rig.cw(0x5F)
    rig.until(lambda: rig.sw & 0x1000)
    rig.cw(0x4F)
    rig.until(lambda: rig.sw & 0x0400)
    rig.w(0x607A, -5000)
    rig.cw(0x5F)
    rig.until(lambda: rig.sw & 0x0400 and not rig.axis.moving)
    assert rig.r(0x6064) == 35000


def test_pp_change_set_immediately():
    rig = Rig()
    rig.pp_setup()
    rig.w(0x607A, 1_000_000)
    rig.cw(0x1F)
    rig.cw(0x0F)
    rig.step(100)
    rig.w(0x607A, -50000)
    rig.cw(0x3F)  # bit 5: change set immediately (L18240)
    assert rig.sw & 0x1000
    peak = rig.r(0x6064)
    rig.until(lambda: rig.sw & 0x0400 and not rig.axis.moving)
    assert rig.r(0x6064) == -50000
    assert peak < 1_000_000 / 2  # never went to the first target


def test_pp_setpoint_queued_when_bit5_is_0_is_acknowledged_only_when_it_runs():
    """Bit 5 = 0 (L17172-17174): "若當前運動命令仍在執行 ... 即使新的命令觸發，伺服仍會繼續執行當前
    的運動命令。只有在當前命令執行完成後，新的命令伺服才會被承認並執行": a trigger during a move
    is neither acknowledged (bit 12) nor run until that move completes; then both."""
    rig = Rig()
    rig.pp_setup()
    rig.w(0x607A, 200000)
    rig.cw(0x1F)
    assert rig.sw & 0x1000  # idle: acknowledged at once
    rig.cw(0x0F)
    rig.step(50)
    rig.w(0x607A, 0)
    rig.cw(0x1F)  # the master holds bit 4 until bit 12 (the CiA 402 handshake)
    assert not rig.sw & 0x1000
    t_ack = rig.until(lambda: rig.sw & 0x1000)
    assert rig.r(0x6062) == 200000  # the first move completed before the acknowledge
    assert rig.axis.target == rig.axis.origin  # ... and the second runs from then
    rig.cw(0x0F)
    assert not rig.sw & 0x1000
    rig.until(lambda: rig.sw & 0x0400 and not rig.axis.moving)
    assert rig.r(0x6064) == 0
    assert t_ack > 50 * MS


def test_pp_three_triggers_each_acknowledged_and_run_in_turn():
    """The handshake of L17172-17174 repeated: each trigger given during a move (bit 4 held
    until bit 12) is acknowledged when the move before it completes, and every one runs."""
    rig = Rig()
    rig.pp_setup()
    for target in (100000, 150000, 20000):
        rig.pp_handshake(target)
        rig.step(5)  # the next trigger while this move runs
    rig.settle()
    assert rig.r(0x6064) == 20000


def test_pp_queued_setpoint_withdrawn_when_bit4_falls_before_its_acknowledge():
    """Our choice (docs/manual-choices.md): a trigger waiting for the running move is held
    while bit 4 stays high; bit 4 falling before the acknowledge withdraws it, so nothing
    moves that the master took back."""
    rig = Rig()
    rig.pp_setup()
    rig.pp_pulse(100000)
    rig.step(20)
    rig.pp_pulse(500000)  # withdrawn
    rig.settle()
    rig.step(200)
    assert rig.r(0x6064) == 100000
    rig.pp_pulse(30000, relative=True)  # counts from the target that ran
    rig.settle()
    assert rig.r(0x6064) == 130000


@pytest.mark.parametrize("base", ["demand", "actual"])
def test_pp_relative_set_point_waiting_for_a_move_counts_from_where_it_is_taken(base):
    """A relative set-point (bit 6) given during a move is taken when that move completes
    (L17172-17174): a "demand" or "actual" base is the position then, not at the trigger
    (helper-89: it went back to the trigger's position)."""
    rig = Rig(pp_relative_base=base)
    rig.pp_setup()
    rig.pp_pulse(100000)
    rig.step(30)
    rig.pp_handshake(10000, relative=True)
    rig.settle()
    assert abs(rig.r(0x6064) - 110000) <= 100


def test_pp_drive_taking_the_axis_drops_a_waiting_set_point_without_a_trace():
    """DI JOG / PFQS / CCLR take the axis (`drop_setpoints`): a set-point still waiting for
    its acknowledge is gone, and a later relative move counts from the target that ran
    (helper-89: from the dropped one)."""
    rig = Rig()
    rig.pp_setup()
    rig.pp_pulse(100000)
    rig.step(20)
    rig.w(0x607A, 150000)
    rig.cw(0x1F)  # waits
    rig.cia.drop_setpoints()
    rig.cw(0x0F)
    rig.axis.move_to(rig.axis.demand, 0.0, 100, 100)  # whatever took the axis holds it
    rig.step(500)
    rig.pp_handshake(10000, relative=True)
    rig.settle()
    assert rig.r(0x6064) == 110000


def test_pp_a_wide_position_window_does_not_end_a_move_early():
    """6067h wide enough that bit 10 rises while the profile still runs at speed: the move is
    still running ("尚未完成", L17172), so a bit 5 = 0 trigger waits for it (helper-89)."""
    rig = Rig()
    rig.pp_setup()
    rig.w(0x6067, 50000)
    rig.w(0x6068, 0)
    rig.pp_pulse(500000)
    rig.until(lambda: rig.sw & 0x0400)
    assert rig.axis.demand_velocity != 0.0
    rig.w(0x607A, 0)
    rig.cw(0x1F)
    peak = 0
    while not rig.sw & 0x1000:
        rig.step()
        peak = max(peak, rig.r(0x6062))
    assert peak == 500000
    rig.cw(0x0F)
    rig.until(lambda: rig.sw & 0x0400 and not rig.axis.moving and rig.r(0x6062) == 0)


def test_pp_buffer_of_one_acknowledged_at_once_as_an_option():
    """`pp_ack_when_run=False`: CiA 402's buffer of one [std]: a trigger during a move is
    acknowledged at once and queued; a further one while it waits is refused."""
    rig = Rig(pp_ack_when_run=False)
    rig.pp_setup()
    rig.w(0x607A, 200000)
    rig.cw(0x1F)
    rig.cw(0x0F)
    rig.step(50)
    rig.w(0x607A, 0)
    rig.cw(0x1F)  # queued
    assert rig.sw & 0x1000
    rig.cw(0x0F)
    rig.w(0x607A, 777)
    rig.cw(0x1F)  # buffer full: not acknowledged
    assert not rig.sw & 0x1000
    rig.cw(0x0F)
    reached_first = rig.until(lambda: rig.r(0x6062) == 200000)
    assert reached_first
    rig.until(lambda: rig.sw & 0x0400 and not rig.axis.moving)
    assert rig.r(0x6064) == 0


def test_pp_following_error_bit_13():
    rig = Rig()
    rig.pp_setup(speed_puu_s=5_000_000)  # 3000 rpm
    rig.w(0x6065, 500)  # tight following error window (PUU)
    rig.w(0x607A, 1_000_000)
    rig.cw(0x1F)
    rig.until(lambda: rig.sw & 0x2000)
    assert rig.cia.following_error_exceeded
    assert abs(rig.r(0x60F4)) > 500
    assert rig.r(0x60F4) == rig.r(0x6062) - rig.r(0x6064)  # L19179-19193


def test_halt_decelerates_and_resumes_pp():
    rig = Rig()
    rig.pp_setup()
    rig.w(0x607A, 300000)
    rig.cw(0x1F)
    rig.step(100)
    rig.cw(0x11F)  # bit 8 halt: profile deceleration 6084h, then hold
    rig.until(lambda: not rig.axis.moving)
    held = rig.r(0x6064)
    assert rig.sw & 0x0400  # halted and still: target reached [std]
    rig.step(50)
    assert rig.r(0x6064) == held < 300000
    rig.cw(0x1F)  # halt released: the set-point continues
    rig.until(lambda: rig.sw & 0x0400 and not rig.axis.moving)
    assert rig.r(0x6064) == 300000


# ---- profile velocity / torque / homing / IP ---------------------------------------------


def test_pv_reaches_speed_and_zero_speed_bit():
    rig = Rig()
    rig.enable(3)  # 60FFh = 0 before enabling (L17299)
    assert rig.sw & 0x1000 and rig.sw & 0x0400  # zero speed, at target
    rig.w(0x60FF, 10000)  # 1000 rpm
    rig.step(5)
    assert not rig.sw & 0x1000 and not rig.sw & 0x0400
    rig.until(lambda: rig.sw & 0x0400)
    assert abs(rig.r(0x606C) - 10000) < rig.r(0x606D)  # velocity window (L18536)
    assert rig.r(0x606B) == 10000
    assert 60 * MS <= rig.t <= 120 * MS  # 1000 rpm at 200 ms/3000 rpm: 67 ms ramp
    rig.w(0x60FF, 0)
    rig.until(lambda: rig.sw & 0x1000)
    assert abs(rig.r(0x606C)) <= rig.r(0x606F)  # velocity threshold (L18556-18566)


def test_pt_torque_slope():
    rig = Rig()
    rig.enable(4)
    rig.w(0x6071, 500)  # 50 % rated
    rig.step(50)
    assert rig.r(0x6074) == 250  # 6087h = 200 ms per 100 %
    rig.step(50)
    assert rig.r(0x6074) == 500 and rig.sw & 0x0400
    assert rig.r(0x6077) == 500


def test_homing_hook_and_status_bits():
    rig = Rig()
    rig.enable(6)
    rig.cw(0x1F)  # bit 4 rising edge starts homing (L17255-17267)
    assert rig.homing_starts == 1
    assert not rig.sw & 0x0400  # in progress
    rig.cia.set_homing_status(attained=True, error=False)
    assert rig.sw & 0x1400 == 0x1400  # attained + target reached (L18337)
    rig.cw(0x0F)
    rig.cw(0x1F)
    assert rig.homing_starts == 2 and not rig.sw & 0x1000
    rig.cia.set_homing_status(attained=False, error=True)
    assert rig.sw & 0x2000
    rig.cw(0x0F)
    rig.cw(0x1F)
    rig.cw(0x0F)  # bit 4 falling during homing interrupts it [std]
    assert rig.homing_stops == 1


def test_ip_follows_60c1h():
    rig = Rig()
    rig.enable(7)
    assert rig.sw & 0x1000  # IP active (L18335)
    for k in range(1, 11):
        rig.w(0x60C1, 1000 * k, 1)  # one PUU target per 1 ms period (60C2h = 1, -3)
        rig.step(1)
    rig.until(lambda: not rig.axis.moving)
    assert rig.r(0x6064) == 10000 and rig.sw & 0x0400


# ---- limits ----------------------------------------------------------------------------


def test_limit_is_a_quick_stop_and_inhibits_that_direction():
    rig = Rig()
    rig.w(0x60FF, 10000)
    rig.enable(3)
    rig.step(100)
    rig.cia.set_limits(False, True)  # PL trip = transition 11 (L18260)
    assert rig.cia.state == QUICK_STOP_ACTIVE
    assert rig.sw & 0xC000 == 0x4000  # bit 14 positive limit (L18316)
    assert rig.r(0x60FD) == 0b010  # bit 1 positive limit (L19229-19231)
    t0 = rig.t
    rig.until(lambda: rig.r(0x606B) == 0)
    assert rig.t - t0 == 10 * MS  # 1000 rpm at P5.035 = 30 ms per 3000 rpm (L11462, L4164)
    rig.until(lambda: not rig.axis.moving)
    assert rig.cia.state == QUICK_STOP_ACTIVE and rig.cia.servo_enable_requested
    rig.cw(0x0F)  # 16: back to OE, PV into the limit is inhibited
    rig.step(100)
    assert rig.cia.state == OPERATION_ENABLED and abs(rig.r(0x606C)) < 100
    rig.w(0x60FF, -10000)  # away from the limit is allowed
    rig.step(200)
    assert rig.r(0x606C) < -9000
    rig.cia.set_limits(False, False)
    assert rig.sw & 0xC000 == 0
