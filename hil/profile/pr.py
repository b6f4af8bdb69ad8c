"""PR paths (Procedure Register, A3 manual chapter 7): the table and the path decoder.

A3 PR#0 is homing (P6.000/P6.001); PR#1..#99 are two 32-bit parameters each, a definition
`DCBA:UZYX` and a data word (L4140-4160): PR#n (1..49) = P6.(2n)/P6.(2n+1), PR#n (50..99)
= P7.(2n-100)/P7.(2n-99) (8.3 P6.002 L12666, P7.000 L13652; the ch.7 table L4834-4840
prints PR#50 at P6.098 and PR#51 at P7.000, an off-by-one: docs/manual-choices.md#pr).

TYPE (X) 1 SPEED, 2 SINGLE, 3 AUTO, 7 JUMP, 8 WRITE, 0xA INDEX, 0xB STATEMENT (L4148-4155);
field layouts: speed L4432-4451, position L4478-4501, jump L4514-4527, write L4545-4589,
index L4613-4645. This module is pure: `decode()` is also what `hil run --check` uses.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cache

from hil.profile.errors import ModelError
from hil.profile.params import ParamTable, parse_name
from hil.units import s32

N_PATHS = 100  # PR#0 homing + PR#1..#99 (L4148)

SPEED, SINGLE, AUTO, JUMP, WRITE, INDEX, STATEMENT = 1, 2, 3, 7, 8, 0xA, 0xB
TYPE_NAMES = {
    0: "none", SPEED: "speed", SINGLE: "single", AUTO: "auto", JUMP: "jump",
    WRITE: "write", INDEX: "index", STATEMENT: "statement",
}
CMD_NAMES = ("ABS", "REL", "INC", "CAP")  # position OPT bits 3-2 (L4489-4495)
SOURCES = ("constant", "parameter", "array", "monitor")  # write C bits 3-2 (L4566-4575)
INDEX_DIRS = ("forward", "reverse", "shortest")  # index OPT bits 3-2 (L4623)
SPEED_LIMIT_0P1 = 60000  # speed PR data -60000..60000 (0.1 rpm, L4451)


# a path word the drive cannot decode when it reads it: AL809 "驅動器 Motion 執行發生指令解碼
# 異常" (L20229-20232), which only a power cycle clears
DECODE = "AL809"


class PrError(ModelError):
    """A PR definition the drive cannot run (the reason names the field and the line);
    `alarm`: the alarm the drive raises when it reads such a path."""

    def __init__(self, message: str, alarm: str = "") -> None:
        super().__init__(message)
        self.alarm = alarm


@dataclass(frozen=True)
class PrPath:
    """One decoded PR path (fields named as in the manual's tables)."""

    number: int
    type: int
    ins: bool = False  # OPT bit 0: interrupt the previous command (L4447)
    auto: bool = False  # speed / write: OPT bit 1; index: C bit 2 (L4449, L4553, L4633)
    ovlp: bool = False  # position / index: OPT bit 1 (L4497)
    cmd: str = "ABS"  # position: ABS REL INC CAP (L4489-4495)
    unit_pps: bool = False  # speed: OPT bit 2, 0 = 0.1 rpm, 1 = PUU/s (L4449)
    acc: int = 0  # Z: index into P5.020-P5.035
    dec: int = 0  # U
    spd: int = 0  # A: index into P5.060-P5.075 (position / index)
    dly: int = 0  # B: index into P5.040-P5.055
    data: int = 0  # signed 32-bit data word
    # write (TYPE 8)
    dest_array: bool = False  # C bit 0 (L4566)
    source: str = "constant"  # C bits 3-2 (L4566-4575)
    dest: int = 0  # bits 23..12 (A U Z): parameter group/number or array index (L4579)
    rom: bool = False  # OPT bit 2: also EEPROM (L4555)
    # index (TYPE 0xA)
    direction: str = "forward"
    s_low: bool = False  # C bit 0: speed unit 0.01 rpm (L4633)

    @property
    def name(self) -> str:
        return TYPE_NAMES.get(self.type, hex(self.type))

    @property
    def is_motion(self) -> bool:
        return self.type in (SPEED, SINGLE, AUTO, INDEX)

    @property
    def continues(self) -> bool:
        """The next PR (n+1) is read after this one (AUTO chain)."""
        return self.type == AUTO or (self.type in (SPEED, WRITE, INDEX) and self.auto)

    @property
    def dest_param(self) -> str:
        """Write destination parameter: group in A, number in U Z (L4579-4581)."""
        return f"P{(self.dest >> 8) & 0xF}.{self.dest & 0xFF:03d}"

    @property
    def source_param(self) -> str:
        """Write source parameter: group in Z, number in Y X (L4585-4589, choice)."""
        return f"P{(self.data >> 8) & 0xF}.{self.data & 0xFF:03d}"


def pr_params(n: int) -> tuple[str, str]:
    """(definition, data) parameter names of PR#n, 1..99 (L12666, L13652)."""
    if not 1 <= n <= 99:
        raise PrError(f"PR#{n}: path number must be 1..99 (AL249, L20099)")
    if n < 50:
        return f"P6.{2 * n:03d}", f"P6.{2 * n + 1:03d}"
    return f"P7.{2 * n - 100:03d}", f"P7.{2 * n - 99:03d}"


def param_to_pr(name: str) -> tuple[int, str] | None:
    """(PR number, "def"|"data") of a P6.002-P7.099 name, else None."""
    try:
        g, i = int(name[1]), int(name[3:])
    except (ValueError, IndexError):
        return None
    if g == 6 and i >= 2:
        return i // 2, ("def", "data")[i % 2]
    if g == 7:
        return 50 + i // 2, ("def", "data")[i % 2]
    return None


def decode(n: int, definition: int, data: int) -> PrPath:
    """Decode PR#n; raise PrError for a path the drive would refuse to run."""
    d = definition & 0xFFFFFFFF
    x, y = d & 0xF, (d >> 4) & 0xF
    z, u, a, b, c, dd = ((d >> s) & 0xF for s in (8, 12, 16, 20, 24, 28))
    data = s32(data)
    where = f"PR#{n} (0x{d:08X})"
    common = {"number": n, "type": x, "ins": bool(y & 1), "dly": b, "data": data}
    if x == 0:
        return PrPath(**common)  # an empty path: nothing to run
    if x == SPEED:
        if not y & 4 and not -SPEED_LIMIT_0P1 <= data <= SPEED_LIMIT_0P1:
            raise PrError(f"{where}: speed {data} outside -60000..60000 x0.1 rpm (L4451)",
                          DECODE)
        return PrPath(**common, auto=bool(y & 2), unit_pps=bool(y & 4), acc=z, dec=u)
    if x in (SINGLE, AUTO):
        return PrPath(
            **common, ovlp=bool(y & 2), cmd=CMD_NAMES[y >> 2], acc=z, dec=u, spd=a
        )
    if x == JUMP:
        if not 0 <= data <= 99:
            raise PrError(
                f"{where}: jump to PR#{data}, must be 0..99 (AL249, L4527, L20099)", "AL249"
            )
        return PrPath(**common)
    if x == WRITE:
        if dd != 0:
            raise PrError(f"{where}: D must be 0 for a write PR (L4549)", DECODE)
        if c & 2:
            raise PrError(f"{where}: C bit 1 is unused for a write PR (L4566)", DECODE)
        p = PrPath(
            **common, auto=bool(y & 2), rom=bool(y & 4), dest_array=bool(c & 1),
            source=SOURCES[c >> 2], dest=(d >> 8) & 0xFFF,
        )
        _check_write(p, where)
        return p
    if x == INDEX:
        if y >> 2 == 3:
            raise PrError(f"{where}: index DIR 3 is undefined (L4623)", DECODE)
        if data < 0:
            raise PrError(f"{where}: index target {data} must be >= 0 (L4645)", DECODE)
        return PrPath(
            **common, ovlp=bool(y & 2), direction=INDEX_DIRS[y >> 2], acc=z, dec=u, spd=a,
            auto=bool(c & 4), s_low=bool(c & 1),
        )
    if x == STATEMENT:
        raise PrError(
            f"{where}: statement PRs are set up with ASDA-Soft only (L4649)", "AL809"
        )
    raise PrError(f"{where}: TYPE {x:X} undefined (1, 2, 3, 7, 8, A, B: L4148-4155)", DECODE)


ARRAY_SIZE = 800  # data array 0..799 (L5097)
# (a monitor source is read as P0.009-P0.013 show it, `Hooks.monitors`: a code the model does
# not have is AL231 when the WRITE runs, `PrEngine.monitor`; `hil run --check` takes 0-127)


def _check_write(p: PrPath, where: str) -> None:
    """Static checks of a write PR (alarms AL207/AL209/AL231 at run time, L20044-20081)."""
    if p.dest_array:
        if p.dest >= ARRAY_SIZE:
            raise PrError(f"{where}: destination array index {p.dest} > 799 (L5097; AL213)",
                          "AL213")
    elif not _known_param(p.dest_param):
        raise PrError(f"{where}: destination {p.dest_param} does not exist (AL213)", "AL213")
    if p.source == "parameter":
        source_error(p, where)
    elif p.source == "array":
        if not 0 <= p.data < ARRAY_SIZE:
            raise PrError(f"{where}: source array index {p.data} outside 0..799 (L5097; AL209)",
                          "AL209")
    elif p.source == "monitor" and not 0 <= p.data <= 127:  # P0.017's range (L7199)
        raise PrError(f"{where}: monitor code {p.data} not available (AL231)", "AL231")


PARAM_GROUPS = range(8)  # P0..P7 (chapter 8)


def source_error(p: PrPath, where: str) -> None:
    """A source parameter the drive cannot read: its group does not exist (AL207,
    L20044-20047) or its number does not (AL209, L20049-20052)."""
    if (p.data >> 8) & 0xF not in PARAM_GROUPS:
        raise PrError(f"{where}: source group P{(p.data >> 8) & 0xF} does not exist (AL207)",
                      "AL207")
    if not _known_param(p.source_param):
        raise PrError(f"{where}: source {p.source_param} does not exist (AL209)", "AL209")


@cache
def _param_table() -> ParamTable:
    return ParamTable.load()


def _known_param(name: str) -> bool:
    return name in _param_table()


def read_path(get: Callable[[str], int], n: int) -> PrPath:
    """Decode PR#n from parameter values (`get(name)`)."""
    p_def, p_data = pr_params(n)
    return decode(n, get(p_def), get(p_data))


def check_table(values: dict[str, int]) -> list[str]:
    """Problems of a PR table given as parameter values (P6.002..P7.099 names); for
    `hil run --check`. Paths not mentioned count as all-zero (empty)."""
    problems: list[str] = []
    by_pr: dict[int, dict[str, int]] = {}
    for name, value in values.items():
        hit = param_to_pr(name)
        if hit is not None:
            by_pr.setdefault(hit[0], {})[hit[1]] = int(value)
    for n in sorted(by_pr):
        if not 1 <= n <= 99:
            continue
        try:
            decode(n, by_pr[n].get("def", 0), by_pr[n].get("data", 0))
        except PrError as exc:
            problems.append(str(exc))
    return problems


def encode(
    type_: int | str, data: int = 0, *, ins: bool = False, auto: bool = False,
    ovlp: bool = False, cmd: str = "ABS", unit_pps: bool = False, acc: int = 0,
    dec: int = 0, spd: int = 0, dly: int = 0, dest: str | int = 0, dest_array: bool = False,
    source: str = "constant", rom: bool = False, direction: str = "forward",
    s_low: bool = False,
) -> tuple[int, int]:
    """(definition, data) words of a PR given by field names (the inverse of `decode`)."""
    t = _type_of(type_)
    if not isinstance(data, int) or isinstance(data, bool):  # a whole word (1.5 was written)
        raise TypeError(f"data {data!r}: an integer (a 32-bit word)")
    if not -(1 << 31) <= data <= 0xFFFFFFFF:  # one 32-bit data word (P6.003 ..., L4440)
        raise PrError(f"data {data}: a 32-bit word, -2147483648..4294967295")
    y = int(ins)
    c = 0
    a = spd
    z, u = acc, dec
    if t == SPEED:
        y |= (2 if auto else 0) | (4 if unit_pps else 0)
        a = 0
    elif t in (SINGLE, AUTO):
        if cmd not in CMD_NAMES:
            raise PrError(f"cmd {cmd!r}: one of {', '.join(CMD_NAMES)} (L4489-4495)")
        y |= (2 if ovlp else 0) | (CMD_NAMES.index(cmd) << 2)
    elif t == WRITE:
        y |= (2 if auto else 0) | (4 if rom else 0)
        if source not in SOURCES:
            raise PrError(f"source {source!r}: one of {', '.join(SOURCES)} (L4566-4575)")
        c = (SOURCES.index(source) << 2) | int(dest_array)
        if isinstance(dest, str):
            g, i = parse_name(dest)
            dest = (g << 8) | i
        if not 0 <= dest <= 0xFFF:  # A U Z: 12 bits (L4579-4581)
            raise PrError(f"dest {dest}: a parameter (P5.064) or an index 0..0xFFF")
        z, u, a = dest & 0xF, (dest >> 4) & 0xF, (dest >> 8) & 0xF
    elif t == INDEX:
        if direction not in INDEX_DIRS:
            raise PrError(f"direction {direction!r}: one of {', '.join(INDEX_DIRS)} (L4623)")
        y |= (2 if ovlp else 0) | (INDEX_DIRS.index(direction) << 2)
        c = (4 if auto else 0) | int(s_low)
    elif t == JUMP:
        z = u = a = 0
    for nm, v in (("acc", z), ("dec", u), ("spd", a), ("dly", dly)):
        if not 0 <= v <= 15:
            raise PrError(f"{nm} {v}: an index 0..15 (P5.020/P5.040/P5.060 tables, L4164)")
    d = t | (y << 4) | (z << 8) | (u << 12) | (a << 16) | (dly << 20) | (c << 24)
    return d, s32(data)


def _type_of(type_: int | str) -> int:
    names = ", ".join(v for v in TYPE_NAMES.values() if v != "none")
    if isinstance(type_, int):
        if type_ not in TYPE_NAMES:  # a TYPE digit is 4 bits: 99 would set INS (L4440)
            raise PrError(f"type {type_}: one of the TYPE codes "
                          f"{', '.join(f'{k} ({v})' for k, v in TYPE_NAMES.items())}")
        return type_
    for k, v in TYPE_NAMES.items():
        if v == type_.lower():
            return k
    raise PrError(f"type {type_!r}: one of {names}")


__all__ = [
    "AUTO", "INDEX", "JUMP", "N_PATHS", "SINGLE", "SPEED", "STATEMENT", "WRITE", "PrError",
    "PrPath", "check_table", "decode", "encode", "param_to_pr", "pr_params", "read_path",
]
