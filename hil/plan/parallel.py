"""`hil run -j N`: plans in worker processes, each on its own virtual bench.

    results = run_parallel(plans, bench, Path("reports"), jobs=2, listeners=[...])

Each worker process (spawn context) loads the plan and the bench from their files and runs
`run_plan` as `-j 1` does, on its own virtual bench: `auto` transports resolve to names,
ptys and loopback ports of that process, so plans never share a bus, a line or a temporary
file; each writes its own recording and reports. At most `jobs` plans are in flight; the
results come back in the plans' order. Events are replayed in this process, plan by plan in
the order they complete (plan N of M counts completed plans), so progress displays and step
lines read as in a sequential run.

Only a virtual bench whose every transport is private to a process runs in parallel
(`parallel_blocker`): a real bench has one set of drives (and a gateway lease for one holder),
so its plans run one after the other.

Ctrl-C (SIGINT/SIGTERM) stops the workers: each running plan is stopped, its bench driven
safe and its recording closed (as in `-j 1`), plans not started are not run, then
KeyboardInterrupt is raised here as `run_plans` does.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import logging
import multiprocessing
import os
import signal
import sys
import threading
import time
from collections.abc import Iterator
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hil.bench.bench import GATEWAY, Bench, load_bench, with_clock
from hil.plan.events import Listener, Note, Notifier, PlanEnded, PlanStarted, StepEnded
from hil.plan.plan import Plan, check_plan, load_plan
from hil.plan.runner import (
    SELF_SENT,
    PlanResult,
    output_stems,
    run_plan,
    signal_text,
    timing_specs,
)
from hil.report.data import RunData, keep_summary, kept_summary

__all__ = ["jobs_from_arg", "parallel_blocker", "run_parallel"]

log = logging.getLogger(__name__)

STOP_GRACE_S = 60.0  # how long a stopped worker may take to go safe and close its recording


def usable_cpus() -> int:
    """The CPUs this process may run on (its affinity: `taskset`, a container's cpuset), not
    the host's count."""
    try:
        return len(os.sched_getaffinity(0)) or 1
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def jobs_from_arg(text: str) -> int:
    """`-j N`: a positive count; `0` or `auto` = the number of usable CPUs."""
    if text.strip().lower() == "auto":
        return usable_cpus()
    try:
        n = int(text)
    except ValueError:
        n = -1
    if n < 0:
        raise ValueError(f"{text!r}: a number of plans at a time (0 or auto = CPUs)")
    return n or usable_cpus()


def parallel_blocker(bench: Bench) -> str | None:
    """Why `bench` cannot run plans in parallel (None when it can): it must be virtual, with
    every transport (CAN, RS-485, DI/DO and pulse lines) private to the process that opens it
    (`virtual:` in process, or an `auto` target with `auto` loopback ports)."""
    if not bench.virtual:
        how = " behind a gateway lease" if bench.gateway is not None else ""
        return f"bench {bench.name} is not virtual{how}: one set of drives"
    urls = [*bench.can.values(), *bench.rs485.values(),
            *(u for d in bench.drives.values() for u in (d.dio, d.pulse) if u and u != GATEWAY)]
    for url in urls:
        scheme, _, rest = url.strip().partition(":")
        scheme = scheme.lower()  # as `parse_url` reads it
        target, _, query = rest.partition("?")
        if scheme == "virtual" and bench.process == "inproc":
            continue
        fixed_port = any(ep.rsplit(":", 1)[-1] != "auto"
                         for item in query.split("&") if item.startswith(("listen=", "connect="))
                         for ep in item.partition("=")[2].split(","))
        if target != "auto" or fixed_port:
            return f"bench {bench.name}: transport {url} is shared by every run"
    return None


# --- the worker side ---------------------------------------------------------------------


_stop_requested: bool | str = False  # a signal's name (`signal_text`) once one came


def _worker_init(log_level: int) -> None:
    """A worker between plans: SIGINT/SIGTERM only mark it stopped (`run_plan` installs its
    own handlers while a plan runs and restores these after). Logs as `hil run` does."""
    logging.basicConfig(level=log_level, stream=sys.stderr,
                        format="%(levelname)s %(name)s: %(message)s")

    def mark(signum: int, frame: Any) -> None:
        global _stop_requested
        _stop_requested = signal_text(signum)  # a plan stopped before it began names it

    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, mark)
    # the worker started with them blocked (`_stopping_held`): one that came while it
    # imported is taken now, by `mark`
    signal.pthread_sigmask(signal.SIG_UNBLOCK, STOP_SIGNALS)
    threading.Thread(target=_orphan_watch, args=(os.getppid(),), name="hil-orphan-watch",
                     daemon=True).start()


_busy = threading.Event()  # a plan is running in this worker


def _orphan_watch(parent: int, period_s: float = 0.2) -> None:
    """A worker whose `hil run` died (kill -9, OOM) is reparented and would wait on the pool's
    queue forever: stop its plan as Ctrl-C does (bench safe, recording closed), then exit."""
    global _stop_requested
    while os.getppid() == parent:
        time.sleep(period_s)
    log.warning("hil run (pid %d) is gone: stopping this worker (pid %d)", parent, os.getpid())
    why = f"SIGINT (hil run, pid {parent}, is gone)"
    _stop_requested = _stop_requested or why
    SELF_SENT[signal.SIGINT] = why  # the record says so, not "Ctrl-C"
    os.kill(os.getpid(), signal.SIGINT)  # a running plan stops; an idle worker is marked
    end = time.monotonic() + STOP_GRACE_S
    while _busy.is_set() and time.monotonic() < end:
        time.sleep(period_s)
    os._exit(1)


class _Notes(Listener):
    def __init__(self) -> None:
        self.texts: list[str] = []

    def note(self, e: Note) -> None:
        self.texts.append(e.text)


@dataclass
class _Job:
    plan_path: str
    bench_path: str | None
    out_dir: str
    allow_inconclusive: bool
    index: int
    total: int
    stem: str  # output name, unique within the run (runner.output_stems)
    clock: str | None = None  # `--clock` (None: the bench file's)


Summary = tuple[tuple[str, int, int], RunData] | None


def _run_one(job: _Job) -> tuple[PlanResult | None, list[str], bool, Summary]:
    """In a worker: (result, notes, interrupted, the report's summary of the recording). None
    when stopped before it began. The summary spares the parent reading each recording again
    for the run's JUnit and index (`hil.report.data.keep_summary`)."""
    global _stop_requested
    _busy.set()  # before the check: the orphan watch either sees it or stops this plan
    try:
        if _stop_requested:
            return None, [], True, None
        plan = load_plan(job.plan_path)
        bench = with_clock(load_bench(job.bench_path), job.clock)
        notes = _Notes()
        try:
            res = run_plan(plan, bench, Path(job.out_dir), listeners=[notes],
                           allow_inconclusive=job.allow_inconclusive, index=job.index,
                           total=job.total, stop=lambda: _stop_requested, stem=job.stem)
        except KeyboardInterrupt as e:
            _stop_requested = _stop_requested or True
            res = getattr(e, "plan_result", None) or _interrupted_result(plan, bench, job)
            return res, notes.texts, True, _summary(res)
        return res, notes.texts, False, _summary(res)
    finally:
        _busy.clear()


def _warm_up() -> None:
    """A new worker's first job, while the parent checks the plans: what every plan loads,
    every timing spec parsed (a registry parses a spec when first used; `len` reads them all,
    each cached for the worker's later plans)."""
    len(timing_specs())


def _summary(res: PlanResult) -> Summary:
    try:
        return kept_summary(res.recording) if res.recording else None
    except Exception:  # only a shortcut: the parent reads the file instead
        return None


def _interrupted_result(plan: Plan, bench: Bench, job: _Job) -> PlanResult:
    """What `run_plan` wrote for a stopped plan: its recording and reports are on disk."""
    stem = job.stem
    out = Path(job.out_dir)
    return PlanResult(plan.name, plan.path, bench.name, status="aborted",
                      recording=str(out / f"{stem}.mcap"), html=str(out / f"{stem}.html"),
                      junit=str(out / f"{stem}.junit.xml"), error="interrupted")


# --- the parent side ---------------------------------------------------------------------


def _replay(events: Notifier, plan: Plan, res: PlanResult, notes: list[str], index: int,
            total: int, bench: Bench) -> None:
    events.emit(PlanStarted(plan, bench, index, total))
    for s, r in zip(plan.steps, res.steps, strict=False):
        events.emit(StepEnded(plan, s, r, plan.drive or ""))
    for text in notes:
        events.emit(Note(plan, text))
    events.emit(PlanEnded(plan, res, index, total))


def run_parallel(plans: list[Plan], bench: Bench, out_dir: Path, *, jobs: int,
                 allow_inconclusive: bool = False,
                 listeners: list[Listener] | None = None) -> list[PlanResult]:
    """Run `plans` at most `jobs` at a time in worker processes; results in plan order.
    Every plan is checked against the bench first (nothing runs on a bad file); the workers
    start meanwhile (`_warm_up`: their imports and the timing specs, nothing of a plan)."""
    ctx = multiprocessing.get_context("spawn")
    pool = cf.ProcessPoolExecutor(max_workers=min(jobs, len(plans)), mp_context=ctx,
                                  initializer=_worker_init,
                                  initargs=(logging.getLogger().getEffectiveLevel(),))
    try:
        with _stopping_held():  # one submit each starts a worker
            for _ in range(min(jobs, len(plans))):
                pool.submit(_warm_up)
        specs = timing_specs()
        for p in plans:
            check_plan(p, bench, specs)
    except BaseException:
        # the workers' warm-ups are left to run: a worker stopped while it was starting
        # (its queues gone before it had read them) printed a traceback (helper-140)
        pool.shutdown(wait=True)
        raise
    events = Notifier(listeners)
    stems = output_stems(plans)
    todo = [_Job(str(p.path), bench.path or None, str(out_dir), allow_inconclusive, i,
                 len(plans), stems[i - 1], bench.clock) for i, p in enumerate(plans, 1)]
    results: dict[int, PlanResult] = {}
    done = 0
    running: dict[cf.Future, _Job] = {}
    main = threading.current_thread() is threading.main_thread()
    global _received
    _received = signal.SIGINT
    old_handlers = {sig: signal.signal(sig, _as_interrupt)  # as run_plan does with -j 1
                    for sig in (signal.SIGINT, signal.SIGTERM)} if main else {}
    interrupted = False

    def collect(finished: set[cf.Future]) -> None:
        nonlocal done, interrupted
        for fut in finished:
            job = running.pop(fut)
            try:
                res, notes, stopped, summary = fut.result()
            except BrokenProcessPool:
                if interrupted:  # killed while it started up: it ran nothing
                    continue
                raise
            interrupted |= stopped
            if summary is not None:
                keep_summary(*summary)
            if res is not None:
                results[job.index] = res
                done += 1
                _replay(events, plans[job.index - 1], res, notes, done, len(plans), bench)

    try:
        while (todo and not interrupted) or running:
            while todo and not interrupted and len(running) < jobs:
                job = todo.pop(0)
                running[pool.submit(_run_one, job)] = job
            collect(cf.wait(running, return_when=cf.FIRST_COMPLETED)[0])
            if interrupted and running:
                collect(_stop_workers(pool, running))
    except KeyboardInterrupt:
        interrupted = True
        collect(_stop_workers(pool, running))
    finally:
        for sig, handler in old_handlers.items():
            signal.signal(sig, handler)
        pool.shutdown(wait=True, cancel_futures=True)
    if interrupted:
        stop = KeyboardInterrupt("interrupted (Ctrl-C / SIGTERM)")
        stop.results = [results[i] for i in sorted(results)]  # type: ignore[attr-defined]
        raise stop
    return [results[i] for i in range(1, len(plans) + 1)]


_received = signal.SIGINT  # the signal that stopped the run, passed on to the workers
STOP_SIGNALS = frozenset({signal.SIGINT, signal.SIGTERM})


@contextlib.contextmanager
def _stopping_held() -> Iterator[None]:
    """SIGINT and SIGTERM blocked while workers are started: a new process inherits the
    mask, so a Ctrl-C while it imports waits until `_worker_init` has its handlers (it had
    printed the workers' KeyboardInterrupt tracebacks, helper-140). Here, one that came
    meanwhile is delivered as the block ends."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def _as_interrupt(signum: int, frame: Any) -> None:
    global _received
    _received = signal.Signals(signum)
    raise KeyboardInterrupt(signal_text(signum))


def _stop_workers(pool: cf.ProcessPoolExecutor, running: dict[cf.Future, _Job]
                  ) -> set[cf.Future]:
    """Forward the interrupt to every worker and wait for their plans to end safely; a further
    Ctrl-C here only prints a notice."""
    main = threading.current_thread() is threading.main_thread()
    old = {sig: signal.signal(sig, lambda *_: os.write(
        2, b"hil: stopping the workers (benches going safe, recordings closing)\n"))
        for sig in (signal.SIGINT, signal.SIGTERM)} if main else {}
    try:
        for pid in list(getattr(pool, "_processes", {}) or {}):
            with contextlib.suppress(OSError):  # the same signal: the record names it
                os.kill(pid, _received)
        return cf.wait(running, timeout=STOP_GRACE_S)[0]
    finally:
        for sig, h in old.items():
            signal.signal(sig, h)
