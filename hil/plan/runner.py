"""Run plans on a bench: record everything, judge, leave the bench safe, write reports.

    results = run_plans(["servo_on_brake"], bench=load_bench(), out_dir=Path("reports"))

Per plan: `<out>/<plan>.mcap` (recording), `<out>/<plan>.junit.xml`, `<out>/<plan>.html`.
Steps run one at a time in a worker thread so that the step timeout and Ctrl-C are honoured
while a step blocks. Failing steps end the plan (except `check_timing`, which only judges);
then, and always at the end, the bench is driven to its safe state and that is recorded.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

from hil.plan.bench import Bench
from hil.plan.fault_steps import x_fault, x_nmt, x_produce, x_sdo
from hil.plan.plan import Plan, bind_line, check_plan, plan_spec
from hil.plan.pr_steps import EXECUTORS as PR_EXECUTORS
from hil.plan.safety import SafeReport, go_safe
from hil.plan.session import BenchError, DriveIO, Session, open_session
from hil.plan.steps import Condition, Step
from hil.virtual.truth import SensorTap, bench_with_options

PASS, FAIL, ERROR, SKIPPED, ABORTED, INCONCLUSIVE = (
    "pass", "fail", "error", "skipped", "aborted", "inconclusive")


class StepFailed(Exception):
    """A step's expectation was not met (not a harness error)."""


class Cancelled(Exception):
    pass


@dataclass
class StepResult:
    index: int
    label: str
    kind: str
    line: int
    status: str = SKIPPED
    message: str = ""
    duration_ns: int = 0
    verdicts: list[dict] = field(default_factory=list)


@dataclass
class PlanResult:
    plan: str
    path: str
    bench: str
    status: str = PASS
    steps: list[StepResult] = field(default_factory=list)
    recording: str = ""
    html: str = ""
    junit: str = ""
    duration_ns: int = 0
    safe: SafeReport | None = None
    error: str = ""

    @property
    def passed(self) -> bool:
        return self.status == PASS


def timing_specs(extra_dirs: list[Path] | None = None) -> dict[str, Any]:
    """Timing specs by id: the shipped ones plus any in `extra_dirs`."""
    from hil.timing.spec import load_spec, shipped_specs

    paths = list(shipped_specs())
    for d in extra_dirs or []:
        paths += sorted(Path(d).glob("*.yaml"))
    from hil.timing.spec import SpecError

    out = {}
    BROKEN_SPECS.clear()
    for p in paths:
        try:
            s = load_spec(p)
        except SpecError as e:  # one broken spec must not stop plans that do not use it
            BROKEN_SPECS[p.stem] = str(e)
            continue
        out[s.id] = s
    return out


#: Spec files that failed to load (file stem -> error), filled by `timing_specs()`.
BROKEN_SPECS: dict[str, str] = {}


class Progress:
    """One line per step with status and duration (stderr); silent when quiet."""

    def __init__(self, stream: TextIO | None = None, quiet: bool = False) -> None:
        self.stream = stream or sys.stderr
        self.quiet = quiet

    def plan(self, plan: Plan, bench: Bench) -> None:
        self._w(f"== {plan.name} ({len(plan.steps)} steps) on bench {bench.name}")

    def step(self, n: int, total: int, r: StepResult) -> None:
        label = r.label if len(r.label) <= 52 else r.label[:49] + "..."
        msg = f"  [{n:>2}/{total}] {label:<52} {r.status.upper():<12} {r.duration_ns / 1e6:8.1f} ms"
        if r.status not in (PASS, SKIPPED) and r.message:
            msg += f"\n         {r.message}"
        self._w(msg)

    def note(self, text: str) -> None:
        self._w(f"  {text}")

    def _w(self, text: str) -> None:
        if not self.quiet:
            print(text, file=self.stream, flush=True)


class StepContext:
    """What a step executor needs: session, recorder, plan, bench, specs, cancel flag."""

    def __init__(self, session: Session, recorder: Any, plan: Plan, specs: dict[str, Any],
                 cancel: threading.Event, steps: _StepThread | None = None) -> None:
        self.session, self.rec, self.plan, self.specs = session, recorder, plan, specs
        self.bench = session.bench
        self.cancel = cancel
        self.steps = steps or _StepThread()
        for d in session.drives.values():  # driver waits end when the step is cancelled
            if getattr(d, "_cia", None) is not None:
                d._cia.cancel = cancel
        self.store: dict[str, Any] = {}  # readings kept by `abs_read: {store: name}`
        self.checked: dict[str, int] = {}  # spec id -> wall ns its last check_timing ended
        self.started: dict[str, int] = {}  # step name -> wall ns it (last) started

    def drive(self, step: Step | None) -> DriveIO:
        name = (step.drive if step else None) or self.plan.drive or self.bench.default_drive
        return self.session.drive(name)

    def sleep(self, ns: int) -> None:
        if self.cancel.wait(ns / 1e9):
            raise Cancelled()


# --- step executors -----------------------------------------------------------------------


def _x_di(ctx: StepContext, s: Step, d: DriveIO) -> str:
    for f, lv in s.args["levels"].items():
        d.set_function(f, lv)
    return ""


def _x_pulse(ctx: StepContext, s: Step, d: DriveIO) -> str:
    widths = sorted(s.args["widths"].items(), key=lambda x: x[1])
    t0 = time.monotonic_ns()
    for f, _w in widths:
        d.set_function(f, True)
    for f, w in widths:
        left = t0 + w - time.monotonic_ns()
        if left > 0:
            ctx.sleep(left)
        d.set_function(f, False)
    return ""


def _x_sto(ctx: StepContext, s: Step, d: DriveIO) -> str:
    for ch, lv in s.args["levels"].items():
        d.set_line(d.spec.sto[ch], lv)
    return ""


def _x_sto_dropout(ctx: StepContext, s: Step, d: DriveIO) -> str:
    widths = sorted(s.args["widths"].items(), key=lambda x: x[1])
    t0 = time.monotonic_ns()
    for ch, _w in widths:
        d.set_line(d.spec.sto[ch], False)
    for ch, w in widths:
        left = t0 + w - time.monotonic_ns()
        if left > 0:
            ctx.sleep(left)
        d.set_line(d.spec.sto[ch], True)
    return ""


def _x_write(ctx: StepContext, s: Step, d: DriveIO) -> str:
    want = s.args.get("expect_error")
    if want is not None:
        return _refused_write(s, d, want)
    for p, val in s.args["values"].items():
        d.write_param(p, val, s.args["via"])
        if not ctx.bench.virtual:  # a real drive has no ground truth: record what it took
            ctx.rec.drive_params(d.name, {p: val})
    return ""


def _refused_write(s: Step, d: DriveIO, want: int) -> str:
    """A write the drive must refuse with `want` (Modbus exception / SDO abort code)."""
    from hil.plan.session import refusal_code

    [(p, val)] = s.args["values"].items()
    via = s.args["via"] or d.spec.param_via
    what = "exception" if via == "modbus" else "abort"
    try:
        d.write_param(p, val, via)
    except Exception as e:
        got = refusal_code(e)
        if got is None:
            raise
        if got != want:
            raise StepFailed(f"{p} = {val} via {via}: refused with {what} 0x{got:X}, expected "
                             f"0x{want:X} ({e})") from None
        return f"{p} = {val} refused as expected: {e}"
    raise StepFailed(f"{p} = {val} via {via} was accepted; expected a refusal with {what} "
                     f"0x{want:X}")


def _x_read(ctx: StepContext, s: Step, d: DriveIO) -> str:
    got, bad = [], []
    for p, want in s.args["values"].items():
        val = d.read_param(p, s.args["via"])
        got.append(f"{p} = {val}")
        if want is not None and val != want:
            bad.append(f"{p} = {val}, expected {want}")
    if bad:
        raise StepFailed("; ".join(bad))
    return ", ".join(got)


def _x_state(ctx: StepContext, s: Step, d: DriveIO) -> str:
    cia, want = d.cia, s.args["state"]
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
    return ""


def _x_fault_reset(ctx: StepContext, s: Step, d: DriveIO) -> str:
    d.cia.fault_reset()
    return ""


def _x_mode(ctx: StepContext, s: Step, d: DriveIO) -> str:
    d.cia.set_mode(s.args["mode"])
    return ""


def _x_move(ctx: StepContext, s: Step, d: DriveIO) -> str:
    a = s.args
    if a["mode"] == "PP":
        d.cia.move_to(a["target"], a["velocity"], a["accel"], a["decel"], relative=a["relative"],
                      wait=a["wait"])
    elif a["mode"] == "PV":
        d.cia.jog(a["velocity"])
    else:
        d.cia.torque(a["torque"])
    return ""


def _x_home(ctx: StepContext, s: Step, d: DriveIO) -> str:
    a = s.args
    timeout = (s.timeout_ns or ctx.bench.timeouts["homing"]) / 1e9
    sw = d.cia.home(a["method"], speeds=a["speeds"], accel=a["accel"], offset=a["offset"],
                    timeout=timeout)
    return f"statusword 0x{sw:04X}"


def _x_wait(ctx: StepContext, s: Step, d: DriveIO) -> str:
    ctx.sleep(s.args["duration"])
    return ""


def evaluate(ctx: StepContext, d: DriveIO, c: Condition) -> tuple[bool, str]:
    """(met, what was observed) for one condition."""
    if c.kind == "do":
        v = d.do_active(c.key)
        return v == c.value, f"{c.key} {'on' if v else 'off'}"
    if c.kind == "fdbk":
        v = d.line("FDBK")
        return v == c.value, f"FDBK {'closed' if v else 'open'}"
    if c.kind == "state":
        from hil.drivers.cia402 import decode_state

        sw = d.cia.statusword
        st = decode_state(sw)
        return st == c.value, f"{st} (statusword 0x{sw:04X})"
    if c.kind == "param":
        v = d.read_param(c.key, c.via)
        return v == c.value, f"{c.key} = {v}"
    a = d.alarm(c.via)
    return a == c.value, f"alarm {a or 'none'}"


def _x_wait_until(ctx: StepContext, s: Step, d: DriveIO) -> str:
    conds = s.args["conditions"]
    timeout = s.args["timeout"] or ctx.bench.timeouts["wait_until"]
    polls_bus = any(c.kind in ("param", "alarm", "state") for c in conds)
    poll = 10_000_000 if polls_bus else 1_000_000
    t0 = time.monotonic_ns()
    while True:
        seen = [evaluate(ctx, d, c) for c in conds]
        if all(ok for ok, _ in seen):
            return f"met after {(time.monotonic_ns() - t0) / 1e6:.1f} ms"
        if time.monotonic_ns() - t0 >= timeout:
            want = " and ".join(c.describe() for c in conds)
            saw = ", ".join(obs for _, obs in seen)
            raise StepFailed(f"timeout {timeout / 1e6:g} ms waiting for {want}; saw {saw}")
        ctx.sleep(poll)


def _x_expect(ctx: StepContext, s: Step, d: DriveIO) -> str:
    seen = [(c, *evaluate(ctx, d, c)) for c in s.args["conditions"]]
    bad = [f"expected {c.describe()}, saw {obs}" for c, ok, obs in seen if not ok]
    if bad:
        raise StepFailed("; ".join(bad))
    return ", ".join(obs for _, _, obs in seen)


def _x_power_cycle(ctx: StepContext, s: Step, d: DriveIO) -> str:
    ctx.session.world.power_cycle(d.name, battery=s.args["battery"], off_ns=s.args.get("off", 0))
    return ""


def _x_inject(ctx: StepContext, s: Step, d: DriveIO) -> str:
    ctx.session.world.inject(d.name, options=s.args.get("options"), alarm=s.args.get("alarm"))
    ctx.rec.log("warning", f"injected into {d.name}: {s.args}", name="hil.inject")
    return ""


def _x_check_timing(ctx: StepContext, s: Step, d: DriveIO) -> str:
    from hil.timing.checker import check, constants_for, occurrences_since
    from hil.timing.source import RecordingSource

    spec = ctx.specs[s.args["spec"]]
    sample = getattr(ctx.session.world, "sample_truth", None)
    if sample is not None:  # the model's state as of now, not as of its last periodic sample
        sample()
    ctx.rec.flush()
    until = time.time_ns()  # the recording as it stands now (`hil check` re-checks alike)
    source = RecordingSource(ctx.rec.path)
    binding = d.spec.binding() | {k: bind_line(x, d.spec)
                                  for k, x in s.args.get("bind", {}).items()}
    constants = constants_for(spec, ctx.bench.timing_constants) | s.args.get(
        "constants", {})
    verdicts = check(spec, source, params=s.args["params"] or None, binding=binding,
                     constants=constants or None)
    since = s.args.get("since", "start")
    since_ns = None
    if since == "last_check":
        since_ns = ctx.checked.get(spec.id)
    elif since != "start":
        since_ns = ctx.started.get(since)
    verdicts = occurrences_since(verdicts, since_ns)
    ctx.checked[spec.id] = time.time_ns()
    counts: dict[str, int] = {}
    out = []
    for v in verdicts:
        vd = v.to_dict()
        counts[v.status] = counts.get(v.status, 0) + 1
        if v.status in ("pass", "fail", "inconclusive"):
            # binding + check_params: what `hil report` needs to redraw the diagram
            ctx.rec.verdict(vd, plan=ctx.plan.name, step=s.index, binding=binding,
                            check_params=s.args["params"] or {},
                            check_constants=constants or {},
                            check_since_ns=since_ns, check_until_ns=until)
        out.append(vd)
    s.args["_verdicts"] = out
    text = ", ".join(f"{n} {k}" for k, n in sorted(counts.items())) or "no occurrence"
    if not verdicts:
        raise StepFailed(f"spec {spec.id}: nothing to judge (no occurrence in the recording)")
    if counts.get("fail"):
        bad = [f"{v.constraint}: {v.message}" for v in verdicts if v.status == "fail"]
        raise StepFailed(f"{text}; " + "; ".join(bad[:3]))
    if counts.get("inconclusive"):
        bad = [f"{v.constraint}: {v.message}" for v in verdicts if v.status == "inconclusive"]
        raise _Inconclusive(f"{text}; " + "; ".join(bad[:3]))
    return text


class _Inconclusive(StepFailed):
    pass


def _abs_reader(ctx: StepContext, d: DriveIO) -> Any:
    """The host-side reader on the drive's DI/DO port; lines from the (plan's) wiring:
    ABSE/ABSC/ABSW where wired, ABSQ = DI4, ABSR = DO2, ABSD = DO3 (L15143, L15409, L15413)."""
    from hil.drivers.abs_reader import AbsPositionReader

    if d.dio is None:
        raise BenchError(f"drive {d.name}: no DI/DO lines for the absolute handshake")
    w = d.spec.di | d.spec.do
    kw: dict[str, Any] = {"abse": w["ABSE"].line, "abse_active": w["ABSE"].contact == "a"}
    if "ABSC" in w:
        kw |= {"absc": w["ABSC"].line, "absc_active": w["ABSC"].contact == "a"}
    if "ABSW" in w:
        kw |= {"absw": w["ABSW"].line, "absw_active": w["ABSW"].contact == "a"}
    p2009 = d.read_param("P2.009") if d.spec.param_via else 2  # DI filter (L9229)
    return AbsPositionReader(d.dio, p2009_ms=p2009, **kw)


def _x_abs_read(ctx: StepContext, s: Step, d: DriveIO) -> str:
    """The 80-bit DI/DO handshake (L16460-16521), checksum verified by the reader."""
    from hil.drivers.abs_reader import AbsReadError

    reader = _abs_reader(ctx, d)
    reader.retries = s.args["retries"]
    try:
        r = reader.read()
    except AbsReadError as e:
        raise StepFailed(str(e)) from None
    got = {"status": r.status, "turns": r.turns, "position": r.position}
    text = (f"status 0x{r.status:02X}, turns {r.turns}, position {r.position} "
            f"(attempts {r.attempts})")
    ctx.rec.log("info", f"absolute read {d.name}: {text}", name="hil.abs_read")
    want = dict(s.args["expect"])
    if s.args["same_as"]:
        want = ctx.store[s.args["same_as"]] | want
    tol = s.args["tolerance"]
    bad = [f"{k} {got[k]}, expected {x}" + (f" ± {tol}" if k == "position" and tol else "")
           for k, x in want.items()
           if (abs(got[k] - x) > tol if k == "position" else got[k] != x)]
    if r.violations:
        text += "; reader timing: " + "; ".join(r.violations[:3])
    if s.args["store"]:
        ctx.store[s.args["store"]] = got
    if bad:
        same = f" (as {s.args['same_as']})" if s.args["same_as"] else ""
        raise StepFailed(f"{'; '.join(bad)}{same}: read {text}")
    return text


def _x_abs_origin(ctx: StepContext, s: Step, d: DriveIO) -> str:
    """Origin by DI/DO: ABSE on, T_S, ABSC held T_Q (default P2.009 + 250 ms), both off
    (L16436-16450)."""
    reader = _abs_reader(ctx, d)
    hold = s.args["hold"]
    reader.set_origin(None if hold is None else hold / 1e6)
    return f"ABSC held {(hold / 1e6 if hold else reader.p2009_ms + 250):g} ms"


EXECUTORS: dict[str, Callable[[StepContext, Step, DriveIO], str]] = {
    "di": _x_di, "pulse": _x_pulse, "sto": _x_sto, "sto_dropout": _x_sto_dropout,
    "write": _x_write, "read": _x_read, "state": _x_state, "fault_reset": _x_fault_reset,
    "mode": _x_mode, "move": _x_move, "home": _x_home, "wait": _x_wait,
    "wait_until": _x_wait_until, "expect": _x_expect, "power_cycle": _x_power_cycle,
    "inject": _x_inject, "check_timing": _x_check_timing, "abs_read": _x_abs_read,
    "abs_origin": _x_abs_origin,
    "fault": x_fault, "produce": x_produce, "sdo": x_sdo, "nmt": x_nmt,  # docs/faults.md
}
EXECUTORS.update(PR_EXECUTORS)  # pr_table, pr_trigger, pr_wait (hil/plan/pr_steps.py)
# Steps whose failure does not end the plan (they only judge what already happened).
JUDGE_ONLY = ("check_timing",)


# --- the runner ---------------------------------------------------------------------------


class _StepThread:
    """Runs one step executor in a thread the runner can give up on, and join later."""

    def __init__(self) -> None:
        self.thread: threading.Thread | None = None

    def run(self, fn: Callable[[], Any], timeout_ns: int, cancel: threading.Event) -> Any:
        """`fn()` or, at `timeout_ns`, TimeoutError at once (the step is cancelled and left
        to `join`). A KeyboardInterrupt cancels the step and joins it before propagating."""
        box: dict[str, Any] = {}

        def target() -> None:
            try:
                box["value"] = fn()
            except BaseException as e:
                box["error"] = e

        t = self.thread = threading.Thread(target=target, name="hil-step", daemon=True)
        t0 = time.monotonic_ns()
        t.start()
        try:
            t.join(timeout_ns / 1e9)
        except BaseException:
            cancel.set()
            self.join()
            raise
        if t.is_alive():
            cancel.set()
            t.join(0.05)  # a step that honours `cancel` ends now; the others are joined later
            raise TimeoutError(f"step timeout {timeout_ns / 1e9:g} s (bench timeouts.step or "
                               f"the step's timeout), ended after "
                               f"{(time.monotonic_ns() - t0) / 1e9:.3f} s")
        if "error" in box:
            raise box["error"]
        return box.get("value", "")

    def join(self, timeout_s: float = 5.0) -> bool:
        """Wait for the last step to end (bounded); True if no step thread is left running."""
        t = self.thread
        if t is not None:
            end = time.monotonic() + timeout_s
            while t.is_alive() and time.monotonic() < end:
                t.join(0.05)  # short joins: a signal handler still runs in between
        return t is None or not t.is_alive()


class _Interrupts:
    """SIGINT / SIGTERM while a plan runs (main thread only).

    The first signal raises KeyboardInterrupt: the plan stops and the bench goes safe. From
    then on, and at any time while `shield` is set (the safe state, closing the recording),
    a signal only prints a notice: the safe-state sequence and the recording's close always
    run to their end. A signal that arrives while shielded is remembered (`requested`)."""

    NOTICE = (b"hil: making the bench safe and closing the recording; further Ctrl-C is "
              b"ignored until that is done\n")

    def __init__(self) -> None:
        self.count = 0
        self.shield = False
        self._old: dict[int, Any] = {}

    @property
    def requested(self) -> bool:
        return self.count > 0

    def _handler(self, signum: int, frame: Any) -> None:
        self.count += 1
        if self.count == 1 and not self.shield:
            raise KeyboardInterrupt(f"signal {signum}")
        with contextlib.suppress(OSError):
            os.write(2, self.NOTICE)

    def __enter__(self) -> _Interrupts:
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self._old[sig] = signal.signal(sig, self._handler)
        return self

    def __exit__(self, *exc: Any) -> None:
        for sig, old in self._old.items():
            signal.signal(sig, old)


def run_plan(plan: Plan, bench: Bench, out_dir: Path, *, specs: dict[str, Any] | None = None,
             progress: Progress | None = None,
             session_factory: Callable[[Bench, Any], Session] = open_session,
             allow_inconclusive: bool = False, reports: bool = True) -> PlanResult:
    """Run one (already checked) plan; raises KeyboardInterrupt after leaving the bench safe."""
    from hil.record.recorder import Recorder

    progress = progress or Progress(quiet=True)
    specs = specs if specs is not None else timing_specs()
    check_plan(plan, bench, specs)
    out_dir.mkdir(parents=True, exist_ok=True)
    stem = Path(plan.path).stem if plan.path and plan.path != "<string>" else plan.name
    res = PlanResult(plan.name, plan.path, bench.name, recording=str(out_dir / f"{stem}.mcap"))
    res.steps = [StepResult(s.index, s.label, s.kind, s.line) for s in plan.steps]
    rec = Recorder(res.recording, metadata={"plan": plan.name, "plan_file": plan.path,
                                            "bench": bench.name, "bench_file": bench.path})
    rec.add_metadata("hil.plan", {"name": plan.name, "file": plan.path,
                                  "description": plan.description, "steps": len(plan.steps)})
    rec.add_metadata("hil.bench", {"name": bench.name, "file": bench.path,
                                   "virtual": bench.virtual, "drives": list(bench.drives),
                                   "motion_allowed": bench.motion_allowed})
    checked = sorted({s.args["spec"] for s in plan.steps if s.kind == "check_timing"})
    if checked:  # read by `hil check` (docs/timing.md): specs and the default drive's binding
        import json

        dspec = plan_spec(plan, bench.drives[plan.drive or bench.default_drive])
        rec.add_metadata("timing", {"specs": json.dumps(checked),
                                    "binding": json.dumps(dspec.binding()),
                                    "constants": json.dumps(bench.timing_constants)})
    rec.attach("bench.yaml", bench.text.encode(), "application/yaml")
    rec.attach("plan.yaml", plan.text.encode(), "application/yaml")
    progress.plan(plan, bench)
    t_start = time.monotonic_ns()
    tmp = contextlib.ExitStack()
    cancel = threading.Event()
    steps = _StepThread()
    session: Session | None = None
    ctx: StepContext | None = None
    interrupted: BaseException | None = None
    reason = "end of plan"
    with _Interrupts() as intr:
        try:
            try:
                sbench = bench_with_options(bench, plan.options, tmp)
                truth = SensorTap(rec) if bench.virtual else rec
                session = steps.run(lambda: session_factory(sbench, truth),
                                    bench.timeouts["ready"] + 5_000_000_000, cancel)
                ctx = StepContext(session, rec, plan, specs, cancel, steps)  # type: ignore[arg-type]
                _idle_inputs(ctx)
                if plan.params:
                    _initial_params(ctx, plan)
                _apply_plan_wiring(ctx, plan)
                reason = _steps(ctx, plan, res, progress, allow_inconclusive)
            except KeyboardInterrupt as e:
                intr.shield = True
                interrupted, reason = e, "interrupted (Ctrl-C / SIGTERM)"
                res.status = ABORTED
                for r in res.steps:
                    if r.status == SKIPPED and not r.message:
                        r.message = "not run: interrupted"
                if ctx is not None:
                    _record_skipped(ctx, plan, res)
            except Exception as e:
                res.status, res.error = ERROR, f"{type(e).__name__}: {e}"
                reason = f"error: {res.error}"
                rec.log("error", f"plan {plan.name}: {res.error}", name="hil.runner")
                progress.note(f"ERROR {res.error}")
            finally:
                intr.shield = True
                cancel.set()
                if not steps.join():
                    rec.log("warning", "a step did not end within 5 s of its cancel; going "
                            "safe anyway (one SDO transaction at a time)", name="hil.runner")
                if session is not None:
                    _go_safe(session, reason, rec, res, progress)
        finally:
            intr.shield = True
            if session is not None:
                session.close()
            tmp.close()
            res.duration_ns = time.monotonic_ns() - t_start
            rec.add_metadata("hil.result", {"status": res.status, "reason": reason,
                                            "duration_ms": res.duration_ns / 1e6,
                                            "safe_state_ok": res.safe.ok if res.safe else ""})
            rec.close()
            if reports:
                write_reports(res, out_dir, stem)
    if interrupted is None and intr.requested:
        interrupted = KeyboardInterrupt("signal while the bench was made safe")
    if interrupted is not None:
        raise interrupted
    return res


def _go_safe(session: Session, reason: str, rec: Any, res: PlanResult,
             progress: Progress) -> None:
    for d in session.drives.values():
        if getattr(d, "_cia", None) is not None:
            d._cia.cancel = None  # the plan's cancel must not cut the safe state's own waits
    res.safe = go_safe(session, reason, rec)
    if not res.safe.ok:
        progress.note("SAFE STATE NOT CONFIRMED: " + "; ".join(
            f"{a['drive']}: {a['action']}: {a['detail']}"
            for a in res.safe.actions if not a["ok"]))
    elif reason != "end of plan":
        progress.note(f"bench driven to its safe state ({reason})")


# DI functions a machine's sensors drive (the virtual axis drives them from its mechanics):
# the harness never sets them.
SENSOR_FUNCTIONS = ("ORGP", "NL", "PL")


def _apply_plan_wiring(ctx: StepContext, plan: Plan) -> None:
    """From here on the default drive's functions are where the plan's params mapped them."""
    d = ctx.drive(None)
    before = d.spec
    d.spec = plan_spec(plan, d.spec)
    if d.dio is None:
        return
    for f, w in d.spec.di.items():  # newly mapped inputs start inactive, as idle() does;
        if before.di.get(f) != w and f not in SENSOR_FUNCTIONS:  # sensors are the machine's
            d.set_function(f, False)


def _idle_inputs(ctx: StepContext) -> None:
    ctx.session.idle(ctx.rec)


def _initial_params(ctx: StepContext, plan: Plan) -> None:
    d = ctx.drive(None)
    ctx.rec.plan_step("params", "start", plan=plan.name, index=-1)
    for p, v in plan.params.items():
        d.write_param(p, v)
        if not ctx.bench.virtual:
            ctx.rec.drive_params(d.name, {p: v})
    ctx.rec.plan_step("params", "end", plan=plan.name, index=-1, status=PASS,
                      message=", ".join(f"{p}={v}" for p, v in plan.params.items()))


def _steps(ctx: StepContext, plan: Plan, res: PlanResult, progress: Progress,
           allow_inconclusive: bool) -> str:
    rec, total = ctx.rec, len(plan.steps)
    for s, r in zip(plan.steps, res.steps, strict=True):
        d = ctx.drive(s)
        rec.plan_step(r.label, "start", plan=plan.name, index=s.index, kind=s.kind, line=s.line,
                      drive=d.name)
        t0 = time.monotonic_ns()
        if s.name:
            ctx.started[s.name] = time.time_ns()
        timeout = s.timeout_ns or ctx.bench.timeouts["step"]
        try:
            ctx.session.check_lease()  # a bench behind a gateway: only while the lease holds
            ctx.session.check_alive()  # a virtual bench: only while its drive processes live
            r.message = ctx.steps.run(lambda s=s, d=d: EXECUTORS[s.kind](ctx, s, d), timeout,
                                      ctx.cancel)
            ctx.session.check_lease()
            ctx.session.check_alive()
            r.status = PASS
        except _Inconclusive as e:
            r.status, r.message = INCONCLUSIVE, str(e)
        except StepFailed as e:
            r.status, r.message = FAIL, str(e)
        except (TimeoutError, Cancelled) as e:
            r.status, r.message = ERROR, str(e) or "cancelled"
        except BenchError as e:
            r.status, r.message = ERROR, str(e)
        except Exception as e:
            r.status, r.message = ERROR, f"{type(e).__name__}: {e}"
        r.duration_ns = time.monotonic_ns() - t0
        r.verdicts = s.args.pop("_verdicts", [])
        rec.plan_step(r.label, "end", plan=plan.name, index=s.index, kind=s.kind, line=s.line,
                      drive=d.name, status=r.status, message=r.message,
                      duration_ns=r.duration_ns, file=s.file)
        progress.step(s.index + 1, total, r)
        ok = r.status == PASS or (r.status == INCONCLUSIVE and allow_inconclusive)
        if not ok:
            if res.status == PASS:
                res.status = FAIL if r.status in (FAIL, INCONCLUSIVE) else ERROR
            if s.kind not in JUDGE_ONLY:
                rec.log("error", f"step {s.index + 1} ({r.label}) {r.status}: {r.message}",
                        name="hil.runner", file=s.file, line=s.line)
                for later in res.steps[s.index + 1:]:
                    later.message = f"not run: step {s.index + 1} {r.status}"
                _record_skipped(ctx, plan, res)
                return f"step {s.index + 1} ({r.label}) {r.status}: {r.message}"
    return "end of plan"


def _record_skipped(ctx: StepContext, plan: Plan, res: PlanResult) -> None:
    for s, r in zip(plan.steps, res.steps, strict=True):
        if r.status == SKIPPED:
            ctx.rec.plan_step(r.label, "end", plan=plan.name, index=s.index, kind=s.kind,
                              line=s.line, status=SKIPPED, message=r.message, file=s.file)


def write_reports(res: PlanResult, out_dir: Path, stem: str) -> None:
    from hil.report.html import write_html
    from hil.report.junit import write_junit

    try:
        res.junit = str(write_junit([res.recording], out_dir / f"{stem}.junit.xml"))
    except Exception as e:
        res.error = res.error or f"JUnit report failed: {e}"
    try:
        res.html = str(write_html(res.recording, out_dir / f"{stem}.html"))
    except Exception as e:
        res.error = res.error or f"HTML report failed: {e}"


def summary_table(results: list[PlanResult]) -> str:
    rows = [("plan", "status", "steps", "verdicts", "time", "recording")]
    for r in results:
        n_ok = sum(1 for s in r.steps if s.status == PASS)
        vs = [v for s in r.steps for v in s.verdicts if v.get("status") != "skipped"]
        v_ok = sum(1 for v in vs if v.get("status") == "pass")
        rows.append((r.plan, r.status.upper(), f"{n_ok}/{len(r.steps)}", f"{v_ok}/{len(vs)}",
                     f"{r.duration_ns / 1e9:.2f} s", r.recording))
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    lines = ["  ".join(c.ljust(w) for c, w in zip(row, widths, strict=True)).rstrip()
             for row in rows]
    lines.insert(1, "  ".join("-" * w for w in widths))
    passed = sum(r.passed for r in results)
    lines.append(f"{passed}/{len(results)} plans passed")
    return "\n".join(lines)


def run_plans(plans: list[Plan], bench: Bench, out_dir: Path, *, quiet: bool = False,
              stream: TextIO | None = None, allow_inconclusive: bool = False,
              session_factory: Callable[[Bench, Any], Session] = open_session
              ) -> list[PlanResult]:
    """Check every plan against the bench first (nothing moves on a bad file), then run."""
    specs = timing_specs()
    for p in plans:
        check_plan(p, bench, specs)
    progress = Progress(stream, quiet)
    results = []
    for p in plans:
        results.append(run_plan(p, bench, out_dir, specs=specs, progress=progress,
                                session_factory=session_factory,
                                allow_inconclusive=allow_inconclusive))
    return results
