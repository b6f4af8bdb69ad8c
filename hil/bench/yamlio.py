"""YAML with line numbers, the one error type of plan and bench files, and durations.

Every problem in a plan or bench file is a `PlanFileError` whose message is
`file:line: field: problem` (field like `steps[3].wait_until.timeout`), raised before
anything on the bench moves.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from hil.units import MS, S
from hil.yamlio import FileError, LDict, LList, join
from hil.yamlio import load_yaml_file as _load_file
from hil.yamlio import load_yaml_text as _load_text

__all__ = ["LDict", "LList", "join"]  # re-exported for the plan room



class PlanFileError(FileError):
    """A malformed plan or bench file: `file:line: field: problem`."""


def load_yaml_text(text: str, file: str) -> Any:
    """Parse YAML keeping line numbers; syntax errors become `PlanFileError`."""
    return _load_text(text, file, PlanFileError)


def load_yaml_file(path: str | Path) -> Any:
    return _load_file(path, PlanFileError)


# --- durations ---------------------------------------------------------------------------

_DUR_RE = re.compile(r"^\s*([0-9]{1,15}(?:\.[0-9]{0,15})?|\.[0-9]{1,15})\s*(ns|us|µs|ms|s|min)"
                     r"\s*\Z")
_UNITS = {"ns": 1, "us": 1_000, "µs": 1_000, "ms": MS, "s": S, "min": 60 * S}


PARAM_ROUTES = ("modbus", "sdo")  # `via:` of a parameter access (default: the bench's route)
MAX_DURATION_NS = 24 * 3600 * 1_000_000_000  # an absurd duration is a typo, not a test


def shorten(value: Any, limit: int = 40) -> str:
    """`repr(value)` cut to `limit` characters, for error messages about hostile values."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 5] + "...'" + f" ({len(text)} chars)"


def parse_duration(value: Any) -> int:
    """`150ms`, `1.5s`, `20 us`, `2min` -> integer ns. Raises ValueError with the rule."""
    shown = shorten(value)
    if isinstance(value, bool) or not isinstance(value, str):
        raise ValueError(
            f"duration {shown}: write it with a unit, e.g. 150ms, 1.5s (units: "
            f"{', '.join(_UNITS)})"
        )
    m = _DUR_RE.match(value)
    if not m:
        raise ValueError(
            f"duration {shown}: a number (ASCII digits, at most 15 before and after the "
            f"point) and a unit, e.g. 150ms, 1.5s (units: {', '.join(_UNITS)})"
        )
    exact = float(m.group(1)) * _UNITS[m.group(2)]
    ns = round(exact)
    if abs(exact - ns) > max(1e-6, abs(exact) * 1e-12):  # (a float's own error aside)
        raise ValueError(f"duration {shown}: finer than 1 ns (a duration is a whole number "
                         "of nanoseconds)")
    if ns > MAX_DURATION_NS:
        raise ValueError(f"duration {shown} is longer than {MAX_DURATION_NS // S // 3600} h, "
                         "the longest anything in a plan or bench may take")
    return ns


def format_duration(ns: int) -> str:
    if ns % S == 0:
        return f"{ns // S}s"
    if ns % MS == 0:
        return f"{ns // MS}ms"
    if ns >= MS:
        return f"{ns / MS:g}ms"
    return f"{ns / 1000:g}us"


# --- a small validation helper ------------------------------------------------------------


class Checker:
    """Carries the file name; every method raises `PlanFileError` with file, line, field."""

    def __init__(self, file: str) -> None:
        self.file = file

    def err(self, line: int, field: str, problem: str) -> PlanFileError:
        return PlanFileError(self.file, line, field or "(top)", problem)

    def mapping(self, obj: Any, line: int, field: str) -> LDict:
        if not isinstance(obj, LDict):
            raise self.err(line, field, f"must be a mapping, got {_kind(obj)}")
        return obj

    def seq(self, obj: Any, line: int, field: str) -> LList:
        if not isinstance(obj, LList):
            raise self.err(line, field, f"must be a list, got {_kind(obj)}")
        return obj

    def keys(self, d: LDict, allowed: set[str] | dict, field: str,
             required: tuple[str, ...] = ()) -> None:
        for k in d:
            if k not in allowed:
                raise self.err(d.kline(k), join(field, k),
                               f"unknown key; known: {', '.join(sorted(allowed))}")
        for k in required:
            if k not in d:
                raise self.err(d.line, join(field, k), "missing (required)")

    def text(self, d: LDict, key: str, field: str, default: str | None = None) -> str:
        if key not in d:
            if default is None:
                raise self.err(d.line, join(field, key), "missing (required)")
            return default
        v = d[key]
        if not isinstance(v, str):
            raise self.err(d.kline(key), join(field, key), f"must be text, got {_kind(v)}")
        if not v.strip():
            raise self.err(d.kline(key), join(field, key), "must not be empty")
        try:  # a "\ud800" escape: no file, recording or terminal can carry it
            v.encode("utf-8")
        except UnicodeEncodeError:
            raise self.err(d.kline(key), join(field, key),
                           "not valid text (a lone surrogate such as \\ud800)") from None
        return v

    def integer(self, d: LDict, key: str, field: str, lo: int, hi: int,
                default: int | None = None) -> int:
        if key not in d:
            if default is None:
                raise self.err(d.line, join(field, key), "missing (required)")
            return default
        v = d[key]
        if isinstance(v, bool) or not isinstance(v, int):
            raise self.err(d.kline(key), join(field, key),
                           f"must be an integer, got {_kind(v)}{text_number_hint(v)}")
        if not lo <= v <= hi:
            raise self.err(d.kline(key), join(field, key), f"{v} is out of range {lo}..{hi}")
        return v

    def number(self, d: LDict, key: str, field: str, lo: float, hi: float,
               default: float | None = None) -> float:
        """A finite number in lo..hi (NaN, inf and text refused)."""
        if key not in d:
            if default is None:
                raise self.err(d.line, join(field, key), "missing (required)")
            return default
        v = d[key]
        if isinstance(v, bool) or not isinstance(v, int | float):
            raise self.err(d.kline(key), join(field, key),
                           f"must be a number, got {_kind(v)}{text_number_hint(v)}")
        if v != v or not lo <= v <= hi:  # v != v: NaN
            raise self.err(d.kline(key), join(field, key),
                           f"{shorten(v)} is out of range {lo:g}..{hi:g}")
        return float(v)

    def choice(self, d: LDict, key: str, field: str, allowed: tuple[str, ...],
               default: str | None = None) -> str | None:
        """One of `allowed` (None when absent and no default)."""
        if key not in d:
            return default
        v = d[key]
        if not isinstance(v, str) or v not in allowed:
            names = " or ".join(allowed) if len(allowed) == 2 else "one of " + ", ".join(allowed)
            raise self.err(d.kline(key), join(field, key), f"{shorten(v)}: {names}")
        return v

    def boolean(self, d: LDict, key: str, field: str, default: bool) -> bool:
        if key not in d:
            return default
        v = d[key]
        if not isinstance(v, bool):
            raise self.err(d.kline(key), join(field, key), f"must be true or false, got {v!r}")
        return v

    def duration(self, d: LDict, key: str, field: str, default: int | None = None) -> int:
        if key not in d:
            if default is None:
                raise self.err(d.line, join(field, key), "missing (required)")
            return default
        try:
            ns = parse_duration(d[key])
        except ValueError as e:
            raise self.err(d.kline(key), join(field, key), str(e)) from None
        if key == "timeout" and ns <= 0:  # every step kind's `timeout:`: 0 would fail at once
            raise self.err(d.kline(key), join(field, key), "must be > 0")
        return ns


def _kind(v: Any) -> str:
    if v is None:
        return "nothing"
    if isinstance(v, bool):
        return f"a boolean ({v})"
    if isinstance(v, dict):
        return "a mapping"
    if isinstance(v, list):
        return "a list"
    if isinstance(v, int | float):
        return f"a number ({shorten(v)})"
    if isinstance(v, str):
        return f"text ({shorten(v)})"
    # a YAML tag's value (!!binary, a date): named as what it is, not as text
    what = _TAGGED.get(type(v).__name__, f"a {type(v).__name__}")
    return f"{what} ({shorten(v)})"


_TAGGED = {"bytes": "binary data", "date": "a date", "datetime": "a date and time"}
# what YAML 1.1 (PyYAML) reads as text although it looks like a number: an exponent without
# a dot or without a sign (1e9, 1.0e15, 2E-3)
_EXP_TEXT = re.compile(r"([-+]?)(\d+)(\.\d*)?([eE])([-+]?)(\d+)")
_NUMBER_TEXT = re.compile(r"[-+]?(\d+(\.\d*)?([eE][-+]\d+)?|\.\d+|0x[0-9a-fA-F]+)")


def text_number_hint(v: Any) -> str:
    """Where a number is wanted and text came: why YAML read it as text, and how to write it.
    YAML 1.1 (PyYAML) reads an exponent as a number only with a dot and a signed exponent
    (`1e9` is text, `1.0e+9` a number); text that reads as a number was quoted."""
    if not isinstance(v, str):
        return ""
    t = v.strip()
    m = _EXP_TEXT.fullmatch(t)
    if m is not None and not (m.group(3) and len(m.group(3)) > 1 and m.group(5)):
        sign, whole, frac, e, esign, exp = m.groups()
        fixed = f"{sign}{whole}{frac if frac and len(frac) > 1 else '.0'}{e}{esign or '+'}{exp}"
        return (f": YAML reads {t} as text, a number needs a dot and a signed exponent "
                f"({fixed})")
    if _NUMBER_TEXT.fullmatch(t):
        return ": text, not a number: write it without quotes"
    return ""


def level(v: Any) -> bool | None:
    """on/off, true/false, 1/0, high/low -> bool; anything else None."""
    if isinstance(v, bool):
        return v
    if isinstance(v, int) and v in (0, 1):
        return bool(v)
    if isinstance(v, str):
        t = v.strip().lower()
        if t in ("on", "true", "high", "closed", "1", "yes"):
            return True
        if t in ("off", "false", "low", "open", "0", "no"):
            return False
    return None
