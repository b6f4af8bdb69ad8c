"""A progress bar while a long recording is read: every command that reads one whole (`hil
check`, `report`, `diff`, `inspect`, `export`) shows it on a terminal for a large file."""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any

#: files at least this large show a progress bar while read (on a terminal)
PROGRESS_MIN_BYTES = 32 * 1024 * 1024


class ReadProgress:
    """A long recording being read: a transient bar on stderr when it is a terminal
    and the file is large (an hour of a busy bus is about 1 GB), nothing otherwise."""

    def __init__(self, path: str, text: str = "reading", stream: Any = None) -> None:
        self.stream = stream or sys.stderr
        self._text = text  # what is being read
        try:
            big = Path(path).stat().st_size >= PROGRESS_MIN_BYTES
        except OSError:
            big = False
        self.on = big and self.stream.isatty()
        self._bar: Any = None
        self._task: Any = None
        self._last = 0.0

    def __call__(self, done: int, total: int) -> None:
        if not self.on:
            return
        now = time.monotonic()
        if now - self._last < 0.2 and done < total:
            return
        self._last = now
        self._task_of(total)
        self._bar.update(self._task, completed=done, total=total)

    def _task_of(self, total: int) -> None:
        if self._bar is None:
            from rich.console import Console
            from rich.progress import (
                BarColumn,
                DownloadColumn,
                Progress,
                TextColumn,
                TimeRemainingColumn,
            )

            self._bar = Progress(TextColumn("{task.description}"), BarColumn(),
                                 DownloadColumn(), TimeRemainingColumn(),
                                 console=Console(file=self.stream), transient=True)
            self._bar.start()
            self._task = self._bar.add_task(self._text, total=total)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.stop()
            self._bar = None
