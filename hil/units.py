"""Time units: every time in hil is integer nanoseconds, and these are the one definition of
its units (the model, the faces, the drivers, the timing checker and the gateway alike)."""

NS = 1  # one nanosecond
US = 1_000  # ns per microsecond
MS = 1_000_000  # ns per millisecond
S = 1_000_000_000  # ns per second



def fmt_ms(ns: int | float) -> str:
    """`ns` as milliseconds for a label: as short as `:g` but never in e-notation (a
    `wait: 3000s` step read "wait 3e+06ms")."""
    return f"{ns / MS:.12g}"


__all__ = ["MS", "NS", "US", "S", "fmt_ms"]
