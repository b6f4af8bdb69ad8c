"""Child processes for integration tests: output collected, ready line awaited, always stopped."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import threading
from collections.abc import Callable, Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


class ChildProcess:
    """`argv` as a child; ready once a line satisfies `ready`. `stop()` closes stdin (`how`
    "stdin") or sends SIGINT ("sigint"), and kills it if it lingers."""

    def __init__(self, argv: list[str], *, ready: Callable[[str], bool] = lambda s: "ready" in s,
                 how: str = "sigint", timeout_s: float = 30.0, what: str = "child") -> None:
        self.how = how
        self.proc = subprocess.Popen(
            argv, stdin=subprocess.PIPE if how == "stdin" else None, stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT, text=True, cwd=str(ROOT),
            env=dict(os.environ, PYTHONUNBUFFERED="1"),
        )
        self.lines: list[str] = []
        self._ready = threading.Event()
        self._is_ready = ready
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()
        if not self._ready.wait(timeout_s) or (self.proc.poll() is not None and not any(
                ready(line) for line in self.lines)):
            self.stop()
            raise RuntimeError(f"{what} {argv[1:]} not ready: {self.lines[-10:]}")

    @property
    def output(self) -> list[str]:
        return self.lines

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.append(line.rstrip())
            if self._is_ready(line):
                self._ready.set()
        self._ready.set()  # exited: do not wait the whole timeout

    def stop(self) -> int:
        if self.proc.poll() is None:
            if self.how == "stdin":
                with contextlib.suppress(OSError):
                    self.proc.stdin.close()  # type: ignore[union-attr]
            else:
                self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(15)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        self._reader.join(5)
        with contextlib.suppress(OSError):
            self.proc.stdout.close()  # type: ignore[union-attr]
        return self.proc.returncode


def children(make: Callable[..., ChildProcess]) -> Iterator[Callable[..., ChildProcess]]:
    """Fixture body: yields a starter; every child it started is stopped afterwards, the
    newest first."""
    started: list[ChildProcess] = []

    def start(*args: str) -> ChildProcess:
        child = make(*args)
        started.append(child)
        return child

    yield start
    for child in reversed(started):
        child.stop()


def hil(*args: str, what: str = "hil") -> ChildProcess:
    """`python -m hil.cli ARGS`, ready once it prints a line containing `ready`."""
    return ChildProcess([sys.executable, "-m", "hil.cli", *args], what=what)
