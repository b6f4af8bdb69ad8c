"""Transport test helpers: child processes that always get cleaned up, a recording tap."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from hil.transport import zenoh_net

PEER = Path(__file__).with_name("peer.py")


class Child:
    """A `peer.py` child; stopped by closing its stdin, killed if it lingers."""

    def __init__(self, *args: str, timeout_s: float = 15.0):
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        self.proc = subprocess.Popen([sys.executable, str(PEER), *args], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                     text=True, env=env)
        self.output: list[str] = []
        ready = threading.Event()

        def read() -> None:
            for line in self.proc.stdout:
                self.output.append(line.rstrip())
                if line.startswith("ready"):
                    ready.set()

        self._reader = threading.Thread(target=read, daemon=True)
        self._reader.start()
        if not ready.wait(timeout_s):
            self.stop()
            raise RuntimeError(f"child {args} not ready: {self.output[-10:]}")

    def stop(self) -> None:
        try:
            self.proc.stdin.close()
        except OSError:
            pass
        try:
            self.proc.wait(5)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(5)
        self._reader.join(2)
        self.proc.stdout.close()


@pytest.fixture
def spawn():
    children: list[Child] = []

    def start(*args: str) -> Child:
        child = Child(*args)
        children.append(child)
        return child

    yield start
    for child in children:
        child.stop()


@pytest.fixture(autouse=True)
def no_leaked_sessions():
    """Every test closes the zenoh sessions it opened."""
    before = zenoh_net.open_sessions()
    yield
    leaked = zenoh_net.open_sessions() - before
    zenoh_net.close_all()
    assert leaked <= 0, f"{leaked} zenoh session(s) left open"


class RecordingTap:
    """A Tap that keeps everything (hil.record.tap.Tap protocol)."""

    def __init__(self) -> None:
        self.can_frames: list[tuple] = []
        self.serial_chunks: list[tuple] = []
        self.dio_levels: list[tuple] = []

    def can(self, bus, frame, direction, t, source_t):
        self.can_frames.append((bus, frame, direction, t, source_t))

    def serial(self, port, data, direction, t, source_t, gaps_us=None):
        self.serial_chunks.append((port, data, direction, t, source_t, gaps_us))

    def dio(self, name, line, level, t, source_t):
        self.dio_levels.append((name, line, level, t, source_t))


@pytest.fixture
def tap() -> RecordingTap:
    return RecordingTap()
