"""Where the shipped data lives (works from a checkout and from an installed wheel)."""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path


def fixtures_dir() -> Path:
    """The `fixtures/` tree: drive profile, timing specs, benches, layouts."""
    return Path(str(files("hil_fixtures")))


def plans_dir() -> Path:
    """The shipped `plans/` directory."""
    return Path(str(files("hil_plans")))


def fixture(*parts: str) -> Path:
    """Path of one file under `fixtures/`."""
    return fixtures_dir().joinpath(*parts)
