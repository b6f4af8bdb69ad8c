"""What a bench or plan may ask of the virtual drive, for `hil run --check`.

The plan layer validates a virtual bench's model `options:` and `mechanics:` and refuses DI
functions the virtual drive does not model (issue 13 item 6) through this module, so that
`hil.plan` never imports the model itself.
"""

from __future__ import annotations

from hil.model.dio import INERT_DI_FUNCTIONS, inert_mapping
from hil.model.mechanics import Mechanics
from hil.model.options import ModelOptions

__all__ = ["INERT_DI_FUNCTIONS", "Mechanics", "ModelOptions", "inert_mapping"]
