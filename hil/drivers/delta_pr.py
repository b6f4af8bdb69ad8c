"""Host-side driver for Delta ASDA PR mode (A3 manual chapter 7), over Modbus or CANopen SDO.

`DeltaPr(access)` works on anything with `read_param(name) -> int` and
`write_param(name, value)`: `hil.drivers.delta_modbus.DeltaModbus` (RS-485), a plan's
`DriveIO` (Modbus or SDO 2xxxh, as the bench says), or the virtual `Drive.params`.

    pr = DeltaPr(modbus)
    pr.write_table({1: {"type": "auto", "data": 100000, "spd": 4, "dly": 1},
                    2: {"type": "jump", "data": 1, "ins": True}})   # written, read back
    pr.trigger(1)                  # P5.007 = 1 (L11174)
    pr.wait(1, "in_position", timeout_s=5)   # P5.007 reads 20001 (L11185)

PR words come from `hil.profile.pr.encode` and are checked with `decode` — the model's own
decoder — before anything is sent: a table the drive would refuse is never half-written.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, Protocol

from hil import clock
from hil.profile.errors import ParamError
from hil.profile.pr import PrError, decode, encode, pr_params

STATES = {"running": 0, "done": 10000, "in_position": 20000}  # P5.007 read-back (L11185)


class ParamAccess(Protocol):
    def read_param(self, name: str) -> int: ...

    def write_param(self, name: str, value: int) -> None: ...


class PrTableError(ValueError):
    """A PR table that the drive would refuse or that did not read back."""


def table_words(table: Mapping[int, Mapping[str, Any]]) -> dict[str, int]:
    """Parameter values (P6.xxx/P7.xxx) of a PR table given by field names; validated."""
    out: dict[str, int] = {}
    for n, fields in sorted(table.items()):
        f = dict(fields)
        kind = f.pop("type", None)
        if kind is None:
            raise PrTableError(f"PR#{n}: type missing (speed, single, auto, jump, write, index)")
        try:
            definition, data = encode(kind, f.pop("data", 0), **f)
            decode(n, definition, data)
            p_def, p_data = pr_params(n)
        except (PrError, TypeError, ParamError) as exc:  # ParamError: dest no parameter
            raise PrTableError(f"PR#{n}: {exc}") from None
        out[p_def], out[p_data] = definition, data
    return out


class DeltaPr:
    """PR table, trigger and completion through the drive's parameters."""

    def __init__(self, access: ParamAccess, *, poll_s: float = 0.01,
                 sleep: Callable[[float], None] = clock.sleep,
                 clock: Callable[[], float] = clock.monotonic) -> None:
        self.access = access
        self.poll_s = poll_s
        self._sleep, self._clock = sleep, clock

    def write_table(self, table: Mapping[int, Mapping[str, Any]], verify: bool = True) -> dict:
        """Write every path (definition then data) and read it back; returns the words."""
        words = table_words(table)
        for name, value in words.items():
            self.access.write_param(name, value)
        if verify:
            bad = []
            for name, value in words.items():
                got = self.access.read_param(name)
                if (got - value) % (1 << 32):
                    bad.append(f"{name} = {got}, wrote {value}")
            if bad:
                raise PrTableError("read back differs: " + "; ".join(bad))
        return words

    def read_path(self, n: int) -> Any:
        """PR#n as the drive holds it, decoded."""
        p_def, p_data = pr_params(n)
        return decode(n, self.access.read_param(p_def), self.access.read_param(p_data))

    def trigger(self, n: int) -> None:
        """Run PR#n (0 = homing) through P5.007 (L11174)."""
        if not 0 <= n <= 99:
            raise PrTableError(f"PR#{n}: 0..99 (L11174)")
        self.access.write_param("P5.007", n)

    def stop(self) -> None:
        """P5.007 = 1000 = DI.STP (L11183)."""
        self.access.write_param("P5.007", 1000)

    def status(self) -> tuple[int, str]:
        """(PR number, running|done|in_position) from the P5.007 read-back (L11185)."""
        v = self.access.read_param("P5.007")
        if v >= 20000:
            return v - 20000, "in_position"
        if v >= 10000:
            return v - 10000, "done"
        return v, "running"

    def wait(self, n: int, state: str = "in_position", timeout_s: float = 5.0) -> float:
        """Poll P5.007 until PR#n reached `state` (or later); seconds waited."""
        if state not in STATES:
            raise ValueError(f"state {state!r}: one of {', '.join(STATES)}")
        t0 = self._clock()
        while True:
            got, st = self.status()
            if got == n and STATES[st] >= STATES[state]:
                return self._clock() - t0
            left = timeout_s - (self._clock() - t0)
            if left <= 0:
                raise TimeoutError(f"PR#{n} not {state} after {timeout_s:g} s "
                                   f"(P5.007 says PR#{got} {st})")
            self._sleep(min(self.poll_s, left))  # the last look at the timeout itself


__all__ = ["STATES", "DeltaPr", "PrTableError", "table_words"]
