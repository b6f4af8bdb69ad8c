"""The virtual drive's own rules, asked by the bench and the plans for `hil run --check`.

`hil.bench.virtual_rules()` loads this module by name when a virtual bench's model
`options:` and `mechanics:`, an `inject:` step or a DI mapping needs judging, so `hil.bench`
and `hil.plan` never import the model (docs/architecture.md).
"""

from __future__ import annotations

from hil.model.dio import INERT_DI_FUNCTIONS, INERT_DO_FUNCTIONS, inert_mapping
from hil.model.mechanics import Mechanics
from hil.model.options import ModelOptions

__all__ = ["INERT_DI_FUNCTIONS", "INERT_DO_FUNCTIONS", "Mechanics", "ModelOptions",
           "inert_mapping"]
