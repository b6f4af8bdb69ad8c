"""Virtual bench mechanics: what the motor shaft is connected to.

Pure data plus three cheap queries. Positions are **physical motor encoder counts** (the
A3 encoder has 16777216 counts per revolution, L16406, L18414); the fields that describe
the bench are given in motor revolutions because that is how a bench is measured.

Defaults describe a horizontal axis on a 10 mm/rev ball screw with about 1 m of travel:
limit switches at -45 / +45 rev, hard stops at -48 / +48 rev, home sensor (ORGP) between
-0.5 and +0.5 rev, index (Z) pulse at angle 0 of every revolution, no gravity load, and a
motor like the ECM-A3L 0604 (1.27 N·m rated, 3000 rpm rated, 6000 rpm max). A bench file
overrides any field (see `Mechanics.from_dict`).

Sign convention: positive counts = positive direction (towards PL). `gravity_torque` is the
torque the load exerts on the motor, positive pulling towards negative counts (so a vertical
axis whose brake is released without torque falls towards NL / the negative hard stop).

API::

    m = Mechanics(**bench_values)
    m.counts_per_rev                      # 16777216
    m.limit_states(pos_counts) -> (nl, pl)  # physical switch actuated
    m.home_sensor(pos_counts) -> bool       # ORGP cam actuated
    m.index_crossed(a, b) -> list[float]    # Z pulse positions passed when moving a -> b
    m.hard_stop_counts -> (neg | None, pos | None)
    m.total_inertia, m.counts_per_rad
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

COUNTS_PER_REV = 16_777_216  # A3 encoder, 24 bit per revolution (L16406, L18414)


@dataclass
class Mechanics:
    """Mechanical data of one virtual axis (motor + load + switches)."""

    motor_inertia: float = 0.277e-4  # kg·m² (ECM-A3L 0604 class)
    load_inertia: float = 1.0e-4  # kg·m², reflected to the motor shaft
    friction_torque: float = 0.03  # N·m, Coulomb friction (opposes motion, also static)
    load_torque: float = 0.0  # N·m, constant process load (positive opposes + motion)
    gravity_torque: float = 0.0  # N·m, vertical axes: load pulls towards negative counts
    rated_torque: float = 1.27  # N·m, 100.0 % torque (6071h/6077h unit 0.1 % of it)
    rated_current: float = 2.6  # A rms, for 6075h (0.1 mA) and 6078h
    rated_speed: float = 3000.0  # rpm (P1.055 default = rated speed, L6882)
    max_speed: float = 6000.0  # rpm, physical limit of the motor
    dynamic_brake_torque: float = 1.0  # N·m at rated speed (shorted windings, ~ speed)
    counts_per_rev: int = COUNTS_PER_REV
    nl_rev: float = -45.0  # NL switch actuated at and below this position
    pl_rev: float = 45.0  # PL switch actuated at and above this position
    hard_stop_neg_rev: float | None = -48.0  # None = no hard stop
    hard_stop_pos_rev: float | None = 48.0
    home_lo_rev: float = -0.5  # ORGP actuated for home_lo_rev <= pos <= home_hi_rev
    home_hi_rev: float = 0.5
    index_angle: float = 0.0  # Z pulse angle as a fraction of a revolution, 0 <= a < 1
    # Brake mechanics (bench data; Appendix A gives <= 70 ms max for both,
    # L20493-20494, L20777-20778; which column is which is ambiguous, keep them swappable).
    brake_release_ms: float = 20.0  # coil energised -> shaft free
    brake_engage_ms: float = 50.0  # coil off -> shaft clamped
    brake_holding_torque: float = 1.3  # N·m (ECM-A3L 0602/0604, L20485-20494)
    # Bench wiring of the brake coil's relay: DO line 1-6 it hangs on; "auto" = the DO that
    # BRKR is mapped to at power-up (bench wired per the drive's configuration); None = no
    # brake wired (the shaft is never held). An unmapped BRKR controls nothing (L15286).
    brake_do: int | str | None = "auto"

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name == "brake_do" or v is None:
                continue
            if isinstance(v, bool) or not isinstance(v, int | float):
                raise ValueError(f"Mechanics.{f.name}: {v!r} is not a number")
            if not math.isfinite(v):
                raise ValueError(f"Mechanics.{f.name}: {v} is not a finite number")
        if self.counts_per_rev <= 0:
            raise ValueError(f"Mechanics.counts_per_rev: must be > 0, got {self.counts_per_rev}")
        if self.motor_inertia + self.load_inertia <= 0:
            raise ValueError("Mechanics inertia: motor_inertia + load_inertia must be > 0")
        if self.rated_torque <= 0 or self.rated_speed <= 0 or self.max_speed <= 0:
            raise ValueError("Mechanics: rated_torque, rated_speed and max_speed must be > 0")
        if self.nl_rev >= self.pl_rev:
            raise ValueError(f"Mechanics: nl_rev {self.nl_rev} must be below pl_rev {self.pl_rev}")
        if self.home_lo_rev > self.home_hi_rev:
            raise ValueError("Mechanics: home_lo_rev must not exceed home_hi_rev")
        if not 0.0 <= self.index_angle < 1.0:
            raise ValueError(f"Mechanics.index_angle: must be in [0, 1), got {self.index_angle}")
        neg, pos = self.hard_stop_neg_rev, self.hard_stop_pos_rev
        if neg is not None and pos is not None and neg >= pos:
            raise ValueError("Mechanics: hard_stop_neg_rev must be below hard_stop_pos_rev")
        bdo = self.brake_do
        if not (bdo is None or bdo == "auto" or (type(bdo) is int and 1 <= bdo <= 6)):
            raise ValueError(f"Mechanics.brake_do: 1-6, 'auto' or null, got {bdo!r}")
        if self.friction_torque < 0 or self.dynamic_brake_torque < 0:
            raise ValueError("Mechanics: friction_torque and dynamic_brake_torque must be >= 0")
        for name in ("motor_inertia", "load_inertia", "brake_release_ms", "brake_engage_ms",
                     "brake_holding_torque"):  # a negative one ran, with a meaningless motion
            if getattr(self, name) < 0:
                raise ValueError(f"Mechanics.{name}: must be >= 0, got {getattr(self, name)}")
        if self.rated_current <= 0:
            raise ValueError(f"Mechanics.rated_current: must be > 0, got {self.rated_current}")
        if self.counts_per_rev != int(self.counts_per_rev):
            raise ValueError(f"Mechanics.counts_per_rev: a whole number of counts, got "
                             f"{self.counts_per_rev}")

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> Mechanics:
        """Build from a bench-file mapping; unknown keys are an error naming the key."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise ValueError(f"Mechanics: unknown field(s) {unknown}; known: {sorted(known)}")
        return cls(**values)

    # ---- derived values -------------------------------------------------------------
    @property
    def total_inertia(self) -> float:
        """Motor + load inertia seen by the motor (kg·m²)."""
        return self.motor_inertia + self.load_inertia

    @property
    def counts_per_rad(self) -> float:
        return self.counts_per_rev / (2.0 * math.pi)

    def rev_to_counts(self, rev: float) -> float:
        return rev * self.counts_per_rev

    @property
    def hard_stop_counts(self) -> tuple[float | None, float | None]:
        """Hard stop positions in counts (None where the axis has none)."""
        neg, pos = self.hard_stop_neg_rev, self.hard_stop_pos_rev
        cpr = self.counts_per_rev
        return (None if neg is None else neg * cpr, None if pos is None else pos * cpr)

    # ---- switches and encoder marks -------------------------------------------------
    def limit_states(self, pos_counts: float) -> tuple[bool, bool]:
        """(NL, PL) physical switch actuated at this position (before any a/b contact logic)."""
        rev = pos_counts / self.counts_per_rev
        return rev <= self.nl_rev, rev >= self.pl_rev

    def home_sensor(self, pos_counts: float) -> bool:
        """ORGP cam actuated at this position."""
        rev = pos_counts / self.counts_per_rev
        return self.home_lo_rev <= rev <= self.home_hi_rev

    def index_crossed(self, pos_a: float, pos_b: float) -> list[float]:
        """Z-pulse positions (counts) passed when moving from `pos_a` to `pos_b`, in travel order.

        The interval is half-open at the start, (a, b] moving positive and [b, a) moving
        negative, so consecutive steps never report one pulse twice.
        """
        if pos_a == pos_b:
            return []
        cpr = self.counts_per_rev
        off = self.index_angle * cpr
        if pos_b > pos_a:
            k = math.floor((pos_a - off) / cpr) + 1
            out = []
            p = k * cpr + off
            while p <= pos_b:
                out.append(p)
                p += cpr
            return out
        k = math.ceil((pos_a - off) / cpr) - 1
        out = []
        p = k * cpr + off
        while p >= pos_b:
            out.append(p)
            p -= cpr
        return out
