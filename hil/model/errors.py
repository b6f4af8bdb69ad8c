"""Errors the model raises when it is asked something the drive would refuse."""

from __future__ import annotations

# The refusals the A3 tables themselves express live with the tables (hil/profile/errors.py).
from hil.profile.errors import (
    ModelError,
    ObjectError,
    OutOfRange,
    ParamError,
    UnknownFunction,
    UnknownParameter,
)

__all__ = ["ModelError", "ObjectError", "OutOfRange", "ParamError", "UnknownFunction",
           "UnknownParameter"]


class InertFunction(OutOfRange):
    """A DI or DO function of table 8.1 / 8.2 the virtual drive does not model: mapping it is
    refused (SDO abort 0609 0030, Modbus exception 03) instead of silently doing nothing."""

    rule = "DI/DO function not modelled"


class ReadOnly(ParamError):
    rule = "read-only"


class ServoOnLocked(ParamError):
    rule = "not writable while servo on"


class ProtectedParameter(ParamError):
    rule = "protected (needs a key, e.g. P2.008 = 271)"
