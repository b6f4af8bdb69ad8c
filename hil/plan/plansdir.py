"""Which plans directory `hil run` uses: the one the user is editing, else the installed copy.

Order: `--plans DIR`; else the `plans/` of the checkout the current directory is in; else the
plans installed with the package (`hil_plans`). A *checkout* is the nearest directory at or
above the current one holding a `pyproject.toml` whose `[project] name` is `"hil"` and a
`plans/` directory beside it.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

from hil.paths import plans_dir


def checkout_root(start: Path | None = None) -> Path | None:
    """The hil checkout containing `start` (default: the current directory), or None."""
    here = (start or Path.cwd()).resolve()
    for d in (here, *here.parents):
        pyproject = d / "pyproject.toml"
        if not pyproject.is_file():
            continue
        try:
            name = tomllib.loads(pyproject.read_text(encoding="utf-8"))["project"]["name"]
        except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError, KeyError, TypeError):
            continue
        if name == "hil" and (d / "plans").is_dir():
            return d
    return None


def choose_plans_dir(given: str | None = None, start: Path | None = None) -> tuple[Path, str]:
    """(directory, why) for `hil run`; ValueError when `given` is not a directory."""
    if given is not None:
        p = Path(given)
        if not p.is_dir():
            raise ValueError(f"--plans {given}: not a directory")
        return p.resolve(), "--plans"
    root = checkout_root(start)
    if root is not None:
        return root / "plans", f"checkout {root}"

    return plans_dir(), "installed"
