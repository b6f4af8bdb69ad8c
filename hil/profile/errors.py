"""Refusals the A3 tables express: unknown parameter, unknown DI/DO function code.

`ModelError` is the base of every refusal of the virtual drive (hil/model/errors.py adds the
rest); it lives here because the tables in hil/profile raise it too.
"""

from __future__ import annotations


class ModelError(Exception):
    """Base class: a request the virtual drive refuses, with the rule that refuses it."""


class ParamError(ModelError):
    """A parameter access refused like the drive refuses it (names the parameter and rule)."""

    rule = "invalid"

    def __init__(self, param: str, message: str) -> None:
        super().__init__(f"{param}: {message}")
        self.param = param


class OutOfRange(ParamError):
    rule = "out of range"


class UnknownParameter(ParamError):
    rule = "unknown parameter"


class UnknownFunction(ModelError):
    """A DI/DO function code that table 8.1 / 8.2 does not define."""

    def __init__(self, kind: str, code: int, where: str = "") -> None:
        at = f" in {where}" if where else ""
        super().__init__(f"unknown {kind} function code 0x{code:02X}{at}")
        self.kind = kind
        self.code = code


class ObjectError(ModelError):
    """A CANopen object access refused; carries the CiA 301 SDO abort code."""

    def __init__(self, index: int, sub: int, abort_code: int, message: str) -> None:
        super().__init__(f"{index:04X}h sub {sub}: {message} (abort 0x{abort_code:08X})")
        self.index = index
        self.sub = sub
        self.abort_code = abort_code
