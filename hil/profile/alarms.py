"""The chapter 13 alarm table of the A3 as data: `fixtures/drive/a3_alarms.csv`.

Columns and clear rules: fixtures/drive/README.md. The runtime (raise, reset, history) is
`hil.model.alarms.AlarmManager`.
"""

from __future__ import annotations

import csv
import os
from collections.abc import Iterator
from dataclasses import dataclass

from hil.fileio import parsed_once
from hil.paths import fixture
from hil.profile.errors import ModelError

CLEAR_RULES = ("reset", "power_cycle", "auto", "nmt_or_reset", "service", "special")


class UnknownAlarm(ModelError):
    """An alarm code that the chapter 13 table does not list."""

    def __init__(self, code: str) -> None:
        super().__init__(f"{code}: not in the chapter 13 alarm table")
        self.code = code


@dataclass(frozen=True, slots=True)
class AlarmSpec:
    code: str  # "AL500"
    name: str
    kind: str  # "ALM" | "WARN"
    servo_off: bool  # servo state after the event is OFF
    clear: str  # one of CLEAR_RULES
    emcy: int  # CiA 301/402 error code
    lines: str
    note: str = ""

    @property
    def number(self) -> int:
        """Register value of the code (digits read as hex): AL011 -> 0x0011 (L17584)."""
        return int(self.code[2:], 16)

    @classmethod
    def from_row(cls, row: dict[str, str]) -> AlarmSpec:
        try:
            spec = cls(
                code=row["code"].strip().upper(),
                name=row["name"],
                kind=row["kind"].strip(),
                servo_off=row["servo"].strip() == "OFF",
                clear=row["clear"].strip(),
                emcy=int(row["emcy"], 16),
                lines=row.get("lines", ""),
                note=row.get("note", ""),
            )
        except (KeyError, ValueError) as exc:
            raise ValueError(f"bad alarm row {row!r}: {exc}") from exc
        if spec.kind not in ("ALM", "WARN") or spec.clear not in CLEAR_RULES:
            raise ValueError(f"{spec.code}: bad kind {spec.kind!r} or clear {spec.clear!r}")
        return spec


class AlarmTable:
    def __init__(self, specs: list[AlarmSpec]) -> None:
        self._by_code = {s.code: s for s in specs}

    @classmethod
    def load(cls, path: str | os.PathLike[str] | None = None) -> AlarmTable:
        """The alarm table (default: fixtures/drive/a3_alarms.csv), parsed once per file
        version (`fileio.parsed_once`)."""
        if path is None:
            path = fixture("drive", "a3_alarms.csv")
        return parsed_once("alarm table", path, lambda: cls._read(path))

    @classmethod
    def _read(cls, path: str | os.PathLike[str]) -> AlarmTable:
        with open(path, newline="", encoding="utf-8") as f:
            return cls([AlarmSpec.from_row(r) for r in csv.DictReader(f)])

    def spec(self, code: str) -> AlarmSpec:
        key = code.strip().upper() if isinstance(code, str) else code
        try:
            return self._by_code[key]
        except KeyError:
            raise UnknownAlarm(str(code))

    def by_number(self, number: int) -> AlarmSpec:
        for spec in self._by_code.values():
            if spec.number == number:
                return spec
        raise UnknownAlarm(f"0x{number:04X}")

    def __contains__(self, code: object) -> bool:
        return isinstance(code, str) and code.strip().upper() in self._by_code

    def __iter__(self) -> Iterator[AlarmSpec]:
        return iter(self._by_code.values())

    def __len__(self) -> int:
        return len(self._by_code)
