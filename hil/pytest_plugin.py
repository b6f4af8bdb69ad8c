"""pytest plugin `hil` (entry point `pytest11`): the `hil` marker and bench options."""

from __future__ import annotations

import pytest


def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("hil", "hardware-in-the-loop benches")
    group.addoption(
        "--hil-bench",
        action="store",
        default=None,
        metavar="FILE",
        help="bench file for tests marked `hil` (default: the built-in virtual bench)",
    )


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "hil: runs against a bench (virtual by default)")
