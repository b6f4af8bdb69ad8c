"""Time units: every time in hil is integer nanoseconds, and these are the one definition of
its units (the model, the faces, the drivers, the timing checker and the gateway alike)."""

NS = 1  # one nanosecond
US = 1_000  # ns per microsecond
MS = 1_000_000  # ns per millisecond
S = 1_000_000_000  # ns per second

__all__ = ["MS", "NS", "US", "S"]
