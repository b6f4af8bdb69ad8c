"""The virtual Delta ASDA-A3: parameters, DI/DO, CiA 402, motion, brake, STO, alarms.

`Drive` composes the components of this package and is the only class faces and tests
talk to (docs/architecture.md). It is pure and deterministic: time moves only through
`advance()` / `advance_to()`; motion is integrated in substeps of
`ModelOptions.motion_step_ms` aligned to a fixed grid (so results do not depend on how the
caller slices time), and every timer fires at its own deadline.

Servo logic (choices in docs/manual-choices.md):
* servo on when requested (DI.SON L15079, or CiA 402 OPERATION ENABLED), no servo-off alarm
  (chapter 13 "servo state OFF" column), both STO channels present;
* EMGS -> AL013 (WARN, servo off, clears itself when released: L15184, L19338, L19557);
  NL/PL -> AL014/AL015 (WARN, servo stays on; motion towards the limit stops with the
  P5.003 X/Y deceleration: L15188-15191, L8329, L11084-11100);
* DO.SRDY while no ALM-class alarm and the main circuit is in (L15263), DO.SON while the
  servo is on (L15266), ZSPD |v| < P1.038 (L15269), TSPD |v| > P1.039 (L15272, L8426),
  TPOS |error| < P1.054 in PT/PR only (L15275),
  TQL while the torque is held at a limit, not in T/Tz (L15278),
  ALRM/WARN from the alarm classes (L15282, L15307), BRKR from `brake.py`.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

from hil.model.absolute import BATTERY_MONITOR, AbsoluteEncoder, AbsoluteOptions
from hil.model.alarms import AlarmManager, AlarmOptions
from hil.model.brake import Brake, HoldingBrake
from hil.model.canopen_init import HOME_OFFSET_INIT, load_canopen_init
from hil.model.capture import attach_capture
from hil.model.cia402 import Cia402, Cia402Options
from hil.model.comm_supervision import CommSupervision
from hil.model.compare import attach_compare
from hil.model.core import Hooks, new_data_array
from hil.model.counters import attach_counters
from hil.model.di_functions import attach_di_functions
from hil.model.dio import DigitalIO
from hil.model.errors import (
    ModelError,
    ObjectError,
    OutOfRange,
    ParamError,
    ProtectedParameter,
    ReadOnly,
    ServoOnLocked,
    UnknownFunction,
    UnknownParameter,
)
from hil.model.events import (
    AlarmChanged,
    BrakeChanged,
    DoChanged,
    DriveEvent,
    FdbkChanged,
    InputChanged,
    ParamChanged,
    PowerCycled,
)
from hil.model.homing import attach_homing
from hil.model.mechanics import Mechanics
from hil.model.monitors import attach_monitors
from hil.model.motion import Axis, counts_to_puu, puu_to_counts
from hil.model.options import ModelOptions
from hil.model.params import ParameterStore
from hil.model.pr_engine import PR_MODES, attach_pr
from hil.model.pulse_train import attach_pulse_train, gear_problem
from hil.model.sto import Sto
from hil.model.timebase import Scheduler, ms
from hil.profile.dio import mode_dio_defaults
from hil.protocol.canopen import (
    ABORT_DATA_STATE,
    ABORT_DATA_STORE,
    ABORT_NO_OBJECT,
    ABORT_READ_ONLY,
    ABORT_VALUE_HIGH,
    ABORT_VALUE_LOW,
    ABORT_VALUE_RANGE,
)
from hil.protocol.cia402 import MODE_NAMES
from hil.units import MS

# WARN-class alarms that mean the main circuit is not powered: SRDY off (L15263, L19509, L19604)
MAIN_POWER_ALARMS = frozenset({"AL003", "AL022"})
P2030_FUNCTIONS = frozenset({1, 5, 6, 7})  # P2.030 functions n, ended by -n (L9492-9505)
SPEED_EPS_RPM = 1e-6  # speed comparisons (ZSPD, TSPD) ignore float noise below this

# Physical wiring of the virtual bench's sensors: function -> (DI number, contact type).
# Limit switches are normally closed (open at the limit), the home sensor normally open.
DEFAULT_SENSORS: dict[str, tuple[int, str]] = {"NL": (6, "nc"), "PL": (7, "nc"), "ORGP": (9, "no")}


class Drive:
    """One virtual ASDA-A3 (A3-M: CANopen, RS-485, STO)."""

    def __init__(
        self,
        *,
        options: ModelOptions | None = None,
        mechanics: Mechanics | None = None,
        state_path: Path | str | None = None,
        t0: int = 0,
        name: str = "drive1",
        inputs: dict[int, bool] | None = None,
        sensors: dict[str, tuple[int, str]] | None = None,
        params: dict[str, int] | None = None,
    ) -> None:
        self.name = name
        self.options = options = options or ModelOptions()
        self.sched = Scheduler(t0)
        self.mech = mechanics or Mechanics()
        self.state_path = Path(state_path) if state_path else None
        if self.state_path:
            self.state_path.mkdir(parents=True, exist_ok=True)
        self._subs: list[Callable[[DriveEvent], None]] = []
        self.brake_line: int | None = None  # DO line of the brake coil, resolved at power-up
        self.step_ns = max(1, ms(options.motion_step_ms))
        self._axis_t = t0  # model time of the axis state (the last motion step)
        self._ahead = False  # the axis state is that of the end of the cycle in progress
        self.servo_on = False
        self.powered = False  # True from the end of `_boot()`: no servo on before power-up

        self.sensors = dict(DEFAULT_SENSORS if sensors is None else sensors)
        self._make_params(params)
        self._make_parts(options)
        self._make_absolute(options)
        self._wire_functions()
        for n, closed in (inputs or {}).items():
            self.dio.set_input(n, closed, settled=True)  # present before power-up
        self._update_sensors(force=True)
        self.homing = attach_homing(self, absolute=self.absolute)  # homing methods (docs/homing.md)
        # the 32-bit PUU counters: overflow -> HOME off, OVF, AL235 (counters.py)
        self.counters = attach_counters(self, self.homing.lose_home)
        self.homing.on_homed = self.counters.clear
        self.cia402.refuse_setpoint = self.counters.refuse
        self.pr = attach_pr(self, homing=self.homing, counters=self.counters)  # PR#1-#99 (ch. 7)
        self.capture = attach_capture(self, pr=self.pr)  # CAPTURE on DI7 (§7.2.2, docs/capture.md)
        # COMPARE on DO4 (§7.2.3, docs/capture.md)
        self.compare = attach_compare(self, capture=self.capture, pr=self.pr)
        # PFQS, JOG, TRQLM/SPDLM, ZCLAMP, CCLR, GAINUP
        self.difunc = attach_di_functions(self, absolute=self.absolute)
        self.pulse = attach_pulse_train(self)  # PT input, OA/OB/OZ output (docs/pulse.md)
        self.difunc.pulse = self.pulse  # CCLR clears the PT error too (L9749)
        # the monitor codes the parts above do not own, P0.044, P0.008 (monitors.py)
        self.monitors = attach_monitors(self)
        self._boot()

    # ------------------------------------------------------------------ construction
    def _make_params(self, params: dict[str, int] | None) -> None:
        """The parameter store, with a bench's configured values (chapter 8)."""
        self.params = ParameterStore(
            retained_path=self.state_path / "params.json" if self.state_path else None
        )
        self.params.servo_on = lambda: self.servo_on
        # read every motion step: AL009 (P2.035), ZSPD, TSPD, TPOS (P1.038, P1.039, P1.054),
        # the control mode (P1.001)
        self._step_params = self.params.cached("P2.035", "P1.038", "P1.039", "P1.054",
                                               "P1.001")
        self.params.subscribe(lambda n, v: self.emit(ParamChanged(self.sched.now, n, v)))
        for name_, value in (params or {}).items():
            self.params.write(name_, value)
        if params:
            self.params.power_cycle()  # bench-given values act like configured drives
        self._mode_dio_defaults()  # this power-up's P1.001.U (given, or a file left with it)

    def _make_parts(self, options: ModelOptions) -> None:
        """Alarms, DI/DO, axis, brake (BRKR) and holding brake, STO, CiA 402."""
        override = {}
        if options.dev_al501_cleared_by_arst:
            override = {"AL501": "reset", "AL502": "reset"}
        if options.pfqs_clear == "reset":  # the DI table's reading (L15253), not L20145/L20157
            override.update({"AL35F": "reset", "AL3CF": "reset"})
        self.alarms = AlarmManager(
            None, self.sched, self.params, self._on_alarm,
            AlarmOptions(override, fault_reset_listed=options.fault_reset_clears == "listed"),
            on_reset=self.emit,
        )
        # P2.009 filter (L9229-9236): "stable" drops bounces; deviation knob: a pure delay
        filter_mode = "delay" if self.options.dev_di_filter_delay_only else "stable"
        self.dio = DigitalIO(self.params, self.sched, self._on_dio_event, name=self.name,
                             filter_mode=filter_mode,
                             extra_delay_ns=round(self.options.dev_di_filter_extra_ms * MS),
                             mapping_on_write=self.options.mapping_effect == "write")
        self.axis = Axis(self.mech)
        self.brake = Brake(
            self.sched,
            self.params.get,
            lambda: self.axis.velocity_rpm,
            lambda v: self._set_do("BRKR", v),
            options,
        )
        # The bench's mechanical brake hangs on one DO line (`Mechanics.brake_do`).
        self.holding_brake = HoldingBrake(
            self.sched,
            self._on_clamp,
            release_ms=self.mech.brake_release_ms,
            engage_ms=self.mech.brake_engage_ms,
        )
        self.sto = Sto(
            self.sched,
            self.alarms.set_cause,
            self._on_torque_cut,
            lambda c: self.emit(FdbkChanged(self.sched.now, c)),
            options,
        )
        self.cia402 = Cia402(
            self.axis,
            clock=lambda: self.sched.now,
            emit=self.emit,
            options=Cia402Options(**options.extra.get("cia402", {})),
            fault_reset=self._fault_reset,
            on_servo_request=lambda _on, _cause: self._update_servo(source="cia402"),
            on_write=self._on_object_written,
        )
        # CANopen supervision (AL111, AL112, AL180, AL185, AL301, AL3E2, AL3E3), fed by the face
        self.comm = CommSupervision(options, self.raise_alarm, lambda: self.params.get("P3.009"))
        self.hooks = Hooks()  # where the parts hook into the cycle (core.py)
        self.array = new_data_array()  # shared by PR, CAPTURE and COMPARE (L5097)
        # its EEPROM copy: written only by P2.008 = 30 / 35 (L9225); the array is RAM and
        # comes back from this copy at power-up (L5097)
        self.array_eeprom = new_data_array()
        self._hold_timer = None
        self._was_requested = False  # Servo On asked at the last _update_servo (AL053)
        self._p2030: set[int] = set()  # P2.030 functions on (1, 5, 6, 7: `_p2030_written`)
        self._dout_cache: dict[str, bool] = {}
        self._sensor_state: dict[str, bool] = {}
        self._sensor_key: tuple[bool, bool, bool] | None = None  # (NL, PL, ORGP) last seen

    def _make_absolute(self, options: ModelOptions) -> None:
        """The absolute encoder and its DI/DO handshake (section 10.3), restored from the
        drive's state directory."""
        self.absolute = AbsoluteEncoder(
            self.sched,
            self.params,
            set_cause=self.alarms.set_cause,
            clear_alarm=self.alarms.clear,
            set_output=self.dio.set_do_function,
            set_overlay=lambda on: self.dio.overlay() if on else self.dio.clear_overlay(),
            read_absq=lambda: self.dio.function_active("ABSQ"),
            speed_rpm=lambda: self.axis.velocity_rpm,
            motor_counts=lambda: round(self.axis.position),
            clear_position_error=self.clear_position_error,
            options=AbsoluteOptions.from_dict(options.extra.get("absolute")),
        )
        self._abs_file = self.state_path / "absolute.json" if self.state_path else None
        if self._abs_file and self._abs_file.exists():
            self.absolute.restore(json.loads(self._abs_file.read_text()))
        self.absolute.on_origin = self._follow_absolute
        self._follow_absolute()  # a restart keeps the absolute coordinate (L16391-16397)
        self.hooks.step.append(self.absolute.refresh)
        self.hooks.monitors[BATTERY_MONITOR] = self.absolute.battery_monitor
        for fn in ("ABSE", "ABSC", "ABSQ"):
            self.dio.on_function(fn, getattr(self.absolute, f"on_{fn.lower()}"))

    def _wire_functions(self) -> None:
        """What the DI functions do (table 8.1) and the parameters that act at once."""
        self.dio.on_function("SON", lambda _a: self._update_servo())
        self.dio.on_function("EMGS", lambda a: self.alarms.set_cause("AL013", a))
        self.dio.on_function("NL", lambda a: self._on_limit("NL", a))
        self.dio.on_function("PL", lambda a: self._on_limit("PL", a))
        self.dio.on_function("ORGP", self.cia402.set_home_switch)
        self.dio.on_function("ARST", self._on_arst)
        self.params.on_write("P2.030", self._p2030_written)
        self.params.on_write("P2.008", self._special_write)
        # the DO functions follow their parameters at standstill too (ZSPD P1.038, TSPD
        # P1.039, TPOS P1.054, MC_OK hold / AL380 P1.048: L8608-8632, L15269-15275)
        for name_ in ("P1.038", "P1.039", "P1.048", "P1.054"):
            self.params.on_write(name_, lambda *_: self.refresh_outputs())
        for name_ in ("P1.068", "P1.036"):  # IP smoothing (L17232)
            self.params.on_write(name_, lambda *_: self._ip_filters())
        self._ip_filters()
        # P1.055 (no power-cycle mark, L8700) limits every mode at once (L4034), and 607Fh /
        # 6080h read it (L18713-18735)
        self.params.on_write("P1.055", lambda _n, _o, new: self.cia402.set_max_speed(new))
        # 6093h sub 1/2 are P1.044/P1.045 (L18838-18854): a write of the parameter, however
        # it came (212Ch, Modbus, a PR WRITE), is the CiA 402 side's gear at once too
        for name_ in ("P1.044", "P1.045"):
            self.params.on_write(name_, lambda *_: self.cia402.set_gear(
                self.params.get("P1.044"), self.params.get("P1.045")))

    # ------------------------------------------------------------------ public API
    @property
    def now(self) -> int:
        return self.sched.now

    def subscribe(self, fn: Callable[[DriveEvent], None]) -> Callable[[], None]:
        """Call `fn(event)` for every model event; returns an unsubscribe callable."""
        self._subs.append(fn)
        return lambda: self._subs.remove(fn) if fn in self._subs else None

    def advance(self, dt: int) -> None:
        """Let `dt` ns of model time pass."""
        self.advance_to(self.sched.now + dt)

    def advance_to(self, t: int) -> None:
        """Run the model up to time `t` (ns): timers at their deadlines, motion in substeps."""
        sched = self.sched
        while True:
            nxt = sched.next_deadline()
            stop = t if nxt is None or nxt > t else nxt
            self._integrate_to(stop)
            if sched.now >= t and (nxt is None or nxt > t):
                break
            self.commit_cycle()  # a timer inside a cycle may command the axis
            sched.run_due()
        sched.now = max(sched.now, t)

    def set_di(self, n: int, closed: bool) -> None:
        """Physical DI n (1..10): True = contact closed (24 V)."""
        self.commit_cycle()
        changed = self.dio.input_level(n) != bool(closed)
        self.dio.set_input(n, closed)
        if changed:  # the terminal edge, for the ground truth (a latch is judged against it)
            self.emit(InputChanged(self.sched.now, n, bool(closed)))

    def set_sto(self, channel: str, on: bool) -> None:
        """STO channel "A"/"B" (or "STO_A"/"STO_B"): True = 24 V present."""
        self.commit_cycle()
        self.sto.set_channel(channel, on)
        self._update_servo()

    def do(self, n: int) -> bool:
        """DO n (1..6): True = output transistor conducting."""
        return self.dio.do_level(n)

    def feedback_counts(self) -> float:
        """The motor position now, between two motion steps too: the encoder is read in
        hardware (a capture edge, the ground truth), not on the 1 ms command cycle."""
        ax = self.axis
        return ax.position + ax.velocity * (self.sched.now - self._axis_t) * 1e-9

    def fdbk(self) -> bool:
        """STO FDBK output: True = closed."""
        return self.sto.fdbk

    def read_object(self, index: int, sub: int = 0) -> int:
        """Value of a 2000h-2FFFh (parameter) or 6000h-6FFFh object."""
        if 0x2000 <= index <= 0x2FFF:
            if sub != 0:
                raise ObjectError(index, sub, 0x06090011, "parameter objects have sub-index 0")
            return self.params.read(self._param_of(index, sub))
        if 0x6000 <= index <= 0x6FFF:
            return self.cia402.read(index, sub)
        raise ObjectError(index, sub, ABORT_NO_OBJECT, "object does not exist in the drive")

    def write_object(self, index: int, sub: int, value: int) -> None:
        """Write a 2000h-2FFFh or 6000h-6FFFh object; refusals carry the SDO abort code."""
        self.commit_cycle()
        if 0x2000 <= index <= 0x2FFF:
            name = self._param_of(index, sub)
            if name == "P3.001":  # over CANopen only digit Z is set, the others stay (L10542)
                # (of the value stored: a digit written before, waiting for the power cycle)
                value = (self.params.stored(name) & ~0x0F00) | (value & 0x0F00)
            try:
                self.params.write(name, value)
            except ObjectError:
                raise
            except ModelError as exc:  # ParamError, UnknownFunction (P2.010 = 0x0007) ...
                raise ObjectError(index, sub, _abort_for(exc, value), str(exc)) from exc
            return
        if index == 0x6093 and sub in (1, 2):  # 6093h is P1.044 / P1.045 (L18838-18854):
            if self.cia402.servo_enable_requested:  # written as the parameter, its range,
                raise ObjectError(index, sub, ABORT_DATA_STATE,  # ▲ and refusals included
                                  "e-gear not writable while servo on (▲, L6721)")
            try:  # (helper-127: a write here skipped them, and a parameter write never
                self.params.write("P1.044" if sub == 1 else "P1.045", value)  # reached here)
            except ObjectError:
                raise
            except ModelError as exc:
                raise ObjectError(index, sub, _abort_for(exc, value), str(exc)) from exc
            return
        if 0x6000 <= index <= 0x6FFF:
            try:
                self.cia402.write(index, sub, value)
            except ObjectError:
                raise
            except ModelError as exc:  # a refusal from a hook behind the object
                raise ObjectError(index, sub, _abort_for(exc, value), str(exc)) from exc
            self._update_servo()
            return
        raise ObjectError(index, sub, ABORT_NO_OBJECT, "object does not exist in the drive")

    def raise_alarm(self, code: str) -> None:
        """An alarm a face detected (AL020 RS-485 timeout, AL180 heartbeat, ...)."""
        self.commit_cycle()
        extra = self.options.dev_comm_timeout_extra_ms
        if code == "AL020" and extra > 0:  # deviation: AL020 late by `extra` ms
            self.sched.after(round(extra * 1e6), lambda: self._raise_face_alarm(code))
            return
        self._raise_face_alarm(code)

    def modbus_comm_error(self, exception_code: int) -> None:
        """The Modbus face answered an exception: AL019 when the code is an "incorrect
        communication address / value" (L19592-19596, option modbus_al019_exceptions)."""
        if exception_code in self.options.modbus_al019_exceptions:
            self._raise_face_alarm("AL019")

    def _raise_face_alarm(self, code: str) -> None:
        self.alarms.raise_alarm(code)
        if code == "AL020" and self.params.get("P3.003") == 1 and self.servo_on:
            self.axis.ramp_stop(self.p5003_decel(5))  # P3.003 = 1: P5.003.B ramp (L10559)

    def nmt_reset(self, kind: str) -> None:
        """A CANopen NMT reset ("reset node" / "reset communication"): AL401 if the servo is
        on (L20183-20187); clears the alarms an NMT reset clears (AL180 ..., L20025) and
        re-initialises the CiA 402 state machine: FAULT if a servo-off alarm remains, else
        SWITCH ON DISABLED (transition 15 "Alarm 清除", L18265). Reset node also returns the
        6xxxh objects to their power-up values (CiA 301). Choice: docs/manual-choices.md."""
        self.commit_cycle()
        servo_on = self.servo_on
        self.alarms.reset("nmt")  # an earlier AL401 too (L20186), not the one this raises
        if servo_on:
            self.alarms.raise_alarm("AL401")
        if self.options.nmt_reset_reinit_402:
            if kind == "reset node" and not self.servo_on:
                self.cia402.power_on()
            else:
                self.cia402.reinit()
        if load_canopen_init(self.params):  # "或是進行通訊重置後" (L10731)
            self.axis.zero_speed_rpm = self.params.get("P1.038") / 10.0
            self.axis.stop_mode = (self.params.get("P1.032") >> 4) & 0xF
            self._mirror_params()
            self.cia402.write(0x607C, 0, HOME_OFFSET_INIT)
        elif self.options.nmt_reset_reinit_402 and kind == "reset node":
            self._mirror_params()  # after power_on(), which resets 6093h to 1/1

    def nmt_stop(self) -> None:
        """NMT Stop: the node takes no RPDO, SDO or controlword any more (L17089-17095).
        The manual names no motion reaction; `nmt_stop_action` "servo_off" (default)
        disables the CiA 402 drive (P1.032.Y stop, BRKR engages) rather than leave an
        axis turning that only NMT can reach (docs/manual-choices.md)."""
        self.commit_cycle()
        if self.options.nmt_stop_action == "servo_off" and self.servo_on:
            self.cia402.comm_disable()
            self._update_servo(source="cia402")

    def power_cycle(self, *, battery: bool = True, off_for: int = 0) -> None:
        """Switch the drive off (for `off_for` ns) and on again. While it is off nothing of
        the firmware runs: no torque (a P1.043 hold ends), no BRKR (a pending P1.042 release
        is dropped), no DO conducts, no STO timer runs."""
        self._servo_off("normal", None, immediate=True)
        self._end_torque_hold()
        self.axis.set_power(False)
        self.brake.reset()
        self.sto.power_off()
        self.monitors.account()  # P0.008's hours up to the power-off
        self.monitors.cn2.offset = 0  # P5.016's offset is RAM (monitors.AxisPositionCn2)
        self.powered = False
        self.dio.power_off()
        self.holding_brake.coil(False)  # no control power: no DO conducts, the brake engages
        self.advance(off_for)
        self.params.power_cycle()
        self._p2030.clear()  # P2.030's functions end with the power (L9505)
        self.params.no_eeprom = False
        self._mode_dio_defaults()
        self.array[:] = self.array_eeprom  # RAM: lost at power-off (L5097), in place (shared)
        self.dio.power_cycle()
        self.absolute.power_cycle(battery)
        self.absolute.on_abse(self.dio.function_active("ABSE"))
        if not (self.absolute.enabled and self.absolute.coordinate_valid):
            # an incremental coordinate (P2.069 = 0, or the absolute one lost: AL060 /
            # AL06A, L16123, L19796) starts at 0: nothing kept the position while off
            self.axis.set_user_position(0)
        self._follow_absolute()
        self.alarms.power_cycle()
        self.brake.reset()
        self.sto.reset()
        self.axis.set_power(False)
        self.emit(PowerCycled(self.sched.now, battery))
        self._boot()

    def _mode_dio_defaults(self) -> None:
        """P1.001.U = 1 "模式切換時，DIO (P2.010 ~ P2.022) 可重置為相對應各模式之預設值"
        (L7811-7813; "請將 P1.001.U 設為 1，重上電後可重置", L1887): at the power-up where
        it is in effect, the mapping takes the mode's defaults (tables L1862-1913); U itself
        is "斷電不保持": it reads 0 afterwards."""
        p1001 = self.params.get("P1.001")
        if (p1001 >> 12) & 0xF != 1:
            return
        for name, value in mode_dio_defaults(p1001 & 0xFF).items():
            self.params.set_internal(name, value)
        self.params.set_internal("P1.001", p1001 & 0x0FFF)
        self.params.persist()  # kept as any power-up's values are

    def _special_write(self, _name: str, _old: int, new: int) -> None:
        """P2.008 = 30 or 35: store the data array (COMPARE, CAPTURE, E-Cam) in EEPROM
        (L9225, L5097); 10: reset the parameters, then a power cycle (L9222)."""
        if new in (30, 35):
            self.array_eeprom[:] = self.array
        elif new == 10:
            self.params.factory_reset()

    def write_pdo_object(self, index: int, sub: int, value: int) -> None:
        """`write_object` of an RPDO-mapped object: a parameter goes to EEPROM only with
        P3.011.X = 1 ("X = 0：使用 PDO 寫入參數時，不會將參數存入 EEPROM", L10764-10768)."""
        # (a 6xxxh object that is a parameter too, 6093h = P1.044 say, is kept alike)
        ram = not self.params.get("P3.011") & 0x1
        with self.params.ram_only_writes(ram):
            self.write_object(index, sub, value)

    def close(self) -> None:
        """Save retained state (the process is going away)."""
        if self.state_path:
            self.params.save()
        if self._abs_file:
            self._abs_file.write_text(json.dumps(self.absolute.to_dict()))

    def snapshot(self) -> dict[str, Any]:
        """Ground truth for the recorder: what a real bench cannot see directly."""
        ax = self.axis
        fb = self.feedback_counts()
        g44, g45 = self.params.get("P1.044"), self.params.get("P1.045")
        return {
            "t": self.sched.now,
            "state": self.cia402.state,
            "mode": MODE_NAMES.get(self.cia402.mode, str(self.cia402.mode)),
            "servo_on": self.servo_on,
            "torque_enabled": ax.power,
            "position_puu": round(counts_to_puu(fb - ax.origin, g44, g45)),
            "position_counts": round(fb),
            "speed_rpm": round(ax.velocity_rpm, 3),
            "torque_pct": round(ax.torque / 10.0, 2),
            "following_error_counts": round(ax.following_error),
            "brkr": self.brake.brkr,
            "brake_released": not self.holding_brake.clamped,
            "sto_a": self.sto.a,
            "sto_b": self.sto.b,
            "alarms": list(self.alarms.active),
            "abs_turns": self.absolute.turns,
            "abs_single_turn": self.absolute.single_turn,
            "statusword": self.cia402.statusword,
            "do": self.dio.do_levels(),  # DO1..DO6
            # terminal levels DI1..DI10 (the bench's sensors drive some: ORGP, NL, PL)
            "di": self.dio.input_levels(),
            "homing_phase": self.homing.phase,
            "gain_switched": self.difunc.gain_switched,
            **self.pulse.snapshot(),
        }

    # ------------------------------------------------------------------ internals
    def emit(self, event: DriveEvent) -> None:
        for fn in list(self._subs):
            fn(event)

    def _boot(self) -> None:
        """After power on: SRDY, outputs, and the CiA 402 automatic transitions 0/1."""
        for hook in self.hooks.boot:
            hook()
        canopen_init = load_canopen_init(self.params)  # P3.012.Z = 0 (L10731-10745)
        # AL045: an e-gear ratio out of range appears at power-up and goes only with a power
        # cycle once it is right (L19699-19703; alarms.power_cycle cleared it before this)
        if gear_problem(self) is not None:
            self.alarms.raise_alarm("AL045")
        # Level-triggered DI functions act from power-up (EMGS/NL/PL -> AL013-AL015,
        # L2829-2831, L15184-15191), before anything may switch the servo on.
        if not self.options.dev_di_levels_ignored_at_power_up:
            self.dio.apply_levels()
        self.monitors.account()
        self.powered = True
        self.axis.zero_speed_rpm = self.params.get("P1.038") / 10.0
        self.axis.stop_mode = (self.params.get("P1.032") >> 4) & 0xF
        self._set_do("SRDY", self._srdy())
        self._set_do("ALRM", self.alarms.alrm)
        self._set_do("WARN", self.alarms.warn)
        self._set_do("SON", False)
        self._set_do("BRKR", False)
        self._refresh_speed_outputs()
        self._wire_brake()
        self.cia402.power_on()
        self.pulse.power_up()
        self._mirror_params()  # after power_on(), which resets 6093h to 1/1
        if canopen_init:
            self.cia402.write(0x607C, 0, HOME_OFFSET_INIT)  # home offset (L10744)
        self.cia402.set_voltage(True)
        self._on_alarm(None)

    def _wire_brake(self) -> None:
        """Power-up: which DO line the brake coil hangs on, and its level now."""
        bdo = self.mech.brake_do
        if bdo == "auto":
            lines = [n for n in range(1, 7) if self.dio.do_function(n) == "BRKR"]
            bdo = lines[0] if lines else None  # BRKR mapped to no DO: no brake (L15286)
        self.brake_line = bdo
        self.holding_brake.power_up(None if bdo is None else self.dio.do_level(bdo))

    def _on_dio_event(self, event: DriveEvent) -> None:
        if isinstance(event, DoChanged) and event.n == self.brake_line:
            self.holding_brake.coil(event.level)  # the bench's wiring, not the function
        self.emit(event)

    def _mirror_params(self) -> None:
        """Parameters the CiA 402 objects mirror: gear 6093h, max speed, limit ramps."""
        self.cia402.set_gear(self.params.get("P1.044"), self.params.get("P1.045"))
        self.cia402.set_max_speed(self.params.get("P1.055"))
        self.cia402.limit_decel_ms = min(self.p5003_decel(0), self.p5003_decel(1))

    def _ip_filters(self) -> None:
        """P1.068 (moving filter, ms, L8826-8840) then P1.036 (S-curve, ms, L8358-8365) on IP
        set-points, as the IP section recommends (L17232; option `ip_smoothing`)."""
        step_ms = self.step_ns / MS  # one sample per model step
        self.axis.ip_windows = tuple(
            max(1, round(self.params.get(name) / step_ms)) for name in ("P1.068", "P1.036")
        ) if self.options.ip_smoothing == "manual" else ()

    def _on_object_written(self, index: int, sub: int, value: int) -> None:
        if index == 0x6060:  # the mode decides which DI functions act (di_functions.py)
            self.difunc.refresh()
        if index in (0x607F, 0x6080):  # 6080h "is P1.055", 607Fh = P1.055 x 10 (L18713-18735)
            rpm = round(value / 10) if index == 0x607F else value
            if self.params.read("P1.055") != rpm:
                self.params.set_as_written("P1.055", rpm)

    def _param_of(self, index: int, sub: int) -> str:
        try:
            return self.params.by_od_index(index).param
        except UnknownParameter as exc:
            raise ObjectError(index, sub, ABORT_NO_OBJECT, str(exc)) from exc

    def _set_do(self, symbol: str, active: bool) -> None:
        if self._dout_cache.get(symbol) != active:
            self._dout_cache[symbol] = active
            self.dio.set_do_function(symbol, active)

    # -- servo --------------------------------------------------------------------------
    def _requested(self) -> bool:
        src = self.options.son_sources
        return (
            ("DI" in src and self.dio.function_active("SON"))
            or ("CANOPEN" in src and self.cia402.servo_enable_requested)
            or 1 in self._p2030  # forced software servo on (L9496)
        )

    def _p2030_written(self, _name: str, _old: int, new: int) -> None:
        """P2.030 (L9492-9505): 1 forces a software servo on, 5 keeps no value written after
        it, 6/7 simulation / scope (stored, not modelled); each stays on until -n ends it, 0
        ends them all, or the power goes ("-1, -5, -6, -7 分別關閉 1、5、6、7 的功能";
        P2.030 reads 0 after power-up). 8 backs the values in RAM up to EEPROM (L9501)."""
        if new == 0:
            self._p2030.clear()
        elif new in P2030_FUNCTIONS:
            self._p2030.add(new)
        elif -new in P2030_FUNCTIONS:
            self._p2030.discard(-new)
        elif new == 8:
            self.params.backup_to_eeprom()
        self.params.no_eeprom = 5 in self._p2030
        self._update_servo()

    def _update_servo(self, source: str = "") -> None:
        """Switch the servo to what is requested; `source` "cia402": the state machine asked."""
        if not self.powered:
            return
        requested = self._requested()
        if self._was_requested and not requested and "AL053" in self.alarms.active:
            self.alarms.clear("AL053")  # "將伺服切至 Servo Off 狀態即可解除此異警" (L19725)
        self._was_requested = requested
        sto_lost = not (self.sto.a and self.sto.b)
        if sto_lost and self.servo_on and self.options.sto_servo_off == "acknowledged":
            # the hardware has cut the current (L2474); the firmware enters Servo Off only
            # when it acknowledges the loss with AL500 / AL501 / AL502 (L2478, L2482)
            sto_lost = False
        blocked = self.alarms.servo_off_required or sto_lost
        if self._hold_timer and self.alarms.servo_off_required and not self.servo_on and (
                self.alarms.current != "AL022"):
            # EMGS or an alarm during a negative-P1.043 hold: P1.043 acts as 0 for them
            # (L8516), so the torque held after a normal servo off ends now
            self._end_torque_hold()
            self.axis.set_power(False)
        want = requested and not blocked
        if want and not self.servo_on:
            self._servo_on()
        elif not want and self.servo_on:
            if self.alarms.servo_off_required:
                code = self.alarms.current
                cause = "emgs" if "AL013" in self.alarms.active else "alarm"
                self._servo_off(cause, code)
            else:
                self._servo_off("normal", None, by_state_machine=source == "cia402")

    def _stop_mode(self, by_state_machine: bool) -> int:
        """P1.032.Y code of this servo off's stop: 605Bh for a CiA 402 servo off (L18342-
        18358), P1.032.Y for SON off, alarms and EMGS (L8321); `shutdown_option_scope`."""
        if by_state_machine and self.options.shutdown_option_scope == "state_machine":
            return self.cia402.shutdown_stop_mode
        return (self.params.get("P1.032") >> 4) & 0xF

    def _end_torque_hold(self) -> None:
        """The negative-P1.043 torque hold ends now (its timer is dropped)."""
        if self._hold_timer:
            self._hold_timer.cancel()
            self._hold_timer = None

    def _servo_on(self) -> None:
        self.monitors.account()  # P0.008's Servo On hours count from here
        self.servo_on = True
        self._end_torque_hold()
        self.axis.stop_mode = (self.params.get("P1.032") >> 4) & 0xF
        self.axis.set_power(not self.sto.torque_cut)
        self.axis.hold()
        self._set_do("SON", True)
        self.brake.servo_on()
        for hook in self.hooks.servo_on:
            hook()

    def _servo_off(
        self, cause: str, alarm: str | None, immediate: bool = False, by_state_machine: bool = False
    ) -> None:
        if not self.servo_on:
            return
        self.monitors.account()
        self.servo_on = False
        self.axis.stop_mode = self._stop_mode(by_state_machine)
        self.axis.set_power(False)  # torque off first: every event below sees it off
        hold = 0 if immediate else self.brake.servo_off(cause, alarm)
        if hold:  # negative P1.043: brake clamps first, torque held |P1.043| (options.py)
            self.axis.set_power(not self.sto.torque_cut)
            self._hold_timer = self.sched.after(hold, lambda: self.axis.set_power(False))
        self._set_do("SON", False)
        for hook in self.hooks.servo_off:
            hook()

    def _follow_absolute(self) -> None:
        """With a valid absolute coordinate, 6064h reads the absolute PUU (chapter 10)."""
        enc = self.absolute
        if enc.enabled and enc.coordinate_valid:
            counts = puu_to_counts(enc.puu, self.params.get("P1.044"), self.params.get("P1.045"))
            self.axis.set_user_position(counts)

    def clear_position_error(self) -> None:
        """P0.049 = 2: the motor position becomes the command end point (L7477-7491)."""
        self.axis.demand = self.axis.position
        self.axis.hold()

    def _on_torque_cut(self, cut: bool) -> None:
        self.axis.set_power(self.servo_on and not cut)

    def _on_clamp(self, clamped: bool) -> None:
        # Brake calls this on every mechanical change: subscribers (the ground truth) see
        # the instant exactly, not at the next periodic state sample
        self.axis.brake_clamped = clamped
        self.emit(BrakeChanged(self.sched.now, clamped))

    def _fault_reset(self) -> bool:
        """CiA 402 fault reset (6040h bit 7 edge, L18231): True if no servo-off alarm stays."""
        remaining = self.alarms.reset("6040h")
        return not remaining

    def _on_arst(self, active: bool) -> None:
        # ARST acts on the rising edge (L15082); deviation knob: the falling edge.
        if active != self.options.dev_arst_on_falling_edge:
            self.absolute.on_arst()
            self.alarms.reset("di")
            self._update_servo()

    def _on_alarm(self, event: AlarmChanged | None) -> None:
        """React to an alarm change (outputs, CiA 402, servo), then tell subscribers."""
        self._react_to_alarms()
        if event is not None:
            self.emit(event)

    def _main_circuit_in(self) -> bool:
        """No AL003 (undervoltage) or AL022 (main-circuit power lost): WARN-class alarms that
        say the main circuit is not in (SRDY L15263, statusword bit 4 L18307)."""
        return not any(c in MAIN_POWER_ALARMS for c in self.alarms.active)

    def _srdy(self) -> bool:
        """SRDY: control and main-circuit power in, and no fault (L15263): off with any
        ALM-class alarm and without the main circuit."""
        return not self.alarms.alrm and self._main_circuit_in()

    def _react_to_alarms(self) -> None:
        al = self.alarms
        self._set_do("ALRM", al.alrm)
        self._set_do("WARN", al.warn)
        self._set_do("SRDY", self._srdy())
        # statusword bit 4 "voltage enabled": the main circuit is in (L18307)
        self.cia402.set_voltage(self._main_circuit_in())
        fault = any(al.kind(c) == "ALM" and al.table.spec(c).servo_off for c in al.active)
        cur = al.emcy_alarm if self.options.emcy_priority == "class" else al.current
        self.cia402.error_code = al.table.spec(cur).emcy if cur else 0  # 603Fh (L17063)
        self.cia402.set_fault(fault)
        self.cia402.set_servo_blocked(al.servo_off_required and not fault)  # AL013 (L18326)
        self.cia402.set_warning(al.warn)
        self._update_servo()

    def _on_limit(self, which: str, active: bool) -> None:
        self.alarms.set_cause("AL014" if which == "NL" else "AL015", active)
        nl = self.dio.function_active("NL")
        pl = self.dio.function_active("PL")
        self.cia402.set_limits(nl, pl)
        if active and self.servo_on:
            v = self.axis.velocity
            if (which == "PL" and v > 0) or (which == "NL" and v < 0) or self.axis.moving:
                self.axis.ramp_stop(self.p5003_decel(0 if which == "PL" else 1))

    def p5003_decel(self, digit: int) -> float:
        """Deceleration time (ms per 3000 rpm) of P5.003 digit `digit` (L11084-11100)."""
        idx = (self.params.get("P5.003") >> (4 * digit)) & 0xF
        return float(self.params.get(f"P5.{20 + idx:03d}"))

    # -- motion -------------------------------------------------------------------------
    def _needs_steps(self) -> bool:
        ax = self.axis
        # a position pushed off its demand at standstill is corrected (and seen by TPOS)
        # pulses on the line are counted (or lost) at the motion steps (pulse_train.py)
        # a load pulling the shaft (gravity) moves it whenever the brake does not hold it
        return (ax.moving or ax.velocity != 0.0 or (ax.power and ax.position != ax.demand)
                or self.pulse.seg is not None or ax.pulled)

    def commit_cycle(self) -> None:
        """An input arrives inside a 1 ms cycle: the cycle runs to its end with the command
        it began with (computed now, its outputs still due at its end), and the input acts
        from the next cycle, as a drive samples its commands at the cycle start (causal)."""
        step = self.step_ns
        now = self.sched.now
        if self._ahead or now % step == 0:
            return
        if self._needs_steps():
            self.axis.step(step)
        self._axis_t = (now // step + 1) * step
        self._ahead = True

    def _integrate_to(self, stop: int) -> None:
        """Motion in whole steps of the drive's own grid (1 ms: the command generator's
        cycle, L4178, L4909), whatever the caller's slices: between two grid points the
        axis keeps the state of the last one, and a command given inside a cycle acts from
        the next one (`commit_cycle`). So every slicing of the same scenario gives the same
        positions at every grid point (tests/model/test_manual_rules_wave3.py)."""
        sched = self.sched
        step = self.step_ns
        while True:
            if self._ahead:  # a cycle computed at an input inside it: its outputs are due now
                if self._axis_t > stop:
                    break
                sched.now = self._axis_t
                self._ahead = False
                self._after_step()
                due = sched.next_deadline()
                if due is not None and due < stop:
                    return
                continue
            grid = (sched.now // step + 1) * step  # the next grid point after now
            if grid > stop or not self._needs_steps():
                break
            self.axis.step(step)
            sched.now = self._axis_t = grid
            self._after_step()
            due = sched.next_deadline()
            if due is not None and due < stop:  # a step scheduled something earlier
                return
        if sched.now < stop:
            sched.now = stop

    def _after_step(self) -> None:
        self.brake.after_step()
        self.cia402.after_step()
        for hook in self.hooks.step:
            hook()
        self._refresh_speed_outputs()
        self._update_sensors()
        ax = self.axis
        if ax.power and (
            abs(ax.following_error) > self._step_params()[0]
            or self.cia402.following_error_exceeded
        ):
            if self.cia402.following_error_exceeded:
                self.cia402.latch_following_error()  # PP statusword bit 13 (L18338)
            self.alarms.raise_alarm("AL009")  # position error excessive (L19539-19542)

    def refresh_outputs(self) -> None:
        """Recompute the DO functions whose inputs changed outside a motion step."""
        if self.powered:
            self._refresh_speed_outputs()
            self.pr.refresh_outputs()

    def _refresh_speed_outputs(self) -> None:
        ax = self.axis
        rpm = ax.velocity_rpm
        _p2035, p1038, p1039, _p1054, _p1001 = self._step_params()
        last = self._dout_cache.get  # each output is set only when it changes (`_set_do`)
        # compared beyond float noise (a speed settled on P1.039 reads 1000.0000000000001)
        if last("ZSPD") != (on := abs(rpm) < p1038 / 10.0 - SPEED_EPS_RPM):
            self._set_do("ZSPD", on)
        if last("TSPD") != (on := abs(rpm) > p1039 + SPEED_EPS_RPM):  # either way (L8426)
            self._set_do("TSPD", on)
        if last("TPOS") != (on := self.tpos()):
            self._set_do("TPOS", on)
        # TQL: torque at a limit, not in T/Tz (L15278)
        on = ax.torque_limited and self.difunc.control_mode() not in ("T", "Tz")
        if last("TQL") != on:
            self._set_do("TQL", on)

    def control_mode(self) -> str:
        """The table 8.1 control mode (di_functions.py)."""
        return self.difunc.control_mode()

    def tpos(self) -> bool:
        """TPOS (P1.054, L8689-8693): in PT mode the following error is inside P1.054; in PR
        mode the PR's target minus the motor position is, and a new trigger clears TPOS until
        the command has reached its target (L8624)."""
        ax = self.axis
        err = ax.following_error
        _p2035, _p1038, _p1039, p1054, p1001 = self._step_params()
        if self.pulse.used and self.pulse.in_pt_cached():  # PT: pulse command minus feedback
            err = self.pulse.error()
        else:
            mode = self.difunc.control_mode()
            if mode != "PR" and mode != "PT":  # TPOS is a PT / PR output (L15275)
                return False
            # the PR rule for PR by P1.001 (a dual mode only while its PR side is in effect)
            # and for the CiA 402 position modes the drive runs as PR (PP, HM, IP)
            if mode == "PR":
                pr_by_p1001 = p1001 & 0xFF in PR_MODES
                if pr_by_p1001 and self.pr.tpos_off:
                    return False
                if ax.mode == "position":
                    err = ax.target - ax.position
                elif pr_by_p1001 and self.pr.stopped_short():
                    # STP or a software limit stopped the PR short of Cmd_E, which STP keeps
                    # (000:605): TPOS judges "設定目標位置與實際馬達位置" (L8694), still far
                    g44, g45 = self.params.get("P1.044"), self.params.get("P1.045")
                    err = puu_to_counts(self.pr.cmd_e, g44, g45) + ax.origin - ax.position
        return abs(err) < p1054

    def _update_sensors(self, force: bool = False) -> None:
        """Drive the sensor DIs from the axis position (force: at power-up, unfiltered)."""
        if not self.sensors:
            return
        pos = self.axis.position
        nl, pl = self.mech.limit_states(pos)
        org = self.mech.home_sensor(pos)
        if not force and (nl, pl, org) == self._sensor_key:
            return  # no switch changed since the last step (the usual case)
        states = {"NL": nl, "PL": pl, "ORGP": org}
        for fn, (n, kind) in self.sensors.items():
            act = states.get(fn, False)
            if force or self._sensor_state.get(fn) != act:
                self._sensor_state[fn] = act
                level = act if kind == "no" else not act
                self.dio.set_input(n, level, settled=force)
                if not force:
                    self.emit(InputChanged(self.sched.now, n, level))
        self._sensor_key = (nl, pl, org)  # after: a sensor not yet driven is tried again


def _abort_for(exc: ModelError, value: int) -> int:
    """SDO abort code for a refused write (CiA 301 codes, L17024-17042; the manual names few:
    docs/manual-choices.md). Every refusal gets one: an undefined DI/DO function code (table 8.1 /
    8.2) is a value outside the range (0609 0030), as is any other refusal that names no finer
    rule."""
    if isinstance(exc, UnknownFunction) or not isinstance(exc, ParamError):
        return ABORT_VALUE_RANGE
    if isinstance(exc, ReadOnly):
        return ABORT_READ_ONLY
    if isinstance(exc, OutOfRange):
        return ABORT_VALUE_RANGE
    if isinstance(exc, ServoOnLocked):
        return ABORT_DATA_STATE
    if isinstance(exc, ProtectedParameter):
        return ABORT_DATA_STORE
    if isinstance(exc, UnknownParameter):
        return ABORT_NO_OBJECT
    return ABORT_VALUE_HIGH if value > 0 else ABORT_VALUE_LOW


__all__ = ["DEFAULT_SENSORS", "MODE_NAMES", "Drive"]
