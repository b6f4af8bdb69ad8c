"""The motion axis: profile generator, position/velocity loop and rigid-body mechanics.

`Axis(mechanics)` is a fixed-substep integrator. The drive calls `axis.step(dt_ns)` with
dt <= 1 ms while `axis.moving` (or anything else) needs time; `step` allocates nothing and
logs nothing (benchmarks/bench_model.py measures it).

Units inside the axis are **physical encoder counts** (16777216 per rev, L18414) and
counts/s; accessors give rpm and 0.1 % of rated torque. PUU conversions through the
electronic gear are pure functions below (PUU = counts × P1.045 / P1.044, L16408); the user
origin (`origin`, set by homing / absolute origin) separates physical counts from user
counts: ``user = position - origin``.

Acceleration and deceleration are given, as everywhere in the manual, as **the time in ms
to go from 0 to 3000 rpm or from 3000 rpm to 0** (6083h/6084h/6085h/609Ah, P5.020-P5.035,
L11330); it is a constant slope, so 1500 rpm stops in half that time (L4164).

Public API (all that the drive, CiA 402 and homing use)::

    axis = Axis(mech, kpp=100.0, feedforward=0.95, speed_bandwidth_hz=150.0)
    axis.step(dt_ns)
    # power stage and brake (owned by the drive: STO / servo-off / BRKR)
    axis.set_power(on)             # on: bumpless, keeps the command; off: stop per stop_mode
    axis.power                     # bool, torque available
    axis.stop_mode = 0|1|2         # P1.032.Y (L8321-8327): 0 DB, 1 coast, 2 DB then coast
    axis.zero_speed_rpm = 10.0     # P1.038 (used by stop_mode 2)
    axis.brake_clamped = bool      # mechanical brake holds: velocity forced to 0
    axis.set_torque_limits(pos_0p1, neg_0p1)   # 60E0h / 60E1h, 0.1 % of rated
    axis.max_speed_rpm             # P1.055 / 6080h: caps every profile speed and torque mode
    # DI functions of table 8.1 (hil/model/di_functions.py)
    axis.set_internal_torque_limit(pct_0p1 | None)   # TRQLM: the smaller of it and 60E0h/60E1h
    axis.speed_limit_rpm = rpm | None   # SPDLM: torque-mode speed limit below P1.055
    axis.zero_clamp = "" | "lock" | "zero"   # ZCLAMP in velocity mode, below zero_clamp_rpm
    axis.set_gain_ratio(kpp_ratio, speed_ratio)   # GAINUP: gains x P2.001 / P2.005
    axis.lock(owner) / axis.unlock(owner)   # JOG/PFQS/CCLR own the axis: other commands wait
    # commands (act while power is on; issued while off they wait for power); while another
    # owner holds a lock they are ignored (`by=` names the owner); stops always act
    axis.hold()                                  # keep the current demand position
    axis.move_to(target_counts, speed_rpm, accel_ms, decel_ms)   # trapezoid, from current state
    axis.move_to(..., overlap=True)   # PR OVLP: a new trapezoid from rest, summed with what
                                      # is left of the running one (L5051-5057)
    axis.run_velocity(rpm, accel_ms, decel_ms)
    axis.run_torque(target_0p1, slope_ms)        # 6071h / 6087h (slope: ms for 0 -> 100 %)
    axis.ramp_stop(decel_ms)                     # decelerate, then hold
    axis.interpolate_to(target_counts, period_ns)   # IP: linear over one period
    axis.set_user_position(user_counts)          # homing: redefine the origin
    # state (cheap attributes / properties)
    axis.position, axis.velocity, axis.demand, axis.demand_velocity   # counts, counts/s
    axis.last_position             # feedback before the last step (for index_crossed)
    axis.user_position, axis.user_demand          # counts relative to origin
    axis.velocity_rpm, axis.demand_rpm, axis.torque, axis.torque_demand   # rpm, 0.1 %
    axis.following_error           # counts (demand - feedback)
    axis.moving, axis.at_target, axis.mode       # mode: 'hold' 'position' 'velocity' ...

Control model: velocity-controlled modes (PV) command the speed directly; position modes
run ``v_cmd = feedforward·v_demand + kpp·(demand - feedback)`` (P2.000-like gain, rad/s);
the speed loop is a first-order lag of `speed_bandwidth_hz`. The resulting torque
(J·α + load + gravity + friction) is clipped by the torque limits, so a too hard move
lags and the following error grows. Power off: coast, or dynamic brake (torque ∝ speed).
"""

from __future__ import annotations

import math

from hil.model.mechanics import COUNTS_PER_REV, Mechanics

# ---- pure conversions ----------------------------------------------------------------


def counts_to_puu(counts: float, p1_044: int, p1_045: int) -> float:
    """Encoder counts -> PUU: PUU = counts × P1.045 / P1.044 (L16408)."""
    return counts * p1_045 / p1_044


def puu_to_counts(puu: float, p1_044: int, p1_045: int) -> float:
    """PUU -> encoder counts: counts = PUU × P1.044 / P1.045 (L16408)."""
    return puu * p1_044 / p1_045


def rpm_to_counts_per_s(rpm: float, cpr: int = COUNTS_PER_REV) -> float:
    return rpm * cpr / 60.0


def counts_per_s_to_rpm(cps: float, cpr: int = COUNTS_PER_REV) -> float:
    return cps * 60.0 / cpr


def puu_per_s_to_rpm(
    puu_per_s: float, p1_044: int, p1_045: int, cpr: int = COUNTS_PER_REV
) -> float:
    """Profile velocity 6081h (PUU/s) -> rpm through the e-gear."""
    return counts_per_s_to_rpm(puu_to_counts(puu_per_s, p1_044, p1_045), cpr)


def rpm_to_puu_per_s(rpm: float, p1_044: int, p1_045: int, cpr: int = COUNTS_PER_REV) -> float:
    return counts_to_puu(rpm_to_counts_per_s(rpm, cpr), p1_044, p1_045)


def accel_from_ms(ms_per_3000rpm: float, cpr: int = COUNTS_PER_REV) -> float:
    """Slope in counts/s² of a "ms from 0 to 3000 rpm" time (L11330). 0 ms = immediate."""
    ms_ = max(float(ms_per_3000rpm), 1e-3)
    return rpm_to_counts_per_s(3000.0, cpr) * 1000.0 / ms_


def ramp_time_ms(delta_rpm: float, ms_per_3000rpm: float) -> float:
    """Time to change speed by `delta_rpm` at a constant "T ms per 3000 rpm" slope (L4164)."""
    return abs(delta_rpm) * ms_per_3000rpm / 3000.0


def _pos_step(pd: float, vd: float, tgt: float, vmax: float, acc: float, dec: float,
              dt: float) -> tuple[float, float, bool]:
    """One step of a trapezoid from demand `pd` at speed `vd` to `tgt`: (pd, vd, landed)."""
    r = tgt - pd
    if r == 0.0 and vd == 0.0:
        return pd, vd, True
    # the speed from which a stop at `dec` ends on the target after this step's Euler
    # update (v·dt + v²/2dec = |r|): the demand never passes its target
    ddt = dec * dt
    vdes = math.sqrt(ddt * ddt + 2.0 * dec * abs(r)) - ddt
    if vdes < ddt:  # the last step: land on the target, stop within one step
        vdes = min(ddt, abs(r) / dt)
    if vdes > vmax:
        vdes = vmax
    if r < 0.0:
        vdes = -vdes
    vd = _approach(vd, vdes, acc, dec, dt)
    ds = vd * dt
    if ds * r > 0.0 and abs(ds) >= abs(r) and abs(vd) <= abs(vdes) + dec * dt:
        return tgt, 0.0, True
    return pd + ds, vd, False


# ---- the axis --------------------------------------------------------------------------

_HOLD, _POS, _VEL, _TORQUE, _STOP, _INTERP = range(6)
_MODE_NAMES = ("hold", "position", "velocity", "torque", "stop", "interpolated")

_SETTLE_POS = 1.0  # counts: feedback snaps onto the demand below this error ...
_SETTLE_VEL = 500.0  # counts/s (0.0018 rpm): ... and below this speed


def _approach(v: float, vdes: float, acc: float, dec: float, dt: float) -> float:
    """Move speed `v` towards `vdes`: `acc` while |v| grows, `dec` while it shrinks."""
    if v == vdes:
        return v
    if (v > 0.0 and vdes < 0.0) or (v < 0.0 and vdes > 0.0):  # reverse: brake to 0 first
        d = dec * dt
        return v - d if v > d else (v + d if v < -d else 0.0)
    if abs(vdes) > abs(v):
        d = acc * dt
        if vdes > v:
            nv = v + d
            return vdes if nv > vdes else nv
        nv = v - d
        return vdes if nv < vdes else nv
    d = dec * dt
    if vdes < v:
        nv = v - d
        return vdes if nv < vdes else nv
    nv = v + d
    return vdes if nv > vdes else nv


class _MovingAverage:
    """Mean of the last `n` samples (a running sum), primed with `value`."""

    __slots__ = ("_buf", "_i", "_sum", "n")

    def __init__(self, n: int, value: float) -> None:
        self.n = n
        self._buf = [value] * n
        self._i = 0
        self._sum = value * n

    def push(self, x: float) -> float:
        i = self._i
        self._sum += x - self._buf[i]
        self._buf[i] = x
        self._i = (i + 1) % self.n
        return self._sum / self.n

    def fill(self, value: float) -> None:
        self._buf = [value] * self.n
        self._sum = value * self.n


class Axis:
    """One motor axis on its mechanics. See the module docstring for the API."""

    def __init__(
        self,
        mech: Mechanics | None = None,
        *,
        kpp: float = 100.0,
        feedforward: float = 0.95,
        speed_bandwidth_hz: float = 150.0,
        zero_speed_rpm: float = 10.0,
    ) -> None:
        self.mech = mech = mech if mech is not None else Mechanics()
        if kpp <= 0:
            raise ValueError(f"Axis kpp: must be > 0 rad/s, got {kpp}")
        if not 0.0 <= feedforward <= 1.0:
            raise ValueError(f"Axis feedforward: must be in [0, 1], got {feedforward}")
        if speed_bandwidth_hz <= 0:
            raise ValueError(f"Axis speed_bandwidth_hz: must be > 0, got {speed_bandwidth_hz}")
        self.cpr = mech.counts_per_rev
        self.kpp = kpp
        self.feedforward = feedforward
        self._tau_v = 1.0 / (2.0 * math.pi * speed_bandwidth_hz)
        self._alpha_dt = -1
        self._alpha = 1.0
        # counts/s² per N·m, and dynamic brake coefficient in N·m per counts/s
        self._k = mech.counts_per_rad / mech.total_inertia
        self._db = mech.dynamic_brake_torque / rpm_to_counts_per_s(mech.rated_speed, self.cpr)
        self._ext = mech.load_torque + mech.gravity_torque
        self._fric = mech.friction_torque
        self._hs_neg, self._hs_pos = mech.hard_stop_counts
        # held against a hard stop (+1 / -1, 0 = free) and the speed loop's integral there:
        # a PI loop winds its torque up at a stall until the limit (torque homing, L4368)
        self._pressed = 0
        self._stall_tq = 0.0
        # feedback state
        self.position = 0.0
        self.last_position = 0.0
        self.velocity = 0.0
        self.torque_nm = 0.0
        self.origin = 0.0
        # demand state
        self.demand = 0.0
        self.demand_velocity = 0.0
        self._mode = _HOLD
        self._target = 0.0
        self._vmax = 0.0
        self._acc = 1.0
        self._dec = 1.0
        self._vtarget = 0.0
        # PR OVLP (L5051-5057): the decelerations of overlapped position profiles, each
        # [speed when overlapped (counts/s), deceleration (counts/s²), time since (s)],
        # summed with the running profile, whose own state is then `_pmain` / `_vmain`
        self._tails: list[list[float]] = []
        self._pmain = 0.0
        self._vmain = 0.0
        self._sum = (0.0, 0.0)  # the (demand, demand velocity) the sum gave last
        self._tq_target = 0.0  # N·m
        self._tq_dem = 0.0  # N·m
        self._tq_rate = math.inf  # N·m/s
        self._ip_target = 0.0
        self._ip_rate = 0.0
        self._ip_rem = 0
        # IP set-point smoothing (P1.068 moving filter, P1.036 S-curve; L17232): moving
        # averages over the interpolated command, windows in samples (one per model step)
        self.ip_windows: tuple[int, ...] = ()
        self._ip_raw = 0.0
        self._ip_ma: list[_MovingAverage] = []
        self._ip_still = 0
        self._ip_settled = False
        # drive-side controls
        self.power = False
        self.brake_clamped = False
        self.stop_mode = 1  # P1.032.Y: 0 DB, 1 coast, 2 DB then coast (L8321-8327)
        self.zero_speed_rpm = zero_speed_rpm  # P1.038
        self.max_speed_rpm = mech.rated_speed  # P1.055 default = rated speed (L6882)
        self._tmax = 3.0 * mech.rated_torque
        self._tmin = -3.0 * mech.rated_torque
        self._tq_obj = (3.0 * mech.rated_torque, -3.0 * mech.rated_torque)  # 60E0h / 60E1h
        self._tq_internal: float | None = None  # N·m, DI.TRQLM (P1.012-P1.014)
        self.speed_limit_rpm: float | None = None  # DI.SPDLM (P1.009-P1.011), torque mode
        self.zero_clamp = ""  # DI.ZCLAMP: "" off, "lock" position, "zero" speed 0
        self.zero_clamp_rpm = zero_speed_rpm  # P1.038
        self._zc_pos: float | None = None
        self._kpp0 = kpp
        self._tau_v0 = self._tau_v
        self._locks: set[str] = set()
        self.torque_limited = False  # the last step clipped the torque at a limit (DO.TQL)
        self.moving = False

    # ---- controls ----------------------------------------------------------------
    def set_power(self, on: bool) -> None:
        """Power stage on/off. On: demand := feedback (bumpless), the command stays.
        Off: no torque; the stop follows `stop_mode`; the command resets to hold."""
        on = bool(on)
        if on == self.power:
            return
        self.power = on
        self.demand = self.position
        self._tails.clear()
        self._stall_tq = 0.0
        profiling = on and self._mode in (_POS, _VEL, _STOP)
        self.demand_velocity = self.velocity if profiling else 0.0
        self._tq_dem = 0.0
        if not on:
            self._mode = _HOLD
            self.torque_nm = 0.0
            self.torque_limited = False
        elif self._mode == _STOP and self.velocity == 0.0:
            self._mode = _HOLD
        self.moving = self.moving or (on and self._mode != _HOLD)

    def set_torque_limits(self, pos_0p1: float, neg_0p1: float) -> None:
        """Torque limits 60E0h / 60E1h in 0.1 % of rated torque (both given as magnitudes)."""
        rated = self.mech.rated_torque
        self._tq_obj = (abs(pos_0p1) * rated / 1000.0, -abs(neg_0p1) * rated / 1000.0)
        self._apply_torque_limits()

    def set_internal_torque_limit(self, pct_0p1: float | None) -> None:
        """An internal torque limit (0.1 % of rated, both directions) on top of 60E0h/60E1h;
        None removes it. The smaller limit acts."""
        rated = self.mech.rated_torque
        self._tq_internal = None if pct_0p1 is None else abs(pct_0p1) * rated / 1000.0
        self._apply_torque_limits()

    def _apply_torque_limits(self) -> None:
        tmax, tmin = self._tq_obj
        lim = self._tq_internal
        if lim is not None:
            tmax, tmin = min(tmax, lim), max(tmin, -lim)
        self._tmax, self._tmin = tmax, tmin

    @property
    def torque_limited_0p1(self) -> float:
        """The acting positive torque limit in 0.1 % of rated."""
        return self._tmax * 1000.0 / self.mech.rated_torque

    def set_gain_ratio(self, kpp_ratio: float, speed_ratio: float) -> None:
        """Position gain x `kpp_ratio`, speed-loop bandwidth x `speed_ratio` (1.0 = base)."""
        self.kpp = self._kpp0 * kpp_ratio
        self._tau_v = self._tau_v0 / speed_ratio
        self._alpha_dt = -1

    def lock(self, owner: str) -> None:
        """`owner` holds the axis: move/velocity/torque/IP commands of others are ignored."""
        self._locks.add(owner)

    def unlock(self, owner: str) -> None:
        self._locks.discard(owner)

    @property
    def base_kpp(self) -> float:
        """The position gain without a GAINUP ratio."""
        return self._kpp0

    @property
    def locked(self) -> bool:
        return bool(self._locks)

    @property
    def locks(self) -> frozenset[str]:
        return frozenset(self._locks)

    def _refused(self, by: str) -> bool:
        return bool(self._locks) and by not in self._locks

    def hold(self) -> None:
        """Stop the profile now and hold the current demand position."""
        self._tails.clear()
        self._mode = _HOLD
        self.demand_velocity = 0.0

    def move_to(
        self, target_counts: float, speed_rpm: float, accel_ms: float, decel_ms: float,
        *, by: str = "", overlap: bool = False,
    ) -> None:
        """Trapezoidal move of the demand to `target_counts` (physical), starting from the
        current demand position and speed (so calling it during a move is a change-set-
        immediately). `overlap` (PR OVLP, L5051-5057): during a position move, the new
        trapezoid starts from rest at the running move's target instead, and the demand is
        the sum of the two: the running move decelerates on to its end while the new one
        accelerates (figure 7.1.6.11: smooth when Spd1/3000 x Dec = Spd2/3000 x Acc; the
        total travel is the two strokes, 000:692-709)."""
        if self._refused(by):
            return
        if overlap and self._mode == _POS and self.power:
            self._overlap()
        else:
            self._tails.clear()
        if self._mode not in (_POS, _HOLD, _STOP, _INTERP):
            self.demand = self.position  # leaving a velocity/torque mode: start bumpless
            self.demand_velocity = self.velocity
        self._mode = _POS
        self._target = float(target_counts)
        vmax = min(abs(speed_rpm), self.max_speed_rpm)
        self._vmax = rpm_to_counts_per_s(vmax, self.cpr)
        self._acc = accel_from_ms(accel_ms, self.cpr)
        self._dec = accel_from_ms(decel_ms, self.cpr)
        self.moving = True

    def run_velocity(self, rpm: float, accel_ms: float, decel_ms: float, *, by: str = "",
                     overlap: bool = False) -> None:
        """Profile velocity: ramp the speed to `rpm` (capped by `max_speed_rpm`). `overlap`
        (PR OVLP into a speed command, L5051): during a position move the speed ramps from 0,
        summed with what is left of the move's deceleration."""
        if self._refused(by):
            return
        if overlap and self._mode == _POS and self.power:
            self._overlap()
        else:
            self._tails.clear()
        if self._mode == _TORQUE:
            self.demand_velocity = self.velocity  # bumpless from the actual speed
        lim = self.max_speed_rpm
        rpm = max(-lim, min(lim, rpm))
        self._mode = _VEL
        self._vtarget = rpm_to_counts_per_s(rpm, self.cpr)
        self._acc = accel_from_ms(accel_ms, self.cpr)
        self._dec = accel_from_ms(decel_ms, self.cpr)
        self.moving = True

    def run_torque(self, target_0p1: float, slope_ms: float, *, by: str = "") -> None:
        """Profile torque: ramp the torque demand to `target_0p1` (0.1 % of rated) with a
        slope of `slope_ms` per 100 % (6087h, L18803-18817); 0 ms = step."""
        if self._refused(by):
            return
        self._tails.clear()
        rated = self.mech.rated_torque
        if self._mode != _TORQUE:
            self._tq_dem = self.torque_nm if self.power else 0.0
        self._mode = _TORQUE
        self._tq_target = target_0p1 * rated / 1000.0
        self._tq_rate = math.inf if slope_ms <= 0 else rated * 1000.0 / slope_ms
        self.moving = True

    def ramp_stop(self, decel_ms: float) -> None:
        """Decelerate at "decel_ms per 3000 rpm" to standstill, then hold the position."""
        self._tails.clear()  # the summed demand stops as one
        if self._mode in (_TORQUE, _VEL):
            self.demand = self.position
            self.demand_velocity = self.velocity
        self._mode = _STOP
        self._vtarget = 0.0
        self._dec = accel_from_ms(decel_ms, self.cpr)
        self._acc = self._dec
        self.moving = True

    def interpolate_to(self, target_counts: float, period_ns: int, *, by: str = "") -> None:
        """IP mode: move the demand linearly to `target_counts` within `period_ns`."""
        if period_ns <= 0:
            raise ValueError(f"Axis.interpolate_to: period must be > 0 ns, got {period_ns}")
        if self._refused(by):
            return
        self._tails.clear()
        if self._mode in (_TORQUE, _VEL):
            self.demand = self.position
        smooth = by != "PT" and any(w > 1 for w in self.ip_windows)
        if (smooth and self._mode == _INTERP and self._ip_ma and self._ip_rem <= 0
                and float(target_counts) == self._ip_target):
            return  # the same set-point again: nothing to interpolate, the filters settle on
        if smooth and (self._mode != _INTERP or not self._ip_ma):
            # the filters start full of the command they take over from
            self._ip_raw = self.demand
            self._ip_ma = [_MovingAverage(w, self.demand) for w in self.ip_windows if w > 1]
        elif not smooth:
            self._ip_ma = []
        self._mode = _INTERP
        self._ip_target = float(target_counts)
        start = self._ip_raw if self._ip_ma else self.demand
        self._ip_rate = (self._ip_target - start) * 1e9 / period_ns
        self._ip_rem = int(period_ns)
        self._ip_still = 0
        self._ip_settled = False
        self.moving = True

    def _overlap(self) -> None:
        """The running position profile decelerates on at its own rate as a tail, and the
        next one starts from rest where that deceleration ends: the demand stays where it is.
        A tail at speed v0 with deceleration a is v(t) = v0 - a·t, and lies v(t)²/2a short
        of its end (exact at any step length); what the running profile had left beyond
        that (less than a tick's travel, L4909) goes to the next one, so the axis still ends
        on the next profile's target (the total travel of both, 000:692-709)."""
        if self._tails:
            pm, vm = self._pmain, self._vmain
        else:
            pm, vm = self.demand, self.demand_velocity
        if vm != 0.0:
            dec = self._dec
            self._tails.append([vm, dec, 0.0])
            pm += vm * abs(vm) / (2.0 * dec)
        self._pmain, self._vmain = pm, 0.0
        self._sum = (self.demand, self.demand_velocity)

    @property
    def profile_remaining(self) -> float:
        """Counts from the running position profile's demand to its target, overlapped
        tails aside (what tells when its deceleration begins, L5051)."""
        return self._target - (self._pmain if self._tails else self.demand)

    @property
    def profile_velocity(self) -> float:
        """The running profile's own demand velocity, overlapped tails aside."""
        return self._vmain if self._tails else self.demand_velocity

    @property
    def profile_decel(self) -> float:
        """The running profile's deceleration, counts/s²."""
        return self._dec

    def set_user_position(self, user_counts: float) -> None:
        """Make the current feedback read `user_counts` (homing / origin setting)."""
        self.origin = self.position - user_counts

    # ---- accessors -----------------------------------------------------------------
    @property
    def mode(self) -> str:
        return _MODE_NAMES[self._mode]

    @property
    def target(self) -> float:
        """Active position target (physical counts) of the position profile."""
        return self._target

    @property
    def user_position(self) -> float:
        return self.position - self.origin

    @property
    def user_demand(self) -> float:
        return self.demand - self.origin

    @property
    def interpolator_demand(self) -> float:
        """The IP interpolator's output before the set-point filters (P1.068, P1.036): what
        6062h shows in IP mode ("內部插值器所計算出來的插值命令。此命令接著會經過內部濾波器",
        L18410-18412); the filtered demand (60FCh) otherwise and without a filter."""
        if self._mode == _INTERP and self._ip_ma:
            return self._ip_raw - self.origin
        return self.demand - self.origin

    @property
    def velocity_rpm(self) -> float:
        return self.velocity * 60.0 / self.cpr

    @property
    def demand_rpm(self) -> float:
        return self.demand_velocity * 60.0 / self.cpr

    @property
    def target_rpm(self) -> float:
        return self._vtarget * 60.0 / self.cpr

    @property
    def torque(self) -> float:
        """Actual motor torque in 0.1 % of rated (6077h unit)."""
        return self.torque_nm * 1000.0 / self.mech.rated_torque

    @property
    def torque_demand(self) -> float:
        """Torque demand in 0.1 % of rated (6074h): the PT ramp output, else the actual."""
        tq = self._tq_dem if self._mode == _TORQUE else self.torque_nm
        return tq * 1000.0 / self.mech.rated_torque

    @property
    def following_error(self) -> float:
        """Demand minus feedback, counts (0 in velocity/torque control)."""
        return self.demand - self.position

    @property
    def at_target(self) -> bool:
        """The command is fulfilled: position profile at its target, velocity/torque ramp at
        its target value, IP segment finished, holding. A ramp stop is at target once held."""
        m = self._mode
        if m == _POS:
            return self.demand == self._target and self.demand_velocity == 0.0
        if m == _VEL:
            return self.demand_velocity == self._vtarget
        if m == _TORQUE:
            return self._tq_dem == self._tq_target
        if m == _INTERP:
            return self._ip_rem <= 0 and (not self._ip_ma or self._ip_settled)
        return m == _HOLD

    @property
    def pulled(self) -> bool:
        """A load pulls the shaft even at rest (gravity, a constant load torque) and the
        brake does not hold it: time must be stepped at standstill too (a vertical axis sags
        with the torque off, L1351, L2427; the loop holds it with torque)."""
        # (a load static friction holds, with the torque off, moves nothing)
        return (abs(self._ext) > self._fric or (self.power and self._ext != 0.0)) \
            and not self.brake_clamped

    # ---- the integrator ------------------------------------------------------------
    def step(self, dt_ns: int) -> None:
        """Advance the axis by `dt_ns` (<= 1 ms for accuracy): the profile generator gives the
        demand, the torque or velocity loop the new speed (or the axis coasts when power is
        off), then the brake, the hard stops and settling."""
        if dt_ns <= 0:
            return
        dt = dt_ns * 1e-9
        v = self.velocity
        p = self.position
        self.last_position = p
        if self.power:
            pd0 = self.demand  # the error the loop sees is the one sampled at the step start
            mode, pd, vd, done = self._profile(dt_ns, dt)
            if mode == _TORQUE:
                nv, ramp_done = self._torque_loop(v, dt)
                done = done and ramp_done
                vd = nv
            elif mode == _VEL and self.zero_clamp and self._clamping(vd, p):
                nv = self._clamp_loop(v, p, dt_ns, dt)
            else:
                self._zc_pos = None
                nv = self._velocity_loop(v, p, pd0, vd, mode, dt_ns, dt)
        else:
            nv = self._coast(v, dt)
            mode, done, vd, pd = _HOLD, True, 0.0, p
        if self.brake_clamped:
            nv = 0.0
        p, nv = self._hard_stops(p + nv * dt, nv)
        self._settle(p, nv, pd, vd, mode, done)

    def _profile(self, dt_ns: int, dt: float) -> tuple[int, float, float, bool]:
        """(mode, position demand, velocity demand, profile done) after `dt`."""
        mode = self._mode
        if self._tails:
            # (a speed command's demand position is its feedback: `_settle`)
            if self.demand_velocity == self._sum[1] and (
                    mode == _VEL or (mode == _POS and self.demand == self._sum[0])):
                return self._profile_overlapped(mode, dt)
            self._tails.clear()  # the demand was set from outside (P0.049 = 2): one profile
        pd = self.demand
        vd = self.demand_velocity
        done = True
        if mode == _POS:
            pd, vd, done = _pos_step(pd, vd, self._target, self._vmax, self._acc, self._dec, dt)
        elif mode in (_VEL, _STOP):
            vd = _approach(vd, self._vtarget, self._acc, self._dec, dt)
            pd += vd * dt
            if mode == _STOP and vd == 0.0:
                self._mode = mode = _HOLD
            else:
                done = False
        elif mode == _INTERP and self._ip_ma:
            pd, done = self._ip_smoothed(dt_ns)
            vd = (pd - self.demand) / dt
        elif mode == _INTERP:
            rem = self._ip_rem
            if rem > 0:
                use = dt_ns if dt_ns < rem else rem
                self._ip_rem = rem = rem - use
                if rem <= 0:
                    pd = self._ip_target
                else:
                    pd += self._ip_rate * use * 1e-9
                    done = False
                vd = self._ip_rate
            else:
                vd = 0.0
        return mode, pd, vd, done

    def _profile_overlapped(self, mode: int, dt: float) -> tuple[int, float, float, bool]:
        """`_profile` while overlapped tails run (PR OVLP, L5051-5057): the running profile
        from its own state, each tail decelerating on to its target, the demand their sum."""
        if mode == _POS:
            pm, vm, done = _pos_step(self._pmain, self._vmain, self._target, self._vmax,
                                     self._acc, self._dec, dt)
        else:  # _VEL
            vm = _approach(self._vmain, self._vtarget, self._acc, self._dec, dt)
            pm, done = self._pmain + vm * dt, False
        self._pmain, self._vmain = pm, vm
        pd, vd = pm, vm
        left = []
        for tail in self._tails:
            v0, dec, t = tail
            tail[2] = t = t + dt
            speed = abs(v0) - dec * t
            if speed > 0.0:
                v = speed if v0 > 0.0 else -speed
                left.append(tail)
                pd -= v * speed / (2.0 * dec)  # still this far short of the tail's end
                vd += v
        self._tails = left
        if not left:  # the last tail landed: the running profile alone, as if never summed
            pd, vd = pm, vm
        self._sum = (pd, vd)
        return mode, pd, vd, done and not left

    def _ip_smoothed(self, dt_ns: int) -> tuple[float, bool]:
        """The interpolated command through the moving averages (P1.068, then P1.036).
        Once the command has been still for a whole window, the output is the command."""
        raw, rem = self._ip_raw, self._ip_rem
        if rem > 0:
            use = dt_ns if dt_ns < rem else rem
            self._ip_rem = rem = rem - use
            raw = self._ip_target if rem <= 0 else raw + self._ip_rate * use * 1e-9
            self._ip_raw = raw
            self._ip_still = 0
        else:
            self._ip_still += 1
        x = raw
        for ma in self._ip_ma:
            x = ma.push(x)
        if rem <= 0 and self._ip_still >= sum(ma.n for ma in self._ip_ma):
            for ma in self._ip_ma:
                ma.fill(raw)
            self._ip_settled = True
            return raw, True
        return x, False

    def _clamping(self, vd: float, p: float) -> bool:
        """ZCLAMP: the (ramped) speed command is below `zero_clamp_rpm`; the lock position is
        where the clamp began."""
        if abs(vd) * 60.0 / self.cpr >= self.zero_clamp_rpm:
            self._zc_pos = None
            return False
        if self._zc_pos is None:
            self._zc_pos = p
        return True

    def _clamp_loop(self, v: float, p: float, dt_ns: int, dt: float) -> float:
        """Hold the clamp position ("lock") or command speed 0 ("zero")."""
        lock = self._zc_pos
        if self.zero_clamp == "lock" and lock is not None:
            return self._velocity_loop(v, p, lock, 0.0, _POS, dt_ns, dt)
        return self._velocity_loop(v, p, p, 0.0, _VEL, dt_ns, dt)

    def _torque_loop(self, v: float, dt: float) -> tuple[float, bool]:
        """Torque mode: ramp the torque demand, limit it, integrate the speed (P1.055 speed
        limit). Returns (new speed, ramp done)."""
        k, ext, fr = self._k, self._ext, self._fric
        done = True
        tq = self._tq_dem
        tt = self._tq_target
        if tq != tt:
            d = self._tq_rate * dt
            tq = min(tt, tq + d) if tt > tq else max(tt, tq - d)
            self._tq_dem = tq
            done = False
        limited = tq > self._tmax or tq < self._tmin
        if tq > self._tmax:
            tq = self._tmax
        elif tq < self._tmin:
            tq = self._tmin
        self.torque_limited = limited
        net = tq - ext
        if v == 0.0:
            if -fr <= net <= fr:
                net = 0.0
            else:
                net -= fr if net > 0.0 else -fr
        else:
            net -= fr if v > 0.0 else -fr
        nv = v + net * k * dt
        if v != 0.0 and nv * v < 0.0 and (tq - ext) * v <= 0.0:
            nv = 0.0
        lim_rpm = self.max_speed_rpm
        sl = self.speed_limit_rpm
        if sl is not None and sl < lim_rpm:  # DI.SPDLM (P1.009-P1.011)
            lim_rpm = sl
        lim = lim_rpm * self.cpr / 60.0
        if nv > lim or nv < -lim:  # speed-limited torque mode (P1.055)
            nv = lim if nv > 0.0 else -lim
            tq = (nv - v) / (k * dt) + ext + (fr if nv > 0.0 else -fr)
        self.torque_nm = tq
        return nv, done

    def _velocity_loop(self, v: float, p: float, pd: float, vd: float, mode: int, dt_ns: int,
                       dt: float) -> float:
        """Speed (mode _VEL) or position loop with feed-forward; first-order velocity response,
        torque limited. Returns the new speed."""
        k, ext, fr = self._k, self._ext, self._fric
        vcmd = vd if mode == _VEL else self.feedforward * vd + self.kpp * (pd - p)
        if mode == _INTERP:  # a stream of set-points (IP, PT) is capped by P1.055 (L4034)
            vmax = self.max_speed_rpm * self.cpr / 60.0
            vcmd = vmax if vcmd > vmax else (-vmax if vcmd < -vmax else vcmd)
        if dt_ns != self._alpha_dt:
            self._alpha_dt = dt_ns
            self._alpha = 1.0 - math.exp(-dt / self._tau_v)
        nv = v + (vcmd - v) * self._alpha
        f = fr if nv > 0.0 else (-fr if nv < 0.0 else 0.0)
        tq = (nv - v) / (k * dt) + ext + f
        if self._pressed:  # stalled at a hard stop: the loop's integral winds up
            tq = self._stall_wind(tq, dt)
        limited = True
        if tq > self._tmax:
            tq = self._tmax
            nv = v + (tq - ext - f) * k * dt
        elif tq < self._tmin:
            tq = self._tmin
            nv = v + (tq - ext - f) * k * dt
        else:
            limited = False
        self.torque_limited = limited
        self.torque_nm = tq
        return nv

    def _coast(self, v: float, dt: float) -> float:
        """Power off: coast or dynamic brake (implicit, always stable). Returns the new speed."""
        k, ext, fr = self._k, self._ext, self._fric
        sm = self.stop_mode
        c = 0.0
        if sm == 0 or (sm == 2 and abs(v) * 60.0 / self.cpr >= self.zero_speed_rpm):
            c = self._db * k * dt
        if v == 0.0:
            if -fr <= ext <= fr:
                return 0.0
            net = -ext + (fr if ext > 0.0 else -fr)
            return net * k * dt / (1.0 + c)
        nv = (v + (-ext - (fr if v > 0.0 else -fr)) * k * dt) / (1.0 + c)
        return 0.0 if nv * v < 0.0 else nv

    def _hard_stops(self, p: float, nv: float) -> tuple[float, float]:
        """The mechanical end stops hold the axis (position, speed); `_pressed` says whether
        the loop is pushing into one (the next step's torque winds up)."""
        pressed = 0
        hs = self._hs_neg
        if hs is not None and p < hs:
            p = hs
            if nv < 0.0:
                nv, pressed = 0.0, -1
        hs = self._hs_pos
        if hs is not None and p > hs:
            p = hs
            if nv > 0.0:
                nv, pressed = 0.0, 1
        if pressed != self._pressed:
            self._pressed, self._stall_tq = pressed, 0.0
        return p, nv

    def _stall_wind(self, tq: float, dt: float) -> float:
        """The speed loop's integral at a stall: a first-order loop alone holds a torque
        proportional to the speed error, so pushing slowly into a stop would never reach the
        torque limit; a PI loop keeps adding the error and does, within a few speed-loop time
        constants. Only while the command still pushes into the stop."""
        if (tq > 0.0) != (self._pressed > 0):
            self._stall_tq = 0.0
            return tq
        self._stall_tq += tq * dt / self._tau_v
        return tq + self._stall_tq

    def _settle(self, p: float, nv: float, pd: float, vd: float, mode: int,
                done: bool) -> None:
        """Snap to the demand once within the settle band, and store the new state."""
        if not self.power:
            pd = p
            moving = nv != 0.0
        elif mode in (_VEL, _TORQUE):
            pd = p
            if mode == _VEL and vd == 0.0 and -_SETTLE_VEL < nv < _SETTLE_VEL:
                nv = 0.0
            moving = not done or nv != 0.0 or vd != 0.0
        else:
            e = pd - p
            if -_SETTLE_POS < e < _SETTLE_POS and -_SETTLE_VEL < nv < _SETTLE_VEL and vd == 0.0:
                p = pd
                nv = 0.0
            moving = not done or nv != 0.0 or p != pd
        self.position = p
        self.velocity = nv
        self.demand = pd
        self.demand_velocity = vd
        self.moving = moving


__all__ = [
    "Axis",
    "accel_from_ms",
    "counts_per_s_to_rpm",
    "counts_to_puu",
    "puu_per_s_to_rpm",
    "puu_to_counts",
    "ramp_time_ms",
    "rpm_to_counts_per_s",
    "rpm_to_puu_per_s",
]
