"""Absolute encoder model (chapter 10, L16100-16575) on the injected clock, with small fakes."""

from __future__ import annotations

from typing import ClassVar

import pytest

from hil.model.absolute import (
    ACK,
    BLOCKED,
    COUNTS_PER_REV,
    DONE,
    ERROR,
    FRAME_BITS,
    READY,
    STATUS_BATTERY_LOW,
    STATUS_LOST,
    STATUS_NOT_ESTABLISHED,
    STATUS_PUU_OVERFLOW,
    STATUS_TURN_OVERFLOW,
    WAIT_ACK,
    AbsoluteEncoder,
    AbsoluteError,
    AbsoluteOptions,
    EncoderMemory,
    build_frame,
    checksum,
    frame_bits,
    split_frame,
)
from hil.model.errors import ProtectedParameter
from hil.model.timebase import Scheduler
from hil.units import MS

REV = COUNTS_PER_REV


class FakeParams:
    """The slice of ParameterStore the encoder uses; enforces the P2.071 key like the store."""

    DEFAULTS: ClassVar[dict[str, int]] = {
        "P0.049": 0, "P0.050": 0, "P0.051": 0, "P0.052": 0,
        "P1.001": 0, "P1.044": 16777216, "P1.045": 100000, "P6.001": 0,
        "P2.008": 0, "P2.009": 2, "P2.069": 1, "P2.070": 0, "P2.071": 0,
    }  # fmt: skip

    def __init__(self, **values: int) -> None:
        self.values = dict(self.DEFAULTS)
        self.values.update({k.replace("_", "."): v for k, v in values.items()})
        self.hooks: dict[str, list] = {}

    def get(self, name: str) -> int:
        return self.values[name]

    def cached(self, *names: str):
        """`ParameterStore.cached`: here read at every call (a test sets `values` directly)."""
        return lambda: tuple(self.values[n] for n in names)

    def set_internal(self, name: str, value: int) -> None:
        self.values[name] = int(value)

    def on_write(self, name: str, fn) -> None:
        self.hooks.setdefault(name, []).append(fn)

    def write(self, name: str, value: int) -> None:
        if name == "P2.071" and self.values["P2.008"] != 271:
            raise ProtectedParameter(name, "write P2.008 = 271 first (L10081, L16454)")
        old = self.values[name]
        self.values[name] = value
        for fn in self.hooks.get(name, []):
            fn(name, old, value)


class Rig:
    def __init__(self, options: AbsoluteOptions | None = None, speed: float = 0.0, **params):
        self.sched = Scheduler()
        self.params = FakeParams(**params)
        self.causes: dict[str, bool] = {}
        self.history: list[tuple[str, bool]] = []
        self.outputs: dict[str, bool] = {}
        self.overlay = False
        self.cleared = 0
        self.speed = speed
        self.enc = AbsoluteEncoder(
            self.sched,
            self.params,
            set_cause=self._cause,
            set_output=self.outputs.__setitem__,
            set_overlay=self._overlay,
            clear_position_error=self._clear,
            speed_rpm=lambda: self.speed,
            options=options,
        )
        self.enc.on_motor_position(0)

    def _cause(self, code: str, present: bool) -> None:
        self.causes[code] = present
        self.history.append((code, present))

    def _overlay(self, on: bool) -> None:
        self.overlay = on

    def _clear(self) -> None:
        self.cleared += 1

    def active(self) -> set[str]:
        return {c for c, p in self.causes.items() if p}

    def advance(self, dt: int) -> None:
        target = self.sched.now + dt
        while (nd := self.sched.next_deadline()) is not None and nd <= target:
            self.sched.now = nd
            self.sched.run_due()
        self.sched.now = target

    def origin(self) -> None:
        self.enc.establish_origin()


# -- frame and checksum ----------------------------------------------------------------------


def test_checksum_all_zero_words_is_0x9205():
    # By hand from L16476-16486: 0+A700=A700; ^0=A700; +605A=1075A->075A; ^0; +30A5=37FF;
    # ^0; +5A06=9205.
    assert checksum(0, 0, 0, 0) == 0x9205


def test_checksum_worked_example():
    # status 0x0004, turns -1 (0xFFFF), position 0x12345678 (W2 = 5678, W3 = 1234):
    # 0004+A700=A704; ^FFFF=58FB; +605A=B955; ^5678=EF2D; +30A5=11FD2->1FD2; ^1234=0DE6;
    # +5A06=67EC
    assert checksum(0x0004, 0xFFFF, 0x5678, 0x1234) == 0x67EC
    frame = build_frame(0x0004, -1, 0x12345678)
    assert split_frame(frame) == (0x0004, -1, 0x12345678, 0x67EC)


def test_frame_layout_and_bit_orders():
    frame = build_frame(0x0001, -32768, -5)
    status, turns, pos, cs = split_frame(frame)
    assert (status, turns, pos) == (1, -32768, -5)
    assert frame >> 64 == cs
    lsb = frame_bits(frame, "lsb_first")
    assert len(lsb) == FRAME_BITS and lsb[0] == 1  # status bit 0 goes first
    assert frame_bits(frame, "msb_first") == lsb[::-1]
    with pytest.raises(AbsoluteError, match="W1"):
        checksum(0, 0x10000, 0, 0)


# -- coordinates -----------------------------------------------------------------------------


def test_turns_and_pulses_with_negative_and_wrap():
    r = Rig()
    r.origin()
    r.enc.on_motor_position(3 * REV + 1234)
    assert (r.enc.turns, r.enc.single_turn) == (3, 1234)
    # pulse value = m x 16777216 + pulse, pulse 0 ~ 16777215 (L16406)
    r.enc.on_motor_position(-REV - 5)
    assert (r.enc.turns, r.enc.single_turn) == (-2, REV - 5)
    # CCW past 32767 turns -> -32768 (L16404) and AL062
    r.enc.on_motor_position(32767 * REV + 10)
    assert r.enc.turns == 32767 and "AL062" not in r.active()
    r.enc.on_motor_position(32768 * REV + 10)
    assert r.enc.turns == -32768
    assert "AL062" in r.active()


def test_puu_formula_and_direction():
    r = Rig(P6_001=500)
    r.origin()
    r.enc.on_motor_position(REV)  # default gear: 100000 PUU per rev
    assert r.enc.puu == 100000 + 500  # L16408
    r.params.values["P1.001"] = 0x0100  # P1.001.Z = 1: CW positive (option cw_positive_z)
    assert r.enc.puu == -100000 + 500  # L16410
    r.params.values["P1.001"] = 0
    r.enc.on_motor_position(REV // 2)
    assert r.enc.puu == 50000 + 500


def test_direction_option():
    """With Z = CW positive (here Z = 0 by the option) a positive move is CW: the encoder
    counts down (turns negative, L16404) and the PUU still goes up with the motion (L16413)."""
    r = Rig(options=AbsoluteOptions(cw_positive_z=0))
    r.origin()
    r.enc.on_motor_position(REV)
    assert r.enc.puu == 100000 and r.enc.turns == -1
    r = Rig()
    r.origin()
    r.enc.on_motor_position(REV)
    assert r.enc.puu == 100000 and r.enc.turns == 1


# -- start-up, alarms ------------------------------------------------------------------------


def test_first_use_al06a_and_status():
    r = Rig()
    assert r.active() == {"AL06A"}
    assert r.enc.status == STATUS_NOT_ESTABLISHED
    assert r.outputs["ABSW"] is True  # absolute warning present (L15294)
    r.origin()
    assert r.active() == set() and r.enc.status == 0 and r.outputs["ABSW"] is False


def test_p2069_incremental_operation_is_quiet_and_takes_a_power_cycle():
    r = Rig(P2_069=0)
    assert r.active() == set() and not r.enc.enabled
    r.params.values["P2.069"] = 1  # ● parameter: only after a power cycle (L10042)
    assert not r.enc.enabled
    r.enc.power_cycle()
    assert r.enc.enabled and r.active() == {"AL06A"}


def test_al069_on_incremental_motor():
    r = Rig(options=AbsoluteOptions(motor_absolute=False))
    assert r.active() == {"AL069"} and not r.enc.enabled


def test_power_cycle_with_battery_keeps_position_and_counts_while_off():
    r = Rig()
    r.origin()
    r.enc.on_motor_position(5 * REV + 77)
    r.enc.power_cycle(battery=True)
    assert (r.enc.turns, r.enc.single_turn) == (5, 77)
    assert r.active() == set()
    r.enc.on_motor_position(6 * REV + 77)  # the shaft moved on battery power
    assert r.enc.turns == 6


def test_power_cycle_without_battery_loses_turns_al060():
    r = Rig()
    r.origin()
    r.enc.on_motor_position(-7 * REV + 99)
    r.enc.power_cycle(battery=False)
    assert r.active() == {"AL060"}
    assert r.enc.status & STATUS_LOST and not r.enc.status & STATUS_NOT_ESTABLISHED
    assert (r.enc.turns, r.enc.single_turn) == (0, 99)  # single turn survives
    r.origin()
    assert r.active() == set()
    # AL060 was reported gone
    assert ("AL060", False) in r.history


def test_battery_voltage_thresholds():
    r = Rig()
    r.origin()
    r.enc.set_battery_voltage(3.0)  # < 3.1 V: AL061, clears by itself (L19769-19773)
    assert r.active() == {"AL061"} and r.enc.status == STATUS_BATTERY_LOW
    r.enc.set_battery_voltage(3.6)
    assert r.active() == set()
    r.enc.set_battery_voltage(2.4)  # < 2.45 V: data lost at the next power-off (L16381)
    r.enc.power_cycle(battery=True)
    assert "AL060" in r.active() and "AL061" in r.active()
    r.enc.set_battery_voltage(4.0)
    assert "AL028" in r.active()  # > 3.8 V (L19639-19640)


def test_puu_overflow_al289_manual_example_1():
    # P1.044 = 16777216, P1.045 = 100000: AL289 after 21474.8 rev (L16419-16420)
    r = Rig()
    r.origin()
    r.enc.on_motor_position(21474 * REV)
    assert "AL289" not in r.active()
    r.enc.on_motor_position(21475 * REV)
    assert "AL289" in r.active() and "AL062" not in r.active()
    assert r.enc.status & STATUS_PUU_OVERFLOW
    assert r.enc.puu == 21475 * 100000 - 2**32  # wraps to negative (L16417)
    r.enc.on_motor_position(0)
    assert "AL289" in r.active()  # sticky until a new origin
    r.origin()
    assert r.active() == set()


def test_turn_overflow_al062_manual_example_2_and_negative():
    # P1.045 = 10000: AL062 after 32767 rev, PUU still in range (L16421)
    r = Rig(P1_045=10000)
    r.origin()
    r.enc.on_motor_position(32768 * REV)
    assert r.active() == {"AL062"} and r.enc.status == STATUS_TURN_OVERFLOW
    r.enc.on_motor_position(0)
    r.origin()
    r.enc.on_motor_position(-32768 * REV)
    assert r.active() == set()
    r.enc.on_motor_position(-32768 * REV - 1)  # CW past -32768 -> 32767 (L16404)
    assert r.enc.turns == 32767 and r.active() == {"AL062"}


def test_p2070_bit2_suppresses_overflow_warnings():
    r = Rig(P2_070=0x4)
    r.origin()
    r.enc.on_motor_position(40000 * REV)
    assert r.active() == set()  # L10064-10068
    assert r.enc.status == STATUS_TURN_OVERFLOW | STATUS_PUU_OVERFLOW  # status still tells
    r.params.write("P2.070", 0)
    assert r.active() == {"AL062", "AL289"}
    r.params.write("P2.070", 4)
    assert r.active() == set()


# -- origin ----------------------------------------------------------------------------------


def _abse_on(r: Rig) -> None:
    r.enc.on_abse(True)
    r.advance(4 * MS)  # T_S = P2.009 + 4 ms at the terminals, 4 ms after the filtered edge


def test_origin_by_abse_absc():
    r = Rig(P6_001=-1000)
    r.enc.on_motor_position(3 * REV + 5)
    _abse_on(r)
    r.enc.on_absc(True)  # the edge as the P2.009 filter passes it on
    r.advance(4 * MS - 1)
    assert "AL06A" in r.active()
    r.advance(1)  # held P2.009 + 2 ms (L16448): the filtered pulse is as long as the pressed
    assert r.active() == set()  # one, so the hold is counted in full after the filter
    assert (r.enc.turns, r.enc.single_turn, r.enc.puu) == (0, 0, -1000)  # L16441


def test_absc_released_early_or_before_ts_does_nothing():
    r = Rig()
    r.enc.on_abse(True)
    r.enc.on_absc(True)  # before T_S: ignored (L16440)
    r.advance(10 * MS)
    assert "AL06A" in r.active()
    r.enc.on_absc(False)
    r.enc.on_absc(True)
    r.advance(1 * MS)
    r.enc.on_absc(False)  # released before T_Q
    r.advance(10 * MS)
    assert "AL06A" in r.active()
    r.enc.on_absc(True)
    r.enc.on_abse(False)  # ABSE off cancels
    r.advance(10 * MS)
    assert "AL06A" in r.active()


def test_origin_refused_above_200_rpm_al07c_then_al07d_after_power_cycle():
    r = Rig(speed=250.0)
    _abse_on(r)
    r.enc.on_absc(True)
    r.advance(5 * MS)
    assert r.active() == {"AL06A", "AL07C"}  # L19855-19859
    r.enc.on_absc(False)
    r.enc.on_abse(False)
    r.enc.power_cycle()
    assert "AL07D" in r.active()  # L19861-19865
    r.speed = 0.0
    r.params.values["P2.008"] = 271
    r.params.write("P2.071", 1)
    assert r.active() == set()


def test_origin_by_p2071_needs_the_p2008_key():
    r = Rig(P6_001=42)
    r.enc.on_motor_position(-3 * REV)
    with pytest.raises(ProtectedParameter, match=r"P2\.008 = 271"):
        r.params.write("P2.071", 1)
    assert "AL06A" in r.active()
    r.params.write("P2.008", 271)
    r.params.write("P2.071", 1)  # L16454
    assert r.active() == set() and r.enc.puu == 42
    assert r.params.get("P2.071") == 0  # option p2071_returns_to_zero


def test_p2071_ignored_when_absolute_disabled():
    r = Rig(P2_069=0, P2_008=271)
    r.params.write("P2.071", 1)  # needs P2.069.X = 1 (L10081)
    assert r.enc.mem.coordinate == "unset"


def test_establish_origin_at_reference_for_homing():
    r = Rig(P6_001=1000)
    r.enc.on_motor_position(10 * REV)
    r.enc.on_motor_position(10 * REV + 300)  # overshoot after the reference
    r.enc.establish_origin(at_counts=10 * REV)
    assert r.enc.mem.pulse_value == 300
    assert r.active() == set()


# -- P0.049 latched read ---------------------------------------------------------------------


def test_p0049_1_latches_puu_and_returns_to_zero():
    r = Rig(P6_001=7)
    r.origin()
    r.enc.on_motor_position(2 * REV + REV // 4)
    r.params.write("P0.049", 1)
    assert r.params.get("P0.049") == 1  # ready after p0049_ready_ms
    r.advance(1 * MS)
    assert r.params.get("P0.049") == 0  # L7491, L16529
    assert (r.params.get("P0.050"), r.params.get("P0.051")) == (0, 0)  # P2.070 bit1 = 0: 0
    assert r.params.get("P0.052") == 225000 + 7
    r.enc.on_motor_position(0)
    assert r.params.get("P0.052") == 225007  # latched, does not follow the motor
    assert r.cleared == 0


def test_p0049_2_pulse_unit_and_clears_position_error():
    r = Rig(P2_070=0x2)
    r.origin()
    r.enc.on_motor_position(-REV - 5)
    r.enc.set_battery_voltage(3.0)
    r.params.write("P0.049", 2)
    r.advance(1 * MS)
    assert r.params.get("P0.049") == 0
    assert r.params.get("P0.050") == STATUS_BATTERY_LOW
    assert (r.params.get("P0.051"), r.params.get("P0.052")) == (-2, REV - 5)
    assert r.cleared == 1


def test_p0049_immediate_option():
    r = Rig(options=AbsoluteOptions(p0049_ready_ms=0))
    r.params.write("P0.049", 1)
    assert r.params.get("P0.049") == 0
    assert r.params.get("P0.050") == STATUS_NOT_ESTABLISHED


def test_p0049_with_the_real_parameter_store_and_od_indices():
    from hil.model.params import ParameterStore

    sched = Scheduler()
    store = ParameterStore()
    store.write("P2.069", 1)
    store.power_cycle()
    causes: dict[str, bool] = {}
    enc = AbsoluteEncoder(sched, store, set_cause=causes.__setitem__, set_output=lambda s, a: None)
    assert causes["AL06A"]
    with pytest.raises(ProtectedParameter):
        store.write("P2.071", 1)
    store.write("P2.008", 271)
    store.write("P2.071", 1)
    assert not causes["AL06A"] and store.read("P2.071") == 0
    enc.on_motor_position(0)
    enc.on_motor_position(-3 * REV - 10)
    store.write("P2.070", 0x2)
    store.write("P0.049", 1)
    sched.now = 1 * MS
    sched.run_due()
    assert store.read("P0.049") == 0
    # SDO 2031h-2034h = P0.049-P0.052 (2000h + group << 8 + n, L18154)
    assert store.by_od_index(0x2031).param == "P0.049"
    values = {}
    for index in (0x2032, 0x2033, 0x2034):
        name = store.by_od_index(index).param
        values[name] = store.read(name)
    assert values == {"P0.050": 0, "P0.051": -4, "P0.052": REV - 10}


# -- handshake, drive side (direct DI function calls) ----------------------------------------


def _start_read(r: Rig) -> None:
    r.enc.on_absq(True)  # host idles ABSQ on
    _abse_on(r)
    assert r.overlay and r.enc.state == READY


def _one_bit(r: Rig) -> int:
    r.enc.on_absq(False)
    r.advance(4 * MS)
    assert r.enc.state == WAIT_ACK and r.outputs["ABSR"]
    bit = int(r.outputs["ABSD"])
    r.enc.on_absq(True)
    r.advance(4 * MS)
    assert not r.outputs["ABSR"]
    return bit


def test_handshake_sends_the_frame_and_restores_the_pins():
    r = Rig(P2_070=0x1)
    r.origin()
    r.enc.on_motor_position(-5 * REV + 1234)
    _start_read(r)
    bits = [_one_bit(r) for _ in range(FRAME_BITS)]
    # the 80th ABSR off is shown on the pin; the pins are the DIs'/DOs' again once the host
    # ends the cycle, ABSE off (L16519)
    assert r.enc.state == DONE and r.overlay and not r.outputs["ABSR"]
    r.enc.on_abse(False)
    assert not r.overlay
    frame = sum(b << i for i, b in enumerate(bits))
    assert split_frame(frame)[:3] == (0, -5, 1234)
    assert frame == r.enc.last_frame


def test_handshake_refused_while_a_warning_is_present():
    r = Rig()  # AL06A: coordinate not established
    r.enc.on_abse(True)
    r.advance(4 * MS)
    assert r.enc.state == BLOCKED and not r.overlay and r.outputs["ABSW"]  # L16521
    r.enc.on_abse(False)
    assert r.outputs["ABSW"]  # still on: the warning is still there


def test_late_host_gets_absw_and_al068_abse_off_clears_absw():
    r = Rig()
    r.origin()
    _start_read(r)
    _one_bit(r)
    r.enc.on_absq(False)
    r.advance(4 * MS)
    r.advance(201 * MS)  # T_R = 200 ms at the terminals (+2 ms filter inside)
    assert r.enc.state == WAIT_ACK
    r.advance(1 * MS)
    assert r.enc.state == WAIT_ACK  # exactly T_R is still in time ("exceeds", L19789)
    r.advance(1)
    assert r.enc.state == ERROR and r.outputs["ABSW"] and not r.outputs["ABSR"]
    assert r.active() == {"AL068"}  # L19787-19790
    r.enc.on_abse(False)
    assert not r.outputs["ABSW"] and not r.overlay  # L16515
    assert ("AL068", False) in r.history


@pytest.mark.parametrize(
    ("when", "rule"),
    [("prep", "ABSQ on before ABSR on"), ("ack", "ABSQ off before ABSR off")],
)
def test_protocol_violations_raise_absw(when, rule):
    r = Rig()
    r.origin()
    _start_read(r)
    r.enc.on_absq(False)
    if when == "prep":
        r.enc.on_absq(True)
    else:
        r.advance(4 * MS)
        r.enc.on_absq(True)
        assert r.enc.state == ACK
        r.enc.on_absq(False)
    assert r.enc.state == ERROR and rule in r.enc.last_error
    assert r.outputs["ABSW"] and "AL068" in r.active()


def test_dev_no_t_r_never_raises_absw():
    r = Rig(options=AbsoluteOptions(dev_no_t_r=True))
    r.origin()
    _start_read(r)
    r.enc.on_absq(False)
    r.advance(1000 * MS)
    assert r.enc.state == WAIT_ACK and not r.outputs["ABSW"]


def test_dev_bad_checksum_and_swapped_order():
    r = Rig(options=AbsoluteOptions(dev_bad_checksum=True, dev_swap_bit_order=True))
    r.origin()
    cs = split_frame(r.enc.frame())[3]
    assert cs == checksum(0, 0, 0, 0) ^ 1
    _start_read(r)
    assert r.enc._bits == frame_bits(r.enc.last_frame, "msb_first")


# -- options and persistence -----------------------------------------------------------------


def test_memory_round_trip_across_a_process_restart():
    r = Rig()
    r.origin()
    r.enc.on_motor_position(-9 * REV + 5)
    data = r.enc.to_dict()
    assert data["format"] == "hil.absolute/1" and data["coordinate"] == "valid"
    r2 = Rig()
    r2.enc.restore(data)
    assert r2.active() == set()
    assert ("AL06A", False) in r2.history
    r2.enc.on_motor_position(123456)  # new process: the axis restarted at another count
    assert (r2.enc.turns, r2.enc.single_turn) == (-9, 5)  # re-anchored
    r2.enc.on_motor_position(123456 + REV)
    assert r2.enc.turns == -8


def test_bad_state_and_options_are_named():
    with pytest.raises(AbsoluteError, match="coordinate"):
        EncoderMemory.from_dict({"coordinate": "maybe"})
    with pytest.raises(AbsoluteError, match="pulse_value must be int"):
        EncoderMemory.from_dict({"pulse_value": "3"})
    with pytest.raises(AbsoluteError, match="unknown key"):
        EncoderMemory.from_dict({"turns": 3})
    with pytest.raises(AbsoluteError, match="bit_order"):
        AbsoluteOptions(bit_order="middle")
    with pytest.raises(AbsoluteError, match="unknown absolute option"):
        AbsoluteOptions.from_dict({"t_x_ms": 1})
    assert AbsoluteOptions.from_dict({"t_q_margin_ms": 8}).t_q_margin_ms == 8


def test_an_incremental_or_lost_coordinate_starts_at_zero_at_power_up() -> None:
    """Without a valid absolute coordinate (P2.069 = 0, or AL060: no battery, L16123,
    L19796) nothing keeps the position while the drive is off: 6064h starts at 0. It had
    kept 500 000 PUU from before the power-off (an outside review, helper-63)."""
    from hil.model.drive import Drive
    from hil.units import MS

    for params, battery in (({}, True), ({"P2.069": 1}, False)):
        d = Drive(inputs={8: True, 6: True, 7: True}, params=params or None)
        d.advance(10 * MS)
        d.axis.set_user_position(d.axis.cpr * 5)  # 5 turns: 500 000 PUU
        assert d.read_object(0x6064, 0) == 500000
        d.power_cycle(battery=battery, off_for=100 * MS)
        d.advance(10 * MS)
        assert d.read_object(0x6064, 0) == 0, (params, battery)
