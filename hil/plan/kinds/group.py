"""A motion controller's axis group (docs/group.md): `group`, `group_move`, `group_gear`,
`group_wait`, `group_stop`.

    - group: {axes: [drive1, drive2], cycle: 2ms}      # IP mode, PDOs, SYNC every cycle
    - group: {axes: [drive1], cycle: 2ms, heartbeat: 20ms, heartbeat_timeout: 50ms}
    - group_move: {axis: drive1, to: 100000, speed: 50000, acc: 200000, dec: 200000, ramp: 2}
    - group_gear: {axis: drive2, master: drive1, in: 1, out: 2, inc_in: 0.01}
    - group_wait: {rdy: [drive1], timeout: 5s}
    - group_capture: {axis: drive1, control: 1, on: rising, start: 20}
    - group_wait: {captured: [drive1], timeout: 1s}
    - group_stop: {}
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from hil import clock
from hil.bench.yamlio import Checker, join, text_number_hint
from hil.drivers.axis_group import (
    CAM_MEMORY,
    CAPTURE_FALLING,
    CAPTURE_RISING,
    CAPTURE_ZERO,
    MAGNITUDES,
    PG_MIN,
    RAMP_TYPES,
    RATIO_MAX,
    STATUS_FAULT,
    STATUS_LOST,
    STATUS_NEVER,
    STATUS_READY,
    AxisGroup,
    Gea,
    ServoAxis,
    gear_cycle,
    interpolation_period,
    ratio_problem,
    worst_case_bits,
)
from hil.plan.context import Outcome, StepFailed
from hil.plan.kinds.base import CheckContext, NoArgs, StepKind
from hil.plan.kinds.capture import arm_capture, read_array
from hil.transport.urls import can_bitrate
from hil.units import MS, S

if TYPE_CHECKING:
    from hil.plan.context import StepContext
    from hil.plan.session import DriveIO
    from hil.plan.steps import Step

_KEY = "axis_group"


def _group(ctx: StepContext) -> AxisGroup:
    g = ctx.store.get(_KEY)
    if g is None:
        raise StepFailed("no axis group: a `group:` step must come first")
    return g


def _num(v: Checker, m: Any, key: str, where: str, lo: float, hi: float,
         default: float | None = None) -> float:
    if key not in m:
        if default is None:
            raise v.err(m.line, where, f"needs `{key}:`")
        return default
    val = m[key]
    if isinstance(val, bool) or not isinstance(val, int | float) or not lo <= val <= hi:
        raise v.err(m.kline(key), join(where, key),
                    f"{val!r}: a number {lo:g} ~ {hi:g}{text_number_hint(val)}")
    return float(val)


_BIG = 1e15  # no position, speed or cam value on an I32 drive comes near it


def _finite(x: Any) -> bool:
    """A plain number a set-point can be made of: not a bool, not NaN/inf, not huge."""
    return (isinstance(x, int | float) and not isinstance(x, bool)
            and -_BIG <= x <= _BIG)  # NaN fails both comparisons


def _int(v: Checker, m: Any, key: str, where: str, lo: int, hi: int, default: int) -> int:
    """A whole number lo..hi (an array index, a table line): 2.5 or true is an error."""
    if key not in m:
        return default
    val = m[key]
    if isinstance(val, bool) or not isinstance(val, int) or not lo <= val <= hi:
        raise v.err(m.kline(key), join(where, key), f"{val!r}: a whole number {lo} ~ {hi}")
    return val


def _flag(v: Checker, m: Any, key: str, where: str) -> bool:
    val = m[key]
    if not isinstance(val, bool):
        raise v.err(m.kline(key), join(where, key), f"{val!r}: true or false")
    return val


def _axis_name(v: Checker, m: Any, key: str, where: str) -> str:
    val = m.get(key)
    if not isinstance(val, str) or not val:
        raise v.err(m.kline(key) if key in m else m.line, join(where, key),
                    "a drive name of the bench")
    return val


def _axes(v: Checker, m: Any, where: str) -> list[str]:
    """`axis: name` or `axes: [names]`."""
    if ("axis" in m) == ("axes" in m):
        raise v.err(m.line, where, "one of `axis:` or `axes:`")
    if "axis" in m:
        return [_axis_name(v, m, "axis", where)]
    seq = v.seq(m["axes"], m.kline("axes"), join(where, "axes"))
    if not seq or not all(isinstance(x, str) for x in seq):
        raise v.err(m.kline("axes"), join(where, "axes"), "a list of drive names")
    for i, x in enumerate(seq):  # as `group:` does: one command or expectation per axis
        if x in seq[:i]:
            raise v.err(seq.item_lines[i], join(where, f"axes[{i}]"),
                        f"{x!r} is named twice: each drive once")
    return [str(x) for x in seq]


def _coupling(v: Checker, m: Any, line: int, where: str) -> dict[str, Any]:
    """What a gear and a cam share: axis, master, In/Out (neither 0), the master's source."""
    out = {"axis": _axis_name(v, m, "axis", where),
           "master": _axis_name(v, m, "master", where),
           "gin": _num(v, m, "in", where, -RATIO_MAX, RATIO_MAX, 1),
           "gout": _num(v, m, "out", where, -RATIO_MAX, RATIO_MAX, 1)}
    if out["gin"] == 0:
        raise v.err(m.kline("in"), join(where, "in"),
                    "ratio 0: nothing would move (group_command 7 ramps a gear out)")
    side, why = ratio_problem(out["gin"], out["gout"])
    if why:
        raise v.err(m.kline(side) if side in m else m.line, join(where, side), why)
    if out["axis"] == out["master"]:
        raise v.err(line, where, "an axis cannot be its own master")
    src = m.get("source", "write")
    if not isinstance(src, str) or src not in _SOURCES:
        raise v.err(m.kline("source"), join(where, "source"),
                    "write (master WritePosition), actual (master Position) or time "
                    "(ServoTick: one per cycle, 004:230)")
    out["source"] = _SOURCES[src]
    return out


_SOURCES = {"write": 1, "actual": 2, "time": 3}  # GEA.SourcePosition (004:230)


_STATUS_TEXT = {STATUS_FAULT: "the drive is in fault", STATUS_LOST: "no communication",
                # its PG reached the target but the motor did not follow it
                STATUS_READY: "ready without torque: the axis did not follow its PG",
                STATUS_NEVER: "never communicated"}


def _no_cycle(g: AxisGroup, a: _Coupling) -> None:
    """A gear or cam that would close a cycle of masters is refused (each axis would follow
    the other's travel and run away)."""
    chain = gear_cycle(g.by_name, a.axis, a.master, a.source)
    if chain is not None:
        raise StepFailed(f"a gear cycle {' <- '.join(chain)}: each axis would follow the "
                         "other's travel and run away")


def _members(g: AxisGroup, names: list[str]) -> list[ServoAxis]:
    missing = [n for n in names if n not in g.by_name]
    if missing:
        raise StepFailed(f"not in the axis group: {', '.join(missing)}")
    return [g.by_name[n] for n in names]


# the last plan's steps and, per step (by id), the group in force at it: one walk a plan,
# not one a step (helper-139: 20 000 group steps took 71 s to check)
_IN_FORCE: list[Any] = [None, {}]


def _group_in_force(cc: CheckContext) -> list[str] | None:
    """The axes of the `group:` before this step, None when there is none (or a
    `group_stop:` ended it)."""
    steps = cc.plan.steps
    if _IN_FORCE[0] is not steps or id(cc.step) not in _IN_FORCE[1]:
        at: dict[int, list[str] | None] = {}
        axes = None
        for s in steps:
            at[id(s)] = axes
            if s.kind == "group":
                axes = s.args.axes
            elif s.kind == "group_stop":
                axes = None
        _IN_FORCE[:] = [steps, at]
    return _IN_FORCE[1].get(id(cc.step))  # (the checked step is always one of the plan's)


def _check_axes(cc: CheckContext, names: list[str], field: str) -> None:
    """Each name a drive of the bench on a CAN bus and, but for `group:` itself, an axis of
    the group in force at this step."""
    for n in names:
        d = cc.bench.drives.get(n)
        if d is None:
            raise cc.err(f"unknown axis {n!r}: the bench's drives are "
                         f"{', '.join(cc.bench.drives)}", field)
        if not d.can:
            raise cc.err(f"axis {n!r} has no CAN bus (an axis group streams set-points "
                         "over CANopen)", field)
    if cc.step.kind == "group":
        return
    group = _group_in_force(cc)
    if group is None:
        raise cc.err("no axis group: a `group:` step must come first (and no `group_stop:` "
                     "since)")
    outside = [n for n in names if n not in group]
    if outside:
        raise cc.err(f"not in the axis group ({', '.join(group)}): {', '.join(outside)}", field)


@dataclass(frozen=True)
class GroupArgs:
    axes: list[str]  # drive names
    cycle: int  # SYNC period, ns
    heartbeat: int  # the axes' producer time (1017h), ns; 0 = none
    heartbeat_timeout: int  # the group's consumer time, ns; 0 = none
    line: int  # the plan line of `cycle:` (the wire check's error)


@dataclass(frozen=True)
class GroupMoveArgs:
    axes: list[str]
    what: str  # to | by | run
    value: float
    acc: float
    dec: float
    speed: float
    ramp: int  # PG.Type (004:226)


@dataclass(frozen=True)
class _Coupling:
    axis: str
    master: str
    gin: float  # GEA.In (YAML `in:`)
    gout: float  # GEA.Out (YAML `out:`)
    source: int  # GEA.SourcePosition (004:230)


@dataclass(frozen=True)
class GroupGearArgs(_Coupling):
    inc_in: float = 0.0


@dataclass(frozen=True)
class GroupCamArgs(_Coupling):
    scale: float = 1.0
    table: list[float] = field(default_factory=list)
    type: int = 0  # 0 return, 1 incremental


@dataclass(frozen=True)
class GroupCamTableArgs:
    tab: int  # CamTab 0 / 1
    line: int
    values: list[float]


@dataclass(frozen=True)
class GroupCommandArgs:
    axis: str
    code: int  # COMMAND 1-7 (004:244)
    par: list[float]  # Par0-Par14
    timeout: int  # ns


@dataclass(frozen=True)
class GroupSdoArgs:
    axis: str
    control: int  # 1 write, 2 read
    index: int
    sub: int
    bytes: int
    data: int
    expect: dict[str, int] = field(default_factory=dict)  # status / data


@dataclass(frozen=True)
class GroupWaitArgs:
    timeout: int  # ns
    rdy: list[str] = field(default_factory=list)
    captured: list[str] = field(default_factory=list)


@dataclass(frozen=True)
class GroupCaptureArgs:
    axis: str
    control: int  # 1 the drive's input, 2 the registers at a cycle
    typ: int  # Typ_ExtCapture
    start: int  # data-array entry (Control 1)


@dataclass(frozen=True)
class GroupExpectArgs:
    axes: list[str]
    position: tuple[float, float] | None = None
    write_position: tuple[float, float] | None = None
    pg_position: tuple[float, float] | None = None
    capture_position: tuple[float, float] | None = None
    peak_acc: tuple[float, float] | None = None
    missed: int | None = None
    rdy_same_cycle: bool | None = None
    arrived_same_cycle: bool | None = None
    status: int | None = None
    held: bool | None = None
    heartbeat_lost: bool | None = None


@dataclass(frozen=True)
class GroupControlArgs:
    axis: str
    fault_reset: bool | None = None
    torque: bool | None = None
    correction: float | None = None
    mode: int | None = None


class Group(StepKind):
    """`group: {axes: [...], cycle: 2ms}`: the axes in IP mode, the SYNC and PDOs running."""

    name = "group"
    args: GroupArgs
    motion = True

    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> GroupArgs:
        m = v.mapping(obj, line, where)
        v.keys(m, {"axes", "cycle", "heartbeat", "heartbeat_timeout"}, where)
        if "axes" not in m:
            raise v.err(line, where, "needs `axes:` (drive names)")
        names = _axes(v, m, where)  # drive names, each once (as every group step's)
        cycle = v.duration(m, "cycle", where, 2 * MS)
        if not MS <= cycle <= 10 * MS:
            raise v.err(m.kline("cycle"), join(where, "cycle"),
                        "SYNC 1-10 ms (A3 IP mode, L17211-17244)")
        try:  # 1006h in us and 60C2h = u x 10^i s must state the same period (L17218)
            if cycle % 1000:
                raise ValueError
            interpolation_period(cycle / S)
        except ValueError:
            raise v.err(m.kline("cycle"), join(where, "cycle"),
                        "a period 1006h (whole us) and 60C2h (u x 10^i s, u 1-255) both "
                        "state exactly (L17218, L19089-19113): 2ms and 2.5ms can, 1.001ms "
                        "cannot") from None
        hb = v.duration(m, "heartbeat", where, 0) if "heartbeat" in m else 0
        # the group's consumer time is at least `heartbeat` + 2 cycles and at most 65535 ms
        if "heartbeat" in m and (not MS <= hb <= 65535 * MS - 2 * cycle or hb % MS):
            raise v.err(m.kline("heartbeat"), join(where, "heartbeat"),
                        "whole ms, 1 ~ 65535 less 2 cycles (1017h, the producer time of each "
                        "axis; the group's consumer time, at least it + 2 cycles, is at most "
                        "65535 ms)")
        hb_to = 0
        if "heartbeat_timeout" in m:
            if not hb:
                raise v.err(m.kline("heartbeat_timeout"), join(where, "heartbeat_timeout"),
                            "needs `heartbeat:` (the axes' producer time)")
            hb_to = v.duration(m, "heartbeat_timeout", where, 0)
            if not hb + 2 * cycle <= hb_to <= 65535 * MS or hb_to % MS:
                raise v.err(m.kline("heartbeat_timeout"), join(where, "heartbeat_timeout"),
                            "at least `heartbeat:` + 2 cycles (a consumer time at the producer "
                            "time trips on a heartbeat one cycle late), whole ms, at most 65535")
        return GroupArgs(names, cycle, hb, hb_to, m.kline("cycle") if "cycle" in m else line)

    def check(self, cc: CheckContext) -> None:
        _check_axes(cc, self.args.axes, "axes")
        # the wire: each cycle carries an RPDO and a TPDO per axis (6 bytes: at most 115 bits
        # with worst-case stuffing) and the SYNC (50)
        names = self.args.axes
        buses = {cc.bench.drives[n].can for n in names}
        if len(buses) != 1:
            raise cc.err(f"the axes are on different CAN buses ({', '.join(sorted(buses))}): "
                         "an axis group is one bus", "axes")
        url = cc.bench.can[buses.pop()]
        bitrate = can_bitrate(url)
        bits = worst_case_bits(len(names), heartbeat=bool(self.args.heartbeat))
        if bits / bitrate > self.args.cycle / S:
            raise cc.err(f"{len(names)} axes need up to {bits} bits a cycle: "
                         f"{bits / bitrate * 1e3:.2f} ms at {bitrate / 1e3:g} kbit/s, more than "
                         f"the {self.args.cycle / MS:g} ms cycle", "cycle",
                         self.args.line)

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        old = ctx.store.pop(_KEY, None)
        if old is not None:
            old.stop()
        drives = {n: ctx.session.drive(n) for n in self.args.axes}
        net = next(iter(drives.values())).cia.node.network
        axes = [ServoAxis(n, dio.spec.node_id or 1) for n, dio in drives.items()]
        rec = ctx.rec

        def on_cycle(c: dict[str, Any]) -> None:
            if rec is not None:
                rec.write("/group/axes/cycle", c)

        def on_capture(c: dict[str, Any]) -> None:
            if rec is not None:
                rec.write("/group/axes/capture", c)

        group = AxisGroup(net, axes, self.args.cycle / S,
                          sdo_write=lambda name, i, s, val: drives[name].cia.write(i, s, val),
                          on_cycle=on_cycle,
                          bitrate=can_bitrate(ctx.bench.can[drives[axes[0].name].spec.can]),
                          heartbeat_s=self.args.heartbeat / S or None,
                          heartbeat_timeout_s=self.args.heartbeat_timeout / S or None,
                          on_capture=on_capture)
        group.configure()
        for a in axes:
            cia = drives[a.name].cia
            a.position = float(cia.read(0x6064, 0))
            # the state it is in: the first RPDOs go out before any TPDO answers, and an
            # axis taken for switch on disabled would be sent 0x06 (shutdown) when enabled
            a.statusword = cia.read(0x6041, 0)
            group.connect(a)
            cia.write(0x60C1, 1, round(a.position))  # the set-point where it stands
        group.start()
        ctx.store[_KEY] = group
        ctx.session.on_close(group.stop)
        ctx.session.before_safe(group.stop)  # its controlwords must not undo the safe state
        # the RPDO controlwords enable the axes, a CiA 402 step every two cycles (the
        # feedback lags a cycle, ServoAxis.controlword), with no SDO on the bus
        clock.sleep(3 * group.cycle_s)
        deadline = clock.monotonic_ns() + S
        while not all(a.status == 3 for a in axes):
            left = deadline - clock.monotonic_ns()
            if left <= 0:
                raise StepFailed("axes not enabled: " + ", ".join(
                    f"{a.name} status {a.status} (6041h {a.statusword:04X}h)" for a in axes))
            clock.sleep(min(group.cycle_s, left / S))
        return Outcome(f"{len(axes)} axes in IP mode, cycle {self.args.cycle / MS:g} ms")

    def describe(self) -> str:
        return f"group {', '.join(self.args.axes)} every {self.args.cycle / MS:g} ms"


class GroupMove(StepKind):
    """`group_move: {axis, to | by | speed, acc, dec, speed, ramp}`: a PG command (004:226)."""

    name = "group_move"
    args: GroupMoveArgs
    motion = True

    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> GroupMoveArgs:
        m = v.mapping(obj, line, where)
        v.keys(m, {"axis", "axes", "to", "by", "run", "acc", "dec", "speed", "ramp"}, where)
        targets = [k for k in ("to", "by", "run") if k in m]
        if len(targets) != 1:
            raise v.err(line, where, "one of to (absolute), by (relative), run (speed)")
        big = 2**31 - 1  # 60C1h is an I32 (L19059-19070)
        out = {"axes": _axes(v, m, where), "what": targets[0],
               "value": _num(v, m, targets[0], where, -big, big),
               "acc": _num(v, m, "acc", where, 1, 1e12, 100_000),
               "dec": _num(v, m, "dec", where, 1, 1e12, 100_000),
               "speed": _num(v, m, "speed", where, 1, 1e10, 50_000)}
        ramp = m.get("ramp", 3)
        if ramp not in RAMP_TYPES or isinstance(ramp, bool):
            raise v.err(m.kline("ramp") if "ramp" in m else line, join(where, "ramp"),
                        "0 short accel / long decel, 1 short both, 2 harmonic, 3 linear")
        out["ramp"] = ramp
        return GroupMoveArgs(**out)

    def check(self, cc: CheckContext) -> None:
        _check_axes(cc, self.args.axes, "axes")

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        a = self.args
        g = _group(ctx)
        axes = _members(g, a.axes)
        with g._lock:  # every axis starts in the same cycle
            for ax in axes:
                pg = ax.pg
                pg.acc, pg.dec, pg.pos_speed, pg.type = (a.acc, a.dec, a.speed,
                                                         a.ramp)
                if ax.mode == 3:  # the PG joins the gear or cam where it stands (004:218)
                    ax.superimpose()
                if a.what == "to":
                    pg.start_position(a.value)
                elif a.what == "by":
                    pg.start_position(pg.apos + a.value)
                else:
                    pg.start_speed(a.value)
        return Outcome(f"PG {a.what} {a.value:g} (ramp type {a.ramp})")

    def describe(self) -> str:
        a = self.args
        return f"group_move {', '.join(a.axes)} {a.what} {a.value:g}"


def _new_master(gea: Gea, master: str, source: int) -> None:
    """Couple `gea` to `master`'s `source`. Another master or source starts the travel anew
    at the next cycle: the last value taken was the old one's, and its difference to the
    new one would have moved the follower in one cycle (helper-130: 100000 increments)."""
    if (gea.master, gea.source) != (master, source):
        gea.reset_master()
    gea.master, gea.source = master, source


class GroupGear(StepKind):
    """`group_gear: {axis, master, in, out, inc_in, source}`: couple a linear gear (004:230)."""

    name = "group_gear"
    args: GroupGearArgs
    motion = True

    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> GroupGearArgs:
        m = v.mapping(obj, line, where)
        v.keys(m, {"axis", "master", "in", "out", "inc_in", "source"}, where)
        out = _coupling(v, m, line, where)
        out["inc_in"] = _num(v, m, "inc_in", where, 0, 1e9, 0)
        return GroupGearArgs(**out)

    def check(self, cc: CheckContext) -> None:
        _check_axes(cc, [self.args.axis, self.args.master], "axis")

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        a = self.args
        g = _group(ctx)
        ax, master = g.by_name.get(a.axis), g.by_name.get(a.master)
        if ax is None or master is None:
            raise StepFailed("axis or master not in the group")
        with g._lock:
            _no_cycle(g, a)
            gea = ax.gea
            _new_master(gea, a.master, a.source)
            gea.gin, gea.gout, gea.inc_in = a.gin, a.gout, a.inc_in
            if gea.mode == 1:  # geared already: a new ratio, ramped by inc_in (004:236)
                return Outcome(f"{a.axis} geared to {a.master} {a.gin:g}/{a.gout:g}")
            # a new engagement: GEA.Position = 0 and the Offset so the axis stays where it
            # stands (004:236: GEA.Offset = WritePosition - Offset - GEA.Position)
            gea.actual_in = 0.0 if a.inc_in else a.gin
            gea.position = 0.0
            gea.mode = 1
            ax.mode = 4 if ax.mode in (1, 4) else 3
            ax.offset = ax.write_position - ax.correction - ax.base()
        return Outcome(f"{a.axis} geared to {a.master} {a.gin:g}/{a.gout:g}")

    def describe(self) -> str:
        a = self.args
        return f"group_gear {a.axis} <- {a.master} {a.gin:g}/{a.gout:g}"


class GroupCam(StepKind):
    """`group_cam: {axis, master, in, out, table: [...], type: return | incremental,
    scale}`: the axis follows a cam table driven by its master (004:232-236)."""

    name = "group_cam"
    args: GroupCamArgs
    motion = True

    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> GroupCamArgs:
        m = v.mapping(obj, line, where)
        v.keys(m, {"axis", "master", "in", "out", "table", "type", "scale", "source"}, where)
        out = _coupling(v, m, line, where)
        out["scale"] = _num(v, m, "scale", where, -1e6, 1e6, 1)
        if out["scale"] == 0:  # CamScale multiplies the cam's data (004:258): 0 holds it
            raise v.err(m.kline("scale"), join(where, "scale"),  # at 0; COMMAND 6 takes
                        "0 would hold the cam at 0 (CamScale multiplies its values, 004:258; "
                        "COMMAND 6 takes Par8 0 as 1)")  # its Par8 0 as 1
        if "table" not in m:
            raise v.err(line, where, "needs `table:` (cam positions, one per 1024 pointer "
                        "increments)")
        table = v.seq(m["table"], m.kline("table"), join(where, "table"))
        if len(table) < 2:
            raise v.err(m.kline("table"), join(where, "table"),
                        f"cam table too short: {len(table)} point(s), at least 2")
        if not all(_finite(x) for x in table):
            raise v.err(m.kline("table"), join(where, "table"),
                        f"finite numbers within ±{_BIG:g} only")
        out["table"] = [float(x) for x in table]
        kind = m.get("type", "return")
        if kind not in ("return", "incremental"):
            raise v.err(m.kline("type"), join(where, "type"), "return or incremental")
        out["type"] = 0 if kind == "return" else 1
        return GroupCamArgs(**out)

    def check(self, cc: CheckContext) -> None:
        _check_axes(cc, [self.args.axis, self.args.master], "axis")

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        a = self.args
        g = _group(ctx)
        ax, _master = _members(g, [a.axis, a.master])
        with g._lock:
            _no_cycle(g, a)
            gea = ax.gea
            _new_master(gea, a.master, a.source)
            gea.gin = gea.actual_in = a.gin
            gea.gout, gea.inc_in = a.gout, 0.0
            gea.cam, gea.cam_type, gea.cam_scale = a.table, a.type, a.scale
            gea.position = 0.0
            gea.cam_position = gea.cam_value(0.0)
            # the cam starts where the axis stands: WritePosition = CamPosition + Offset +
            # Correction (004:216) holds with the current WritePosition
            ax.offset = ax.write_position - gea.cam_position - ax.correction
            gea.mode = 2
            ax.mode = 3
        return Outcome(f"{a.axis} on a {'return' if a.type == 0 else 'incremental'} cam "
                       f"of {len(a.table)} points from {a.master}")

    def describe(self) -> str:
        a = self.args
        return f"group_cam {a.axis} <- {a.master} ({len(a.table)} points)"


class _OneAxis(StepKind):
    """A step on one axis of the group (`axis:`): the bench check and the lookup."""

    def check(self, cc: CheckContext) -> None:
        _check_axes(cc, [self.args.axis], "axis")

    def _axis(self, ctx: StepContext) -> tuple[AxisGroup, ServoAxis]:
        g = _group(ctx)
        return g, _members(g, [self.args.axis])[0]


class GroupCamTable(StepKind):
    """`group_cam_table: {tab: 0, line: 0, values: [...]}`: doubles into the group's cam
    memory (CamTab 0 TGM_Cam_Profile, 1 TGM_Data; 004:232), for COMMAND 6 with a cam."""

    name = "group_cam_table"
    args: GroupCamTableArgs

    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> GroupCamTableArgs:
        m = v.mapping(obj, line, where)
        v.keys(m, {"tab", "line", "values"}, where)
        tab = m.get("tab", 0)
        if isinstance(tab, bool) or not isinstance(tab, int) or tab not in CAM_MEMORY:
            raise v.err(m.kline("tab") if "tab" in m else line, join(where, "tab"),
                        f"{tab!r}: 0 (TGM_Cam_Profile) or 1 (TGM_Data), 004:232")
        start = _int(v, m, "line", where, 0, CAM_MEMORY[tab] - 1, 0)
        if "values" not in m:
            raise v.err(line, where, "needs `values:` (the cam's points)")
        vals = v.seq(m["values"], m.kline("values"), join(where, "values"))
        if not vals or not all(_finite(x) for x in vals):
            raise v.err(m.kline("values"), join(where, "values"),
                        f"a list of finite numbers within ±{_BIG:g}")
        if start + len(vals) > CAM_MEMORY[tab]:
            raise v.err(m.kline("values"), join(where, "values"),
                        f"line {start} + {len(vals)} values past CamTab {tab}'s "
                        f"{CAM_MEMORY[tab]} doubles")
        return GroupCamTableArgs(tab, start, [float(x) for x in vals])

    def check(self, cc: CheckContext) -> None:
        _check_axes(cc, [], "")

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        a = self.args
        g = _group(ctx)
        with g._lock:
            mem = g.cams[a.tab]
            end = a.line + len(a.values)
            if len(mem) < end:
                mem.extend([0.0] * (end - len(mem)))
            mem[a.line:end] = a.values
        return Outcome(f"CamTab {a.tab} lines {a.line}-{end - 1}")

    def describe(self) -> str:
        return f"group_cam_table {self.args.tab}:{self.args.line}"


class GroupCommand(_OneAxis):
    """`group_command: {axis, code: 1-7, par: {0: 1000000, 3: 200000}, timeout}`: the COMMAND
    interface (004:240-246): write Par and Control, wait until Control is back to 0 (on
    acceptance; for 7, sync off, once the ratio ramp has run out)."""

    name = "group_command"
    args: GroupCommandArgs
    motion = True

    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> GroupCommandArgs:
        m = v.mapping(obj, line, where)
        v.keys(m, {"axis", "code", "par", "timeout"}, where)
        code = m.get("code")
        if not isinstance(code, int) or isinstance(code, bool) or code not in range(1, 8):
            raise v.err(m.kline("code") if "code" in m else line, join(where, "code"),
                        "1 speed, 2 absolute, 3 relative, 4 set reference, 5 abort, "
                        "6 sync on, 7 sync off (004:244)")
        par = [0.0] * 15
        if "par" in m:
            pm = v.mapping(m["par"], m.kline("par"), join(where, "par"))
            seen: set[int] = set()
            for k, val in pm.items():
                # an index is written in ASCII digits: `+3`, ` 3` or `٣` read as 3 in
                # Python, and beside a `3` the last one would win unseen
                if isinstance(k, int) and not isinstance(k, bool):
                    i = k
                elif isinstance(k, str) and k.isascii() and k.isdigit():
                    i = int(k)
                else:
                    i = -1
                if not 0 <= i <= 14:
                    raise v.err(pm.kline(k), join(where, f"par.{k}"),
                                "Par index 0-14, in digits")
                if i in seen:
                    raise v.err(pm.kline(k), join(where, f"par.{k}"),
                                f"Par{i} is named twice")
                seen.add(i)
                if not _finite(val):
                    raise v.err(pm.kline(k), join(where, f"par.{k}"),
                                f"{val!r}: a finite number within ±{_BIG:g}"
                                f"{text_number_hint(val)}")
                if code == 6 and i in (0, 1, 2, 6, 7, 10, 12) and val != int(val):
                    raise v.err(pm.kline(k), join(where, f"par.{k}"),
                                f"{val!r}: a whole number (an index or a code, 004:244)")
                what = dict(MAGNITUDES.get(code, ())).get(i)
                if what is not None and (val < 0 or 0 < val < PG_MIN):
                    raise v.err(pm.kline(k), join(where, f"par.{k}"),
                                f"{val!r}: PG.{what} is a maximum, 0 (keep the register) or "
                                f"at least {PG_MIN:g} (004:220)")
                par[i] = float(val)
        if code in (1, 2, 3) and par[4] not in (0.0, 1.0):  # Enable_GEA (004:240)
            raise v.err(_par_line(m, 4), join(where, "par.4"),
                        f"{par[4]:g}: Enable_GEA, 0 cancels an active GEA, 1 puts the move "
                        "on top of it (004:240)")
        if code == 6:
            _sync_on_pars(v, m, where, par)
        if code == 7 and par[5] < 0:  # GInInc: "a positive number" (004:246)
            raise v.err(_par_line(m, 5), join(where, "par.5"),
                        f"{par[5]:g}: GInInc, the ratio's fall a cycle, is not negative "
                        "(004:246 asks for a positive number; 0 ramps out at once)")
        return GroupCommandArgs(_axis_name(v, m, "axis", where), code, par,
                                v.duration(m, "timeout", where, 5 * S))

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        a = self.args
        g, ax = self._axis(ctx)
        with g._lock:
            ax.par = list(a.par)
            ax.command = a.code
            g.command_errors.pop(ax.name, None)
            c0 = g.cycles
        if not clock.wait_for(lambda: ax.command == 0 or ax.name in g.command_errors,
                              a.timeout / S):
            raise StepFailed(f"COMMAND {a.code} not accepted within the timeout "
                             f"(Control still {ax.command})")
        with g._lock:
            why = g.command_errors.pop(ax.name, None)
            if why is not None:
                ax.command = 0  # refused: withdrawn, so the group does not retry it
        if why is not None:
            raise StepFailed(f"COMMAND {a.code} refused: {why}")
        return Outcome(f"COMMAND {a.code} accepted after {g.cycles - c0} cycle(s)")

    def describe(self) -> str:
        return f"group_command {self.args.axis} {self.args.code}"


def _par_line(m: Any, i: int) -> int:
    """The line of Par `i` in a `par:` mapping (keyed 3 or "3"), else of `par:`."""
    pm = m.get("par")
    for k in (i, str(i)):
        if isinstance(pm, dict) and k in pm:
            return pm.kline(k)
    return m.kline("par") if "par" in m else m.line


def _sync_on_pars(v: Checker, m: Any, where: str, par: list[float]) -> None:
    """COMMAND 6 (004:244): Par2 1 gear, 2 + CamType a cam; Par3/Par4 GIn/GOut, a ratio
    as `group_gear` takes it; Par5 GInInc, the ratio's rise a cycle, not negative."""
    if par[2] not in (1.0, 2.0, 3.0):
        raise v.err(_par_line(m, 2), join(where, "par.2"),
                    f"{par[2]:g}: 1 gear, 2 return cam, 3 incremental cam (004:244)")
    side, why = ratio_problem(par[3], par[4])
    if why:
        i = 3 if side == "in" else 4
        raise v.err(_par_line(m, i), join(where, f"par.{i}"), why)
    if par[5] < 0:
        raise v.err(_par_line(m, 5), join(where, "par.5"),
                    f"{par[5]:g}: GInInc, the ratio's rise a cycle, is not negative (004:244; "
                    "0 engages at once)")


class GroupSdo(_OneAxis):
    """`group_sdo: {axis, write | read: {index, sub, bytes, data}, expect: {status, data}}`:
    the SDO interface's handshake (004:248-250): Control 1 / 2, wait Control = 0, Status 0 OK
    or 2 with the abort code in Data."""

    name = "group_sdo"
    args: GroupSdoArgs

    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> GroupSdoArgs:
        m = v.mapping(obj, line, where)
        v.keys(m, {"axis", "write", "read", "expect"}, where)
        ops = [k for k in ("write", "read") if k in m]
        if len(ops) != 1:
            raise v.err(line, where, "one of write: or read:")
        op = ops[0]
        r = v.mapping(m[op], m.kline(op), join(where, op))
        v.keys(r, {"index", "sub", "bytes", "data"}, join(where, op))
        w = join(where, op)
        out = {"axis": _axis_name(v, m, "axis", where), "control": 1 if op == "write" else 2,
               "index": _int(v, r, "index", w, 0, 0xFFFF, -1),
               "sub": _int(v, r, "sub", w, 0, 0xFF, 0),
               "bytes": _int(v, r, "bytes", w, 1, 4, 4),
               "data": _int(v, r, "data", w, -(2**31), 2**32 - 1, 0) if op == "write"
               else 0}
        if out["index"] < 0:
            raise v.err(r.line, w, "needs `index:`")
        n = out["bytes"]
        if op == "write" and not -(1 << (8 * n - 1)) <= out["data"] < 1 << (8 * n):
            # NumberByte is the object's size (004:250): a value it cannot hold would go on
            # the wire cut to its low bytes, 256 in 1 byte as 0
            raise v.err(r.kline("data") if "data" in r else r.line, join(w, "data"),
                        f"{out['data']} does not fit in {n} byte(s): "
                        f"{-(1 << (8 * n - 1))} ~ {(1 << (8 * n)) - 1}")
        out["expect"] = {}
        if "expect" in m:
            e = v.mapping(m["expect"], m.kline("expect"), join(where, "expect"))
            v.keys(e, {"status", "data"}, join(where, "expect"))
            we = join(where, "expect")
            out["expect"] = {k: _int(v, e, k, we, *((0, 2) if k == "status"
                                                     else (-(2**31), 2**32 - 1)), 0)
                             for k in e}
            want = out["expect"].get("data")
            if (op == "read" and want is not None and out["expect"].get("status") != 2
                    and not 0 <= want < 1 << (8 * n)):
                # a read gives NumberByte bytes unsigned (a 1-byte -4 reads 252); Data holds
                # an abort code only with Status 2
                raise v.err(e.kline("data"), join(we, "data"),
                            f"{want}: a read of {n} byte(s) gives 0 ~ {(1 << (8 * n)) - 1} "
                            "(unsigned; with `status: 2` Data is the abort code)")
        return GroupSdoArgs(**out)

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        a = self.args
        _g, ax = self._axis(ctx)
        s = ax.sdo
        s.number_byte, s.index, s.sub, s.data = a.bytes, a.index, a.sub, a.data
        s.control = a.control
        sdo = ctx.session.drive(ax.name).cia.node.sdo
        s.execute(sdo.upload, sdo.download)
        seen = {"status": s.status, "data": s.data}
        text = (f"{'write' if a.control == 1 else 'read'} {a.index:04X}h:{a.sub:02X}: "
                f"Status {s.status}, Data 0x{s.data:X}")
        bad = [f"{k} {seen[k]:#x}, expected {v:#x}" for k, v in a.expect.items()
               if seen[k] != v]
        if bad:
            raise StepFailed("; ".join(bad) + f" ({text})")
        return Outcome(text)

    def describe(self) -> str:
        a = self.args
        return f"group_sdo {a.axis} {a.index:04X}h:{a.sub}"


class GroupWait(StepKind):
    """`group_wait: {rdy: [axes], timeout}`: until each PG reached its target (PG.Rdy)."""

    name = "group_wait"
    args: GroupWaitArgs

    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> GroupWaitArgs:
        m = v.mapping(obj, line, where)
        v.keys(m, {"rdy", "captured", "timeout"}, where)
        if "rdy" not in m and "captured" not in m:
            raise v.err(line, where, "needs `rdy:` (PG.Rdy) or `captured:` (CAPTURE done)")
        out: dict[str, Any] = {"timeout": v.duration(m, "timeout", where, 5 * S)}
        for k in ("rdy", "captured"):
            seq = v.seq(m[k], m.kline(k), join(where, k)) if k in m else []
            if k in m and (not seq or not all(isinstance(x, str) and x for x in seq)):
                raise v.err(m.kline(k), join(where, k), "a list of the group's axes (an empty "
                            "one would wait for nothing)")
            out[k] = [str(x) for x in seq]
        return GroupWaitArgs(**out)

    def check(self, cc: CheckContext) -> None:
        _check_axes(cc, self.args.rdy, "rdy")
        _check_axes(cc, self.args.captured, "captured")

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        g = _group(ctx)
        timeout = self.args.timeout / S
        axes = [g.by_name[n] for n in self.args.rdy if n in g.by_name]
        if not clock.wait_for(lambda: all(a.pg.rdy for a in axes), timeout):
            raise StepFailed("PG not ready: " + ", ".join(a.name for a in axes
                                                          if not a.pg.rdy))
        bad = [f"{a.name}: {a.setpoint_error}" for a in axes if a.setpoint_error]
        bad += [f"{a.name}: Status {a.status} ({_STATUS_TEXT[a.status]}, 004:254)"
                for a in axes if a.status in _STATUS_TEXT]
        if bad:
            raise StepFailed("; ".join(bad))
        text = [f"{a.name} at {a.write_position:.0f}" for a in axes]
        for a in _members(g, self.args.captured):
            text.append(_await_capture(ctx, g, a, timeout))
        return Outcome(", ".join(text))

    def describe(self) -> str:
        return f"group_wait {', '.join(self.args.rdy + self.args.captured)}"


def _await_capture(ctx: StepContext, g: AxisGroup, a: ServoAxis, timeout: float) -> str:
    """CAPTURE Control 1 (004:252): the drive's capture (P5.038 counts down to 0 once the
    point is stored, L5155) polled over SDO once a cycle, then its value read from the data
    array into the register of its type; Control back to 0. Control 2 is the group's own."""
    cap = a.capture
    if cap.armed == 2:  # the group takes it at a cycle: perhaps already before this step
        if not clock.wait_for(lambda: cap.captures > cap.armed_at, timeout):
            raise StepFailed(f"{a.name}: CAPTURE Control 2 not taken in {timeout:g} s")
        return f"{a.name} registers captured at {cap.position:.0f}"
    if cap.armed == 1 and cap.control == 0 and cap.captures > cap.armed_at:
        return f"{a.name} captured {cap.position:.0f} (already read)"
    if cap.armed != 1 or cap.control != 1:
        raise StepFailed(f"{a.name}: no CAPTURE armed (group_capture first)")
    dio = ctx.session.drive(a.name)
    deadline = clock.monotonic_ns() + round(timeout * S)
    while dio.read_param("P5.038", "sdo") != 0:
        left = deadline - clock.monotonic_ns()
        if left <= 0:
            raise StepFailed(f"{a.name}: nothing captured in {timeout:g} s (P5.038 still "
                             f"{dio.read_param('P5.038', 'sdo')})")
        clock.sleep(min(g.cycle_s, left / S))
    value = read_array(dio, cap.start, 1, "sdo")[0]
    with g._lock:
        cap.store(float(value), a.write_position)
        record = cap.record(a.name, g.cycles)
    if ctx.rec is not None:
        ctx.rec.write("/group/axes/capture", record)
    return f"{a.name} captured {value} (Typ_ExtCapture 0x{cap.typ_ext_capture:02X})"


_CAPTURE_TYPES = {"rising": CAPTURE_RISING, "falling": CAPTURE_FALLING, "zero": CAPTURE_ZERO}


class GroupCapture(_OneAxis):
    """`group_capture: {axis, control: 1|2, on: rising|falling|zero, start: 20}`: the CAPTURE
    interface (004:252). Control 1 arms the drive's own capture over SDO (P5.036 = start,
    P5.038 = 1, P5.039: CN2, NO for a rising edge or the zero pulse, NC for a falling one;
    L11471-11542): `group_wait: {captured: [axis]}` then reads it. Control 2 captures the
    group's registers at its next cycle."""

    name = "group_capture"
    args: GroupCaptureArgs

    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> GroupCaptureArgs:
        m = v.mapping(obj, line, where)
        v.keys(m, {"axis", "control", "on", "start"}, where)
        control = m.get("control", 1)
        if control not in (1, 2) or isinstance(control, bool):
            raise v.err(m.kline("control") if "control" in m else line,
                        join(where, "control"),
                        f"{control!r}: 1 (the drive's input) or 2 (one-shot, 004:252)")
        on = m.get("on", "rising")
        if not isinstance(on, str) or on not in _CAPTURE_TYPES:
            raise v.err(m.kline("on") if "on" in m else line, join(where, "on"),
                        f"{on!r}: rising, falling (the A3's DI7, L5150) or zero (the encoder "
                        "zero pulse looped into it: options.extra.capture.trigger Z)")
        if control == 2 and "on" in m:
            raise v.err(m.kline("on"), join(where, "on"),
                        "Control 2 captures the registers at a cycle, not on an edge")
        start = _int(v, m, "start", where, 0, 799, 0)
        return GroupCaptureArgs(_axis_name(v, m, "axis", where), control,
                                _CAPTURE_TYPES[on] if control == 1 else 0, start)

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        g, a = self._axis(ctx)
        cap = a.capture
        if self.args.control == 2:
            with g._lock:
                cap.armed, cap.armed_at = 2, cap.captures
                cap.typ_ext_capture, cap.control = 0, 2
            return Outcome(f"{a.name}: CAPTURE Control 2 (the registers at the next cycle)")
        dio = ctx.session.drive(a.name)
        typ, start = self.args.typ, self.args.start
        # one point on CN2 (source 3), NC for a falling edge, NO for a rising one or Z
        arm_capture(ctx, dio, start=start, count=1, nc=1 if typ == CAPTURE_FALLING else 0,
                    source=3, via="sdo")
        with g._lock:
            cap.armed, cap.armed_at = 1, cap.captures
            cap.typ_ext_capture, cap.start, cap.control = typ, start, 1
        return Outcome(f"{a.name}: CAPTURE Control 1, Typ_ExtCapture 0x{typ:02X} into "
                       f"Array[{start}]")

    def describe(self) -> str:
        return f"group_capture {self.args.axis} control {self.args.control}"


class GroupExpect(StepKind):
    """`group_expect: {axis | axes, position: [lo, hi], write_position: [lo, hi],
    pg_position: [lo, hi], missed: n, rdy_same_cycle: true, status: -1..3, held: bool,
    heartbeat_lost: bool, capture_position: [lo, hi], arrived_same_cycle: true,
    peak_acc: [lo, hi]}`: the
    group's view of its axes (capture_position: the CAPTURE register of the last capture's
    type; arrived_same_cycle: every axis's feedback first showed its PG target in the same
    cycle; peak_acc: the PG's largest speed change per second since its last move)."""

    name = "group_expect"
    args: GroupExpectArgs
    judge_only = True

    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> GroupExpectArgs:
        m = v.mapping(obj, line, where)
        v.keys(m, {"axis", "axes", "position", "write_position", "pg_position", "missed",
                   "rdy_same_cycle", "arrived_same_cycle", "status", "held", "heartbeat_lost",
                   "capture_position", "peak_acc"},
               where)
        out: dict[str, Any] = {"axes": _axes(v, m, where)}
        for k in ("position", "write_position", "pg_position", "capture_position", "peak_acc"):
            if k in m:
                r = m[k]
                if (not isinstance(r, list) or len(r) != 2
                        or not all(_finite(x) for x in r) or r[0] > r[1]):
                    raise v.err(m.kline(k), join(where, k), "[low, high]")
                out[k] = (float(r[0]), float(r[1]))
        if "missed" in m:
            n = m["missed"]  # a count of cycles: 0.5 had been taken as 0 (helper-139)
            if not isinstance(n, int) or isinstance(n, bool) or not 0 <= n <= 10**9:
                raise v.err(m.kline("missed"), join(where, "missed"),
                            f"{n!r}: a whole count of cycles, 0 or more")
            out["missed"] = n
        for k in ("rdy_same_cycle", "arrived_same_cycle"):
            if k in m:
                out[k] = _flag(v, m, k, where)
        if "status" in m:
            if (not isinstance(m["status"], int) or isinstance(m["status"], bool)
                    or m["status"] not in (-1, 0, 1, 2, 3)):
                raise v.err(m.kline("status"), join(where, "status"),
                            "-1 lost, 0 never, 1 fault, 2 ready, 3 with torque (004:254)")
            out["status"] = m["status"]
        for k in ("held", "heartbeat_lost"):
            if k in m:
                out[k] = _flag(v, m, k, where)
        if len(out) == 1:  # axes alone: an expectation of nothing passes whatever happened
            raise v.err(line, where, "nothing to expect: give position, write_position, "
                        "pg_position, capture_position, peak_acc, missed, status, held, "
                        "heartbeat_lost, rdy_same_cycle or arrived_same_cycle")
        return GroupExpectArgs(**out)

    def check(self, cc: CheckContext) -> None:
        _check_axes(cc, self.args.axes, "axes")

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        a = self.args
        g = _group(ctx)
        axes = _members(g, a.axes)
        bad: list[str] = []
        with g._lock:
            for ax in axes:
                for k in ("position", "write_position", "pg_position", "capture_position",
                          "peak_acc"):
                    if getattr(a, k) is not None:
                        lo, hi = getattr(a, k)
                        val = {"pg_position": ax.pg.apos, "peak_acc": ax.pg.peak_acc,
                               "capture_position": ax.capture.position}.get(k)
                        val = getattr(ax, k) if val is None else val
                        if not lo <= val <= hi:
                            bad.append(f"{ax.name} {k} {val:.0f} not in [{lo:g}, {hi:g}]")
                if ax.setpoint_error:
                    bad.append(f"{ax.name}: {ax.setpoint_error}")
                if a.missed is not None and ax.missed > a.missed:
                    bad.append(f"{ax.name} missed {ax.missed} cycles")
                if a.status is not None and ax.status != a.status:
                    bad.append(f"{ax.name} status {ax.status}, not {a.status}")
                if a.held is not None and (ax.name in g.held) != a.held:
                    bad.append(f"{ax.name} {'not ' if a.held else ''}held")
                if a.heartbeat_lost is not None and ax.heartbeat_lost != a.heartbeat_lost:
                    bad.append(f"{ax.name} heartbeat {'' if ax.heartbeat_lost else 'not '}lost")
            if a.rdy_same_cycle and len({ax.rdy_cycle for ax in axes}) != 1:
                bad.append("targets reached in cycles " + ", ".join(
                    f"{ax.name} {ax.rdy_cycle}" for ax in axes))
            if a.arrived_same_cycle and (
                    len({ax.arrived_cycle for ax in axes}) != 1 or not axes[0].arrived_cycle):
                bad.append("feedback at the target in cycles " + ", ".join(
                    f"{ax.name} {ax.arrived_cycle or 'never'}" for ax in axes))
        text = ", ".join(f"{ax.name} at {ax.position:.0f} (missed {ax.missed})" for ax in axes)
        if bad:
            raise StepFailed("; ".join(bad) + f" ({text})")
        return Outcome(text)

    def describe(self) -> str:
        return f"group_expect {', '.join(self.args.axes)}"


class GroupControl(_OneAxis):
    """`group_control: {axis, fault_reset: true, torque: false, correction: 100, mode: 4}`:
    Servo.Control, Servo.Correction and Servo.Mode (004:216, 004:254).
    `fault_reset` sets bit 0 (controlword 0x80) for two cycles, then clears it: held at
    least one cycle, as the seed asks; `torque: false` sets bit 1 (no torque: shutdown, the
    set-point follows the motor), `torque: true` clears it and the group enables the axis
    again from where it stands. `correction` is added to WritePosition as it is (a step);
    `mode` chooses what makes WritePosition: 1 PG, 3 GEA, 4 PG + GEA."""

    name = "group_control"
    args: GroupControlArgs
    motion = True

    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> GroupControlArgs:
        m = v.mapping(obj, line, where)
        v.keys(m, {"axis", "fault_reset", "torque", "correction", "mode"}, where)
        if not {"fault_reset", "torque", "correction", "mode"} & set(m):
            raise v.err(line, where, "needs one of fault_reset, torque, correction, mode")
        out: dict[str, Any] = {"axis": _axis_name(v, m, "axis", where)}
        for k in ("fault_reset", "torque"):
            if k in m:
                out[k] = _flag(v, m, k, where)
        if "correction" in m:
            out["correction"] = _num(v, m, "correction", where, -(2**31 - 1), 2**31 - 1)
        if "mode" in m:
            mode = m["mode"]
            if isinstance(mode, bool) or mode not in (1, 3, 4) or not isinstance(mode, int):
                raise v.err(m.kline("mode"), join(where, "mode"),
                            f"{mode!r}: 1 PG, 3 GEA, 4 PG + GEA (Servo.Mode, 004:254)")
            out["mode"] = mode
        return GroupControlArgs(**out)

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        a = self.args
        g, ax = self._axis(ctx)
        with g._lock:
            if a.torque is not None:
                ax.control = (ax.control & ~0x2) | (0 if a.torque else 0x2)
            if a.correction is not None:  # added to WritePosition as it is (004:216)
                ax.correction = a.correction
            if a.mode is not None:  # the generator joins where the axis stands (004:224)
                ax.set_mode(a.mode)
        if a.fault_reset:
            with g._lock:
                ax.control |= 0x1
            c0 = g.cycles
            clock.wait_for(lambda: g.cycles >= c0 + 2, 10 * g.cycle_s)
            with g._lock:
                ax.control &= ~0x1
        return Outcome(f"{ax.name}: Control 0x{ax.control:X}")

    def describe(self) -> str:
        return f"group_control {self.args.axis}"


class GroupStop(StepKind):
    """`group_stop: {}`: the SYNC and set-points stop (the drives keep their last one)."""

    name = "group_stop"

    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> NoArgs:
        if obj not in (None, {}):
            raise v.err(line, where, f"{obj!r}: takes nothing (`group_stop: {{}}`)")
        return NoArgs()

    def check(self, cc: CheckContext) -> None:
        _check_axes(cc, [], "")

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        g = _group(ctx)
        g.stop()
        ctx.store.pop(_KEY, None)
        return Outcome(f"{g.cycles} cycles, {g.missed_cycles} missed")


KINDS = (Group, GroupMove, GroupGear, GroupCam, GroupCamTable, GroupCommand, GroupSdo,
         GroupCapture, GroupControl, GroupWait, GroupExpect, GroupStop)
