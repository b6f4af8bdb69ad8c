"""CiA 402 over CANopen: `state`, `mode`, `move`, `home`, `fault_reset`."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from hil.bench.yamlio import Checker, join
from hil.plan.context import Outcome
from hil.plan.kinds import fields
from hil.plan.kinds.base import CheckContext, NoArgs, StepKind
from hil.profile.homing_methods import CANOPEN_METHODS

if TYPE_CHECKING:
    from hil.plan.context import StepContext
    from hil.plan.session import DriveIO
    from hil.plan.steps import Step


@dataclass(frozen=True)
class StateArgs:
    state: str  # a commandable CiA 402 state


@dataclass(frozen=True)
class ModeArgs:
    mode: str  # PP, PV, PT, HM, IP ... (6060h)


@dataclass(frozen=True)
class MoveArgs:
    mode: str  # PP | PV | PT
    target: int | None = None  # PP: 607Ah
    velocity: int | None = None  # PP: 6081h; PV: 60FFh
    accel: int | None = None
    decel: int | None = None
    relative: bool | None = None
    wait: bool | None = None
    torque: int | None = None  # PT: 6071h, 0.1 %


@dataclass(frozen=True)
class HomeArgs:
    method: int  # 6098h
    accel: int  # 609Ah
    offset: int  # 607Ch
    speeds: tuple[int, int]  # 6099h sub 1 (switch), sub 2 (zero)


class _Cia402(StepKind):
    def check(self, cc: CheckContext) -> None:
        fields.check_can(cc)


class State(_Cia402):
    """`state: OPERATION ENABLED`: command a CiA 402 state through 6040h."""

    name = "state"
    args: StateArgs

    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> StateArgs:
        if not isinstance(obj, str) or obj.strip().upper() not in fields.COMMANDABLE:
            raise v.err(line, where, f"{obj!r}: one of {', '.join(fields.COMMANDABLE)}")
        return StateArgs(obj.strip().upper())

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        cia, want = d.cia, self.args.state
        if want == "OPERATION ENABLED":
            cia.enable_operation()
        elif want == "SWITCH ON DISABLED":
            cia.disable_voltage()
        elif want == "READY TO SWITCH ON":
            cia.shutdown()
        elif want == "QUICK STOP ACTIVE":
            cia.quick_stop()
        elif want == "SWITCHED ON":
            if cia.state not in ("READY TO SWITCH ON", "SWITCHED ON", "OPERATION ENABLED"):
                cia.shutdown()
            cia.write(0x6040, 0, 0x07)  # switch on (L18300-18319)
            cia.wait_state("SWITCHED ON")
        return Outcome()

    def describe(self) -> str:
        return f"state {self.args.state}"


class FaultReset(_Cia402):
    """`fault_reset: true`: 6040h bit 7 rising edge."""

    name = "fault_reset"

    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> NoArgs:
        if obj not in (None, True):
            raise v.err(line, where, "write `fault_reset: true`")
        return NoArgs()

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        d.cia.fault_reset()
        return Outcome()

    def describe(self) -> str:
        return "fault reset (6040h bit 7)"


class Mode(_Cia402):
    """`mode: PP`: 6060h, confirmed through 6061h."""

    name = "mode"
    args: ModeArgs

    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> ModeArgs:
        if not isinstance(obj, str) or obj.strip().upper() not in fields.MODES:
            raise v.err(line, where, f"{obj!r}: one of {', '.join(fields.MODES)}")
        return ModeArgs(obj.strip().upper())

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        d.cia.set_mode(self.args.mode)
        return Outcome()

    def describe(self) -> str:
        return f"mode {self.args.mode}"


_MOVE_FIELDS = {  # each mode's fields, in the order `describe` lists them
    "PP": ("target", "velocity", "accel", "decel", "relative", "wait"),
    "PV": ("velocity",),
    "PT": ("torque",),
}


class Move(_Cia402):
    """`move: {mode: PP, target: ..., velocity: ...}` (or PV velocity, PT torque)."""

    name = "move"
    args: MoveArgs
    motion = True

    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> MoveArgs:
        m = v.mapping(obj, line, where)
        mode = str(m.get("mode", "PP")).upper()
        if mode not in _MOVE_FIELDS:
            raise v.err(m.kline("mode"), join(where, "mode"), f"{m.get('mode')!r}: PP, PV or PT")
        v.keys(m, {"mode", *_MOVE_FIELDS[mode]}, where)
        i32 = fields.INT32
        if mode == "PP":
            return MoveArgs(mode, target=v.integer(m, "target", where, *i32),
                            velocity=v.integer(m, "velocity", where, 1, i32[1]),
                            accel=v.integer(m, "accel", where, 1, i32[1], 200),
                            decel=v.integer(m, "decel", where, 1, i32[1], 200),
                            relative=v.boolean(m, "relative", where, False),
                            wait=v.boolean(m, "wait", where, True))
        if mode == "PV":
            return MoveArgs(mode, velocity=v.integer(m, "velocity", where, *i32))
        return MoveArgs(mode, torque=v.integer(m, "torque", where, -3000, 3000))  # 0.1 % 6071h

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        a = self.args
        if a.mode == "PP":
            d.cia.move_to(a.target, a.velocity, a.accel, a.decel,
                          relative=a.relative, wait=a.wait)
        elif a.mode == "PV":
            d.cia.jog(a.velocity)
        else:
            d.cia.torque(a.torque)
        return Outcome()

    def describe(self) -> str:
        a = self.args
        return f"move {a.mode} " + ", ".join(f"{x}={getattr(a, x)}" for x in _MOVE_FIELDS[a.mode])


class Home(_Cia402):
    """`home: {method: 3, speeds: [fast, slow]}`: CiA 402 homing (6098h/6099h/609Ah)."""

    name = "home"
    args: HomeArgs
    motion = True

    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> HomeArgs:
        m = v.mapping(obj, line, where)
        v.keys(m, {"method", "speeds", "accel", "offset"}, where, required=("method",))
        i32 = fields.INT32
        method = v.integer(m, "method", where, -128, 127)  # 6098h (L18838)
        accel = v.integer(m, "accel", where, 1, i32[1], 100)
        offset = v.integer(m, "offset", where, *i32, 0)
        speeds = (100, 20)
        if method not in CANOPEN_METHODS:  # 6098h range 0..35, 15/16/31/32 reserved
            raise v.err(m.kline("method"), join(where, "method"),
                        f"homing method {method}: the A3 supports 1-14, 17-30 and 33-35 "
                        "(6098h, L18856-18869)")
        if "speeds" in m:
            s = m["speeds"]
            if (not isinstance(s, list) or len(s) != 2
                    or not all(isinstance(x, int) and not isinstance(x, bool) and x > 0
                               for x in s)):
                raise v.err(m.kline("speeds"), join(where, "speeds"),
                            "[fast, slow]: two positive integers (6099h sub 1 and 2)")
            speeds = (s[0], s[1])
        return HomeArgs(method, accel, offset, speeds)

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        a = self.args
        timeout = (step.timeout_ns or ctx.bench.timeouts["homing"]) / 1e9
        sw = d.cia.home(a.method, speeds=a.speeds, accel=a.accel, offset=a.offset,
                        timeout=timeout)
        return Outcome(f"statusword 0x{sw:04X}")

    def describe(self) -> str:
        return f"home method {self.args.method}"


KINDS = (State, Mode, Move, Home, FaultReset)
