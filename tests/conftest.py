"""Shared test helpers: free loopback ports, a temporary state directory."""

from __future__ import annotations

import os
import socket

import pytest


def free_port() -> int:
    """A TCP port on 127.0.0.1 that is free right now (each test gets its own)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def port() -> int:
    return free_port()


@pytest.fixture
def free_port_factory():
    """A callable giving a fresh free loopback port each call."""
    return free_port


# Tests marked `integration` run the virtual drive, buses and processes in real time on a host
# that is not real-time (CI shares 2 cores): a stall of tens of ms can move one timing verdict
# past its window. Each such test is rerun once on failure (pytest-rerunfailures); a failure
# in both runs fails the suite, and every rerun is listed with its traceback (`-raR`).
# Tests on the injected clock or in virtual time are never rerun: they are deterministic.
# That is a test marked `virtual_time` (docs/clock.md), and any other whose failed attempt
# installed a virtual clock in this process and no wall clock (`hil.clock.installs`: a plan
# or `hil_session` on the built-in bench). Mark `virtual_time` a test whose virtual-time run
# is in a child process (`hil run` on the built-in bench). Nor is anything run against a
# bench file (`--hil-bench` / HIL_BENCH): a failed plan is never repeated on hardware
# without an engineer deciding so.
INTEGRATION_RERUNS = 1
_CLOCKS_AT_START = pytest.StashKey[tuple[int, int]]()


def pytest_configure(config):
    if hasattr(config.option, "rerun_show_tracebacks"):  # why each rerun happened, in the log
        config.option.rerun_show_tracebacks = True


def _clocks() -> tuple[int, int]:
    from hil import clock

    return clock.installs["virtual"], clock.installs["real"]


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item):
    item.stash[_CLOCKS_AT_START] = _clocks()  # each attempt's own (a rerun sets it again)


def _ran_on_the_wall_clock(item) -> bool:
    """The rerun condition: False once the failed attempt ran only in virtual time."""
    virtual0, real0 = item.stash.get(_CLOCKS_AT_START, (0, 0))
    virtual, real = _clocks()
    return not (virtual > virtual0 and real == real0)


def _rerun_condition(item):
    return lambda: _ran_on_the_wall_clock(item)  # no argument: called without the error


def pytest_collection_modifyitems(config, items):
    if config.getoption("--hil-bench", None) or os.environ.get("HIL_BENCH"):
        return
    for item in items:
        if item.get_closest_marker("virtual_time"):
            # deterministic: a failure is a failure, even under `pytest --reruns N` (the
            # marker overrides the command line in pytest-rerunfailures)
            item.add_marker(pytest.mark.flaky(reruns=0))
            continue
        if item.get_closest_marker("integration") and not item.get_closest_marker("flaky"):
            item.add_marker(pytest.mark.flaky(
                reruns=INTEGRATION_RERUNS, reruns_delay=1,
                condition=_rerun_condition(item)))
