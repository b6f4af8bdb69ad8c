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
# Tests on the injected clock or in virtual time (`virtual_time`, docs/clock.md) are never
# rerun: they are deterministic. Nor is anything run
# against a bench file (`--hil-bench` / HIL_BENCH): a failed plan is never repeated on
# hardware without an engineer deciding so.
INTEGRATION_RERUNS = 1


def pytest_configure(config):
    if hasattr(config.option, "rerun_show_tracebacks"):  # why each rerun happened, in the log
        config.option.rerun_show_tracebacks = True


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
            item.add_marker(pytest.mark.flaky(reruns=INTEGRATION_RERUNS, reruns_delay=1))
