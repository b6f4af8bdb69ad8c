"""The step kinds, by YAML key: the built-in ones and those entry points add.

    from hil.plan.kinds import kinds
    kinds()["write"]      # -> the Write class

A package adds kinds with an entry point in the group `hil.steps` whose value is a
`StepKind` subclass (its `name` is the YAML key), e.g. in its pyproject.toml:

    [project.entry-points."hil.steps"]
    my_kind = "my_pkg.steps:MyKind"
"""

from __future__ import annotations

from importlib.metadata import entry_points

from hil.plan.kinds import (
    absolute,
    capture,
    cia402,
    comm,
    group,
    io,
    params,
    plc,
    pr,
    timing,
    virtual,
    waits,
)
from hil.plan.kinds.base import CheckContext, StepKind

__all__ = ["BUILTIN", "CheckContext", "StepKind", "kinds"]

ENTRY_POINT_GROUP = "hil.steps"

BUILTIN: dict[str, type[StepKind]] = {
    k.name: k
    for module in (io, params, cia402, waits, virtual, timing, absolute, comm, pr, capture,
                   plc, group)
    for k in module.KINDS
}

_loaded: dict[str, type[StepKind]] | None = None


def kinds() -> dict[str, type[StepKind]]:
    """Every step kind by name: built-in first, then entry points (a name clash is an error)."""
    global _loaded
    if _loaded is None:
        table = dict(BUILTIN)
        for ep in entry_points(group=ENTRY_POINT_GROUP):
            cls = ep.load()
            if not (isinstance(cls, type) and issubclass(cls, StepKind)) or not cls.name:
                raise TypeError(f"entry point {ep.name} = {ep.value} ({ENTRY_POINT_GROUP}) is "
                                "not a StepKind subclass with a name")
            if cls.name in table and table[cls.name] is not cls:
                raise TypeError(f"entry point {ep.value}: step kind {cls.name!r} exists already")
            table[cls.name] = cls
        _loaded = table
    return _loaded
