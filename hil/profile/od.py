"""The A3 object dictionary as data: fixtures/drive/a3_objects.csv + parameters as 2aBCh.

One `Entry` per (index, sub). 2000h-2FFFh entries are generated from
fixtures/drive/a3_parameters.csv: Pa.bc -> 2aBCh (BC = bc in hex), INTEGER16/INTEGER32 by
size, rw (ro for read-only ★ parameters), PDO-mappable (L18141-L18156).
"""

from __future__ import annotations

import csv
import re
from dataclasses import dataclass
from pathlib import Path

from hil.fileio import parsed_once
from hil.paths import fixture
from hil.profile.canopen_init import CANOPEN_INIT_VALUES
from hil.profile.errors import ObjectError
from hil.protocol.canopen import ABORT_NO_OBJECT, ABORT_NO_SUBINDEX

FIXTURES = fixture("drive")  # checkout or installed wheel (hil.paths)
OBJECTS_CSV = FIXTURES / "a3_objects.csv"
PARAMETERS_CSV = FIXTURES / "a3_parameters.csv"

SIZES = {
    "BOOLEAN": 1,
    "INTEGER8": 1,
    "INTEGER16": 2,
    "INTEGER32": 4,
    "UNSIGNED8": 1,
    "UNSIGNED16": 2,
    "UNSIGNED32": 4,
}
SIGNED = {"INTEGER8", "INTEGER16", "INTEGER32"}
VARIABLE = {"VISIBLE_STRING", "DOMAIN"}
# CiA 306 data type codes (for the EDS).
TYPE_CODES = {
    "BOOLEAN": 0x0001,
    "INTEGER8": 0x0002,
    "INTEGER16": 0x0003,
    "INTEGER32": 0x0004,
    "UNSIGNED8": 0x0005,
    "UNSIGNED16": 0x0006,
    "UNSIGNED32": 0x0007,
    "VISIBLE_STRING": 0x0009,
    "DOMAIN": 0x000F,
}


@dataclass(frozen=True)
class Entry:
    """One object dictionary entry (one row of a3_objects.csv)."""

    index: int
    sub: int
    name: str
    object: str  # VAR | ARRAY | RECORD (of the object this entry belongs to)
    type: str
    access: str  # ro | rw | wo | const
    pdo: bool
    default: int | None
    min: int | None
    max: int | None
    unit: str = ""
    lines: str = ""
    note: str = ""
    nodeid_relative: bool = False  # default is "$NODEID + default" (COB-IDs)

    @property
    def size(self) -> int | None:
        """Size in bytes (None for VISIBLE_STRING / DOMAIN)."""
        return SIZES.get(self.type)

    @property
    def bits(self) -> int:
        return 8 * (self.size or 0)

    @property
    def readable(self) -> bool:
        return self.access != "wo"

    @property
    def writable(self) -> bool:
        return self.access in ("rw", "wo")

    @property
    def object_name(self) -> str:
        """The name of the whole ARRAY/RECORD (the part before ': ')."""
        return self.name.split(": ", 1)[0]

    @property
    def sub_name(self) -> str:
        return self.name.split(": ", 1)[-1]

    def default_for(self, node_id: int) -> int:
        value = self.default or 0
        return value + node_id if self.nodeid_relative else value

    def type_min(self) -> int:
        size = self.size or 4
        return -(1 << (8 * size - 1)) if self.type in SIGNED else 0

    def type_max(self) -> int:
        size = self.size or 4
        if self.type == "BOOLEAN":
            return 1
        return (1 << (8 * size - 1)) - 1 if self.type in SIGNED else (1 << (8 * size)) - 1

    def encode(self, value: int) -> bytes:
        """Little-endian bytes of `value` in this entry's type (wraps to the type's width)."""
        size = self.size or 4
        return (value & ((1 << (8 * size)) - 1)).to_bytes(size, "little")

    def decode(self, data: bytes) -> int:
        return int.from_bytes(data, "little", signed=self.type in SIGNED)


def _int(text: str) -> int | None:
    text = (text or "").strip()
    if not text:
        return None
    return int(text, 0)


def load_objects(path: Path = OBJECTS_CSV) -> list[Entry]:
    """Rows of a3_objects.csv as entries (1xxx and 6xxx)."""
    out = []
    with open(path, newline="", encoding="utf-8") as f:
        for row in csv.DictReader(f):
            out.append(
                Entry(
                    index=int(row["index"], 16),
                    sub=int(row["sub"]),
                    name=row["name"],
                    object=row["object"],
                    type=row["type"],
                    access=row["access"],
                    pdo=row["pdo"].strip() == "1",
                    default=_int(row["default"]),
                    min=_int(row["min"]),
                    max=_int(row["max"]),
                    unit=row["unit"],
                    lines=row["lines"],
                    note=row["note"],
                    nodeid_relative="$NODEID" in row["note"],
                )
            )
    return out


_PARAM = re.compile(r"^P([0-9])\.([0-9]{3})\Z")
_TRUE = {"1", "true", "yes", "y", "★", "ro", "x"}


def parameter_index(param: str) -> int | None:
    """P3.000 -> 0x2300, P1.044 -> 0x212C (L18156); None for PM.xxx and bad names."""
    m = _PARAM.match(param.strip())
    if not m:
        return None
    group, number = int(m.group(1)), int(m.group(2))
    if number > 0xFF:
        return None
    return 0x2000 | group << 8 | number


def _num(row: dict, key: str) -> int | None:
    try:
        return _int(row.get(key) or "")
    except ValueError:
        return None


def load_parameter_objects(path: Path = PARAMETERS_CSV) -> list[Entry]:
    """2aBCh entries from a3_parameters.csv (empty list if the file does not exist yet)."""
    if not path.exists():
        return []
    out = []
    with open(path, newline="", encoding="utf-8") as f:
        for row in csv.DictReader(f):
            index = parameter_index(row.get("param", ""))
            if index is None:
                continue
            size = (row.get("size") or "16").strip().lower()
            wide = size in ("32", "32-bit", "4", "2w", "dword")
            ro = (row.get("read_only") or "").strip().lower() in _TRUE

            out.append(
                Entry(
                    index=index,
                    sub=0,
                    name=f"{row['param']} {row.get('name', '')}".strip(),
                    object="VAR",
                    type="INTEGER32" if wide else "INTEGER16",
                    access="ro" if ro else "rw",
                    pdo=True,
                    # a CANopen drive (P3.012.Z = 0 by default) reads the init table's
                    # values after power-up: 212Ch (P1.044) = 1 (L10737-10745, L18184)
                    default=CANOPEN_INIT_VALUES.get(row["param"], _num(row, "default")),
                    min=_num(row, "min"),
                    max=_num(row, "max"),
                    unit=row.get("unit", "") or "",
                    lines="L18139-L18156",
                    note=row["param"],
                )
            )
    return out


class ObjectDictionary:
    """Entries by (index, sub), with CiA 301 lookup errors."""

    def __init__(self, entries: list[Entry]) -> None:
        self.entries: dict[tuple[int, int], Entry] = {}
        self.indices: dict[int, list[Entry]] = {}
        for e in entries:
            self.entries[(e.index, e.sub)] = e
            self.indices.setdefault(e.index, []).append(e)

    @classmethod
    def a3(
        cls,
        objects_csv: Path = OBJECTS_CSV,
        parameters_csv: Path = PARAMETERS_CSV,
        extra: list[Entry] | None = None,
    ) -> ObjectDictionary:
        """The A3 dictionary: 1xxx + 6xxx from the objects table, 2xxx from the parameters.
        The two tables are parsed once per file version (`fileio.parsed_once`)."""
        entries = (parsed_once("objects table", objects_csv, lambda: load_objects(objects_csv))
                   + parsed_once("parameter objects", parameters_csv,
                                 lambda: load_parameter_objects(parameters_csv)))
        return cls(entries + list(extra or []))

    def __contains__(self, key: tuple[int, int]) -> bool:
        return key in self.entries

    def get(self, index: int, sub: int) -> Entry:
        """The entry, or ObjectError 06020000 (no object) / 06090011 (no sub-index)."""
        e = self.entries.get((index, sub))
        if e is not None:
            return e
        if index in self.indices:
            raise ObjectError(index, sub, ABORT_NO_SUBINDEX, "sub-index does not exist")
        raise ObjectError(index, sub, ABORT_NO_OBJECT, "object does not exist")


EDS_PATH = FIXTURES / "a3.eds"  # written by hil.profile.eds
