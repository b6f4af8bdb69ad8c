"""Run plans on a bench: record everything, judge, leave the bench safe, write reports.

    results = run_plans(["servo_on_brake"], bench=load_bench(), out_dir=Path("reports"))

Per plan: `<out>/<plan>.mcap` (recording), `<out>/<plan>.junit.xml`, `<out>/<plan>.html`.
Steps run one at a time in a worker thread so that the step timeout and Ctrl-C are honoured
while a step blocks. Failing steps end the plan (except `check_timing`, which only judges);
then, and always at the end, the bench is driven to its safe state and that is recorded.
"""

from __future__ import annotations

import contextlib
import gc
import json
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

from hil import clock
from hil.bench import virtual_module
from hil.bench.bench import Bench, line_warnings
from hil.fileio import fit_name, safe_stem
from hil.plan.context import (
    Cancelled,
    Inconclusive,
    StepContext,
    StepFailed,
    StepThread,
)
from hil.plan.events import (
    Listener,
    Note,
    Notifier,
    PlanEnded,
    PlanStarted,
    StepEnded,
    StepStarted,
)
from hil.plan.listeners import Reports, StepLines, StepRecords, recorded_file
from hil.plan.plan import Plan, check_plan, plan_spec
from hil.plan.safety import SafeReport, go_safe_watched
from hil.plan.session import BenchError, Session, open_session
from hil.record.recorder import Recorder
from hil.report.data import forget as forget_report
from hil.terminal import terminal_text
from hil.timing.registry import SpecRegistry, load_specs

__all__ = ["Cancelled", "PlanResult", "StepContext", "StepFailed", "StepResult", "run_plan",
           "run_plans", "summary_table", "timing_specs"]

PASS, FAIL, ERROR, SKIPPED, ABORTED, INCONCLUSIVE = (
    "pass", "fail", "error", "skipped", "aborted", "inconclusive")


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


def timing_specs(extra_dirs: list[Path] | None = None) -> SpecRegistry:
    """Timing specs by id: the shipped ones plus any in `extra_dirs` (`.broken` says which
    files did not load)."""
    return load_specs(extra_dirs)


# --- the runner ---------------------------------------------------------------------------


# Why this process sent itself a signal (a `-j` worker whose `hil run` died): the handler
# that takes it names the stop so, once, instead of "SIGINT (Ctrl-C)" (helper-140)
SELF_SENT: dict[int, str] = {}


def signal_text(signum: int) -> str:
    """How a stop by `signum` is named on the record: "SIGINT (Ctrl-C)", "SIGTERM", or the
    cause this process gave a signal it sent itself (`SELF_SENT`)."""
    if (why := SELF_SENT.pop(signum, None)) is not None:
        return why
    try:
        name = signal.Signals(signum).name
    except ValueError:
        name = f"signal {signum}"
    return f"{name} (Ctrl-C)" if signum == signal.SIGINT else name


def first_line(e: BaseException) -> str:
    """`Type: first line of its message`."""
    what = str(e).splitlines()[0] if str(e) else ""
    return f"{type(e).__name__}: {what}".rstrip(": ")


def interrupt_cause(e: BaseException) -> str:
    """The signal a KeyboardInterrupt names (`signal_text`), else "Ctrl-C / SIGTERM"."""
    text = str(e)
    return text if text.startswith("SIG") else "Ctrl-C / SIGTERM"


class Interrupts:
    """SIGINT / SIGTERM while a plan or a fixture test runs (main thread only).

    The first signal raises KeyboardInterrupt naming it (`cause`): the plan or test stops and
    the bench goes safe. With `clk` a virtual clock whose events this thread runs (a pytest
    fixture test), it is raised between two events, never inside one (`defer_interrupt`).
    From then on, and at any time while `shield` is set (the safe state, closing the
    recording), a signal only prints a notice (on a line of its own: a progress line may be
    half written): the safe-state sequence and the recording's close always run to their
    end. A signal that arrives while shielded is remembered (`requested`)."""

    NOTICE = (b"\nhil: making the bench safe and closing the recording; further Ctrl-C is "
              b"ignored until that is done\n")

    def __init__(self, clk: Any = None, *, hold: bool = False, held: bytes = b"") -> None:
        self.count = 0
        self.shield = False
        # a signal is only counted, and raised by `release` (or `raise_lost`): the short
        # stretches that must end whole (a recording's opening, a step's end record); `held`
        # is said on stderr when one comes then (a stretch that may take a while)
        self.hold = hold
        self.held = held
        self.cause = ""  # the signal that stopped the run ("SIGINT (Ctrl-C)", "SIGTERM")
        self.clk = clk
        self._old: dict[int, Any] = {}
        # another handler's exception (pytest-timeout's) that the test never saw: deferred
        # and then dropped, or raised while shielded; the caller raises it once it is done
        self.alarm: BaseException | None = None
        self._pending: BaseException | None = None  # deferred, maybe not raised yet

    @property
    def requested(self) -> bool:
        return self.count > 0

    def _handler(self, signum: int, frame: Any) -> None:
        self.count += 1
        if self.count == 1 and not self.shield:
            self.cause = signal_text(signum)
            if self.hold:
                if self.held:
                    with contextlib.suppress(OSError):
                        os.write(2, self.held)
                return
            exc = KeyboardInterrupt(self.cause)
            defer = getattr(self.clk, "defer_interrupt", None)
            if defer is None or not defer(exc):
                raise exc
            return
        if self.hold and self.held:  # said once already; no bench is going safe here
            return
        with contextlib.suppress(OSError):
            os.write(2, self.NOTICE)

    def __enter__(self) -> Interrupts:
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self._old[sig] = signal.signal(sig, self._handler)
            if (undo := self.wrap_alarm()) is not None:
                self._old[signal.SIGALRM] = undo
        return self

    def wrap_alarm(self) -> Any:
        """On a virtual clock, wrap the SIGALRM handler in place (pytest-timeout's, also one
        installed later, for the test function only: the plugin calls this again then) so
        that its exception is raised between two clock events, as an interrupt is, never
        inside one: a host tick it cut stopped the virtual drive, and the safe state after
        the timeout failed. While shielded (the safe state, closing the recording) it is
        kept in `alarm` instead. Returns the handler it replaced (None: nothing wrapped)."""
        alarm = getattr(signal, "SIGALRM", None)
        if (self.clk is None or alarm is None
                or threading.current_thread() is not threading.main_thread()):
            return None
        other = signal.getsignal(alarm)
        if not callable(other) or getattr(other, "_hil_deferred", False):
            return None
        signal.signal(alarm, self._deferred(other))
        return other

    def _deferred(self, handler: Callable[[int, Any], Any]) -> Callable[[int, Any], None]:
        def run(signum: int, frame: Any) -> None:
            try:
                handler(signum, frame)
            except BaseException as exc:
                if self.shield:  # the safe state and the recording's close run to their end
                    self.alarm = self.alarm or exc
                    return
                defer = getattr(self.clk, "defer_interrupt", None)
                if defer is None or not defer(exc):
                    raise
                self._pending = exc

        run._hil_deferred = True  # type: ignore[attr-defined]
        return run

    def raise_lost(self) -> None:
        """Raise again a signal's KeyboardInterrupt that never reached the run: a handler that
        raised while this thread ran a weakref callback of the garbage collector (threading's
        WeakSet of threads) had its exception printed as "ignored", and the plan went on to
        its end (a CI run, session 31). Called between steps and while a step runs (`watch`);
        once the run has taken the interrupt, it is shielded and this does nothing. Not for a
        fixture test's deferred interrupt (`clk`): the clock raises that one itself."""
        if self.count and not self.shield and self.clk is None:
            raise KeyboardInterrupt(self.cause or "Ctrl-C / SIGTERM")

    def release(self) -> None:
        """End a `hold`; a signal that came during it is raised now (`raise_lost`)."""
        self.hold = False
        self.raise_lost()

    def drop_pending(self) -> None:
        """Before the safe state: a deferred exception not raised yet is dropped from the
        clock (it must not cut the safe state) and kept in `alarm` if it was another
        handler's (a deferred Ctrl-C is known by `cause`)."""
        drop = getattr(self.clk, "drop_interrupt", None)
        lost = drop() if drop is not None else None
        if lost is not None and lost is self._pending:
            self.alarm = self.alarm or lost

    def __exit__(self, *exc: Any) -> None:
        for sig, old in self._old.items():
            signal.signal(sig, old)


# While a virtual-time plan runs, the cyclic garbage collector's older generations are
# collected this seldom (in collections of the next younger one; Python's own are 10 and
# 10): a run keeps every message it recorded for its checks, and passes over them cost a
# homing plan 10-15 % of its time (docs/performance.md, session 18). The young generation
# is collected as usual, so short-lived cycles still go at once.
VIRTUAL_GC_OLDER = (1000, 1000)


@contextlib.contextmanager
def _older_generations_seldom() -> Any:
    """The collector's thresholds for the block (one run at a time per process, as the
    clock itself: `clock.use`)."""
    old = gc.get_threshold()
    gc.set_threshold(old[0], *VIRTUAL_GC_OLDER)
    try:
        yield
    finally:
        gc.set_threshold(*old)


@contextlib.contextmanager
def bench_clock(bench: Bench) -> Iterator[clock.RealClock | clock.VirtualClock]:
    """The bench's clock for one run (a plan, a `hil_session` test): a fresh `VirtualClock`
    for `clock: virtual` (docs/clock.md), with the collector's older generations collected
    seldom while it runs; the wall clock otherwise."""
    if bench.clock != "virtual":
        with clock.use(clock.REAL) as clk:
            yield clk
        return
    with clock.use(clock.VirtualClock()) as clk, _older_generations_seldom(), \
            _threads_switch_seldom():
        yield clk


# While a virtual-time run runs, a thread waiting for the GIL (the recorder's writer, which
# wakes every 2 ms) takes it from the run's thread this seldom, not every 5 ms (Python's
# default): the writer's batches grow and the hand-overs shrink. Nothing in a virtual run
# waits on a thread's latency: time is the clock's (docs/performance.md, session 29).
VIRTUAL_SWITCH_INTERVAL_S = 0.05


@contextlib.contextmanager
def _threads_switch_seldom() -> Any:
    old = sys.getswitchinterval()
    sys.setswitchinterval(VIRTUAL_SWITCH_INTERVAL_S)
    try:
        yield
    finally:
        sys.setswitchinterval(old)


def run_plan(plan: Plan, bench: Bench, out_dir: Path, **kwargs: Any) -> PlanResult:
    """`_run_plan` on the bench's clock (`bench_clock`)."""
    with bench_clock(bench):
        return _run_plan(plan, bench, out_dir, **kwargs)


def _run_plan(plan: Plan, bench: Bench, out_dir: Path, *,
              specs: Mapping[str, Any] | None = None,
              listeners: list[Listener] | None = None,
              session_factory: Callable[[Bench, Any], Session] = open_session,
              allow_inconclusive: bool = False, reports: bool = True, index: int = 1,
              total: int = 1, stop: Callable[[], bool | str] | None = None,
              stem: str | None = None) -> PlanResult:
    """Run one plan (checked here against the bench first); raises KeyboardInterrupt after
    leaving the bench safe. Listeners hear plan and step events; the recording's step records
    and, with `reports`, the JUnit and HTML reports are listeners too. `stop()` true once the
    signal handlers are in place: a stop asked for while the plan was being set up (a `-j`
    worker's signal, named where `stop()` gives its name), handled as Ctrl-C. `stem`: the
    output files' name (default: the plan file's; `output_stems` makes them unique within a
    run)."""
    specs = specs if specs is not None else timing_specs()
    check_plan(plan, bench, specs)
    # a signal while the recording is opened and announced waits until it is (`release`):
    # a Ctrl-C there had left a 0-byte .mcap (helper-140)
    with Interrupts(hold=True) as intr:
        # in virtual time (short runs, messages in memory anyway for the checks) the reports
        # take the recorder's mirror; a real-time run's reports read the file
        res, rec, stem = _open_recording(plan, bench, out_dir, stem,
                                         mirror=reports and bench.clock == "virtual")
        events = Notifier([StepRecords(), *(listeners or [])]
                          + ([Reports(out_dir, stem)] if reports else []))
        events.emit(PlanStarted(plan, bench, index, total, rec))
        t_start = time.monotonic_ns()
        tmp = contextlib.ExitStack()
        cancel = threading.Event()
        steps = StepThread()
        session: Session | None = None
        ctx: StepContext | None = None
        interrupted: BaseException | None = None
        reason = "end of plan"
        try:
            try:
                intr.release()  # a signal that came while the recording opened stops it here
                why = stop() if stop is not None else None
                if why:  # the signal's name where `stop` knows it (`interrupt_cause`)
                    raise KeyboardInterrupt(why if isinstance(why, str)
                                            else "stopped before the plan began")
                sbench, truth = bench, rec
                if bench.virtual:  # the virtual world's ground truth and model options
                    vt = virtual_module("truth")
                    sbench = vt.bench_with_options(bench, plan.options, tmp)
                    truth = vt.SensorTap(rec)
                session = steps.run(lambda: session_factory(sbench, truth),
                                    bench.timeouts["ready"] + 5_000_000_000, cancel)
                ctx = StepContext(session, rec, plan, specs, cancel, steps)  # type: ignore[arg-type]
                _idle_inputs(ctx)
                record_dut(session, rec, bench)
                if plan.params:
                    _initial_params(ctx, plan)
                _apply_plan_wiring(ctx, plan)
                reason = _steps(ctx, plan, res, events, allow_inconclusive, intr)
            except Exception as e:
                res.status, res.error = ERROR, f"{type(e).__name__}: {e}"
                reason = f"error: {res.error}"
                rec.log("error", f"plan {plan.name}: {res.error}", name="hil.runner")
                events.emit(Note(plan, f"ERROR {res.error}"))
            except BaseException as e:  # Ctrl-C / SIGTERM, pytest-timeout's Failed,
                intr.shield = True      # SystemExit: the plan is cut, never "end of plan"
                interrupted = e         # passed; raised again once the bench is safe
                if isinstance(e, KeyboardInterrupt):
                    reason, why = f"interrupted ({interrupt_cause(e)})", "interrupted"
                else:
                    reason = why = res.error = f"stopped: {first_line(e)}"
                res.status = ABORTED
                for r in res.steps:
                    if r.status == SKIPPED and not r.message:
                        r.message = f"not run: {why}"
                if ctx is not None:
                    _record_skipped(ctx, plan, res, events)
            finally:
                intr.shield = True
                cancel.set()
                if not steps.join():
                    rec.log("warning", "a step did not end within 5 s of its cancel; going "
                            "safe anyway (one SDO transaction at a time)", name="hil.runner")
                if session is not None:
                    _go_safe(session, reason, rec, res, events, plan)
                elif reason != "end of plan":  # stopped or failed before the bench was up
                    rec.safety("safe_state_not_confirmed", reason, ok=False,
                               detail="the bench was not up yet: no safe state was driven")
                    events.emit(Note(plan, "SAFE STATE NOT CONFIRMED: the bench was not up "
                                     f"yet ({reason})"))
        finally:
            intr.shield = True
            if session is not None:
                session.close()
            tmp.close()
            res.duration_ns = time.monotonic_ns() - t_start
            if reason == "end of plan" and res.error:  # the safe state failed a passed plan
                reason = res.error
            rec.add_metadata("hil.result", {"status": res.status, "reason": reason,
                                            "duration_ms": res.duration_ns / 1e6,
                                            "safe_state_ok": res.safe.ok if res.safe else ""})
            rec.close()
            events.emit(PlanEnded(plan, res, index, total,
                                  ctx.live if ctx is not None else None))
    if interrupted is None and intr.requested:
        # a signal the plan's end took in (its safe state, a failed step's end record):
        # named as it came (helper-141: a SIGTERM there was called a signal)
        interrupted = KeyboardInterrupt(intr.cause or "signal while the bench was made safe")
    if interrupted is not None:
        with contextlib.suppress(AttributeError):
            interrupted.plan_result = res  # type: ignore[attr-defined]  # for `-j N` workers
        raise interrupted
    return res


# After the safe state the bench is recorded on for this long, on either clock (longer than the
# motor's brake takes to clamp after BRKR went off, and than a P1.043 delay up to 200 ms): the
# drive's reaction is on the record. (On a virtual clock nothing at all would pass otherwise;
# a real-time run used to close about 2 ms after the safe state, before the brake clamped.)
SAFE_TAIL_NS = 200_000_000
# a plan without `check_timing` steps keeps its messages in memory for its reports up to this
# many (about 2 KB each: 50 s of a 1 kHz ground truth); past it they read the file, so a long
# soak or wait in virtual time does not grow without bound (docs/clock.md)
REPORT_MIRROR_LIMIT = 50_000
# a step whose own timeout (`wait_until`, `pr_wait`, ...) or `wait` is longer than the bench's
# step timeout: the step's watchdog waits this much past it, so the step fails saying what it
# saw, or ends (docs/plans.md)
OWN_TIMEOUT_GRACE_NS = 1_000_000_000


def safe_tail(session: Session) -> None:
    """Run the bench on for `SAFE_TAIL_NS` after the safe state (a plan's end, a
    `hil_session` test's teardown), on the run's clock, then take a last ground-truth sample
    (a virtual world's)."""
    with contextlib.suppress(Exception):
        clock.sleep(SAFE_TAIL_NS / 1e9)
        sample = getattr(session.world, "sample_truth", None)
        if sample is not None:
            sample()


def record_dut(session: Session, rec: Recorder, bench: Bench) -> None:
    """The drives under test, as OpenHTF records a dut_id: per drive the bench's name, node
    and station, P0.000 firmware (L7070) and the 1018h identity (vendor, product, revision,
    serial, L17762-17800) where the bench reaches them; recorded as metadata `hil.dut` (for
    a plan, and for a pytest test through `hil_session`). What a drive does not answer is
    "unavailable", never a failed plan or test."""
    meta: dict[str, str] = {}
    for name, spec in bench.drives.items():
        meta[f"{name}.node_id"] = str(spec.node_id or "")
        meta[f"{name}.station"] = str(spec.station or "")
        try:
            d = session.drive(name)
        except Exception:  # a fake or partial session
            continue
        try:
            meta[f"{name}.firmware"] = str(d.read_param("P0.000"))
        except Exception:  # no route for parameters on this bench
            meta[f"{name}.firmware"] = "unavailable"
        if spec.can:
            for sub, key in ((1, "vendor_id"), (2, "product_code"), (3, "revision"),
                             (4, "serial")):
                try:
                    meta[f"{name}.{key}"] = f"0x{int(d.cia.read(0x1018, sub)):08X}"
                except Exception:  # 1018h sub 4 is optional (CiA 301)
                    meta[f"{name}.{key}"] = "unavailable"
    rec.add_metadata("hil.dut", meta)


def record_bench(rec: Recorder, bench: Bench, options: dict[str, Any] | None = None) -> None:
    """The `hil.bench` and `hil.clock` metadata of a recording made on `bench`, on the clock
    in use (a plan's, and a pytest test's through `hil_session`), and on `/log` the bench's
    `line_warnings`. `deviations`: the model's
    deliberate deviation knobs (`dev_*`) in effect, the bench's and the plan's `options`."""
    deviations = sorted({f"{name}.{k}={v}" for name, d in bench.drives.items()
                         for k, v in (dict(d.options) | dict(options or {})).items()
                         if k.startswith("dev_") and v not in (0, False, None, "")}
                        if bench.virtual else ())
    rec.add_metadata("hil.bench", {"name": bench.name, "file": bench.path,
                                   "virtual": bench.virtual, "drives": list(bench.drives),
                                   "motion_allowed": bench.motion_allowed,
                                   "deviations": json.dumps(deviations)})
    clk = clock.current()
    bind = getattr(rec, "bind_clock", None)  # test doubles may lack it
    if bind is not None:
        bind(clk)
    rec.add_metadata("hil.clock", {"clock": clk.name, "epoch_ns": str(getattr(clk, "epoch_ns", 0)),
                                   "started_wall_ns": str(time.time_ns())})
    for warning in line_warnings(bench):  # why Modbus may go unanswered (a plan's, a test's)
        rec.log("warning", warning, name="hil.bench")


def plan_stem(plan: Plan) -> str:
    """The name of a plan's output files: its file's stem (its name for a plan from text)."""
    return Path(plan.path).stem if plan.path and plan.path != "<string>" else plan.name


def output_stems(plans: list[Plan]) -> list[str]:
    """One output name per plan, unique within the run (case-folded): two `x.yaml` of
    different folders become `a-x` and `b-x` (parent folders until they differ), and any
    name still taken gets a number, so no recording overwrites another, with or without
    `-j`. Names are file names: no path separator, no anchor."""
    stems = [plan_stem(p) for p in plans]
    out = list(stems)
    groups: dict[str, list[int]] = {}
    for i, s in enumerate(stems):
        groups.setdefault(s.casefold(), []).append(i)
    for idx in groups.values():
        if len(idx) < 2:
            continue
        parents = [Path(plans[i].path).resolve().parent.parts[1:] for i in idx]
        for depth in range(1, max(len(p) for p in parents) + 1):
            cand = ["-".join((*p[-depth:], stems[i])) for p, i in zip(parents, idx, strict=True)]
            if len({c.casefold() for c in cand}) == len(cand):
                break
        for i, c in zip(idx, cand, strict=True):
            out[i] = c
    seen: set[str] = set()
    for i, s in enumerate(out):
        # room for `-2` and `.junit.xml`; a cut name gets a hash of the whole one: the same
        s = fit_name(safe_stem(s) or "plan", 200)  # name whatever is selected
        base, k = s, 2
        while s.casefold() in seen:
            s, k = f"{base}-{k}", k + 1
        seen.add(s.casefold())
        out[i] = s
    return out




def _open_recording(plan: Plan, bench: Bench, out_dir: Path, stem: str | None = None, *,
                    mirror: bool = False) -> tuple[PlanResult, Recorder, str]:
    """The plan's result skeleton and its recording, with the plan, bench and timing
    metadata `hil check` and `hil report` read back. `mirror`: keep every message written
    in memory too (the reports read them there, not from the file again)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    stem = stem or plan_stem(plan)
    res = PlanResult(plan.name, plan.path, bench.name, recording=str(out_dir / f"{stem}.mcap"))
    res.steps = [StepResult(s.index, s.label, s.kind, s.line) for s in plan.steps]
    forget_report(res.recording)  # a report's cache of the file this run overwrites
    rec = Recorder(res.recording, metadata={"plan": plan.name, "plan_file": plan.path,
                                            "bench": bench.name, "bench_file": bench.path})
    rec.add_metadata("hil.plan", {"name": plan.name, "file": plan.path,
                                  "description": plan.description, "steps": len(plan.steps),
                                  "tags": json.dumps(plan.tags)})
    record_bench(rec, bench, plan.options)
    checked = sorted({s.args.spec for s in plan.steps if s.kind == "check_timing"})
    if checked:  # the live checks read each message once (LiveSource)
        rec.keep_messages()
    elif mirror:  # for the reports only, which read the file instead past the limit
        rec.keep_messages(REPORT_MIRROR_LIMIT)
    if checked:  # read by `hil check` (docs/timing.md): specs and the default drive's binding
        dspec = plan_spec(plan, bench.drives[plan.drive or bench.default_drive])
        rec.add_metadata("timing", {"specs": json.dumps(checked),
                                    "binding": json.dumps(dspec.binding()),
                                    "constants": json.dumps(bench.timing_constants)})
    rec.attach("bench.yaml", bench.text.encode(), "application/yaml")
    rec.attach("plan.yaml", plan.text.encode(), "application/yaml")
    return res, rec, stem


def _go_safe(session: Session, reason: str, rec: Any, res: PlanResult, events: Notifier,
             plan: Plan) -> None:
    for d in session.drives.values():
        if getattr(d, "_cia", None) is not None:
            d._cia.cancel = None  # the plan's cancel must not cut the safe state's own waits
    res.safe = go_safe_watched(session, reason, rec, safe_tail)  # the tail after it too
    if not res.safe.ok:
        failed = "; ".join(f"{a['drive']}: {a['action']}: {a['detail']}"
                           for a in res.safe.actions if not a["ok"])
        events.emit(Note(plan, "SAFE STATE NOT CONFIRMED: " + failed))
        if res.status == PASS:  # a plan passes only if it leaves the bench safe
            res.status, res.error = ERROR, f"safe state not confirmed: {failed}"
            rec.log("error", f"plan {plan.name}: {res.error}", name="hil.runner")
    elif reason != "end of plan":
        events.emit(Note(plan, f"bench driven to its safe state ({reason})"))


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
    line = plan.key_line("params")  # the plan's `params:` line, as a step's own
    t0 = clock.monotonic_ns()
    ctx.rec.plan_step("params", "start", plan=plan.name, index=-1, line=line)
    for p, v in plan.params.items():
        d.write_param(p, v)
        ctx.written(d.name, {p: v})
    ctx.rec.plan_step("params", "end", plan=plan.name, index=-1, status=PASS, line=line,
                      file=recorded_file(plan.path), duration_ns=clock.monotonic_ns() - t0,
                      message=", ".join(f"{p}={v}" for p, v in plan.params.items()))


def _steps(ctx: StepContext, plan: Plan, res: PlanResult, events: Notifier,
           allow_inconclusive: bool, intr: Interrupts) -> str:
    """The plan's steps in order. A signal's interrupt that never reached the run is raised
    before each step and while one runs (`Interrupts.raise_lost`), and one that comes as a
    step ends waits until its end is recorded (`hold`, helper-140: the end record of a step
    that had passed was lost; after a failed step the plan's end names it)."""
    rec = ctx.rec

    def watch() -> None:
        intr.raise_lost()
        ctx.session.check_alive()

    for s, r in zip(plan.steps, res.steps, strict=True):
        intr.release()
        d = ctx.drive(s)
        events.emit(StepStarted(plan, s, r, d.name, rec))
        t0 = clock.monotonic_ns()  # steps last in bench time (virtual on a virtual clock)
        if s.name:
            ctx.started[s.name] = clock.time_ns()
        timeout = s.timeout_ns or ctx.bench.timeouts["step"]
        # a step-level `timeout:` is the plan's word for the whole step; else the step's own
        # timeout (a failure that says what it saw) or a `wait` comes first: the watchdog
        # waits longer
        own = None if s.timeout_ns else s.action.own_timeout_ns(s, ctx.bench)
        if own:
            timeout = max(timeout, own + OWN_TIMEOUT_GRACE_NS)
        try:
            ctx.session.check_lease()  # a bench behind a gateway: only while the lease holds
            ctx.session.check_alive()  # a virtual bench: only while its drive processes live
            outcome = ctx.steps.run(lambda s=s, d=d: s.action.run(ctx, s, d), timeout,
                                    ctx.cancel, watch=watch)
            intr.hold = True  # until the step's end is recorded
            r.message, r.verdicts = outcome.text, outcome.verdicts
            ctx.session.check_lease()
            ctx.session.check_alive()
            r.status = PASS
        except Inconclusive as e:
            intr.hold = True  # a failed step's end is recorded too (helper-141)
            r.status, r.message, r.verdicts = INCONCLUSIVE, str(e), e.verdicts
        except StepFailed as e:
            intr.hold = True  # a failed step's end is recorded too (helper-141)
            r.status, r.message, r.verdicts = FAIL, str(e), e.verdicts
        except (TimeoutError, Cancelled) as e:
            intr.hold = True  # a failed step's end is recorded too (helper-141)
            r.status, r.message = ERROR, str(e) or "cancelled"
        except BenchError as e:
            intr.hold = True  # a failed step's end is recorded too (helper-141)
            r.status, r.message = ERROR, str(e)
        except Exception as e:
            intr.hold = True  # a failed step's end is recorded too (helper-141)
            r.status, r.message = ERROR, f"{type(e).__name__}: {e}"
        except BaseException as e:  # this step ran and was cut (Ctrl-C, pytest-timeout's
            r.status = ERROR        # Failed): it ends on the record too
            r.message = (f"interrupted ({interrupt_cause(e)}) while it ran"
                         if isinstance(e, KeyboardInterrupt) else
                         f"stopped ({first_line(e)}) while it ran")
            r.duration_ns = clock.monotonic_ns() - t0
            events.emit(StepEnded(plan, s, r, d.name, rec))
            raise
        r.duration_ns = clock.monotonic_ns() - t0
        events.emit(StepEnded(plan, s, r, d.name, rec))
        ok = r.status == PASS or (r.status == INCONCLUSIVE and allow_inconclusive)
        if not ok:
            if res.status in (PASS, INCONCLUSIVE):  # a plan only inconclusive says so
                res.status = {FAIL: FAIL, INCONCLUSIVE: INCONCLUSIVE}.get(r.status, ERROR)
            # on /log too (Foxglove's Log panel), a judging step's failure as well, though
            # the plan goes on after it
            rec.log("error", f"step {s.index + 1} ({r.label}) {r.status}: {r.message}",
                    name="hil.runner", file=recorded_file(s.file), line=s.line)
            if not s.action.judge_only:
                for later in res.steps[s.index + 1:]:
                    later.message = f"not run: step {s.index + 1} {r.status}"
                _record_skipped(ctx, plan, res, events)
                return f"step {s.index + 1} ({r.label}) {r.status}: {r.message}"
    intr.release()  # a signal as the last step ended: the plan was interrupted after all
    return "end of plan"


def _record_skipped(ctx: StepContext, plan: Plan, res: PlanResult, events: Notifier) -> None:
    for s, r in zip(plan.steps, res.steps, strict=True):
        if r.status == SKIPPED:
            events.emit(StepEnded(plan, s, r, ctx.drive(s).name, ctx.rec))


def summary_table(results: list[PlanResult]) -> str:
    rows = [("plan", "status", "steps", "verdicts", "time", "recording")]
    for r in results:
        n_ok = sum(1 for s in r.steps if s.status == PASS)
        vs = [v for s in r.steps for v in s.verdicts if v.get("status") != "skipped"]
        v_ok = sum(1 for v in vs if v.get("status") == "pass")
        rows.append((terminal_text(r.plan), r.status.upper(), f"{n_ok}/{len(r.steps)}",
                     f"{v_ok}/{len(vs)}", f"{r.duration_ns / 1e9:.2f} s",
                     terminal_text(r.recording, limit=1 << 62)))
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    lines = ["  ".join(c.ljust(w) for c, w in zip(row, widths, strict=True)).rstrip()
             for row in rows]
    lines.insert(1, "  ".join("-" * w for w in widths))
    passed = sum(r.passed for r in results)
    lines.append(f"{passed}/{len(results)} plans passed")
    return "\n".join(lines)


def run_plans(plans: list[Plan], bench: Bench, out_dir: Path, *, quiet: bool = False,
              stream: TextIO | None = None, allow_inconclusive: bool = False,
              session_factory: Callable[[Bench, Any], Session] = open_session,
              listeners: list[Listener] | None = None) -> list[PlanResult]:
    """Check every plan against the bench first (nothing moves on a bad file), then run them
    one after the other. Default listeners: a line per step on `stream` (none if `quiet`)."""
    specs = timing_specs()
    for p in plans:
        check_plan(p, bench, specs)
    if listeners is None:
        listeners = [] if quiet else [StepLines(stream)]
    stems = output_stems(plans)
    results: list[PlanResult] = []
    try:
        for i, (p, stem) in enumerate(zip(plans, stems, strict=True), 1):
            results.append(run_plan(p, bench, out_dir, specs=specs, listeners=listeners,
                                    session_factory=session_factory,
                                    allow_inconclusive=allow_inconclusive, index=i,
                                    total=len(plans), stem=stem))
    except KeyboardInterrupt as e:  # the results so far, the stopped plan's last: the run's
        cut = getattr(e, "plan_result", None)  # summary files are written from them
        e.results = results + ([cut] if cut is not None else [])  # type: ignore[attr-defined]
        raise
    return results
