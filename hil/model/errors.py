"""Errors the model raises when it is asked something the drive would refuse."""

from __future__ import annotations

# The refusals the A3 tables themselves express live with the tables (hil/profile/errors.py).
from hil.profile.errors import ModelError, ParamError, UnknownFunction, UnknownParameter

__all__ = ["ModelError", "ParamError", "UnknownFunction", "UnknownParameter"]


class OutOfRange(ParamError):
    rule = "out of range"


class InertFunction(OutOfRange):
    """A DI function of table 8.1 the virtual drive does not model: mapping it is refused
    (SDO abort 0609 0030, Modbus exception 03) instead of silently doing nothing."""

    rule = "DI function not modelled"


class ReadOnly(ParamError):
    rule = "read-only"


class ServoOnLocked(ParamError):
    rule = "not writable while servo on"


class ProtectedParameter(ParamError):
    rule = "protected (needs a key, e.g. P2.008 = 271)"


class ObjectError(ModelError):
    """A CANopen object access refused; carries the CiA 301 SDO abort code."""

    def __init__(self, index: int, sub: int, abort_code: int, message: str) -> None:
        super().__init__(f"{index:04X}h sub {sub}: {message} (abort 0x{abort_code:08X})")
        self.index = index
        self.sub = sub
        self.abort_code = abort_code


# CiA 301 SDO abort codes used by the model and the CANopen face.
ABORT_TOGGLE = 0x05030000
ABORT_TIMEOUT = 0x05040000
ABORT_COMMAND = 0x05040001
ABORT_UNSUPPORTED_ACCESS = 0x06010000
ABORT_WRITE_ONLY = 0x06010001
ABORT_READ_ONLY = 0x06010002
ABORT_NO_OBJECT = 0x06020000
ABORT_NOT_MAPPABLE = 0x06040041
ABORT_PDO_LENGTH = 0x06040042
ABORT_LENGTH = 0x06070010
ABORT_LENGTH_HIGH = 0x06070012
ABORT_LENGTH_LOW = 0x06070013
ABORT_NO_SUBINDEX = 0x06090011
ABORT_VALUE_RANGE = 0x06090030
ABORT_VALUE_HIGH = 0x06090031
ABORT_VALUE_LOW = 0x06090032
ABORT_GENERAL = 0x08000000
ABORT_DATA_STORE = 0x08000020
ABORT_DATA_STATE = 0x08000022
