"""Integration fixtures: `hil drive` as a real child process, always cleaned up."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from tests.children import children, hil


@pytest.fixture
def drive_process() -> Iterator:
    """Start `hil drive ARGS`; it is ready once it prints `ready`, stopped by SIGINT."""
    yield from children(lambda *args: hil("drive", *args, what="hil drive"))

