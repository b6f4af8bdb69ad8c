"""A withdrawn asynchronous exception leaves the interpreter clean (session 31).

Before Python 3.13, `PyThreadState_SetAsyncExc(id, NULL)` (a withdrawal) sets the
interpreter's "an asynchronous exception is pending" flag, and only a thread that takes one
clears it. The safe-state watchdog withdrew one at the end of every safe state, so after a
plan's first safe state every call and loop in the process stopped to look for an exception
(about 8 % of a virtual run), and the first call made under a profiler (`cProfile`,
`sys.setprofile`) looped for ever at its first instruction: `python -m cProfile` on a run
hung at the session's close. Each case runs in its own process: on the old code it hangs.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap
import threading

import pytest

from hil import clock

HANG_S = 60  # wall s: the old code never ends; the new one ends in about a second


def _run(code: str, tmp_path) -> str:
    try:
        out = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], cwd=tmp_path,
                             capture_output=True, text=True, timeout=HANG_S)
    except subprocess.TimeoutExpired:
        pytest.fail(f"the process hung for {HANG_S} s (a profiled call looping at the "
                    "pending-exception check)")
    assert out.returncode == 0, out.stderr
    return out.stdout


def test_a_profiled_call_after_a_withdrawal_returns(tmp_path) -> None:
    out = _run("""
        import sys, threading
        from hil import clock
        clock.async_raise(threading.get_ident(), None)  # nothing was raised: withdraw
        sys.setprofile(lambda *a: None)
        def f():
            return 41
        n = f() + 1
        sys.setprofile(None)
        print("returned", n)
    """, tmp_path)
    assert "returned 42" in out


def test_a_plan_runs_under_cprofile_to_its_end(tmp_path) -> None:
    """A virtual-time plan (its safe state under the watchdog), profiled whole, as a
    developer profiles `hil run`."""
    out = _run("""
        import cProfile, dataclasses, io
        from pathlib import Path
        from hil.bench.bench import load_bench
        from hil.plan.plan import find_plans, load_plan
        from hil.plan.runner import run_plans
        bench = dataclasses.replace(load_bench(None), clock="virtual")
        plans = [load_plan(p) for p in find_plans(["param_access"])]
        prof = cProfile.Profile()
        prof.enable()
        res = run_plans(plans, bench, Path("out"), stream=io.StringIO(), quiet=True)
        prof.disable()
        print("status", res[0].status, res[0].safe.ok)
    """, tmp_path)
    assert "status pass True" in out


def _started(target) -> threading.Thread:
    th = threading.Thread(target=target, daemon=True)
    th.start()
    while not th.ident:
        pass
    return th


def test_a_withdrawn_exception_is_not_raised() -> None:
    """The withdrawal itself still works: raised at a thread blocked in a C-level wait,
    then withdrawn before it ran Python again, it never lands."""
    go, landed = threading.Event(), []

    def target() -> None:
        try:
            go.wait()
        except BaseException as exc:  # what landed is the result
            landed.append(exc)

    th = _started(target)
    clock.async_raise(th.ident, KeyboardInterrupt)
    clock.async_raise(th.ident, None)
    go.set()
    th.join(5)
    assert not th.is_alive() and landed == []


def test_a_raised_exception_still_lands() -> None:
    stop, landed = threading.Event(), []

    def target() -> None:
        try:
            while not stop.is_set():
                stop.wait(0.001)
        except KeyboardInterrupt as exc:
            landed.append(exc)

    th = _started(target)
    clock.async_raise(th.ident, KeyboardInterrupt)
    th.join(5)
    stop.set()
    assert len(landed) == 1
