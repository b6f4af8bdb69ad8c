"""The chapter 8 parameter table of the A3 as data: names, defaults, limits, attributes, addresses.

The table lives in `fixtures/drive/a3_parameters.csv` (columns: fixtures/drive/README.md).
Values are raw integers in communication units, as Modbus and SDO carry them.

Attributes (§8.1, L6719-6723): ★ read-only, ▲ not writable while Servo On,
● takes effect after a power cycle, ■ not retained at power-off.

Addressing: Modbus address of Pg.n = (g << 8) + 2*n, low word first (L7156, L8492);
CANopen index = 0x2000 + (g << 8) + n (Pa-bc <=> 2aBCh, L18154-18156).
The runtime store (values, hooks, retention) is `hil.model.params.ParameterStore`.
"""

from __future__ import annotations

import csv
import os
import re
from collections.abc import Iterable, Iterator
from dataclasses import dataclass

from hil.fileio import parsed_once
from hil.paths import fixture
from hil.profile.errors import UnknownParameter

# P0.001: writing 0 clears the alarm (= DI.ARST); 0x0001-0xFFFF are display only (L7079-7083).
WRITE_ZERO_ONLY = frozenset({"P0.001"})

# Parameters set digit by digit (hex digits X, Y, Z, U from the lowest) where each digit has
# a range of its own, narrower than the table's whole range: (manual lines, ((digit name,
# shift, low, high), ...)). P3.001: X (RS-485 baud) 0-5, Y 0, Z (CANopen rate) 0-4, U (DMCNET)
# 0-3 (L10519-L10522).
DIGIT_RANGES: dict[str, tuple[str, tuple[tuple[str, int, int, int], ...]]] = {
    # pulse input: X form 0-2 (others reserved), Z logic 0-1, UY filter width (U 0-1),
    # range 0x0000-0x11F2 (L7662-L7674)
    "P1.000": ("L7662-L7674", (("X", 0, 0, 2), ("Z", 8, 0, 1), ("U", 12, 0, 1))),
    "P3.001": ("L10519-L10522", (("X", 0, 0, 5), ("Y", 4, 0, 0), ("Z", 8, 0, 4),
                                 ("U", 12, 0, 3))),
    # P5.098 / P5.099: each digit (EV1-EV4) 0 = nothing or 1-D = PR#51-#63 (L12509-L12523,
    # L12526-L12551)
    "P5.098": ("L12509-L12523", tuple((d, 4 * i, 0, 0xD) for i, d in enumerate("XYZU"))),
    "P5.099": ("L12526-L12551", tuple((d, 4 * i, 0, 0xD) for i, d in enumerate("XYZU"))),
    # CAPTURE: Y source 0-3, Z trigger 0-1 (L11500-L11531, range 0x0000-0xF13F)
    "P5.039": ("L11500-L11531", (("Y", 4, 0, 3), ("Z", 8, 0, 1))),
    # COMPARE, low word U Z Y X: Y source 0-3, Z output 0-1, U 0-3 (L11726-L11770, range
    # 0x00010000-0x0FFF313F)
    "P5.059": ("L11726-L11770", (("Y", 4, 0, 3), ("Z", 8, 0, 1), ("U", 12, 0, 3))),
    # X (CAPTURE) 0-1, Y reserved, Z (COMPARE) 0-1, U reserved (L8122-L8132, 0x0000-0x0101)
    "P1.019": ("L8122-L8132", (("X", 0, 0, 1), ("Y", 4, 0, 0), ("Z", 8, 0, 1),
                               ("U", 12, 0, 0))),
}


def digit_problem(param: str, value: int) -> str | None:
    """Why `value` is refused for `param` digit by digit (DIGIT_RANGES), or None."""
    lines, digits = DIGIT_RANGES.get(param, ("", ()))
    for digit, shift, lo, hi in digits:
        d = (value >> shift) & 0xF
        if not lo <= d <= hi:
            rng = f"{lo:X}" if lo == hi else f"{lo:X}-{hi:X}"
            return f"digit {digit} = {d:X} of 0x{value:04X}: it must be {rng} ({lines})"
    return None

_NAME_RE = re.compile(r"^\s*P([0-7])[.\-]([0-9]{1,3})\s*\Z", re.IGNORECASE)


def parse_name(name: str) -> tuple[int, int]:
    """ "P1.042" -> (1, 42). Also accepts "P1-42" / "p1.42". Raises UnknownParameter."""
    m = _NAME_RE.match(name) if isinstance(name, str) else None
    if not m:
        raise UnknownParameter(
            str(name), "not a parameter name (expected P<group 0-7>.<nnn>, e.g. P1.042)"
        )
    group, index = int(m.group(1)), int(m.group(2))
    if index > 0xFF:
        raise UnknownParameter(str(name), f"index {index} > 255")
    return group, index


def canonical(name: str) -> str:
    """ "p1-42" -> "P1.042"."""
    group, index = parse_name(name)
    return f"P{group}.{index:03d}"


def _int(text: str) -> int:
    text = text.strip()
    return int(text, 16) if text.lower().startswith(("0x", "-0x")) else int(text)


@dataclass(frozen=True, slots=True)
class ParamSpec:
    """One row of the parameter table (values in communication units)."""

    param: str  # "P1.042"
    name: str  # English name
    default: int
    min: int
    max: int
    unit: str
    size: int  # 16 or 32
    read_only: bool  # ★
    servo_off_only: bool  # ▲
    power_cycle: bool  # ●
    not_retained: bool  # ■
    hex: bool
    lines: str  # "<8.2 row>/<8.3 entry>" manual lines
    note: str = ""

    @property
    def group(self) -> int:
        return int(self.param[1])

    @property
    def index(self) -> int:
        return int(self.param[3:])

    @property
    def modbus_address(self) -> int:
        """Address of the low word; the high word is at +1 (L7156)."""
        return (self.group << 8) + 2 * self.index

    @property
    def od_index(self) -> int:
        """CANopen object index (sub 0): P1.044 -> 0x212C (L18154-18156)."""
        return 0x2000 + (self.group << 8) + self.index

    @property
    def signed(self) -> bool:
        return self.min < 0

    @property
    def retained(self) -> bool:
        return not self.not_retained

    def format(self, value: int) -> str:
        """Human display, hex when the manual displays it as hex."""
        if self.hex and value >= 0:
            return f"0x{value:0{self.size // 4}X}"
        return str(value)

    def to_words(self, value: int) -> tuple[int, int]:
        """(low, high) 16-bit words; 16-bit parameters read their high word as sign extension."""
        raw = value & 0xFFFFFFFF
        return raw & 0xFFFF, raw >> 16

    def from_words(self, low: int, high: int) -> int:
        """Value from two words (for 16-bit parameters only the low word counts)."""
        if self.size == 16:
            raw = low & 0xFFFF
            return raw - 0x10000 if self.signed and raw & 0x8000 else raw
        raw = ((high & 0xFFFF) << 16) | (low & 0xFFFF)
        return raw - 0x100000000 if self.signed and raw & 0x80000000 else raw

    @classmethod
    def from_row(cls, row: dict[str, str]) -> ParamSpec:
        try:
            param = canonical(row["param"])
            return cls(
                param=param,
                name=row["name"],
                default=_int(row["default"]),
                min=_int(row["min"]),
                max=_int(row["max"]),
                unit=row.get("unit", ""),
                size=int(row["size"]),
                read_only=row["read_only"].strip() == "1",
                servo_off_only=row["servo_off_only"].strip() == "1",
                power_cycle=row["power_cycle"].strip() == "1",
                not_retained=row["not_retained"].strip() == "1",
                hex=row.get("hex", "0").strip() == "1",
                lines=row.get("lines", ""),
                note=row.get("note", ""),
            )
        except (KeyError, ValueError) as exc:
            raise ValueError(f"bad parameter row {row!r}: {exc}") from exc


class ParamTable:
    """The chapter 8 parameter table, indexed by name, Modbus address and OD index."""

    def __init__(self, specs: Iterable[ParamSpec]) -> None:
        self._by_name: dict[str, ParamSpec] = {}
        self._by_addr: dict[int, ParamSpec] = {}
        self._by_od: dict[int, ParamSpec] = {}
        for spec in specs:
            if spec.param in self._by_name:
                raise ValueError(f"{spec.param}: duplicate row in parameter table")
            if not spec.min <= spec.default <= spec.max:
                raise ValueError(f"{spec.param}: default {spec.default} outside min/max")
            self._by_name[spec.param] = spec
            self._by_addr[spec.modbus_address] = spec
            self._by_od[spec.od_index] = spec

    @classmethod
    def load(cls, path: str | os.PathLike[str] | None = None) -> ParamTable:
        """Load the CSV (default: fixtures/drive/a3_parameters.csv)."""
        if path is None:
            path = fixture("drive", "a3_parameters.csv")
        return parsed_once("parameter table", path, lambda: cls._read(path))

    @classmethod
    def _read(cls, path: str | os.PathLike[str]) -> ParamTable:
        with open(path, newline="", encoding="utf-8") as f:
            return cls(ParamSpec.from_row(row) for row in csv.DictReader(f))

    def __contains__(self, name: object) -> bool:
        try:
            return canonical(str(name)) in self._by_name
        except UnknownParameter:
            return False

    def __iter__(self) -> Iterator[ParamSpec]:
        return iter(self._by_name.values())

    def __len__(self) -> int:
        return len(self._by_name)

    def spec(self, name: str) -> ParamSpec:
        hit = self._by_name.get(name)  # fast path: canonical names (the hot path in the model)
        if hit is not None:
            return hit
        key = canonical(name)
        try:
            return self._by_name[key]
        except KeyError:
            raise UnknownParameter(key, "not in the chapter 8 parameter table (reserved?)")

    def by_modbus_address(self, address: int) -> ParamSpec:
        """The parameter whose low or high word is at `address`."""
        spec = self._by_addr.get(address & ~1)
        if spec is None:
            raise UnknownParameter(f"address 0x{address:04X}", "not a parameter word")
        return spec

    def by_od_index(self, index: int) -> ParamSpec:
        spec = self._by_od.get(index)
        if spec is None:
            raise UnknownParameter(f"object 0x{index:04X}", "no parameter at this OD index")
        return spec
