"""Time units: every time in hil is integer nanoseconds, and these are the one definition of
its units (the model, the faces, the drivers, the timing checker and the gateway alike); and
`s32`, the one reading of a signed 32-bit register."""

NS = 1  # one nanosecond
US = 1_000  # ns per microsecond
MS = 1_000_000  # ns per millisecond
S = 1_000_000_000  # ns per second



def fmt_ms(ns: int | float) -> str:
    """`ns` as milliseconds for a label: as short as `:g` but never in e-notation (a
    `wait: 3000s` step read "wait 3e+06ms")."""
    return f"{ns / MS:.12g}"


def s32(n: float) -> float:
    """`n` as a signed 32-bit register holds it: past ±2^31 it wraps (an unsigned 32-bit
    value reads signed; an int stays an int, a float keeps its fraction)."""
    return (n + 0x80000000) % 0x100000000 - 0x80000000


__all__ = ["MS", "NS", "US", "S", "fmt_ms", "s32"]
