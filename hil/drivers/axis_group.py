"""A motion controller's axis group: cyclic interpolated position (CiA 402 IP mode) to many
drives on one CAN bus, with a profile generator (PG) and an electronic gear (GEA) per axis.

Seed 004 (TG Motion v4 "Servo" group, digest `../shared/spec/others.md` §4) gives the
semantics, cited `004:N`; the A3 manual the drive's side (IP mode, L17211-17244). Each
CycleTime the group computes every axis's `WritePosition` (004:214-218), sends it by RPDO1
(60C1h sub 1 and the controlword 6040h, synchronous: applied at the next SYNC, L17051), then
the SYNC; each drive answers with TPDO1 (6041h, 6064h) sampled at that SYNC (L17055). A
feedback that has not come when the next cycle starts is a **missed cycle**, counted per
axis and recorded on `/group/<name>/cycle` with the cycle's bus load.

When an axis is lost (status -1) or faulted (1), the group's policy is that every axis geared
or cammed to it holds its gear input where that master was last seen (`held` on the cycle
record), so no follower jumps or chases; the other axes go on.

Per axis (`ServoAxis`, 004:254-256): `mode` 1 PG, 3 GEA, 4 PG+GEA; `write_position` = PG.APos
(+ GEA.Position) + Offset + Correction; `position`, `position_error`, `speed`; `control` bits
(0 fault reset, held >= 1 cycle; 1 axis not under torque); `status` -1 lost after
communicating, 0 never, 1 fault, 2 ready without torque, 3 with torque.

Choices where the seed is silent (docs/group.md): the ramp shapes 0 and 1 (only type 2's
157 % peak and "the same duration for all shapes" are given): 3 linear, a = Acc; 2 harmonic,
v = V (1 - cos(pi t / T)) / 2; 1 "short both", v = V (1 - (1 - t/T)^2) on both ramps; 0 "short
accel, long decel": the type-1 acceleration and the harmonic deceleration.
"""

from __future__ import annotations

import math
import struct
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import can

from hil import clock
from hil.transport.cyclic import Cyclic
from hil.transport.sim import frame_bits

RAMP_TYPES = (0, 1, 2, 3)
PEAK = {3: 1.0, 2: math.pi / 2, 1: 2.0}  # peak acceleration / Acc of each shape (004:226)
SYNC_ID = 0x80
MAX_CONSUMER_S = 65.535  # a consumer heartbeat time is 16 bits of ms (CiA 301 1016h)
GEAR_SETTLE_S = 0.1  # engaged time before the gear judge takes its reference
MIN_TRAVEL = 1000  # increments of follower travel before a ratio is measured
I32_MIN, I32_MAX = -(1 << 31), (1 << 31) - 1  # 60C1h sub 1 (L19059-19070)
STATUS_LOST, STATUS_NEVER, STATUS_FAULT, STATUS_READY, STATUS_TORQUE = -1, 0, 1, 2, 3


# ------------------------------------------------------------------------------ ramp shapes


def _shape(kind: int, x: float) -> float:
    """Fraction of the speed change done at fraction `x` of a ramp (0..1)."""
    x = min(max(x, 0.0), 1.0)
    if kind == 3:
        return x
    if kind == 2:
        return (1.0 - math.cos(math.pi * x)) / 2.0
    return 1.0 - (1.0 - x) ** 2  # "short": the steepest at the start


def _area(kind: int) -> float:
    """Mean of `_shape` over a ramp: distance = V x T x area."""
    return {3: 0.5, 2: 0.5}.get(kind, 2.0 / 3.0)


def _shapes(ramp_type: int) -> tuple[int, int]:
    """(acceleration shape, deceleration shape) of a PG.Type (0-3)."""
    return {0: (1, 2), 1: (1, 1), 2: (2, 2), 3: (3, 3)}[ramp_type]


# ------------------------------------------------------------------------------ PG


@dataclass
class Pg:
    """The profile generator of one axis (004:220-226): position moves and speed runs with
    four ramp types, the same ramp duration for every shape (T = speed / Acc)."""

    acc: float = 100_000.0  # inc/s²
    dec: float = 100_000.0
    pos_speed: float = 50_000.0  # inc/s
    type: int = 3
    apos: float = 0.0  # actual (generated) position
    aspeed: float = 0.0
    dpos: float = 0.0
    rdy: bool = True
    mode: int = 0  # 0 speed / abort, 1 position, 3 braking
    peak_acc: float = 0.0  # the largest |speed change| / cycle since the last start
    _plan: tuple | None = None
    _t: float = 0.0

    def start_position(self, target: float) -> None:
        """Absolute positioning to `target` (PG.Mode = 1); from rest or on the fly. Acc, Dec
        and PosSpeed are limits (004:220): a move running away from the new target, faster
        than PosSpeed, or too fast to stop on it first brakes with Dec (to rest, or down to
        PosSpeed), then plans the rest from there; nothing jumps."""
        self.peak_acc = 0.0
        self.dpos = float(target)
        self.mode = 1
        self.rdy = False
        self._plan_to(self.dpos)

    def _plan_to(self, target: float) -> None:
        self._t = 0.0
        v0, dist = self.aspeed, target - self.apos
        sign = 1.0 if dist >= 0 else -1.0
        toward = v0 * sign
        _, sd = _shapes(self.type)
        stop = toward * toward / self.dec * (1.0 - _area(sd)) if self.dec > 0 else 0.0
        if v0 and (toward < 0 or stop > abs(dist) + 1e-9):
            self._brake(0.0, target)  # away, or past it: to rest, then back
        elif abs(v0) > self.pos_speed > 0:
            self._brake(math.copysign(self.pos_speed, v0), target)
        else:
            self._plan = self._position_plan(self.apos, v0, target)

    def _brake(self, v1: float, then: float) -> None:
        """Ramp the speed to `v1` with Dec, then position to `then`."""
        v0 = self.aspeed
        t = abs(v1 - v0) / self.dec if self.dec > 0 else 0.0
        self._plan = ("brake", v0, v1, t, _shapes(self.type)[1], then)

    def start_speed(self, speed: float, slope: float | None = None) -> None:
        """Speed control (PG.Mode = 0): ramp to `speed` with Acc (004:226), or `slope`."""
        self.peak_acc = 0.0
        self.mode = 0
        self.rdy = False
        v0 = self.aspeed
        slope = self.acc if slope is None else slope
        t = abs(speed - v0) / slope if slope > 0 else 0.0
        self._plan = ("speed", v0, float(speed), t, _shapes(self.type)[0])
        self._t = 0.0

    def abort(self, dec: float | None = None) -> None:
        """PG.Mode = 0, PG.Speed = 0: brake to rest (004:226), with `dec` (COMMAND 5's Par1)
        if given; PG.Acc is left as it was."""
        self.start_speed(0.0, dec)
        self.mode = 3

    def _position_plan(self, p0: float, v0: float, p1: float) -> tuple:
        sa, sd = _shapes(self.type)
        dist = p1 - p0
        sign = 1.0 if dist >= 0 else -1.0
        d = abs(dist)
        v0s = max(0.0, v0 * sign)  # an on-the-fly start keeps its speed towards the target
        vmax = self.pos_speed
        ka, kd = _area(sa), _area(sd)

        def dist_at(v: float) -> float:
            ta = (v - v0s) / self.acc if self.acc > 0 else 0.0
            td = v / self.dec if self.dec > 0 else 0.0
            return v0s * ta + (v - v0s) * ta * ka + v * td * (1.0 - kd)

        v = vmax
        if dist_at(v) > d:  # a triangle: the highest speed that still stops on the target
            lo, hi = v0s, vmax
            for _ in range(60):
                mid = (lo + hi) / 2
                lo, hi = (mid, hi) if dist_at(mid) <= d else (lo, mid)
            v = lo
            if v <= v0s and d > 0 and self.acc > 0 and self.dec > 0:
                # below the search's resolution (PosSpeed 1e20 over Acc 0.001): the root of
                # dist_at(v) = d, a quadratic; v = 0 would land on the target in one cycle
                a = ka / self.acc + (1.0 - kd) / self.dec
                b = v0s * (1.0 - 2.0 * ka) / self.acc
                c = v0s * v0s * (ka - 1.0) / self.acc - d
                v = max(v0s, (-b + math.sqrt(max(0.0, b * b - 4.0 * a * c))) / (2.0 * a))
        ta = (v - v0s) / self.acc if self.acc > 0 else 0.0
        td = v / self.dec if self.dec > 0 else 0.0
        cruise = (d - dist_at(v)) / v if v > 0 else 0.0
        return ("pos", p0, sign, v0s, v, ta, max(cruise, 0.0), td, sa, sd, p1)

    def tick(self, dt: float) -> None:
        """Advance by one cycle of `dt` s (and note the peak acceleration)."""
        v0 = self.aspeed
        self._tick(dt)
        if dt > 0:
            self.peak_acc = max(self.peak_acc, abs(self.aspeed - v0) / dt)

    def _tick(self, dt: float) -> None:
        plan = self._plan
        if plan is None:
            self.apos += self.aspeed * dt  # speed control at its speed (0 at rest)
            return
        self._t += dt
        t = self._t
        if plan[0] in ("speed", "brake"):
            v0, v1, tr, shape = plan[1:5]
            v = v1 if tr <= 0 or t >= tr else v0 + (v1 - v0) * _shape(shape, t / tr)
            self.apos += (self.aspeed + v) / 2 * dt
            self.aspeed = v
            if t >= tr:
                if plan[0] == "brake":  # then position from here
                    self._plan_to(plan[5])
                    return
                self._plan = None
                if v1 == 0.0:
                    self.mode = 0
                # Rdy means the target position was reached (004:220, 004:256): not at the
                # end of a speed ramp, whose end the manual waits for by ASpeed = 0 (004:224)
            return
        _, p0, sign, v0, v, ta, tc, td, sa, sd, p1 = plan
        if t < ta:
            s = v0 * t + (v - v0) * ta * _integral(sa, t / ta)
            speed = v0 + (v - v0) * _shape(sa, t / ta)
        elif t < ta + tc:
            s = v0 * ta + (v - v0) * ta * _area(sa) + v * (t - ta)
            speed = v
        elif t < ta + tc + td:
            u = t - ta - tc
            s0 = v0 * ta + (v - v0) * ta * _area(sa) + v * tc
            s = s0 + v * u - v * td * _integral(sd, u / td)
            speed = v * (1.0 - _shape(sd, u / td))
        else:
            self.apos, self.aspeed, self.rdy, self._plan = p1, 0.0, True, None
            return
        self.apos = p0 + sign * s
        self.aspeed = sign * speed


def _integral(kind: int, x: float) -> float:
    """Integral of `_shape` from 0 to x (x in 0..1)."""
    if kind == 3:
        return x * x / 2
    if kind == 2:
        return (x - math.sin(math.pi * x) / math.pi) / 2
    return x * x - x ** 3 / 3


# ------------------------------------------------------------------------------ GEA


CAM_STEP = 1024  # the pointer is 1024 x finer than the table (004:232)
# the cam tables' shared memory, in doubles (004:232): CamTab 0 TGM_Cam_Profile 1048576 B,
# CamTab 1 TGM_Data 524288 B
CAM_MEMORY = {0: 1048576 // 8, 1: 524288 // 8}


class CommandError(ValueError):
    """A COMMAND the group cannot accept (Control stays set; the step names why)."""


# a gear's In and Out, and the ratio In/Out: a group's choice, the seed gives no limit.
# 1e9 / 1e-300 overflowed the cycle; a slave moved 1e9 times its master is no axis either
RATIO_MAX = 1e9


def ratio_problem(gin: float, gout: float) -> tuple[str, str]:
    """('in' or 'out', why) when In/Out is no gear ratio, else ('', ''); In 0 is a ratio of
    0 (nothing moves). The side named is the one to change."""
    if not math.isfinite(gin):
        return "in", f"In {gin:g}: a finite number"
    if not math.isfinite(gout):
        return "out", f"Out {gout:g}: a finite number"
    if abs(gin) > RATIO_MAX:
        return "in", f"In {gin:g}: within ±{RATIO_MAX:g}"
    if gout == 0:
        return "out", f"Out 0: the ratio In/Out = {gin:g}/0 needs Out"
    if abs(gout) > RATIO_MAX:
        return "out", f"Out {gout:g}: within ±{RATIO_MAX:g}"
    if gin and abs(gin / gout) > RATIO_MAX:
        return "out", (f"ratio In/Out = {gin:g}/{gout:g}: at most {RATIO_MAX:g} (a slave "
                       f"moved more than {RATIO_MAX:g} times its master is no axis)")
    if gin and abs(gin / gout) < 1 / RATIO_MAX:
        return "in", (f"ratio In/Out = {gin:g}/{gout:g}: at least {1 / RATIO_MAX:g}, 0 "
                      f"aside (our limit, the mirror of {RATIO_MAX:g})")
    return "", ""


# PG magnitudes per COMMAND code (004:220 "maximální akcelerace / decelerace / rychlost"):
# Par0 Acc, Par1 Dec, Par2 PosSpeed (code 1's Par2 is a signed speed); 0 keeps the register
MAGNITUDES = {1: ((0, "Acc"),), 2: ((0, "Acc"), (1, "Dec"), (2, "PosSpeed")),
              3: ((0, "Acc"), (1, "Dec"), (2, "PosSpeed")), 5: ((1, "Dec"),)}
# the least non-zero PG.Acc / Dec / PosSpeed a COMMAND may give (inc/s², inc/s): the seed sets
# none, but a smaller one is no move at all (Acc 1e-300 over 200000 inc takes 1e150 s) and
# its profile is below the arithmetic's resolution (it had landed on the target at once)
PG_MIN = 1e-3
# the COMMAND functions (004:240-246): 1 speed, 2 absolute, 3 relative, 4 set reference,
# 5 abort, 6 sync on, 7 sync off
COMMAND_CODES = (1, 2, 3, 4, 5, 6, 7)
# the Par each function reads (004:240-246)
COMMAND_READS = {1: (0, 2, 4, 5), 2: (0, 1, 2, 3, 4, 5), 3: (0, 1, 2, 3, 4, 5), 4: (3,),
                 5: (1, 5), 6: (0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 12, 13), 7: (5,)}


def gear_cycle(axes: Mapping[str, Any], follower: str, master: str,
               source: int) -> list[str] | None:
    """The chain `follower <- master <- ... <- follower` that taking `master` by position
    (source 1 WritePosition, 2 Position) would close, else None: each would follow the other's
    travel and run away. Source 3 (ServoTick) reads no axis (004:230)."""
    if source == 3:
        return None
    chain, seen, m = [follower, master], {follower}, master
    while m not in seen:
        seen.add(m)
        a = axes.get(m)
        if a is None or not a.gea.mode or a.gea.source == 3:
            return None
        m = a.gea.master
        chain.append(m)
    return chain if m == follower else None


@dataclass
class Gea:
    """Gear and cam from a master axis (004:228-238). Linear gear (mode 1): Position +=
    d(master) x ActualIn / Out; ActualIn ramps towards In by IncIn per tick (the clutch),
    ActualShift towards Shift by IncShift. Cam (mode 2): the same Position is the table
    pointer, 1024 increments per table step, linearly interpolated; a return cam (type 0)
    runs from the last entry back to the first and repeats, an incremental cam (type 1) adds
    the last entry as a stroke on every pass; CamPosition = table value x CamScale."""

    master: str = ""
    source: int = 1  # 1 master WritePosition, 2 master Position, 3 ServoTick (time: the
    # master's name is then only the group's reference; the tick counts cycles)
    gin: float = 1.0
    gout: float = 1.0
    inc_in: float = 0.0  # 0: the ratio at once
    shift: float = 0.0
    inc_shift: float = 0.0
    actual_in: float = 0.0
    actual_shift: float = 0.0
    position: float = 0.0
    mode: int = 0  # 0 idle, 1 linear gear, 2 cam
    cam: list[float] = field(default_factory=list)
    cam_type: int = 0  # 0 return, 1 incremental
    cam_scale: float = 1.0
    cam_position: float = 0.0
    # CamIncPosition (COMMAND Par13): the incremental cam's stroke given outright, in place of
    # its last table value (004:242, "to remove the rounding error"); 0: the last value
    cam_inc_position: float = 0.0
    _last: float | None = None

    def cam_value(self, pointer: float) -> float:
        """The cam at `pointer` (GEA.Position, in master increments x ratio)."""
        table = self.cam
        n = len(table)
        step = pointer / CAM_STEP
        if self.cam_type == 0:  # return: n segments, the last one back to the first
            k = math.floor(step)
            frac = step - k
            i = k % n
            a, b = table[i], table[(i + 1) % n]
            return (a + (b - a) * frac) * self.cam_scale
        # incremental (004:232): n segments a pass, the first from an explicit 0 to the first
        # value; the last value is the stroke each pass adds (or CamIncPosition)
        k = math.floor(step)
        passes, i = divmod(k, n)
        frac = step - k
        a = table[i - 1] if i else 0.0
        b = table[i]
        stroke = self.cam_inc_position or table[-1]
        return (passes * stroke + a + (b - a) * frac) * self.cam_scale

    def reset_master(self) -> None:
        """Forget the master's last value: the next tick takes its value as the start, so a
        new master or source moves nothing at once (004:236-238: nothing jumps)."""
        self._last = None

    def tick(self, master_value: float) -> None:
        if self.mode == 0:
            self._last = None
            return
        if self.inc_in <= 0:
            self.actual_in = self.gin
        else:
            step = math.copysign(min(self.inc_in, abs(self.gin - self.actual_in)),
                                 self.gin - self.actual_in)
            self.actual_in += step
        if self.inc_shift <= 0:
            ds = self.shift - self.actual_shift
        else:
            ds = math.copysign(min(self.inc_shift, abs(self.shift - self.actual_shift)),
                               self.shift - self.actual_shift)
        self.actual_shift += ds
        delta = 0.0 if self._last is None else master_value - self._last
        self._last = master_value
        self.position += delta * self.actual_in / self.gout + ds
        if self.mode == 2 and self.cam:
            self.cam_position = self.cam_value(self.position)


# ------------------------------------------------------------------------------ SDO interface


# CiA 301's abort "data type does not match, length of service parameter does not match"
SDO_LENGTH_MISMATCH = 0x06070010


class _SdoLength(Exception):
    code = SDO_LENGTH_MISMATCH


@dataclass
class SdoInterface:
    """The SDO interface of one axis (004:248-250): Control 1 write / 2 read (0 when done),
    Status 0 OK / 1 in progress / 2 error, NumberByte 1-4, Index, SubIndex, Data (the value,
    or the abort code when Status = 2)."""

    control: int = 0
    status: int = 0
    number_byte: int = 4
    index: int = 0
    sub: int = 0
    data: int = 0

    def execute(self, upload: Callable[[int, int], bytes],
                download: Callable[[int, int, bytes], None]) -> None:
        """Carry out the request in `control` through an SDO client's upload/download."""
        if self.control not in (1, 2):
            return
        self.status = 1
        if self.number_byte not in (1, 2, 3, 4):  # 1-4, the object's size (004:248-250):
            self.status, self.data, self.control = 2, SDO_LENGTH_MISMATCH, 0  # nothing sent
            return
        try:
            if self.control == 1:
                raw = (self.data & ((1 << (8 * self.number_byte)) - 1)).to_bytes(
                    self.number_byte, "little")
                download(self.index, self.sub, raw)
            else:
                raw = upload(self.index, self.sub)
                if len(raw) > self.number_byte:  # more than NumberByte: no value cut short
                    raise _SdoLength()  # (a smaller object reads whole: the seed's own
                self.data = int.from_bytes(raw, "little")  # example, 6060h in 2 bytes)
            self.status = 0
        except Exception as e:
            self.status = 2
            self.data = int(getattr(e, "code", 0x05040000))  # SDO protocol timed out
        self.control = 0


# ------------------------------------------------------------------------------ CAPTURE

CAPTURE_RISING, CAPTURE_FALLING, CAPTURE_ZERO = 0x01, 0x02, 0x10  # Typ_ExtCapture (004:252)


@dataclass
class CaptureInterface:
    """The CAPTURE interface of one axis (004:252, offsets 004:260): Control 0 disabled, 1
    capture on the drive's input (the A3's own capture on DI7 or the looped Z pulse, armed
    and read over SDO by the group's steps), 2 a one-shot capture of the registers by the
    group at its next cycle; Control returns to 0 once captured. Typ_ExtCapture bit 0 rising
    DI1, bit 1 falling DI1, bit 4 encoder zero pulse (the A3 captures on DI7 only, L5150:
    the seed's DI1 is its DI7). Results: PPosition / NPosition (actual at the rising /
    falling edge), Write_Position (set-point), Zero_Position (at the zero pulse)."""

    control: int = 0
    typ_ext_capture: int = 0
    start: int = 0  # the A3 data array entry the drive stores the value in (P5.036)
    p_position: float = 0.0
    n_position: float = 0.0
    write_position: float = 0.0
    zero_position: float = 0.0
    captures: int = 0  # completed captures
    armed_at: int = 0  # `captures` when it was last armed: done once it has grown
    armed: int = 0  # the Control it was last armed with (1, 2; 0 never)

    def store(self, value: float, write_position: float) -> None:
        """A captured actual position: into the register its type names; Control to 0."""
        if self.typ_ext_capture & CAPTURE_ZERO:
            self.zero_position = value
        elif self.typ_ext_capture & CAPTURE_FALLING:
            self.n_position = value
        else:
            self.p_position = value
        self.write_position = write_position
        self.control = 0
        self.captures += 1

    @property
    def position(self) -> float:
        """The register this capture type fills."""
        if self.typ_ext_capture & CAPTURE_ZERO:
            return self.zero_position
        return self.n_position if self.typ_ext_capture & CAPTURE_FALLING else self.p_position

    def record(self, name: str, cycle: int) -> dict[str, Any]:
        return {"axis": name, "cycle": cycle, "typ_ext_capture": self.typ_ext_capture,
                "p_position": round(self.p_position), "n_position": round(self.n_position),
                "zero_position": round(self.zero_position),
                "write_position": round(self.write_position), "captures": self.captures}


# ------------------------------------------------------------------------------ the axes


@dataclass
class ServoAxis:
    """One axis of the group (004:254-256)."""

    name: str
    node: int
    mode: int = 1  # 1 PG, 3 GEA, 4 PG + GEA
    control: int = 0  # bit 0 fault reset (held >= 1 cycle), bit 1 axis not under torque
    offset: float = 0.0
    correction: float = 0.0
    write_position: float = 0.0
    position: float = 0.0
    speed: float = 0.0
    write_speed: float = 0.0  # WriteSpeed: d/dt WritePosition (004 appendix, offset 520)
    status: int = STATUS_NEVER
    statusword: int = 0
    missed: int = 0
    rdy_cycle: int = 0  # the cycle in which the PG last reached its target
    arrived_cycle: int = 0  # the cycle whose feedback first showed the PG's target (0: not)
    sdo: SdoInterface = field(default_factory=SdoInterface)
    capture: CaptureInterface = field(default_factory=CaptureInterface)
    command: int = 0  # COMMAND.Control (004:240): the function number, 0 once accepted
    par: list[float] = field(default_factory=lambda: [0.0] * 15)  # COMMAND.Par[0..14]
    pg: Pg = field(default_factory=Pg)
    gea: Gea = field(default_factory=Gea)
    heartbeat_lost: bool = False  # its heartbeat is older than the consumer time
    rebooted: bool = False  # its boot-up heartbeat came: mapping and IP mode are gone
    enabling: bool = True  # walk it up to operation enabled (see controlword)
    setpoint_error: str = ""  # why its last set-point could not be sent
    _last_control: int = 0
    gear_phase_error: float = 0.0  # a geared follower's drift from its master (increments)
    gear_ratio_error: float = 0.0  # |measured ratio - In/Out| / |In/Out| since engagement
    _gear_ref: tuple[float, float] | None = None  # (follower, master) when judging began
    _gear_settle: int = 0  # cycles engaged so far
    _gear_key: tuple = ()  # the gear the reference was taken for
    _hb_ns: int | None = None  # when its last heartbeat came (None: none yet, not watched)
    _seen: bool = False  # feedback of the current cycle arrived
    _silent: int = 0  # cycles in a row without its feedback
    _ever: bool = False
    _last_pos: float | None = None
    _sent: list[float] = field(default_factory=list)  # the last set-points sent, newest last
    _cw: int = -1  # the state-keeping controlword sent last (-1: none yet)
    _fb_since_cw: int = 2  # feedbacks since it changed: the 2nd is the first to show it

    @property
    def follow_error(self) -> float:
        """The set-point the feedback answers minus the feedback: the set-point of cycle k
        reaches the drive at SYNC k and is interpolated to by SYNC k + 1, whose TPDO the
        group reads in cycle k + 2 (L17051-17057)."""
        return self._sent[0] - self.position if len(self._sent) == 3 else 0.0

    def accept_command(self, axes: dict[str, ServoAxis],
                       cams: dict[int, list[float]] | None = None) -> None:
        """COMMAND (004:240-246): the function in `command` with `par`, taken at the start
        of a cycle; `command` returns to 0 on acceptance, 7 (sync off) only once the ratio
        ramp has run out."""
        code, p = self.command, self.par
        if code == 0:
            return
        if code not in COMMAND_CODES:
            raise CommandError(f"Control {code}: a COMMAND function 1-7 (004:240)")
        bad = next((i for i in COMMAND_READS[code] if not math.isfinite(p[i])), None)
        if bad is not None:  # a NaN target ran away or hung the ramp (an unread Par is moot:
            raise CommandError(f"Par{bad} {p[bad]}: a finite number")  # an abort still acts)
        pg = self.pg
        if code in (1, 2, 3, 5):
            if int(p[5]) not in RAMP_TYPES or p[5] != int(p[5]):
                raise CommandError(f"Par5 {p[5]:g}: a ramp type 0-3 (004:222)")
            for i, what in MAGNITUDES[code]:
                if p[i] < 0 or 0 < p[i] < PG_MIN:
                    raise CommandError(f"Par{i} {p[i]:g}: PG.{what} is a maximum, 0 (keep "
                                       f"the register) or at least {PG_MIN:g} (004:220)")
            pg.type = int(p[5])
        if code == 1:  # run speed: Par0 Acc, Par2 Speed, Par4 0 cancel GEA / 1 superimpose
            pg.acc = p[0] or pg.acc
            if not p[4] and self.gea.mode:  # Par4 0: an active GEA is cancelled (004:240);
                self._connect_pg(self.write_speed)  # with none, the PG runs on as it is
                self.gea.mode = 0
                self.mode = 1
            elif p[4] and self.gea.mode:
                self.superimpose()
            else:
                self.set_mode(1)  # the PG where the axis stands (a mode 3 axis had jumped)
            pg.start_speed(p[2])
        elif code in (2, 3):  # absolute / relative: Par0 Acc, Par1 Dec, Par2 Speed, Par3
            pg.acc, pg.dec, pg.pos_speed = p[0] or pg.acc, p[1] or pg.dec, p[2] or pg.pos_speed
            if not p[4] and self.gea.mode:  # Par4 0: an active GEA is cancelled, the PG
                self._connect_pg(self.write_speed)  # takes over where and as fast as the
                # axis goes (004:242): the move starts on the fly, nothing jumps
                self.gea.mode = 0
                self.mode = 1
            elif self.mode == 3:
                self.superimpose()
            pg.start_position(p[3] if code == 2 else pg.apos + p[3])
        elif code == 4:  # set reference: the PG's position is declared Par3; Offset takes
            # the difference, so the set-point (and the motor) stays where it is (004:226):
            # WritePosition = [PG.APos] + [GEA part] + Offset + Correction, by Servo.Mode
            pg.apos = p[3]
            if pg._plan is not None and pg._plan[0] == "pos":  # a move running: on from
                pg._plan_to(pg.dpos)  # here to DPos in the new frame, at its speed
            self.offset = self.write_position - self.correction - self.base()
        elif code == 5:  # abort: Par1 Dec (PG.Acc stays for the next move)
            pg.abort(p[1] or pg.dec)  # Par1 0 keeps PG.Dec (004:242)
        elif code == 6:  # sync on: Par0 master, Par1 source, Par2 1 gear / 2 + CamType cam,
            g = self.gea  # Par3/4 In/Out, Par5 IncIn; cams: Par6 CamLine, Par7 CamLen, Par8
            names = list(axes)  # CamScale, Par9 IniPosition, Par10 CamTab, Par12 ServoMode,
            idx = int(p[0])  # Par13 CamIncPosition (004:244)
            kind = int(p[2])
            if kind not in (1, 2, 3) or p[2] != kind:
                raise CommandError(f"Par2 {p[2]:g}: 1 gear, 2 return cam, 3 incremental cam")
            src = int(p[1])
            if src not in (1, 2, 3):  # 0 "GEA inactive", 4 the master's ExtPosition (004:230,
                raise CommandError(  # 004:258): no gear to run / no external encoder modelled
                    f"Par1 {p[1]:g}: the master's source 1 WritePosition, 2 Position or "
                    "3 ServoTick (0 is no gear; 4 ExtPosition is not modelled)")
            if not 0 <= idx < len(names) or p[0] != idx:
                raise CommandError(f"Par0 {p[0]:g}: the master is an axis index 0-"
                                   f"{len(names) - 1} of the group")
            side, why = ratio_problem(p[3], p[4])
            if why:
                raise CommandError(f"Par{3 if side == 'in' else 4} {why}")
            if names[idx] == self.name:
                raise CommandError(f"Par0 {idx}: an axis cannot be its own master")
            chain = gear_cycle(axes, self.name, names[idx], src)
            if chain is not None:
                raise CommandError(f"Par0 {idx}: a gear cycle {' <- '.join(chain)} (each "
                                   "would follow the other's travel and run away)")
            if p[12] not in (0, 3, 4):
                raise CommandError(f"Par12 {p[12]:g}: ServoMode 3 (GEA) or 4 (PG + GEA), 0 "
                                   "as the axis is (004:242; Mode 1, 6-8 not modelled)")
            table = self._cam_table(cams or {}, p) if kind >= 2 else None
            if self.gea.mode:  # 004:244: not called again on a synchronised axis
                raise CommandError("sync on of an axis already synchronised: sync off "
                                   "(COMMAND 7) first (004:244)")
            g.master = names[idx]
            g.source = src
            g.reset_master()  # the travel counts from the next cycle's master value
            g.gin, g.gout, g.inc_in = p[3], p[4], p[5]
            g.actual_in = 0.0 if p[5] else p[3]
            if table is None:
                g.mode = 1
                # Par12 ServoMode for a gear too (004:242); without it the PG stays in
                self.mode = (int(p[12]) if int(p[12]) in (3, 4)
                             else 4 if self.mode in (1, 4) else 3)
                # GEA.Position at the switch is Par9 (004:242; the seed's example sets it to 0
                # and the Offset so the axis stays, 004:236-238): a second sync after a sync
                # off does not jump by the gear's old position
                g.position = p[9]
            else:
                g.cam, g.cam_type, g.cam_scale = table, kind - 2, p[8] or 1.0
                g.position, g.cam_inc_position = p[9], p[13]
                g.cam_position = g.cam_value(g.position)
                g.mode = 2
                self.mode = int(p[12]) if int(p[12]) in (3, 4) else 3
            # the gear or cam starts where the axis stands: 004:216 holds at the switch (with
            # the PG's position in it for ServoMode 4), the Offset takes the difference
            self.offset = self.write_position - self.correction - self.base()
        elif code == 7:  # sync off: the ratio ramps to 0 by Par5 a cycle, then GEA idles
            g = self.gea
            if not g.mode:  # no gear or cam on: nothing to switch off
                self.command = 0
                return
            if p[5] < 0:
                raise CommandError(f"Par5 {p[5]:g}: the ratio ramp a cycle, not negative "
                                   "(004:244; 0 stops the gear at once)")
            g.gin, g.inc_in = 0.0, p[5]
            if g.actual_in != 0.0:
                return  # still ramping: Control stays 7 (004:240)
            if self.mode == 4:  # the PG on top runs on as it is: the gear's part stays in
                self.set_mode(1)  # the Offset (it had restarted the PG's move from the
            else:  # gear's travel: a jump by all of it)
                self._connect_pg()  # the PG takes over at rest where the axis stands
                self.pg._plan = None
                self.mode = 1
            g.mode = 0
        self.command = 0

    @staticmethod
    def _cam_table(cams: dict[int, list[float]], p: list[float]) -> list[float]:
        """The cam of COMMAND 6: CamLen doubles from CamLine of table CamTab (004:232)."""
        tab, line_bytes, length = int(p[10]), int(p[6]), int(p[7])
        if tab not in CAM_MEMORY:
            raise CommandError(f"CamTab {tab}: 0 (TGM_Cam_Profile) or 1 (TGM_Data)")
        if line_bytes % 8:  # CamLine: the data's start in bytes, 8 a double (004:258)
            raise CommandError(f"CamLine {line_bytes}: a byte offset of a double, a multiple "
                               "of 8")
        line = line_bytes // 8
        if int(p[2]) not in (2, 3):
            raise CommandError(f"Par2 {p[2]:g}: 1 gear, 2 return cam, 3 incremental cam")
        if line < 0:
            raise CommandError(f"CamLine {line_bytes}: the start of the cam in its table, "
                               "in bytes, 0 or more")
        if length < 2:
            raise CommandError(f"CamLen {length}: a cam needs 2 points or more")
        mem = cams.get(tab, [])
        if line + length > len(mem):
            raise CommandError(f"CamLine {line_bytes} (value {line}) + CamLen {length} past the "
                               f"{len(mem)} values written to CamTab {tab}")
        return list(mem[line:line + length])

    def superimpose(self) -> None:
        """Servo.Mode 4: the PG's moves on top of the gear / cam (004:218)."""
        self.set_mode(4)

    def set_mode(self, mode: int) -> None:
        """Servo.Mode (004:216-218) changed without a jump: a generator joins with its
        position as it stands and the Offset takes the difference (as the seed sets GEA.Offset
        or PG.APos before it connects one, 004:224, 004:236), so WritePosition stays."""
        if mode != self.mode:
            before = self.base()
            self.mode = mode
            self.offset += before - self.base()

    def _connect_pg(self, speed: float = 0.0) -> None:
        """The PG takes over where the axis stands: PG.APos = WritePosition - Offset -
        Correction (004:224), so leaving the gear moves nothing; `speed`: PG.ASpeed, the
        set-point's speed when a move or run starts at once from a moving gear."""
        self.pg.apos = self.write_position - self.offset - self.correction
        self.pg.aspeed = speed

    @property
    def position_error(self) -> float:
        return self.write_position - self.position

    def base(self) -> float:
        """The PG's and the GEA's parts of WritePosition in this Servo.Mode (004:216-218)."""
        base = 0.0
        if self.mode in (1, 4):
            base += self.pg.apos
        if self.mode in (3, 4):
            base += self.gea.cam_position if self.gea.mode == 2 else self.gea.position
        return base

    def compute(self) -> None:
        """WritePosition from the PG and/or GEA (004:216). An axis without torque (never
        enabled, faulted, ready without torque) follows itself: its Offset takes up what the
        PG or GEA moved, so the set-point is where the motor is when torque comes on."""
        base = self.base()
        if self.status in (STATUS_NEVER, STATUS_FAULT, STATUS_READY) and self._ever:
            self.offset = self.position - base - self.correction
        self.write_position = base + self.offset + self.correction

    def controlword(self) -> int:
        """The RPDO's controlword. Control bit 0 a fault reset (0x80), bit 1 no torque
        (shutdown, 0x06). Otherwise the group keeps the state it has, and walks an axis up
        to operation enabled only while `enabling` (set when the group starts and when
        Control bit 0 or 1 falls; cleared once enabled): 0x06 from switch on disabled, 0x07
        from ready to switch on, 0x0F from switched on (CiA 402). It does not re-enable what
        something else switched off (the safe state, a plan step, the drive), and never
        leaves a quick stop the drive is in (0x0B keeps it); but a word already on its way
        when a plan step switches an axis off over SDO still acts: 0x0F on a drive in ready
        to switch on enables it for a cycle (transitions 3 + 4, L18276).

        The TPDO of SYNC k is sampled before the RPDO of cycle k acts (L17051-17057), so
        the first feedback after a changed word cannot show it and the second can. A changed
        word is held until that second feedback has come: judged on a statusword that does
        not show it yet, the next word would undo it, and the two would alternate every
        cycle (a lost TPDO only holds it longer)."""
        if self.control & 0x3:
            self._cw, self._fb_since_cw = -1, 2
            return 0x80 if self.control & 0x1 else 0x06
        cw = self._state_word()
        if self._cw >= 0 and self._fb_since_cw < 2:
            cw = self._cw  # the change is not in the feedback yet: hold it
        if cw != self._cw:
            self._fb_since_cw = 0
        self._cw = cw
        return cw

    def _state_word(self) -> int:
        sw = self.statusword
        if sw & 0x4F in (0x00, 0x40):  # not ready / switch on disabled
            return 0x06 if self.enabling else 0x00
        if sw & 0x6F == 0x21:  # ready to switch on
            return 0x07 if self.enabling else 0x06
        if sw & 0x6F == 0x23:  # switched on
            return 0x0F if self.enabling else 0x07
        if sw & 0x6F == 0x07:  # quick stop active: stay (transition 16 is not the group's)
            return 0x0B
        if sw & 0x4F in (0x08, 0x0F):  # fault / fault reaction active
            return 0x00
        return 0x0F  # operation enabled

    def on_feedback(self, statusword: int, position: int, dt: float) -> None:
        if self._last_pos is not None and dt > 0:
            self.speed = (position - self._last_pos) / dt
        self._last_pos = position
        self.position = float(position)
        self.statusword = statusword
        self._seen = self._ever = True
        self._fb_since_cw += 1
        if statusword & 0x6F == 0x27:
            self.enabling = False  # there: from now on the group only keeps it
        if self.heartbeat_lost:
            self.status = STATUS_LOST  # until its heartbeat comes back, whatever its PDOs say
        elif statusword & 0x08:
            self.status = STATUS_FAULT
        elif statusword & 0x6F == 0x27:
            self.status = STATUS_TORQUE
        else:
            self.status = STATUS_READY


def interpolation_period(cycle_s: float) -> tuple[int, int]:
    """60C2h sub 1 (U8) and sub 2 (the power of ten) for a cycle of `cycle_s`: the period is
    sub1 x 10^sub2 s (L19089-19113) and must equal 1006h (L17218), so the cycle exactly."""
    us = round(cycle_s * 1e6)
    for index in (-3, -4, -5, -6):
        unit, rest = divmod(us, 10 ** (6 + index))
        if not rest and 0 < unit <= 255:
            return unit, index
    raise ValueError(f"a cycle of {us} us has no 60C2h form u x 10^i s with u 1-255")


def worst_case_bits(axes: int, *, heartbeat: bool = False) -> int:
    """The bits a cycle of `axes` axes may need on the wire, worst-case stuffing: an RPDO
    and a TPDO of 6 bytes each (115 bits) per axis and the SYNC (50), and with heartbeats
    one 1-byte heartbeat (65) per axis, as they may all fall in one cycle."""
    return axes * (115 + 115 + (65 if heartbeat else 0)) + 50


def _bits(cob: int, dlc: int) -> int:
    return frame_bits(can.Message(arbitration_id=cob, data=bytes(dlc), is_extended_id=False))


_RX = struct.Struct("<iH")  # RPDO1: 60C1h sub 1 (I32), 6040h (U16)
_TX = struct.Struct("<Hi")  # TPDO1: 6041h (U16), 6064h (I32)


def _map_pdo(w: Callable[[int, int, int], None], comm: int, mapping: int, cob: int,
             entries: tuple[int, ...]) -> None:
    """Map one PDO (CiA 301): invalid while mapping, the entries, then valid again on
    `cob`, transmission type 1 (every SYNC)."""
    w(comm, 1, 0x80000000 + cob)
    w(mapping, 0, 0)
    for k, entry in enumerate(entries, 1):
        w(mapping, k, entry)
    w(mapping, 0, len(entries))
    w(comm, 2, 1)
    w(comm, 1, cob)


class AxisGroup:
    """N axes in IP mode on one canopen `Network`, one cycle every `cycle_s`."""

    def __init__(self, network: Any, axes: list[ServoAxis], cycle_s: float, *,
                 sdo_write: Callable[[str, int, int, int], None],
                 on_cycle: Callable[[dict[str, Any]], None] | None = None,
                 bitrate: int = 1_000_000, heartbeat_s: float | None = None,
                 heartbeat_timeout_s: float | None = None,
                 on_capture: Callable[[dict[str, Any]], None] | None = None,
                 lost_after: int = 3) -> None:
        if not axes:
            raise ValueError("an axis group needs at least one axis")
        if not 0.001 <= cycle_s <= 0.010:
            raise ValueError(f"cycle {cycle_s * 1e3:g} ms: SYNC 1-10 ms (L17211-17244)")
        self.net, self.axes, self.cycle_s = network, axes, cycle_s
        self.by_name = {a.name: a for a in axes}
        self._sdo_write = sdo_write
        self.on_cycle = on_cycle
        self.on_capture = on_capture
        # cycles in a row without feedback before an axis that communicated is lost (-1):
        # one late TPDO is a missed cycle, not a lost axis (the seed gives no count, 004:254)
        self.lost_after = lost_after
        self.cycles = 0
        self.missed_cycles = 0
        self.bitrate = bitrate
        # the wire per cycle (the same frames every cycle): RPDO1 + TPDO1 per axis and the
        # SYNC, stuff bits of zero data counted (hil.transport.sim.frame_bits)
        self.cycle_bits = _bits(SYNC_ID, 0) + sum(
            _bits(0x200 + a.node, _RX.size) + _bits(0x180 + a.node, _TX.size) for a in axes)
        # heartbeat: each axis produces it (1017h), the group consumes it (CiA 301); the
        # consumer time defaults to twice the producer time, at most 65535 ms (the largest
        # a 1016h entry or `heartbeat_timeout:` holds), at least it + 2 cycles
        self.heartbeat_s = heartbeat_s
        self.heartbeat_timeout_s = heartbeat_timeout_s or (
            max(min(2 * heartbeat_s, MAX_CONSUMER_S), heartbeat_s + 2 * cycle_s)
            if heartbeat_s else None)
        self._cyclic: Cyclic | None = None
        self.held: list[str] = []  # followers holding: their master is lost or faulted
        self.cams: dict[int, list[float]] = {0: [], 1: []}  # CamTab 0/1 (004:232)
        self.command_errors: dict[str, str] = {}  # axis -> why its COMMAND is refused
        self.gear_judged = 0  # geared followers whose phase the last cycle judged
        self.gear_ratio_judged = 0  # ... and whose ratio (their master moved enough)
        self._lock = threading.Lock()

    # -- setup ---------------------------------------------------------------------------
    def configure(self) -> None:
        """Per axis over SDO: RPDO1 = 60C1h:01 + 6040h and TPDO1 = 6041h + 6064h, both on
        every SYNC; 60C2h = the cycle (L19089-19113); 1006h; 6060h = 7 (IP)."""
        us = round(self.cycle_s * 1e6)
        for a in self.axes:
            w = lambda i, s, v, a=a: self._sdo_write(a.name, i, s, v)  # noqa: E731
            _map_pdo(w, 0x1400, 0x1600, 0x200 + a.node, (0x60C10120, 0x60400010))  # RPDO1
            _map_pdo(w, 0x1800, 0x1A00, 0x180 + a.node, (0x60410010, 0x60640020))  # TPDO1
            unit, index = interpolation_period(self.cycle_s)
            w(0x60C2, 1, unit)  # must equal 1006h (L17218): 2.5 ms is 25 x 10^-4 s
            w(0x60C2, 2, index)
            w(0x1006, 0, us)
            w(0x6060, 0, 7)
            if self.heartbeat_s:
                w(0x1017, 0, round(self.heartbeat_s * 1000))  # producer time, ms
                self.net.subscribe(0x700 + a.node, self._heartbeat(a))
            self.net.subscribe(0x180 + a.node, self._tpdo(a))
            self.net.send_message(0x000, bytes([0x01, a.node]))  # NMT start: PDOs run

    def _tpdo(self, a: ServoAxis) -> Callable[[int, bytearray, float], None]:
        def cb(_cob: int, data: bytearray, _ts: float) -> None:
            if len(data) >= _TX.size:
                sw, pos = _TX.unpack_from(bytes(data))
                with self._lock:
                    a.on_feedback(sw, pos, self.cycle_s)
        return cb

    def _heartbeat(self, a: ServoAxis) -> Callable[[int, bytearray, float], None]:
        def cb(_cob: int, data: bytearray, _ts: float) -> None:
            if not data:
                return
            with self._lock:
                if data[0] == 0:  # boot-up: the node restarted, its PDO mapping and IP
                    a.rebooted = a.heartbeat_lost = True  # mode are gone (CiA 301): lost
                    a._hb_ns = None  # until the group is set up again
                    a.status, a.statusword = STATUS_LOST, 0
                elif not a.rebooted:  # monitoring starts with the first heartbeat
                    a._hb_ns = clock.monotonic_ns()
                    a.heartbeat_lost = False
        return cb

    def connect(self, a: ServoAxis) -> None:
        """PG follows from where the axis stands: PG.APos = WritePosition - Offset -
        Correction (004:224)."""
        a.pg.apos = a.position - a.offset - a.correction
        a.pg.aspeed = 0.0
        a.write_position = a.position

    def _judge_gears(self, masters: dict[str, ServoAxis]) -> None:
        """Gear ratio and phase error of each linear-geared follower, from the feedback
        (docs/group.md): once the clutch and the shift ramps are done and the set-points
        have had GEAR_SETTLE_CYCLES to reach the drives, the follower's and its master's
        positions are the reference; then the phase error is how far the follower drifted
        from In/Out x the master's travel, the ratio error the measured ratio's relative
        error once the master moved MIN_TRAVEL. Source 3 (ServoTick) counts cycles."""
        self.gear_judged = self.gear_ratio_judged = 0
        for a in self.axes:
            g = a.gea
            m = masters.get(g.master)
            engaged = (g.mode == 1 and m is not None and a.name not in self.held
                       and g.gin != 0 and g.gout != 0
                       and g.actual_in == g.gin and g.actual_shift == g.shift)
            key = (g.gin, g.gout, g.source, g.master, g.shift)
            if not engaged or key != a._gear_key:  # a new ratio, source or shift: anew
                a._gear_ref, a._gear_settle, a._gear_key = None, 0, key
                a.gear_phase_error = a.gear_ratio_error = 0.0
                if not engaged:
                    continue
            mv = float(self.cycles) if g.source == 3 else m.position
            a._gear_settle += 1
            if a._gear_ref is None:
                if a._gear_settle * self.cycle_s >= GEAR_SETTLE_S:
                    a._gear_ref = (a.position, mv)
                continue
            ratio = g.gin / g.gout
            df, dm = a.position - a._gear_ref[0], mv - a._gear_ref[1]
            a.gear_phase_error = df - ratio * dm
            self.gear_judged += 1
            if abs(ratio * dm) >= MIN_TRAVEL:  # the follower's travel: whole increments
                a.gear_ratio_error = abs(df / dm - ratio) / abs(ratio)
                self.gear_ratio_judged += 1

    # -- the cycle -----------------------------------------------------------------------
    def start(self) -> None:
        """Cycles on the bench's clock (hil.transport.cyclic: exact in virtual time)."""
        self._cyclic = Cyclic(self.cycle, self.cycle_s, name="axis-group")

    def stop(self) -> None:
        if self._cyclic is not None:
            self._cyclic.stop()

    def cycle(self) -> None:
        """One CycleTime: judge the last cycle's feedback, compute and send the set-points,
        then the SYNC."""
        dt = self.cycle_s
        with self._lock:
            missed = [a.name for a in self.axes if self.cycles and not a._seen]
            for a in self.axes:
                if self.cycles and not a._seen:
                    a.missed += 1
                    a._silent += 1
                    if a._ever and a._silent >= self.lost_after:
                        a.status = STATUS_LOST  # communicated before, now silent (004:254)
                else:
                    a._silent = 0
                a._seen = False
            if missed:
                self.missed_cycles += 1
            if self.heartbeat_timeout_s:
                now, limit = clock.monotonic_ns(), round(self.heartbeat_timeout_s * 1e9)
                for a in self.axes:
                    if a._hb_ns is not None and now - a._hb_ns > limit:
                        a.heartbeat_lost = True
                    if a.heartbeat_lost:
                        a.status = STATUS_LOST  # its PDOs may still come: lost all the same
            masters = {a.name: a for a in self.axes}
            for a in self.axes:
                if a._last_control & 0x3 and not a.control & 0x3:
                    a.enabling = True  # fault reset done / torque wanted again
                a._last_control = a.control
                try:
                    a.accept_command(masters, self.cams)
                except CommandError as e:  # refused: Control stays, the step reports it
                    self.command_errors[a.name] = str(e)
            for a in self.axes:
                was = a.pg.rdy
                # the feedback judged this cycle: the first that shows the target reached
                if not was:
                    a.arrived_cycle = 0
                elif not a.arrived_cycle and round(a.position) == round(a.write_position):
                    a.arrived_cycle = self.cycles
                a.pg.tick(dt)
                if a.pg.rdy and not was:
                    a.rdy_cycle = self.cycles + 1
            for a in self.axes:
                g = a.gea
                if g.mode and g.master in masters:
                    m = masters[g.master]
                    if m.status in (STATUS_LOST, STATUS_FAULT) and g._last is not None:
                        # the group's policy: a follower of a lost or faulted master holds
                        # its gear input where the master was last seen (no jump, no chase)
                        src = g._last
                        if a.name not in self.held:
                            self.held.append(a.name)
                    else:  # 1 WritePosition, 2 Position, 3 ServoTick (one per cycle)
                        src = {1: m.write_position, 2: m.position}.get(g.source, self.cycles)
                        if a.name in self.held:  # the master is back: the gear goes on
                            self.held.remove(a.name)  # from where it is now, without
                            g._last = src  # taking the travel it missed in one cycle
                    g.tick(src)
                elif not g.mode:  # off (COMMAND 7, COMMAND 1-3 with Par4 0): the next
                    g.reset_master()  # engagement counts from its own first master value
                a.compute()
            self._judge_gears(masters)
            captured = []
            for a in self.axes:  # CAPTURE Control 2: the registers, once, at this cycle
                if a.capture.control == 2:
                    a.capture.store(a.position, a.write_position)
                    captured.append(a.capture.record(a.name, self.cycles + 1))
            for a in self.axes:
                if not (math.isfinite(a.write_position)
                        and I32_MIN <= a.write_position <= I32_MAX):
                    # 60C1h is an I32 (L19059-19070): such a set-point cannot be sent; the
                    # axis holds its last one, and group_wait / group_expect say why
                    a.setpoint_error = (f"set-point {a.write_position!r} outside 60C1h's I32 "
                                        "range: the last one is held")
                    a.write_position = a._sent[-1] if a._sent else a.position
                if a._sent and dt > 0:
                    a.write_speed = (a.write_position - a._sent[-1]) / dt
                a._sent = [*a._sent[-2:], a.write_position]
        bus = self.net.bus  # the bus itself: canopen's send lock may be held by an SDO
        for a in self.axes:
            bus.send(can.Message(arbitration_id=0x200 + a.node, is_extended_id=False,
                                 data=_RX.pack(round(a.write_position), a.controlword())))
        bus.send(can.Message(arbitration_id=SYNC_ID, is_extended_id=False, data=b""))
        self.cycles += 1
        if self.on_capture is not None:
            for c in captured:
                self.on_capture(c)
        if self.on_cycle is not None:
            self.on_cycle({"cycle": self.cycles, "missed": missed, "held": list(self.held),
                           "heartbeat_lost": [a.name for a in self.axes if a.heartbeat_lost],
                           "status": {a.name: a.status for a in self.axes},
                           "bus_load_pct": round(100.0 * self.cycle_bits / (self.bitrate * dt),
                                                 2),
                           "write_position": {a.name: round(a.write_position)
                                              for a in self.axes},
                           "position": {a.name: round(a.position) for a in self.axes},
                           "position_error": {a.name: round(a.position_error)
                                              for a in self.axes},
                           "speed": {a.name: round(a.speed) for a in self.axes},
                           "mode": {a.name: a.mode for a in self.axes},
                           "offset": {a.name: round(a.offset) for a in self.axes},
                           "correction": {a.name: round(a.correction) for a in self.axes},
                           "follow_error": {a.name: round(a.follow_error) for a in self.axes},
                           "max_follow_error": round(max(abs(a.follow_error)
                                                         for a in self.axes)),
                           "cam_follow_error": round(max(
                               (abs(a.follow_error) for a in self.axes if a.gea.mode == 2),
                               default=0.0)),
                           "cam_axes": sum(1 for a in self.axes if a.gea.mode == 2),
                           "gear_phase_error": {a.name: round(a.gear_phase_error)
                                                for a in self.axes if a.gea.mode == 1},
                           "gear_judged": self.gear_judged,
                           "gear_ratio_judged": self.gear_ratio_judged,
                           "max_gear_phase_error": round(max(
                               (abs(a.gear_phase_error) for a in self.axes), default=0.0)),
                           "max_gear_ratio_error": round(max(
                               (a.gear_ratio_error for a in self.axes), default=0.0), 6)})
