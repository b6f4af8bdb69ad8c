"""CiA 402 device state machine of the ASDA-A3 and its 6000h-6FFFh objects.

Sources: manual L18202-L19278 (CiA 402 objects and state machine). Choices where the manual is
silent are model options (`Cia402Options`) and are listed in docs/manual-choices.md#cia402-motion.

Interface to the drive (everything else is internal)::

    cia = Cia402(axis, clock=lambda: sched.now, emit=drive_emit,
                 options=Cia402Options(), fault_reset=hook, start_homing=hook,
                 stop_homing=hook, on_servo_request=hook, on_write=hook)
    cia.power_on()                     # objects to defaults, transitions 0/1 -> SWITCH ON DISABLED
    # objects (raw integers as SDO/PDO carry them; ObjectError with a CiA 301 abort code)
    cia.read(index, sub) -> int
    cia.write(index, sub, value)       # 6040h drives the state machine
    # inputs from the drive
    cia.set_fault(active)              # servo-off alarm present: transitions 13/14
    cia.set_warning(active)            # statusword bit 7
    cia.set_limits(nl, pl)             # physical NL/PL function active: bits 15/14, 60FDh b0/b1,
                                       # rising edge in OPERATION ENABLED = quick stop (11)
    cia.set_voltage(present)           # main power: bit 4
    cia.set_home_switch(active)        # 60FDh bit 2
    cia.set_homing_status(attained, error)   # HM bits 12/13 (ends the homing run)
    cia.limit_decel_ms = 30.0          # limit-stop ramp, the drive keeps it = P5.003 X/Y entry
    cia.set_gear(p1_044, p1_045)       # mirror of P1.044/P1.045 (6093h)
    cia.set_max_speed(rpm)             # mirror of P1.055 (607Fh/6080h)
    cia.error_code = 0x7305            # 603Fh, set by the drive's alarm manager
    cia.after_step()                   # after every axis.step(): queues, ramps ends, bit 10
    cia.next_deadline() -> int | None  # when bit 10 changes by itself (window time)
    # outputs
    cia.state                          # 'OPERATION ENABLED' ... (canopen BaseNode402 names)
    cia.statusword                     # 6041h
    cia.mode                           # 6061h
    cia.servo_enable_requested         # the power stage should be on
    cia.shutdown_stop_mode             # P1.032.Y code for a state-machine servo off (605Bh)
    cia.following_error_exceeded       # |60F4h| > 6065h (the drive raises AL009)

Hooks: ``fault_reset() -> bool`` (on every bit-7 rising edge; True = no servo-off alarm
left; default: no `set_fault` active); ``start_homing()`` on the HM bit-4 rising edge in
OPERATION ENABLED; ``stop_homing()`` on halt, bit-4 falling edge, leaving HM or leaving
OPERATION ENABLED while homing; ``on_servo_request(on, cause)`` with cause "state" or
"fault" whenever `servo_enable_requested` changes (default: set `axis.stop_mode` from
605Bh and call `axis.set_power(on)`, enough for tests without a drive); ``on_write(index,
sub, value)`` after every accepted write (the drive mirrors 6093h into P1.044/P1.045 ...).

The CiA 402 machine commands the axis directly (profiles, ramp stops, holds); the power
stage itself belongs to the drive (STO, brake, alarms) and is switched through
`on_servo_request`.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass, replace

from hil.model.errors import ObjectError
from hil.model.events import StateChanged
from hil.model.motion import Axis, counts_to_puu, puu_per_s_to_rpm, puu_to_counts
from hil.profile.od import load_objects
from hil.protocol.canopen import (
    ABORT_DATA_STATE,
    ABORT_NO_OBJECT,
    ABORT_NO_SUBINDEX,
    ABORT_READ_ONLY,
    ABORT_VALUE_HIGH,
    ABORT_VALUE_LOW,
    ABORT_VALUE_RANGE,
)
from hil.protocol.cia402 import MODES
from hil.units import MS, S, s32

# ---- states (names as canopen.BaseNode402 uses them) ------------------------------------
NOT_READY = "NOT READY TO SWITCH ON"
SWITCH_ON_DISABLED = "SWITCH ON DISABLED"
READY = "READY TO SWITCH ON"
SWITCHED_ON = "SWITCHED ON"
OPERATION_ENABLED = "OPERATION ENABLED"
QUICK_STOP_ACTIVE = "QUICK STOP ACTIVE"
FAULT_REACTION_ACTIVE = "FAULT REACTION ACTIVE"
FAULT = "FAULT"

# Statusword bits 6..0 per state, don't-care bits 0 (L18321-18331).
_STATE_BITS = {
    NOT_READY: 0x00,
    SWITCH_ON_DISABLED: 0x40,
    READY: 0x21,
    SWITCHED_ON: 0x23,
    OPERATION_ENABLED: 0x27,
    QUICK_STOP_ACTIVE: 0x07,
    FAULT_REACTION_ACTIVE: 0x0F,
    FAULT: 0x08,
}

# ---- modes (6060h, L18375-18381; 6502h = 0x6D, L19250-19278) ----------------------------
PP, PV, PT, HM, IP = (MODES[m] for m in ("PP", "PV", "PT", "HM", "IP"))  # hil.protocol.cia402
SUPPORTED_MODES = frozenset({0, PP, PV, PT, HM, IP})  # 0 = no mode (the default value)
SUPPORTED_DRIVE_MODES = 0x6D

# controlword commands (L18272-18281)
_CMD_DISABLE_VOLTAGE, _CMD_QUICK_STOP, _CMD_SHUTDOWN, _CMD_SWITCH_ON, _CMD_ENABLE = range(5)

# data types: (lo, hi)
_TYPES = {
    "U8": (0, 0xFF),
    "I8": (-0x80, 0x7F),
    "U16": (0, 0xFFFF),
    "I16": (-0x8000, 0x7FFF),
    "U32": (0, 0xFFFFFFFF),
    "I32": (-0x80000000, 0x7FFFFFFF),
}

_OPTION_CODES = {  # model-only option-code objects (absent from the A3 object list, L18202-L19278)
    0x605A: frozenset(range(9)),  # quick stop option code
    0x605C: frozenset({0, 1}),  # disable operation option code
    0x605D: frozenset({1, 2, 3, 4}),  # halt option code
    0x605E: frozenset({0, 1, 2, 3, 4}),  # fault reaction option code
}


_BLOCKED_STATES = ("switch_on_disabled", "switched_on", "operation_enabled")

# 607Fh / 6080h are P1.055 (L18713-18718, L18730-18735), whose range starts at 10 rpm (L8702)
MIN_SPEED_LIMIT_RPM = 10

# position demand (PUU), actual (counts), actual (PUU): 32-bit counters that wrap
_COUNTERS = frozenset({0x6062, 0x6063, 0x6064})


@dataclass
class Cia402Options:
    """Choices where the manual is silent (docs/manual-choices.md#cia402-motion)."""

    # 605Ah model: 6 = the 6085h ramp, then QUICK STOP ACTIVE until a command: transition 12
    # Disable Voltage or 16 Enable Operation (L18262-18265); 2 = then SWITCH ON DISABLED
    quick_stop_option: int = 6
    disable_operation_option: int = 0  # 605Ch model: transition 5 = servo off (L18253)
    halt_option: int = 1  # 605Dh model: profile deceleration, then hold
    fault_reaction_option: int = 0  # 605Eh model: alarm = servo off at once (L18264)
    option_objects: bool = False  # 605Ah/605Ch/605Dh/605Eh answer SDO (A3 list: absent)
    limit_quick_stop_hold: bool = True  # limit QS stays in QUICK STOP ACTIVE, servo on (AL014/15)
    limit_decel_ms: float = 30.0  # P5.003 X/Y default F -> P5.035 = 30 ms (L11085, L11462)
    mode_change_while_enabled: str = "accept"  # or "refuse" (abort 0x08000022)
    pp_relative_base: str = "target"  # bit 6 relative to: "target" | "demand" | "actual"
    remote_bit: bool = True  # statusword bit 9 (no description, L18312)
    homing_stop_on_bit4_fall: bool = True  # HM bit 4 1->0 interrupts homing [std]
    # PP, bit 5 = 0: a set-point triggered while a move runs is acknowledged (bit 12) and
    # run only once that move completes (L17172-17174); until then it is held while bit 4
    # stays high, and bit 4 falling withdraws it. False: acknowledged at once into a buffer
    # of one, a further trigger then refused ([std] CiA 402; the model before session 26)
    pp_ack_when_run: bool = True
    # State while a servo-off warning (EMGS AL013: WARN class, servo OFF, L19338) blocks the
    # servo: OPERATION ENABLED means servo on (L18326), so the machine leaves it and refuses
    # transition 4 while blocked. "switch_on_disabled" | "switched_on" | "operation_enabled"
    # (the old model: state kept, servo off anyway).
    servo_blocked_state: str = "switch_on_disabled"

    def __post_init__(self) -> None:
        for index, name in (
            (0x605A, "quick_stop_option"),
            (0x605C, "disable_operation_option"),
            (0x605D, "halt_option"),
            (0x605E, "fault_reaction_option"),
        ):
            if getattr(self, name) not in _OPTION_CODES[index]:
                raise ValueError(
                    f"Cia402Options.{name} ({index:04X}h): {getattr(self, name)} not in "
                    f"{sorted(_OPTION_CODES[index])}"
                )
        if self.mode_change_while_enabled not in ("accept", "refuse"):
            raise ValueError("Cia402Options.mode_change_while_enabled: 'accept' or 'refuse'")
        if self.pp_relative_base not in ("target", "demand", "actual"):
            raise ValueError("Cia402Options.pp_relative_base: 'target', 'demand' or 'actual'")
        if self.limit_decel_ms <= 0:
            raise ValueError("Cia402Options.limit_decel_ms: must be > 0 ms")
        if self.servo_blocked_state not in _BLOCKED_STATES:
            raise ValueError(
                f"Cia402Options.servo_blocked_state: one of {', '.join(_BLOCKED_STATES)}"
            )


@dataclass(frozen=True)
class _Obj:
    name: str
    dtype: str
    rw: bool
    default: int
    lo: int | None = None
    hi: int | None = None


# the object list's data types (hil.profile.od) -> the model's value ranges (_TYPES)
_DTYPES = {"UNSIGNED8": "U8", "INTEGER8": "I8", "UNSIGNED16": "U16", "INTEGER16": "I16",
           "UNSIGNED32": "U32", "INTEGER32": "I32"}


@functools.cache
def _od_objects() -> dict[tuple[int, int], _Obj]:
    """The 6xxx rows of the A3 object list (hil.profile.od, fixtures/drive/a3_objects.csv:
    L18202-L19278), read once."""
    return {
        (e.index, e.sub): _Obj(e.name, _DTYPES[e.type], e.writable, e.default or 0, e.min, e.max)
        for e in load_objects() if 0x6000 <= e.index <= 0x6FFF
    }


def _objects(max_speed_rpm: int) -> dict[tuple[int, int], _Obj]:
    """6xxx objects: the object list's, stored ones with their defaults, RO ones computed;
    plus what the list leaves to the drive."""
    objs = dict(_od_objects())
    for key, default in (((0x607F, 0), max_speed_rpm * 10), ((0x6080, 0), max_speed_rpm)):
        objs[key] = replace(objs[key], default=default)  # the motor's speed (L18703-18735)
    for sub in (1, 2):  # written to P1.044 / P1.045, whose ranges start at 1 (L8525-8540)
        objs[(0x6093, sub)] = replace(objs[(0x6093, sub)], lo=1)
    o = _Obj
    objs.update({  # model-only option-code objects (_OPTION_CODES; option_objects)
        (0x605A, 0): o("Quick stop option code", "I16", True, 6),
        (0x605C, 0): o("Disable operation option code", "I16", True, 0),
        (0x605D, 0): o("Halt option code", "I16", True, 1),
        (0x605E, 0): o("Fault reaction option code", "I16", True, 0),
    })
    return objs


def _clip(value: int, dtype: str) -> int:
    lo, hi = _TYPES[dtype]
    return lo if value < lo else hi if value > hi else value


class Cia402:
    """Device-side CiA 402 state machine plus the 6xxx objects. See the module docstring."""

    def __init__(
        self,
        axis: Axis,
        *,
        clock: Callable[[], int],
        emit: Callable[[object], None] | None = None,
        options: Cia402Options | None = None,
        fault_reset: Callable[[], bool] | None = None,
        start_homing: Callable[[], None] | None = None,
        stop_homing: Callable[[], None] | None = None,
        on_servo_request: Callable[[bool, str], None] | None = None,
        on_write: Callable[[int, int, int], None] | None = None,
    ) -> None:
        self.axis = axis
        self.clock = clock
        self.emit = emit or (lambda event: None)
        self.options = options or Cia402Options()
        self._fault_reset_hook = fault_reset
        self.start_homing = start_homing
        self.stop_homing = stop_homing
        self.refuse_setpoint: Callable[[], bool] | None = None  # AL235 (counters.py)
        self._servo_hook = on_servo_request
        self.on_write = on_write
        self._defs = _objects(round(axis.mech.rated_speed))
        self._indices = {i for i, _ in self._defs}
        self.state = NOT_READY
        self.servo_enable_requested = False
        self.error_code = 0
        self._fault = False
        self._blocked = False  # a servo-off warning (AL013) holds the servo off
        self._warning = False
        self._voltage = True
        self._nl = self._pl = False
        self._home = False
        self._reset_runtime()

    # ---- life cycle ----------------------------------------------------------------
    def _reset_runtime(self) -> None:
        self._v = {key: d.default for key, d in self._defs.items() if d.rw}
        opts = self.options
        self._v[(0x605A, 0)] = opts.quick_stop_option
        self._v[(0x605C, 0)] = opts.disable_operation_option
        self._v[(0x605D, 0)] = opts.halt_option
        self._v[(0x605E, 0)] = opts.fault_reaction_option
        self.limit_decel_ms = opts.limit_decel_ms
        self._cw = self._v[(0x6040, 0)]
        self._mode = 0
        self._num, self._den = 1, 1
        self._halted = False
        self._ack = False
        self._pp_active: tuple[float, float, int, int] | None = None
        self._pp_queue: tuple[float, float, int, int] | None = None
        # the set-point waiting, unacknowledged, for the running move (pp_ack_when_run):
        # (607Ah in counts, relative, speed, 6083h, 6084h), its target worked out when it runs
        self._pp_waiting: tuple[float, bool, float, int, int] | None = None
        self._pp_last: float | None = None  # the last set-point's target (None: none yet)
        self._ip_target: float | None = None
        self._homing_active = False
        self._hm_attained = False
        self._hm_error = False
        self._fe_latched = False  # PP bit 13: the following error AL009 came from, until reset
        self._qs_disable = False  # QUICK STOP ACTIVE ends in SWITCH ON DISABLED
        self._off_after_stop = False  # 605Ch = 1: ramp, then servo off
        self._tr_since: int | None = None
        self._inhibited = False
        self.axis.set_torque_limits(3000, 3000)
        self.axis.max_speed_rpm = self.axis.mech.rated_speed

    def power_on(self) -> None:
        """Objects to defaults; transitions 0/1 to SWITCH ON DISABLED (13/14 if faulted)."""
        self._set_servo(False, "state")
        self._reset_runtime()
        self._set_state(NOT_READY)
        if self._fault:
            self._set_state(FAULT_REACTION_ACTIVE)
            self._set_state(FAULT)
        else:
            self._set_state(SWITCH_ON_DISABLED)

    def comm_disable(self) -> None:
        """The master can no longer command the drive (NMT Stop): transition 9/12 to
        SWITCH ON DISABLED, as a "disable voltage" controlword would."""
        if self.state in (OPERATION_ENABLED, QUICK_STOP_ACTIVE, SWITCHED_ON,
                          READY):
            self._disable(SWITCH_ON_DISABLED)

    def reinit(self) -> None:
        """An NMT reset re-initialises the state machine: FAULT while a servo-off alarm
        remains, else SWITCH ON DISABLED (transition 15 from FAULT, L18265)."""
        if self.state in (OPERATION_ENABLED, QUICK_STOP_ACTIVE, FAULT_REACTION_ACTIVE):
            return  # the servo is still on: AL401 (the drive) takes it down first
        if self._fault:
            if self.state != FAULT:
                self._set_state(FAULT)
        elif self.state != SWITCH_ON_DISABLED:
            self._set_state(SWITCH_ON_DISABLED)

    # ---- inputs from the drive -----------------------------------------------------
    def set_fault(self, active: bool) -> None:
        """A servo-off alarm is present (True) or gone. Rising: transition 13 (+14)."""
        active = bool(active)
        rising = active and not self._fault
        self._fault = active
        if not rising or self.state in (FAULT_REACTION_ACTIVE, FAULT, NOT_READY):
            return
        powered = self.state in (OPERATION_ENABLED, QUICK_STOP_ACTIVE) or self._off_after_stop
        self._leave_operation()
        self._set_state(FAULT_REACTION_ACTIVE)  # 13
        opt = self._v[(0x605E, 0)]
        if opt == 0 or not powered:
            self._set_servo(False, "fault")
            self._set_state(FAULT)  # 14
        else:
            self.axis.ramp_stop(self._stop_decel(opt))

    def set_servo_blocked(self, active: bool) -> None:
        """A servo-off event that is no fault (EMGS, AL013 WARN/servo OFF, L19338) is present.

        OPERATION ENABLED is "servo on" (L18326): while blocked the machine leaves it (to
        `servo_blocked_state`) and refuses transition 4 (enable operation).
        """
        self._blocked = bool(active)
        target = self.options.servo_blocked_state
        if not self._blocked or target == "operation_enabled":
            return
        if self.state in (OPERATION_ENABLED, QUICK_STOP_ACTIVE) or self._off_after_stop:
            self._off_after_stop = False
            self._disable(SWITCH_ON_DISABLED if target == "switch_on_disabled" else SWITCHED_ON)

    def set_warning(self, active: bool) -> None:
        self._warning = bool(active)

    def set_voltage(self, present: bool) -> None:
        self._voltage = bool(present)

    def set_home_switch(self, active: bool) -> None:
        self._home = bool(active)

    def set_limits(self, nl: bool, pl: bool) -> None:
        """NL/PL function state. A rising edge while OPERATION ENABLED is a quick stop
        (transition 11, L18260) unless a homing run uses the switches."""
        rising = (nl and not self._nl) or (pl and not self._pl)
        self._nl, self._pl = bool(nl), bool(pl)
        if rising and self.state == OPERATION_ENABLED and not self._homing_busy():
            self._quick_stop(limit=True)

    def set_homing_status(self, attained: bool, error: bool) -> None:
        """Homing result for HM statusword bits 12/13; either flag ends the run. An error
        with a limit switch active (one the method does not use, or a second one) is then the
        limit's quick stop, as in every other mode (transition 11, L18260)."""
        self._hm_attained = bool(attained)
        self._hm_error = bool(error)
        if attained or error:
            self._homing_active = False
        self._update_window()
        if error and (self._nl or self._pl) and self.state == OPERATION_ENABLED:
            self._quick_stop(limit=True)

    def drop_setpoints(self) -> None:
        """The drive took the axis (DI JOG, PFQS, CCLR): the PP set-points are gone, so the
        next one starts at once instead of waiting for a move that no longer runs."""
        self._pp_active = self._pp_queue = self._pp_waiting = None
        self._ip_target = None

    def set_gear(self, p1_044: int, p1_045: int) -> None:
        """Mirror P1.044/P1.045 into 6093h sub 1/2 (no checks beyond > 0)."""
        if p1_044 <= 0 or p1_045 <= 0:
            raise ObjectError(0x6093, 1, ABORT_VALUE_LOW, "gear numerator/denominator must be > 0")
        self._num, self._den = int(p1_044), int(p1_045)
        self._v[(0x6093, 1)], self._v[(0x6093, 2)] = self._num, self._den

    def set_max_speed(self, rpm: float) -> None:
        """Mirror P1.055 into 607Fh (0.1 rpm) and 6080h (rpm)."""
        self.axis.max_speed_rpm = float(rpm)
        self._v[(0x6080, 0)] = round(rpm)
        self._v[(0x607F, 0)] = round(rpm * 10)

    # ---- outputs ---------------------------------------------------------------------
    @property
    def mode(self) -> int:
        """6061h: the active mode of operation."""
        return self._mode

    @property
    def shutdown_stop_mode(self) -> int:
        """P1.032.Y code for a state-machine servo off: 605Bh 0 = free run -> 1 (coast),
        605Bh 1 = dynamic brake -> 0 (L18356-18358, L8323-8327)."""
        return 0 if self._v[(0x605B, 0)] == 1 else 1

    def latch_following_error(self) -> None:
        """AL009 from |60F4h| > 6065h in PP: statusword bit 13 (L18338) stays set with the
        alarm until a fault reset (or a mode change), so a master polling after the servo
        went off still reads why; the manual does not say how long it shows (⚠)."""
        if self._mode == PP:
            self._fe_latched = True

    @property
    def following_error_exceeded(self) -> bool:
        """|60F4h| > 6065h (AL009 in position modes, L18452)."""
        if self._mode not in (PP, IP, HM) or not self.servo_enable_requested:
            return False
        limit = self._v[(0x6065, 0)]
        ax = self.axis
        # |round(a) - round(b)| <= |a - b| + 1: an error this far inside the window cannot
        # exceed it, so the exact PUU difference is worked out only near the limit (+1 more
        # for the float rounding of positions far from 0)
        # (60F4h's own demand: the IP interpolator's, before the filters, L19193)
        if abs(ax.interpolator_demand - ax.user_position) * self._den / self._num + 2 <= limit:
            return False
        return abs(self._fe_puu()) > limit

    @property
    def statusword(self) -> int:
        st = self.state
        sw = _STATE_BITS[st]
        if self._voltage:
            sw |= 0x0010
        if self._warning:
            sw |= 0x0080
        if self.options.remote_bit:
            sw |= 0x0200
        if st in (OPERATION_ENABLED, QUICK_STOP_ACTIVE) and self._target_reached():
            sw |= 0x0400
        mode = self._mode
        if mode == PP:
            if self._ack:
                sw |= 0x1000
            if self._fe_latched or self.following_error_exceeded:
                sw |= 0x2000
        elif mode == HM:
            if self._hm_attained:
                sw |= 0x1000
            if self._hm_error:
                sw |= 0x2000
        elif mode == PV:
            if abs(round(self.axis.velocity_rpm * 10)) <= self._v[(0x606F, 0)]:
                sw |= 0x1000
        elif mode == IP and st == OPERATION_ENABLED:
            sw |= 0x1000
        if self._pl:
            sw |= 0x4000  # L18316
        if self._nl:
            sw |= 0x8000  # L18317
        return sw

    def next_deadline(self) -> int | None:
        """Model time at which bit 10 turns on by itself (window time running), or None."""
        since = self._tr_since
        if since is None:
            return None
        deadline = since + self._window_time() * MS
        return deadline if deadline > self.clock() else None

    # ---- objects -----------------------------------------------------------------------
    def _def(self, index: int, sub: int) -> _Obj:
        if index in _OPTION_CODES and not self.options.option_objects:
            raise ObjectError(index, sub, ABORT_NO_OBJECT, "object does not exist on the A3")
        d = self._defs.get((index, sub))
        if d is None:
            if index in self._indices:
                raise ObjectError(index, sub, ABORT_NO_SUBINDEX, "sub-index does not exist")
            raise ObjectError(index, sub, ABORT_NO_OBJECT, "object does not exist")
        return d

    def read(self, index: int, sub: int = 0) -> int:
        """SDO/PDO read of a 6xxx object (raw integer)."""
        d = self._def(index, sub)
        if d.rw:
            if index == 0x6093:
                return self._num if sub == 1 else self._den
            return self._v[(index, sub)]
        value = self._actual(index, sub, d)
        if index in _COUNTERS:  # 32-bit counters wrap (L15290, counters.py)
            return s32(value)
        return _clip(value, d.dtype)

    def _actual(self, index: int, sub: int, d: _Obj) -> int:
        ax = self.axis
        if index == 0x6041:
            return self.statusword
        if index == 0x6061:
            return self._mode
        if index == 0x6062:  # before the IP filters (L18410-18412); 60FCh after (L19207)
            return round(counts_to_puu(ax.interpolator_demand, self._num, self._den))
        if index == 0x6063:
            return round(ax.user_position)
        if index == 0x6064:
            return round(counts_to_puu(ax.user_position, self._num, self._den))
        if index == 0x606B:
            return round(ax.demand_rpm * 10)
        if index == 0x606C:
            return round(ax.velocity_rpm * 10)
        if index == 0x6074:
            return round(ax.torque_demand)
        if index == 0x6075:
            return round(ax.mech.rated_current * 10000)  # 0.1 mA
        if index == 0x6076:
            return round(ax.mech.rated_torque * 1000)  # 0.001 N·m
        if index in (0x6077, 0x6078):
            return round(ax.torque)
        if index == 0x60F4:
            return self._fe_puu()
        if index == 0x60FC:
            return round(ax.user_demand)
        if index == 0x60FD:
            return int(self._nl) | int(self._pl) << 1 | int(self._home) << 2  # L19227-19232
        if index == 0x603F:
            return self.error_code
        return d.default

    def write(self, index: int, sub: int, value: int) -> None:
        """SDO/PDO write; raises ObjectError with the CiA 301 abort code."""
        d = self._def(index, sub)
        if not d.rw:
            raise ObjectError(index, sub, ABORT_READ_ONLY, f"{d.name} is read-only")
        value = int(value)
        tlo, thi = _TYPES[d.dtype]
        if not tlo <= value <= thi:
            raise ObjectError(
                index, sub, ABORT_VALUE_RANGE, f"{d.name}: {value} outside {d.dtype} {tlo}~{thi}"
            )
        if d.hi is not None and value > d.hi:
            raise ObjectError(index, sub, ABORT_VALUE_HIGH, f"{d.name}: {value} > {d.hi}")
        if d.lo is not None and value < d.lo:
            raise ObjectError(index, sub, ABORT_VALUE_LOW, f"{d.name}: {value} < {d.lo}")
        key = (index, sub)
        if index in _OPTION_CODES and value not in _OPTION_CODES[index]:
            raise ObjectError(index, sub, ABORT_VALUE_RANGE, f"{d.name}: {value} not supported")
        if index == 0x6060:
            self._write_mode(value)
        elif index == 0x6093:
            if self.servo_enable_requested:  # P1.044/P1.045 are ▲ (L6879-6880)
                raise ObjectError(
                    index, sub, ABORT_DATA_STATE, "e-gear not writable while servo on"
                )
            if sub == 1:
                self._num = value
            else:
                self._den = value
        elif index in (0x607F, 0x6080):
            rpm = value / 10 if index == 0x607F else value
            if rpm < MIN_SPEED_LIMIT_RPM:  # they are P1.055, 10 ~ max (L8700-8702)
                raise ObjectError(index, sub, ABORT_VALUE_LOW,
                                  f"{d.name}: P1.055 is at least {MIN_SPEED_LIMIT_RPM} rpm")
            if rpm > self.axis.mech.max_speed:
                raise ObjectError(
                    index,
                    sub,
                    ABORT_VALUE_HIGH,
                    f"{d.name}: above the motor's max speed {self.axis.mech.max_speed} rpm",
                )
            self.set_max_speed(rpm)
        self._v[key] = value
        if index == 0x6040:
            self._controlword(value)
        elif index in (0x60E0, 0x60E1):
            self.axis.set_torque_limits(self._v[(0x60E0, 0)], self._v[(0x60E1, 0)])
        elif self.state == OPERATION_ENABLED and not self._halted:
            mode = self._mode
            if mode == PV and index in (0x60FF, 0x6083, 0x6084):
                self._run_pv()
            elif mode == PT and index in (0x6071, 0x6087):
                self._run_pt()
            elif mode == IP and key == (0x60C1, 1):
                self._ip_step(value)
        self._update_window()
        if self.on_write is not None:
            self.on_write(index, sub, value)

    def _write_mode(self, value: int) -> None:
        if value not in SUPPORTED_MODES:  # 6502h = 0x6D (L19250-19278)
            raise ObjectError(
                0x6060,
                0,
                ABORT_VALUE_RANGE,
                f"Modes of operation: {value} not supported (A3: 1 PP, 3 PV, 4 PT, 6 HM, 7 IP)",
            )
        if value == self._mode:
            return
        enabled = self.state == OPERATION_ENABLED
        if enabled and self.options.mode_change_while_enabled == "refuse":
            raise ObjectError(
                0x6060, 0, ABORT_DATA_STATE, "mode change refused in OPERATION ENABLED"
            )
        self._leave_mode()
        self._mode = value
        self._fe_latched = False
        if enabled:
            self._enter_mode(change=True)

    # ---- controlword -------------------------------------------------------------------
    def _controlword(self, cw: int) -> None:
        old = self._cw
        self._cw = cw
        rising = cw & ~old
        falling = old & ~cw
        if rising & 0x80:
            self._do_fault_reset()
        if cw & 0x80:  # fault reset command: the other bits are not evaluated [std]
            return
        if not cw & 0x02:
            cmd = _CMD_DISABLE_VOLTAGE
        elif not cw & 0x04:
            cmd = _CMD_QUICK_STOP
        elif not cw & 0x01:
            cmd = _CMD_SHUTDOWN
        elif not cw & 0x08:
            cmd = _CMD_SWITCH_ON
        else:
            cmd = _CMD_ENABLE
        self._command(cmd)
        if self.state == OPERATION_ENABLED:
            halt = bool(cw & 0x100)
            if halt != self._halted:
                self._halted = halt
                if halt:
                    self._apply_halt()
                else:
                    self._release_halt()
            self._mode_bits(cw, rising, falling)
        elif falling & 0x10:
            self._ack = False

    def _command(self, cmd: int) -> None:
        st = self.state
        if st == SWITCH_ON_DISABLED:
            if cmd == _CMD_SHUTDOWN:
                self._set_state(READY)  # 2
        elif st == READY:
            if cmd in (_CMD_DISABLE_VOLTAGE, _CMD_QUICK_STOP):
                self._set_state(SWITCH_ON_DISABLED)  # 7
            elif cmd == _CMD_SWITCH_ON:
                self._set_state(SWITCHED_ON)  # 3
            elif cmd == _CMD_ENABLE:
                self._set_state(SWITCHED_ON)  # 3 + 4 (L18276)
                self._enable()
        elif st == SWITCHED_ON:
            if cmd in (_CMD_DISABLE_VOLTAGE, _CMD_QUICK_STOP):
                self._set_state(SWITCH_ON_DISABLED)  # 10
            elif cmd == _CMD_SHUTDOWN:
                self._set_state(READY)  # 6
            elif cmd == _CMD_ENABLE:
                self._enable()  # 4
        elif st == OPERATION_ENABLED:
            if cmd == _CMD_QUICK_STOP:
                self._quick_stop(limit=False)  # 11
            elif cmd == _CMD_SWITCH_ON:
                self._disable(SWITCHED_ON, operation=True)  # 5
            elif cmd == _CMD_SHUTDOWN:
                self._disable(READY)  # 8
            elif cmd == _CMD_DISABLE_VOLTAGE:
                self._disable(SWITCH_ON_DISABLED)  # 9
        elif st == QUICK_STOP_ACTIVE:
            # 12 "Command Disable Voltage (OD 6040h : 0000 0110 or xxxx xx0x)" (L18262): a
            # shutdown (06h) leaves it for SWITCH ON DISABLED too
            if cmd in (_CMD_DISABLE_VOLTAGE, _CMD_SHUTDOWN):
                self._disable(SWITCH_ON_DISABLED)  # 12
            elif cmd == _CMD_ENABLE and not self._qs_disable:
                self._set_state(OPERATION_ENABLED)  # 16
                self._halted = bool(self._cw & 0x100)
                self._enter_mode(change=False)

    def _do_fault_reset(self) -> None:
        hook = self._fault_reset_hook
        ok = hook() if hook is not None else not self._fault
        if ok:
            self._fault = False
            self._fe_latched = False
            if self.state == FAULT:
                self._set_state(SWITCH_ON_DISABLED)  # 15

    # ---- transitions' actions ------------------------------------------------------------
    def _enable(self) -> None:
        """Transition 4: servo on and run the mode (L18252); refused while blocked."""
        if self._blocked and self.options.servo_blocked_state != "operation_enabled":
            return
        self._off_after_stop = False
        self._set_servo(True, "state")
        self._set_state(OPERATION_ENABLED)
        self._halted = bool(self._cw & 0x100)
        self._enter_mode(change=False)

    def _disable(self, new_state: str, operation: bool = False) -> None:
        """Transitions 5, 8, 9, 12: servo off (605Ch = 1 ramps first on 5)."""
        self._leave_operation()
        self._set_state(new_state)
        if operation and self._v[(0x605C, 0)] == 1 and self.axis.power:
            self._off_after_stop = True
            self.axis.ramp_stop(self._v[(0x6084, 0)])
        else:
            self._set_servo(False, "state")

    def _quick_stop(self, limit: bool) -> None:
        """Transition 11: controlword quick stop or limit switch (L18260)."""
        self._leave_operation(keep_homing=False)
        self._set_state(QUICK_STOP_ACTIVE)
        if limit:
            self._qs_disable = not self.options.limit_quick_stop_hold
            self.axis.ramp_stop(self.limit_decel_ms)
            return
        opt = self._v[(0x605A, 0)]
        if opt == 0:  # disable drive: servo off at once, then SWITCH ON DISABLED
            self._qs_disable = True
            self._set_servo(False, "state")
            self._set_state(SWITCH_ON_DISABLED)
            return
        self._qs_disable = opt <= 4
        self.axis.ramp_stop(self._stop_decel(opt if opt <= 4 else opt - 4))

    def _stop_decel(self, opt: int) -> float:
        """Deceleration (ms per 3000 rpm) of option code 1 (profile), 2 (quick stop),
        3/4 (current/voltage limit: the torque limit bounds a 1 ms ramp, L8329)."""
        if opt == 1:
            return self._v[(0x609A, 0)] if self._mode == HM else self._v[(0x6084, 0)]
        if opt == 2:
            return self._v[(0x6085, 0)]
        return 1.0

    def _leave_operation(self, keep_homing: bool = False) -> None:
        """Common bookkeeping when OPERATION ENABLED ends."""
        if self._homing_active and not keep_homing:
            self._homing_active = False
            if self.stop_homing is not None:
                self.stop_homing()
        self._ack = False
        self._pp_active = self._pp_queue = self._pp_waiting = None
        self._halted = False
        self._inhibited = False
        self._tr_since = None

    def _set_state(self, new: str) -> None:
        old = self.state
        if new == old:
            return
        self.state = new
        self.emit(StateChanged(self.clock(), old, new))

    def _set_servo(self, on: bool, cause: str) -> None:
        if on == self.servo_enable_requested:
            return
        self.servo_enable_requested = on
        if self._servo_hook is not None:
            self._servo_hook(on, cause)
        else:
            if not on:
                self.axis.stop_mode = self.shutdown_stop_mode
            self.axis.set_power(on)

    # ---- modes ---------------------------------------------------------------------------
    def _enter_mode(self, change: bool) -> None:
        """Start the mode's motion on enable (4), restart (16) or a mode change."""
        self._tr_since = None
        mode = self._mode
        if self._halted:
            self._apply_halt()
        elif mode == PV:
            self._run_pv()
        elif mode == PT:
            self._run_pt()
        elif change:
            self.axis.ramp_stop(self._v[(0x6084, 0)])
        elif self.axis.mode != "stop":  # a stop ramp (a quick stop's 6085h, 16) runs on to
            self.axis.hold()            # standstill and holds there: no jump to a hold
        # no set-point yet in this mode: a relative one (bit 6) counts from where the demand
        # is when it is taken, not from where it was at the change (the ramp still ran)
        self._pp_last = None

    def _leave_mode(self) -> None:
        if self._mode == HM and self._homing_active:
            self._homing_active = False
            if self.stop_homing is not None:
                self.stop_homing()
        self._ack = False
        self._pp_active = self._pp_queue = self._pp_waiting = None
        self._ip_target = None

    def _run_pv(self) -> None:
        v = self._v
        self.axis.run_velocity(v[(0x60FF, 0)] / 10.0, v[(0x6083, 0)], v[(0x6084, 0)])

    def _run_pt(self) -> None:
        self.axis.run_torque(self._v[(0x6071, 0)], self._v[(0x6087, 0)])

    def _ip_step(self, pos_puu: int) -> None:
        unit, index = self._v[(0x60C2, 1)], self._v[(0x60C2, 2)]
        period = round(unit * 10.0**index * S) if unit > 0 else MS  # L19089-19113
        target = self.axis.origin + puu_to_counts(pos_puu, self._num, self._den)
        self._ip_target = target
        demand = self.axis.demand
        if (self._pl and target > demand) or (self._nl and target < demand):
            return  # PL/NL forbid running that way in every mode (L15188-15191): the stop holds
        self.axis.interpolate_to(target, max(period, 1))

    def _apply_halt(self) -> None:
        """Halt (bit 8): decelerate per 605Dh (default profile deceleration) and hold."""
        if self._mode == PT:
            self.axis.run_torque(0, self._v[(0x6087, 0)])
            return
        if self._mode == HM and self._homing_active:
            self._homing_active = False
            if self.stop_homing is not None:
                self.stop_homing()
        self.axis.ramp_stop(self._stop_decel(self._v[(0x605D, 0)]))

    def _release_halt(self) -> None:
        mode = self._mode
        if mode == PV:
            self._run_pv()
        elif mode == PT:
            self._run_pt()
        elif mode == PP and self._pp_active is not None:
            self._start_pp(self._pp_active)

    def _mode_bits(self, cw: int, rising: int, falling: int) -> None:
        mode = self._mode
        if falling & 0x10:
            self._ack = False
            self._pp_waiting = None  # withdrawn before it was acknowledged (pp_ack_when_run)
            if mode == HM and self._homing_active and self.options.homing_stop_on_bit4_fall:
                self._homing_active = False
                if self.stop_homing is not None:
                    self.stop_homing()
        if not rising & 0x10:
            return
        if mode == PP:
            self._new_setpoint(cw)
        elif mode == HM:
            if self._halted:  # bit 8 "interrupt homing operation" (L18232): a start edge
                return        # while halted starts nothing (PP waits the same way)
            self._hm_attained = self._hm_error = False
            self._homing_active = True
            if self.start_homing is not None:
                self.start_homing()

    def _new_setpoint(self, cw: int) -> None:
        """PP bit 4 rising edge (L17143-17206, L18235-18241). Refused, unacknowledged, while
        `refuse_setpoint()` says so (the position counters overflowed: AL235, counters.py)."""
        if self.refuse_setpoint is not None and self.refuse_setpoint():
            return
        v = self._v
        num, den = self._num, self._den
        speed = min(puu_per_s_to_rpm(v[(0x6081, 0)], num, den, self.axis.cpr), v[(0x607F, 0)] / 10)
        req = (puu_to_counts(v[(0x607A, 0)], num, den), bool(cw & 0x40), speed,
               v[(0x6083, 0)], v[(0x6084, 0)])
        busy = self._pp_active is not None and not self._pp_done()
        if not busy or cw & 0x20:  # idle, or change set immediately (bit 5)
            self._pp_queue = self._pp_waiting = None
            self._start_pp(self._pp_setpoint(req))
        elif self.options.pp_ack_when_run:
            if self._pp_waiting is None:  # acknowledged and worked out when it runs
                self._pp_waiting = req    # (L17172-17174)
            return
        elif self._pp_queue is None:
            self._pp_queue = self._pp_setpoint(req)  # [std] a buffer of one, acknowledged now
        else:
            return  # one set-point already waits: not acknowledged
        self._ack = True
        self._tr_since = None

    def _pp_setpoint(self, req: tuple[float, bool, float, int, int]
                     ) -> tuple[float, float, int, int]:
        """(target counts, rpm, 6083h, 6084h) of a set-point as it is taken: a relative one
        (bit 6) from the base `pp_relative_base` names, as it stands now."""
        delta, relative, speed, acc, dec = req
        if relative:
            base = self.options.pp_relative_base
            if base == "target" and self._pp_last is not None:
                ref = self._pp_last
            elif base in ("target", "demand"):  # no set-point yet: the demand now
                ref = self.axis.demand
            else:
                ref = self.axis.position
            target = ref + delta
        else:
            target = self.axis.origin + delta
        self._pp_last = target
        return (target, speed, acc, dec)

    def _start_pp(self, sp: tuple[float, float, int, int]) -> None:
        self._pp_active = sp
        self._inhibited = False
        if not self._halted:
            self.axis.move_to(*sp)

    def _pp_done(self) -> bool:
        ax = self.axis
        return ax.mode == "position" and ax.at_target

    def _homing_busy(self) -> bool:
        return self._mode == HM and self._homing_active

    # ---- per-substep work ----------------------------------------------------------------
    def after_step(self) -> None:
        """Call after every `axis.step()`: PP queue, run inhibit at a limit, end of
        quick-stop / fault-reaction / disable-operation ramps, bit 10 windows."""
        st = self.state
        ax = self.axis
        if st == OPERATION_ENABLED:
            if (
                (self._pp_queue is not None or self._pp_waiting is not None)
                and not self._halted
                and self._mode == PP
                and self._pp_done()
            ):
                if self._pp_waiting is not None:  # acknowledged as it starts (L17172-17174)
                    sp = self._pp_setpoint(self._pp_waiting)
                    self._pp_waiting = None
                    self._ack = True
                    self._tr_since = None
                else:
                    sp = self._pp_queue
                self._pp_queue = None
                self._start_pp(sp)
            if not self._inhibited and (self._pl or self._nl) and not self._homing_busy():
                vd = ax.demand_velocity if ax.mode != "torque" else ax.velocity
                if (self._pl and vd > 0.0) or (self._nl and vd < 0.0):  # run inhibit (bits 14/15)
                    self._inhibited = True
                    ax.ramp_stop(self.limit_decel_ms)
        elif st == QUICK_STOP_ACTIVE:
            if self._qs_disable and not ax.moving:
                self._set_servo(False, "state")
                self._set_state(SWITCH_ON_DISABLED)
        elif st == FAULT_REACTION_ACTIVE:
            if not ax.moving:
                self._set_servo(False, "fault")
                self._set_state(FAULT)  # 14
        elif self._off_after_stop and not ax.moving:
            self._off_after_stop = False
            self._set_servo(False, "state")
        if self._inhibited and ax.mode != "stop" and ax.mode != "hold":
            self._inhibited = False
        self._update_window()

    # ---- target reached ------------------------------------------------------------------
    def _fe_puu(self) -> int:
        ax = self.axis
        num, den = self._num, self._den
        # 60F4h = 6062h - 6064h (L19193): the IP filters' lag included
        return round(counts_to_puu(ax.interpolator_demand, num, den)) - round(
            counts_to_puu(ax.user_position, num, den)
        )

    def _window_time(self) -> int:
        return self._v[(0x606E, 0)] if self._mode == PV else self._v[(0x6068, 0)]

    def _window_condition(self) -> bool | None:
        """Inside the target window now (None: this mode has no timed window)."""
        if self.state != OPERATION_ENABLED or self._halted:
            return None
        mode = self._mode
        ax = self.axis
        if mode == PP and self._pp_active is not None:
            if self._pp_queue is not None or self._pp_waiting is not None:
                return False  # a buffered set-point still to run: its target is not reached
            # the target (607Ah) minus the feedback inside 6067h, whether or not the profile
            # has ended (L18469)
            err = abs(self._pp_active[0] - ax.position) * self._den / self._num
            return err < self._v[(0x6067, 0)]
        if mode == IP and self._ip_target is not None:
            err = abs(self._ip_target - ax.position) * self._den / self._num
            return err < self._v[(0x6067, 0)]
        if mode == PV:
            err = abs(round(ax.velocity_rpm * 10) - self._v[(0x60FF, 0)])
            return err < self._v[(0x606D, 0)]  # L18536
        return None

    def _update_window(self) -> None:
        cond = self._window_condition()
        if not cond:
            self._tr_since = None
        elif self._tr_since is None:
            self._tr_since = self.clock()

    def _target_reached(self) -> bool:
        ax = self.axis
        if self.state == QUICK_STOP_ACTIVE or self._halted:
            return not ax.moving
        cond = self._window_condition()
        if cond is None:
            mode = self._mode
            if mode == PT:
                return ax.at_target
            if mode == HM:
                return not self._homing_active and not ax.moving
            return not ax.moving
        since = self._tr_since
        return (
            bool(cond) and since is not None and (self.clock() - since >= self._window_time() * MS)
        )
