"""Homing that moves the axis: CANopen (6098h, L18838-18869) and PR mode (P5.004, manual chapter 7).

`attach_homing(core, absolute=...)` wires a `Homing` into a drive through its public pieces
only (core.py):

* CANopen: `drive.cia402.start_homing` / `stop_homing` (6040h bit 4 edges in HM, halt,
  leaving OPERATION ENABLED); result through `cia402.set_homing_status(attained, error)`
  (6041h bits 12/13, L18337-18338).
* PR: DI.SHOM rising edge (L15197), DI.CTRG rising edge with POS0-POS6 off = PR#0
  (L15098, L4701), P5.007 written 0 (L11174), first servo on after power-up when
  P6.000.D BOOT = 1 (L12633-12635). Triggers act on the next 1 ms PR tick (L4916).
* Sensors: the home cam and the limits through their DI functions ORGP/NL/PL, i.e. after the
  P2.009 filter, as the drive sees them (L9229); the index (Z) pulse from the encoder
  (`Mechanics.index_crossed`) in a step hook, exact to the count.
* DO.HOME off at once on a trigger, on at completion (L15290); P0.046 bit 8 follows.
* After the reference is found the coordinate is set (CANopen: 6064h = 607Ch at the home
  point; PR: P6.001 at the reference, L12641) and an absolute encoder, if the drive has one
  (`absolute`, given to `attach_homing`), gets its origin (L16458).

Method tables: `hil.profile.homing_methods`. Choices and deviation knobs (ModelOptions
.extra["homing"]): `HomingOptions`, docs/manual-choices.md#homing.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Any

from hil.model.errors import ModelError
from hil.model.events import HomingPhase
from hil.model.motion import puu_to_counts, rpm_to_counts_per_s
from hil.model.pr_engine import pr_mode
from hil.model.timebase import Timer, ms
from hil.profile.homing_methods import (
    EDGE,
    HERE,
    INDEX,
    TORQUE,
    Plan,
    canopen_plan,
    check_p5004,
    pr_plan,
)
from hil.units import MS

if TYPE_CHECKING:
    from hil.model.absolute import AbsoluteEncoder
    from hil.model.core import DriveCore

POS_FUNCTIONS = ("POS0", "POS1", "POS2", "POS3", "POS4", "POS5", "POS6")  # L15123-15133


@dataclass
class HomingOptions:
    """Choices (manual gaps) and deviation knobs (`ignore_index`, `wrong_direction`,
    `home_early_ms`: a deliberately wrong drive for checker tests)."""

    # CANopen: after the stop, move back to the home point at the zero-search speed so that
    # 6064h reads 607Ch (CiA 402 "homing attained"; the A3 figures are missing, L18856).
    canopen_return: bool = True
    # 6064h at the home point = offset_sign x 607Ch (CiA 402 figure: +1; L18698-18699 only
    # says the user origin is offset from the home point).
    offset_sign: int = 1
    # PR X = 4/5 (Z directly): search speed "low" = P5.006 or "high" = P5.005 (L4348 silent).
    pr_z_speed: str = "low"
    # An edge that is itself the home (no Z after it) entered at the search speed (6099h sub1)
    # is not latched there but found again at the zero-search speed (sub2): out of the region
    # and back in (CiA 402's two speeds; the same home from every start, L4336). False: the
    # edge at search speed, off by that speed x the DI filter (the model before session 26)
    reapproach_edge: bool = True
    # --- deviations ---
    ignore_index: bool = False  # Z pulse ignored: the switch edge is taken as home
    wrong_direction: bool = False  # final search (edge crossing and Z) the other way
    home_early_ms: float | None = None  # HOME / bit 12 this long after the reference, moving

    def __post_init__(self) -> None:
        if self.offset_sign not in (1, -1):
            raise ValueError("homing.offset_sign: 1 or -1")
        if self.pr_z_speed not in ("low", "high"):
            raise ValueError("homing.pr_z_speed: 'low' or 'high'")
        if self.home_early_ms is not None and self.home_early_ms < 0:
            raise ValueError("homing.home_early_ms: must be >= 0 ms")

    @classmethod
    def from_dict(cls, data: dict[str, Any] | None) -> HomingOptions:
        data = dict(data or {})
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(
                f"options.extra.homing: unknown key(s) {unknown}; known: {sorted(known)}"
            )
        return cls(**data)


class Homing:
    """One homing engine per drive (both routes share it; one run at a time)."""

    def __init__(self, drive: DriveCore, options: HomingOptions | None = None,
                 absolute: AbsoluteEncoder | None = None) -> None:
        self.drive = drive
        self.absolute = absolute  # gets its origin at the reference (L16458)
        self.options = options or HomingOptions.from_dict(drive.options.extra.get("homing"))
        self.route = ""  # "canopen" | "pr" while a run is active
        # "" idle | search | exit | cross | back | index | torque | stop | return
        self._phase = ""
        self.plan: Plan | None = None
        self.homed = False  # coordinate established since power-up
        self.on_homed: Callable[[], None] | None = None  # HOME came on (counters.py clears)
        self.last_error = ""
        self.reference: float | None = None  # physical counts of the reference (edge / Z)
        self.home_counts: float | None = None  # physical counts of the home point
        self.trace: list[tuple[int, str]] = []  # (t, phase) transitions, for tests/recording
        self._dir = 0
        self._want = False
        self._reversed = False
        self._v1 = self._v2 = 0.0
        self._acc = self._dec1 = self._dec2 = 100.0
        self._user_home = 0.0
        self._reported = False
        self._torque_since: int | None = None
        # torque homing: the direction of the stop it pushed into while the P1.087 limit is
        # still held after the detection (0: not held)
        self._push_dir = 0
        self._pending: Timer | None = None
        self._early: Timer | None = None
        self._boot_armed = True
        # PR engine hooks (pr_engine.attach_pr): a PR#0 run starts / finished (PATH, L12607)
        self.on_pr_start: Callable[[], None] | None = None
        self.on_pr_done: Callable[[], None] | None = None

    # ---------------------------------------------------------------- routes / triggers
    def start_canopen(self) -> None:
        """6040h bit 4 rising edge in HM / OPERATION ENABLED (L17267, L18239)."""
        cia = self.drive.cia402
        self._cancel_pending()
        try:
            plan = canopen_plan(cia.read(0x6098, 0))
        except ModelError as exc:
            self._begin("canopen")
            self._error(str(exc))
            return
        acc = float(cia.read(0x609A, 0))  # both ramps (L19021)
        self._v1 = cia.read(0x6099, 1) / 10.0  # 0.1 rpm (L18998)
        self._v2 = cia.read(0x6099, 2) / 10.0  # 0.1 rpm (L19007)
        self._acc = self._dec1 = self._dec2 = acc
        # 6064h is computed with the gear the CiA 402 objects hold (6093h), so use that one
        g_num, g_den = cia.read(0x6093, 1), cia.read(0x6093, 2)
        offset = self.options.offset_sign * cia.read(0x607C, 0)
        self._user_home = puu_to_counts(offset, g_num, g_den)
        self._begin("canopen")
        self._run(plan)

    def stop(self) -> None:
        """Halt / bit 4 falling edge / leaving HM or OPERATION ENABLED: abort the run."""
        self._cancel_pending()
        if not self.route:
            return
        self._end()
        ax = self.drive.axis
        if ax.power:
            ax.ramp_stop(self._dec2)

    def trigger_pr(self, source: str) -> None:
        """A PR homing trigger (SHOM, CTRG+POS=0, P5.007=0, BOOT): HOME off now, start on
        the next 1 ms PR tick; several triggers in one tick start one run (L4916)."""
        d = self.drive
        if not d.servo_on or self._pending is not None or self.route == "canopen":
            return
        if not pr_mode(d):  # SHOM / CTRG / P5.007 = 0 are PR-mode triggers (L15197,
            return  # L11174); so is BOOT: P6.000 is a PR-mode parameter (L12600-12601)
        self._set_home(False)  # "goes Off immediately when homing is triggered" (L15290)
        self.trace.append((d.now, f"trigger:{source}"))
        tick = (d.now // MS + 1) * MS
        self._pending = d.sched.at(tick, self._start_pr)

    def _start_pr(self) -> None:
        self._pending = None
        d = self.drive
        if not d.servo_on:
            return
        p = d.params.get
        if self.route:
            self._end()  # a new trigger replaces the running homing (PR executor)
        if self.on_pr_start is not None:
            self.on_pr_start()
        try:
            plan = pr_plan(p("P5.004"), self.options.pr_z_speed)
        except ModelError as exc:  # a P5.004 that bypassed the write check
            self._begin("pr")
            self._error(str(exc))
            return
        p6000 = p("P6.000")
        self._acc = _accel_ms(p, (p6000 >> 8) & 0xF)  # Z: ACC index (L12619)
        self._dec1 = _accel_ms(p, (p6000 >> 12) & 0xF)  # U: DEC1 (L12621)
        self._dec2 = _accel_ms(p, (p6000 >> 16) & 0xF)  # A: DEC2 (L12623)
        self._v1 = p("P5.005") / 10.0  # 0.1 rpm comm units (L11135-11149)
        self._v2 = p("P5.006") / 10.0
        self._user_home = puu_to_counts(p("P6.001"), p("P1.044"), p("P1.045"))
        self._begin("pr")
        self._run(plan)

    def on_servo_on(self) -> None:
        """First servo on after power-up: P6.000.D BOOT = 1 homes by itself (L12633-12635)."""
        if self._boot_armed:
            self._boot_armed = False
            if (self.drive.params.get("P6.000") >> 28) & 0xF == 1:
                self.trigger_pr("BOOT")

    @property
    def phase(self) -> str:
        return self._phase

    @phase.setter
    def phase(self, value: str) -> None:
        if value != self._phase:
            self._phase = value
            self.drive.emit(HomingPhase(self.drive.now, value))  # ground truth, exact time

    def on_power_up(self) -> None:
        """Power-up: HOME off (L15290), coordinate not homed, BOOT armed again."""
        self._cancel_pending()
        self._end()
        self.homed = False
        self._boot_armed = True
        self._set_home(False)
        self.drive.dio.set_do_function("IDXD", False)

    @property
    def active(self) -> bool:
        return bool(self.route)

    @property
    def pr_busy(self) -> bool:
        """A PR homing is triggered (it starts on the next tick) or running."""
        return self.route == "pr" or self._pending is not None

    # ---------------------------------------------------------------- the run
    def _begin(self, route: str) -> None:
        self.route = route
        self.phase = ""
        self.reference = self.home_counts = None
        self.last_error = ""
        self._reversed = False
        self._reported = False
        self._torque_since = None
        self._set_home(False)

    def _run(self, plan: Plan) -> None:
        opts = self.options
        if opts.ignore_index and plan.index:
            plan = plan.without_index()
        if opts.wrong_direction:
            plan = plan.flipped()
        self.plan = plan
        d = self.drive
        if plan.kind == HERE:
            self._found(d.axis.position)
            return
        if plan.kind == INDEX:
            self.reference = d.axis.position
            speed = self._v1 if plan.speed == "high" else self._v2
            self._move("index", plan.d0, speed)
            return
        if plan.kind == TORQUE:
            lvl = d.params.get("P1.087") * 10 + 100  # max torque ~ P1.087 + 10 % (L4383)
            d.axis.set_torque_limits(lvl, lvl)
            self._move("torque", plan.d0, self._v1)
            return
        if d.dio.function_active(plan.signal):
            self._inside()
        else:
            self._move("search", plan.d0, self._v1, want=True)

    def _inside(self) -> None:
        """On the signal's active region: leave it through the edge or cross it (low speed)."""
        plan = self.plan
        assert plan is not None
        if plan.pre_inside():
            self._move("cross", plan.cross, self._v2, want=False)
        else:
            self._move("exit", -plan.cross, self._v2, want=False)

    def _move(self, phase: str, direction: int, rpm: float, want: bool = False) -> None:
        # the ramp out of the first stage (the high-speed search) is DEC1, "the first homing
        # deceleration"; later slowdowns are DEC2 (P6.000 U / A, L4267-4269, L12627-12630)
        first = self.phase in ("search", "torque") or phase in ("search", "torque")
        self.phase = phase
        self._dir = direction
        self._want = want
        d = self.drive
        self.trace.append((d.now, phase))
        if self._limit_ahead():
            self._on_limit_ahead()
            return
        d.axis.run_velocity(direction * rpm, self._acc, self._dec1 if first else self._dec2)

    def _limit_ahead(self) -> bool:
        """The limit switch in the travel direction is active (and is not the reference)."""
        plan = self.plan
        lim = "PL" if self._dir > 0 else "NL"
        if plan is not None and plan.kind == EDGE and plan.signal == lim:
            return False
        return self.drive.dio.function_active(lim)

    def _on_limit_ahead(self) -> None:
        plan = self.plan
        assert plan is not None
        first = self.phase in ("search", "torque") or (plan.kind == INDEX and self.phase == "index")
        if first and plan.limit == "reverse" and not self._reversed:
            self._reversed = True
            if plan.kind == INDEX:
                self.reference = self.drive.axis.position
            speed = self._v1 if self.phase != "index" or plan.speed == "high" else self._v2
            self._move(self.phase, -self._dir, speed, want=self._want)
            return
        lim = "PL" if self._dir > 0 else "NL"
        self._error(f"{plan.name}: limit {lim} reached in phase {self.phase} (L4229, L18869)")

    # ---------------------------------------------------------------- sensor events
    def on_signal(self, symbol: str, active: bool) -> None:
        """DI function ORGP/NL/PL changed (after the P2.009 filter)."""
        plan = self.plan
        if not self.route or plan is None or self.phase in ("", "stop", "return"):
            return
        if active and symbol in ("NL", "PL") and self._limit_ahead():
            self._on_limit_ahead()
            return
        if plan.kind != EDGE or symbol != plan.signal or active != self._want:
            return
        if self._moving_dir() != self._dir:
            return  # overshoot while decelerating / reversing: not the edge being sought
        phase = self.phase
        if phase == "search":
            entered = "lo" if self._dir > 0 else "hi"
            at_speed_home = not plan.index and self.options.reapproach_edge
            if entered == plan.edge and self._dir == plan.cross and not at_speed_home:
                self._edge()  # a Z after it sets the home exactly
            else:
                self._inside()
        elif phase == "exit":
            self._move("cross", plan.cross, self._v2, want=True)
        elif phase == "cross":
            if not plan.index and self.options.reapproach_edge and self._above_v2():
                # the home edge itself, reached while the slowdown from v1 still ran (a cam
                # narrower than that ramp): back into the region at v2, then cross again, so
                # the home does not move with the start (L4292, L4336)
                self._move("back", -plan.cross, self._v2, want=not self._want)
            else:
                self._edge()
        elif phase == "back":  # in the region again (or, crossing into it, out again)
            if plan.pre_inside():
                self._inside()
            else:
                self._move("cross", plan.cross, self._v2, want=True)

    def _above_v2(self) -> bool:
        """The commanded speed is still above the zero-search speed (6099h sub 2, P5.006)."""
        ax = self.drive.axis
        v2 = rpm_to_counts_per_s(self._v2, ax.cpr)
        return abs(ax.demand_velocity) > v2 * 1.001 + 1.0

    def _moving_dir(self) -> int:
        ax = self.drive.axis
        v = ax.velocity if ax.velocity != 0.0 else ax.demand_velocity
        return 1 if v > 0 else (-1 if v < 0 else 0)

    def _edge(self) -> None:
        plan = self.plan
        assert plan is not None
        pos = self.drive.axis.position
        self.reference = pos
        if plan.index:
            self._move("index", plan.index, self._v2)
        else:
            self._found(pos)

    def after_step(self) -> None:
        """Step hook: index pulses, torque level, end of the stop / return moves."""
        if not self.route:
            return
        d = self.drive
        ax = d.axis
        if not ax.power:
            self._end()
            return
        if self._push_dir and ax.demand_velocity * self._push_dir <= 0.0:
            self._restore_torque_limits()  # the command has left the stop
        phase = self.phase
        if phase == "index":
            last, pos = ax.last_position, ax.position
            step = pos - last
            if step * self._dir <= 0:
                return
            ref = self.reference if self.reference is not None else last
            for p in d.mech.index_crossed(last, pos):
                if (p - ref) * self._dir > 0:
                    self._found(p)
                    return
        elif phase == "torque":
            lvl = d.params.get("P1.087") * 10  # 0.1 % units
            if ax.torque * self._dir >= lvl:
                if self._torque_since is None:
                    self._torque_since = d.now
                elif d.now - self._torque_since >= ms(d.params.get("P1.088")):  # L8973-8984
                    # the P1.087 + 10 % limit stays until the command no longer pushes into
                    # the stop (a harder impact may damage the machine, L4383, L8960-8971)
                    self._push_dir = self._dir
                    self.reference = ax.position
                    plan = self.plan
                    assert plan is not None
                    if plan.index:
                        self._move("index", plan.index, self._v2)
                    else:
                        self._found(ax.position)
            else:
                self._torque_since = None
        elif phase == "stop":
            if not ax.moving:
                back = ax.position != self.home_counts  # 35/37: already there, no move
                if self.route == "canopen" and self.options.canopen_return and back:
                    self.phase = "return"
                    self.trace.append((d.now, "return"))
                    ax.move_to(self.home_counts, self._v2, self._acc, self._dec2)
                else:
                    self._complete()
        elif phase == "return" and not ax.moving and ax.at_target:
            self._complete()

    # ---------------------------------------------------------------- endings
    def _found(self, home: float) -> None:
        """Reference found at physical counts `home`: set the coordinate, stop."""
        d = self.drive
        ax = d.axis
        self.home_counts = home
        if self.reference is None:
            self.reference = home
        ax.set_user_position(ax.position - home + self._user_home)
        self.homed = True
        self.phase = "stop"
        self.trace.append((d.now, "stop"))
        if ax.moving or ax.velocity != 0.0:
            ax.ramp_stop(self._dec2)
        early = self.options.home_early_ms
        if early is not None:
            self._early = d.sched.after(ms(early), self._report)
        if not ax.moving:
            self.after_step()

    def _complete(self) -> None:
        route = self.route
        self._report()
        self._end()
        if route == "pr" and self.on_pr_done is not None:
            self.on_pr_done()  # P6.000 PATH (L12607-12631)

    def _report(self) -> None:
        self._early = None
        if self._reported:
            return
        self._reported = True
        d = self.drive
        self.trace.append((d.now, "homed"))
        if self.absolute is not None:
            self.absolute.establish_origin(at_counts=round(self.home_counts or 0.0))
        self._set_home(True)
        if self.route == "canopen":
            d.cia402.set_homing_status(True, False)

    def _error(self, reason: str) -> None:
        d = self.drive
        self.last_error = reason
        self.trace.append((d.now, "error"))
        route = self.route
        self._end()
        if d.axis.power:
            d.axis.ramp_stop(self._dec1)
        if route == "canopen":
            d.cia402.set_homing_status(False, True)

    def _end(self) -> None:
        if self.phase == "torque" or self._push_dir:
            self._restore_torque_limits()
        if self._early is not None:
            self._early.cancel()
            self._early = None
        self.route = ""
        self.phase = ""

    def _restore_torque_limits(self) -> None:
        self._push_dir = 0
        cia = self.drive.cia402
        self.drive.axis.set_torque_limits(cia.read(0x60E0, 0), cia.read(0x60E1, 0))

    def _cancel_pending(self) -> None:
        if self._pending is not None:
            self._pending.cancel()
            self._pending = None

    def _set_home(self, on: bool) -> None:
        dio = self.drive.dio
        dio.set_do_function("HOME", on)
        if on:  # IDXD: "the index coordinate is defined once homing completes" (L15298)
            dio.set_do_function("IDXD", True)
            if self.on_homed is not None:
                self.on_homed()

    def lose_home(self) -> None:
        """The position counters overflowed: the coordinate means nothing any more, HOME and
        IDXD off (L15290, L15298)."""
        self.homed = False
        self._set_home(False)
        self.drive.dio.set_do_function("IDXD", False)


def _accel_ms(get: Any, index: int) -> float:
    """Accel/decel time entry #index = P5.020 + index, ms per 3000 rpm (L11323-11462)."""
    return float(get(f"P5.{20 + index:03d}"))


def attach_homing(drive: DriveCore, options: HomingOptions | None = None, *,
                  absolute: AbsoluteEncoder | None = None) -> Homing:
    """Create the homing engine of `drive` and wire it through the drive's public pieces."""
    homing = Homing(drive, options, absolute)
    cia = drive.cia402
    cia.start_homing = homing.start_canopen
    cia.stop_homing = homing.stop
    dio = drive.dio
    for sym in ("ORGP", "NL", "PL"):
        dio.on_function(sym, lambda a, s=sym: homing.on_signal(s, a))
    dio.on_function("SHOM", lambda a: a and homing.trigger_pr("SHOM"))  # L15197

    def on_ctrg(active: bool) -> None:  # CTRG with POS0-6 off = PR#0 = homing (L4701)
        if active and not any(dio.function_active(f) for f in POS_FUNCTIONS):
            homing.trigger_pr("CTRG")

    dio.on_function("CTRG", on_ctrg)
    params = drive.params
    params.on_validate("P5.004", check_p5004)
    params.on_write("P5.007", lambda _n, _o, new: new == 0 and homing.trigger_pr("P5.007"))
    drive.hooks.step.append(homing.after_step)

    drive.hooks.servo_on.append(homing.on_servo_on)
    drive.hooks.boot.append(homing.on_power_up)  # first: the boot may switch the servo on
    if drive.servo_on:
        homing._boot_armed = False
    homing._set_home(False)
    return homing


__all__ = ["POS_FUNCTIONS", "Homing", "HomingOptions", "attach_homing"]
