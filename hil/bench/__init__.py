"""What a bench has: drives, buses, lines, their URLs, the safe state, timeouts (a leaf).

Like labgrid's resources, this package describes a bench and imports no room above it: the
plan runner, the gateway, the virtual world and the pytest plugin all read it. What only the
virtual drive can judge (its model options, mechanics, the DI functions it models) is asked of
`hil.virtual.rules` through `virtual_rules()`, loaded by name when a virtual bench or a plan
needs it, so a real bench never imports the model.
"""

from __future__ import annotations

import importlib
from functools import cache
from types import ModuleType

#: the module that knows the virtual drive's rules (loaded by name: no static import)
VIRTUAL_RULES = "hil.virtual.rules"


@cache
def virtual_rules() -> ModuleType:
    """`hil.virtual.rules`: ModelOptions, Mechanics, INERT_DI_FUNCTIONS, inert_mapping."""
    return importlib.import_module(VIRTUAL_RULES)


def virtual_module(name: str) -> ModuleType:
    """`hil.virtual.<name>` (world, truth, ...), loaded by name: the runner opens a virtual
    bench's world through it, so importing the runner for a real bench loads no model."""
    return importlib.import_module(f"hil.virtual.{name}")


__all__ = ["VIRTUAL_RULES", "virtual_module", "virtual_rules"]
