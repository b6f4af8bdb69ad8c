"""A virtual drive's `options:` checked whole: its model's, and the rooms of `extra:` that
belong to its faces (the model does not import them: docs/architecture.md)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from hil.faces.modbus_slave import ModbusFaceOptions
from hil.model.options import ModelOptions

# the rooms of `options.extra` that belong to a virtual drive's faces, not to its model
FACE_ROOMS = {"modbus": ModbusFaceOptions.from_dict}


def model_options(data: Mapping[str, Any] | None, where: str = "options") -> ModelOptions:
    """The model options of `data`, a bench's `options:` mapping, with its faces' rooms of
    `extra:` checked too (`FACE_ROOMS`). ValueError names the field."""
    return ModelOptions.from_dict(dict(data or {}), where=where, faces=FACE_ROOMS)
