"""Transport test helpers: child processes that always get cleaned up, a recording tap."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from hil.transport import zenoh_net
from tests.children import ChildProcess, children

PEER = Path(__file__).with_name("peer.py")


@pytest.fixture
def spawn():
    """A `peer.py` child; stopped by closing its stdin, killed if it lingers."""
    yield from children(lambda *args: ChildProcess(
        [sys.executable, str(PEER), *args], how="stdin", timeout_s=15.0,
        ready=lambda line: line.startswith("ready"), what="peer"))


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
        self.pulse_messages: list[tuple] = []

    def can(self, bus, frame, direction, t, source_t):
        self.can_frames.append((bus, frame, direction, t, source_t))

    def serial(self, port, data, direction, t, source_t, gaps_us=None):
        self.serial_chunks.append((port, data, direction, t, source_t, gaps_us))

    def dio(self, name, line, level, t, source_t):
        self.dio_levels.append((name, line, level, t, source_t))

    def pulse(self, name, kind, body, t, source_t):
        self.pulse_messages.append((name, kind, dict(body), t, source_t))


@pytest.fixture
def tap() -> RecordingTap:
    return RecordingTap()
