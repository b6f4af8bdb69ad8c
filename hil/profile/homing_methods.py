"""Homing methods as data: what each CANopen 6098h method and each PR P5.004 mode looks for.

Pure tables, no motion. `hil.model.homing` runs a `Plan` on the axis. Choices and sources:
docs/manual-choices.md#homing.

Every switch is treated as a *region* in which its DI function is active: the home cam ORGP
is active on [lo, hi], NL on (-inf, nl], PL on [pl, +inf). A plan names one edge of one
region, the direction in which the axis must cross that edge for the reference (`cross`),
and the direction of the index (Z) search after it (`index`, 0 = no index: the edge itself
is the reference). `d0` is the first search direction when the signal is off at the start;
`limit` says what a limit switch in the travel direction means during the first search:
"error" (homing error) or "reverse" (search the other way, once).

CANopen methods follow CiA 402 (IEC 61800-7-201, homing method figures) because the manual
gives only one-line labels with missing figures (L18856-18972):

* 1/2 (17/18): negative/positive limit switch, reference where the switch turns off
  moving away from it, then the first index beyond it (L18871, L18875).
* 3/4 (19/20): "positive home switch" (active on the + side of its edge = the cam's lower
  edge): index on the - (3) / + (4) side of the edge (L18879).
* 5/6 (21/22): "negative home switch" (active on the - side = the cam's upper edge):
  index on the + (5) / - (6) side (L18883).
* 7-10 (23-26): first move +, reverse at PL; 7: index - side of the lower edge, 8: + side
  of the lower edge, 9: - side of the upper edge, 10: + side of the upper edge (L18886-18899).
* 11-14 (27-30): first move -, reverse at NL; 11: + side of the upper edge, 12: - side of
  the upper edge, 13: + side of the lower edge, 14: - side of the lower edge (L18902-18914).
* 33/34: the next index moving - / + (L18968). 35: the current position (L18972).
* 0, 15, 16, 31, 32: no method (reserved, L18917, L18966): homing error at the start.

PR modes P5.004 = 0xUZYX (L4211-4238, L11102-11133, sequences L4331-4368):

* X 0/1: forward to PL / reverse to NL. Y=0 back off the limit at low speed to the first Z
  inside; Y=1 find Z forward (past the limit's rising edge); Y=2 back to the edge (L4331-4338).
* X 2/3: ORG off->on (the near edge). Y=0 low speed back until ORG off, continue back to Z;
  Y=1 Z forward after the rising edge; Y=2 the edge crossed back at low speed (L4340-4346).
* X 4/5: the next Z forward / reverse (L4348). X 6/7: ORG on->off (the far edge), crossed
  forward at low speed; Y=0 then back to Z, Y=1 Z forward, Y=2 the edge (L4352-4356).
* X 8: current position (L4360). X 9/A: torque (bump) homing, Y=0 back to Z, Y=2 the bump
  point (L4364-4368). Z digit: on a limit 0 = error, 1 = reverse (L4220-4238).
"""

from __future__ import annotations

from dataclasses import dataclass

from hil.profile.errors import OutOfRange

EDGE, INDEX, TORQUE, HERE = "edge", "index", "torque", "here"
RESERVED_METHODS = frozenset({15, 16, 31, 32})


@dataclass(frozen=True)
class Plan:
    """What one homing method searches (see the module docstring)."""

    name: str
    kind: str  # edge | index | torque | here
    signal: str = ""  # ORGP | NL | PL (kind == edge)
    edge: str = ""  # lo | hi: which boundary of the signal's active region
    cross: int = 0  # direction (+1/-1) in which crossing that edge is the reference
    index: int = 0  # direction of the index search after the reference; 0 = none
    d0: int = 1  # first search direction (signal off at the start; index/torque: the move)
    limit: str = "error"  # limit switch in the first search: "error" | "reverse"
    speed: str = "low"  # index-only plans: search speed "low" (sub2 / P5.006) | "high"

    def pre_inside(self) -> bool:
        """The side from which the edge is crossed lies inside the active region."""
        return (self.edge == "lo" and self.cross < 0) or (self.edge == "hi" and self.cross > 0)

    def flipped(self) -> Plan:
        """Deviation knob `wrong_direction`: the final search runs the other way."""
        return Plan(
            self.name + " (wrong direction)", self.kind, self.signal, self.edge, -self.cross,
            -self.index, -self.d0 if self.kind == INDEX else self.d0, self.limit, self.speed,
        )  # fmt: skip

    def without_index(self) -> Plan:
        """Deviation knob `ignore_index`: the Z pulse is ignored, the edge is the home."""
        return Plan(
            self.name + " (index ignored)", self.kind, self.signal, self.edge, self.cross,
            0, self.d0, self.limit, self.speed,
        )  # fmt: skip


# CiA 402 methods 1-14: (signal, edge, cross, first direction d0, limit rule).
_CIA_INDEXED: dict[int, tuple[str, str, int, int, str]] = {
    1: ("NL", "hi", +1, -1, "error"),
    2: ("PL", "lo", -1, +1, "error"),
    3: ("ORGP", "lo", -1, +1, "error"),
    4: ("ORGP", "lo", +1, +1, "error"),
    5: ("ORGP", "hi", +1, -1, "error"),
    6: ("ORGP", "hi", -1, -1, "error"),
    7: ("ORGP", "lo", -1, +1, "reverse"),
    8: ("ORGP", "lo", +1, +1, "reverse"),
    9: ("ORGP", "hi", -1, +1, "reverse"),
    10: ("ORGP", "hi", +1, +1, "reverse"),
    11: ("ORGP", "hi", +1, -1, "reverse"),
    12: ("ORGP", "hi", -1, -1, "reverse"),
    13: ("ORGP", "lo", +1, -1, "reverse"),
    14: ("ORGP", "lo", -1, -1, "reverse"),
}
# The index side equals `cross` (CiA 402: the edge is crossed towards the home index).

CANOPEN_METHODS = frozenset(range(1, 15)) | frozenset(range(17, 31)) | {33, 34, 35}


def canopen_plan(method: int) -> Plan:
    """Plan of CANopen homing method `method` (6098h). Raises OutOfRange for 0 / reserved."""
    if method not in CANOPEN_METHODS:
        why = "reserved (L18917, L18966)" if method in RESERVED_METHODS else "no homing method"
        raise OutOfRange("6098h", f"homing method {method}: {why}; supported 1-14, 17-30, 33-35")
    name = f"CiA 402 method {method}"
    if method == 35:
        return Plan(name, HERE)
    if method in (33, 34):
        return Plan(name, INDEX, index=-1 if method == 33 else 1, d0=-1 if method == 33 else 1)
    base = method if method <= 14 else method - 16
    sig, edge, cross, d0, limit = _CIA_INDEXED[base]
    return Plan(name, EDGE, sig, edge, cross, cross if method <= 14 else 0, d0, limit)


def decode_p5004(value: int) -> tuple[int, int, int]:
    """(X, Y, Z) digits of P5.004 (L11102-11133)."""
    return value & 0xF, (value >> 4) & 0xF, (value >> 8) & 0xF


def check_p5004(name: str, value: int) -> None:
    """Validator: X 0-A, Y 0-2 (0 or 2 for X = 9/A), Z 0-1, U 0 (L4220-4238)."""
    x, y, z = decode_p5004(value)
    if x > 0xA or y > 2 or z > 1 or value >> 12:
        raise OutOfRange(name, f"0x{value:X}: digits X 0-A, Y 0-2, Z 0-1 (L4220-4238)")
    if x in (9, 0xA) and y == 1:
        raise OutOfRange(name, f"0x{value:X}: torque homing X={x:X} allows Y = 0 or 2 (L4237)")


def pr_plan(value: int, z_speed: str = "low") -> Plan:
    """Plan of PR homing mode P5.004 = `value`."""
    check_p5004("P5.004", value)
    x, y, z = decode_p5004(value)
    name = f"PR homing P5.004=0x{value:03X}"
    limit = "reverse" if z == 1 else "error"
    d = 1 if x in (0, 2, 4, 6, 9) else -1
    if x == 8:
        return Plan(name, HERE)
    if x in (4, 5):
        return Plan(name, INDEX, index=d, d0=d, limit=limit, speed=z_speed)
    if x in (9, 0xA):
        return Plan(name, TORQUE, index=-d if y == 0 else 0, d0=d, limit=limit)
    if x in (0, 1):
        sig, edge = ("PL", "lo") if d > 0 else ("NL", "hi")
        cross = d if y == 1 else -d
        return Plan(name, EDGE, sig, edge, cross, 0 if y == 2 else cross, d, "error")
    if x in (2, 3):  # ORG off->on: the edge met first when moving d (L4340-4346)
        edge = "lo" if d > 0 else "hi"
        cross = d if y == 1 else -d
        return Plan(name, EDGE, "ORGP", edge, cross, 0 if y == 2 else cross, d, limit)
    # X 6/7: ORG on->off, the far edge, crossed forward; Y=0 then back to Z (L4352-4356)
    edge = "hi" if d > 0 else "lo"
    index = {0: -d, 1: d, 2: 0}[y]
    return Plan(name, EDGE, "ORGP", edge, d, index, d, limit)


__all__ = [
    "CANOPEN_METHODS",
    "EDGE",
    "HERE",
    "INDEX",
    "RESERVED_METHODS",
    "TORQUE",
    "Plan",
    "canopen_plan",
    "check_p5004",
    "decode_p5004",
    "pr_plan",
]
