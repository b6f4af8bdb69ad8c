"""What a drive would refuse of a parameter in a plan or bench file, judged before anything
moves (`hil run --check`) from the same chapter 8 table the virtual drive uses."""

from __future__ import annotations

from functools import cache

from hil.bench.yamlio import Checker, PlanFileError
from hil.profile.dio import DI_PARAMS, DO_PARAMS
from hil.profile.errors import ParamError
from hil.profile.params import WRITE_ZERO_ONLY, ParamTable, digit_problem


@cache
def _table() -> ParamTable:
    return ParamTable.load()


def check_param(v: Checker, line: int, field: str, name: str, value: int | None, *,
                write: bool) -> None:
    """Raise `file:line: field: problem` for an unknown parameter, a written value outside its
    range (refused with Modbus exception 03 / SDO abort 0609 0031/0032) or a write to a
    read-only one. Read values are not range-checked: some read back other numbers than may
    be written (P5.007 shows n+10000 / n+20000, L11185)."""
    try:
        spec = _table().spec(name)
    except ParamError as e:
        raise v.err(line, field, f"unknown parameter: {e}") from None
    if write and spec.read_only:
        raise v.err(line, field, f"{spec.param} is read-only (★, L6719): the drive refuses "
                    "the write")
    if spec.param in DI_PARAMS or spec.param in DO_PARAMS:
        return  # DI/DO mappings: the mapping check names the function (hil/plan/plan.py)
    if write and value is not None and not spec.min <= value <= spec.max:
        raise v.err(line, field, f"{value} outside {spec.param}'s range {spec.min}..{spec.max} "
                    "(chapter 8): the drive refuses the write")
    if write and value is not None and (why := digit_problem(spec.param, value)) is not None:
        raise v.err(line, field, f"{spec.param} = 0x{value:04X}: {why}: the drive refuses the "
                    "write")
    if write and value not in (None, 0) and spec.param in WRITE_ZERO_ONLY:
        raise v.err(line, field, f"{spec.param} = {value}: only 0 (alarm reset) may be "
                    "written (L7079-7083): the drive refuses the write")


def wire_range(name: str, via: str) -> tuple[int, int]:
    """The values a write of parameter `name` can carry on a route: its 2xxxh object is an
    INTEGER16 / INTEGER32 on SDO (hil.profile.od), its Modbus words are its size, signed when
    its range is (hil.drivers.delta_modbus). A value outside is never sent."""
    spec = _table().spec(name)
    bits = spec.size
    if via == "modbus" and not spec.signed:
        return 0, (1 << bits) - 1
    return -(1 << (bits - 1)), (1 << (bits - 1)) - 1


def sdo_parameter(index: int, sub: int, value: int) -> tuple[str, int] | None:
    """A raw SDO write to a 2xxxh object as the parameter it sets (Pa-bc <=> 2aBCh,
    L18154-18156): (name, value as the parameter reads it), or None for any other object."""
    if sub != 0 or not 0x2000 <= index <= 0x2FFF:
        return None
    try:
        spec = _table().by_od_index(index)
    except ParamError:
        return None
    low, high = spec.to_words(value)
    return spec.param, spec.from_words(low, high)


__all__ = ["PlanFileError", "check_param", "sdo_parameter"]

