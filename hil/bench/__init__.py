"""What a bench has: drives, buses, lines, their URLs, the safe state, timeouts (a leaf).

Like labgrid's resources, this package describes a bench and imports no room above it: the
plan runner, the gateway, the virtual world and the pytest plugin all read it. What only the
virtual drive can judge (its model options, mechanics, the DI functions it models) is asked of
`hil.virtual.rules` through `virtual_rules()`, loaded by name when a virtual bench or a plan
needs it, so a real bench never imports the model.
"""

from __future__ import annotations

import importlib
from types import ModuleType


def virtual_module(name: str) -> ModuleType:
    """`hil.virtual.<name>` (world, truth, rules), loaded by name: the runner opens a virtual
    bench's world through it, so importing the runner for a real bench loads no model."""
    return importlib.import_module(f"hil.virtual.{name}")


def virtual_rules() -> ModuleType:
    """`hil.virtual.rules`: ModelOptions, Mechanics, INERT_DI_FUNCTIONS,
    INERT_DO_FUNCTIONS, inert_mapping."""
    return virtual_module("rules")


__all__ = ["virtual_module", "virtual_rules"]
