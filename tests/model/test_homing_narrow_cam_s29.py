"""An edge that is the home itself, on a home cam narrower than the slowdown from the switch
search speed, written from the manual (seed 002; found by an outside probe, helper-119).

L4292: once the reference is detected the drive runs the low-speed phase to find it
precisely; L4336: the start point does not change the result. 6099h sub 1 is the speed of
the switch search, sub 2 that of the slow phase (L18992-19007). With a 0.2 rev cam, 200 and
30 rpm and a 3000 ms ramp (609Ah), the slowdown from 200 rpm (about 0.33 rev) is longer than
the cam: the far edge was latched while the axis still ran at up to 130 rpm, so the home moved
with the start by that speed x the 2 ms DI filter (P2.009). Expected edges are CiA 402's:
23 (as 7) and 30 (as 14) the cam's lower edge, 26 (as 10) and 27 (as 11) its upper edge.
"""

from __future__ import annotations

import pytest

from hil.model.drive import Drive
from hil.model.mechanics import Mechanics
from hil.units import MS

COUNTS = 16_777_216
LO, HI = -0.9, -0.7  # the cam (rev), 0.2 rev wide
STARTS = (-2.0, -0.8, 1.5)  # below the cam, on it, above it (rev)
# one slow-phase filter delay: 30 rpm x 2 ms = 0.001 rev, plus the 1 ms step
TOL = 0.0015
# DI9 = ORGP (a), DI10 = SHOM (a); EMGS (DI8, b) closed
IO = {"P2.036": 0x0124, "P2.037": 0x0127}


def _mech(s: float) -> Mechanics:
    return Mechanics(nl_rev=-3.3 - s, pl_rev=3.7 - s, hard_stop_neg_rev=-6.0 - s,
                     hard_stop_pos_rev=6.0 - s, home_lo_rev=LO - s, home_hi_rev=HI - s,
                     index_angle=(0.6 - s) % 1.0)


def _run(d: Drive) -> None:
    for _ in range(1200):
        d.advance(50 * MS)
        if not d.homing.active and not d.axis.moving:
            return
    raise AssertionError(f"homing did not end: phase {d.homing.phase}")


def _canopen(method: int, s: float) -> float:
    d = Drive(mechanics=_mech(s), inputs={8: True}, params=IO | {"P1.001": 0x0C})
    w = d.write_object
    w(0x6060, 0, 6)
    w(0x6098, 0, method)
    w(0x6099, 1, 2000)  # 200 rpm switch search
    w(0x6099, 2, 300)  # 30 rpm slow phase
    w(0x609A, 0, 3000)  # ms per 3000 rpm
    for cw in (0x06, 0x07, 0x0F):
        w(0x6040, 0, cw)
    d.advance(100 * MS)
    w(0x6040, 0, 0x1F)
    _run(d)
    assert d.read_object(0x6041, 0) & 0x3000 == 0x1000  # attained, no error
    return d.homing.home_counts / COUNTS + s


@pytest.mark.parametrize(("method", "edge"), [(23, LO), (26, HI), (27, HI), (30, LO)])
def test_canopen_edge_home_is_one_point_from_every_start(method: int, edge: float) -> None:
    homes = [_canopen(method, s) for s in STARTS]
    assert all(abs(h - edge) <= TOL for h in homes), homes
    assert max(homes) - min(homes) <= TOL, homes


def test_pr_org_edge_home_is_one_point_from_every_start() -> None:
    """P5.004 X = 6 (ORG, forward), Y = 2 (no Z): the home is where ORG goes off going
    forward, the cam's upper edge (L4356), at the P5.006 speed, with DEC1 = P5.022."""
    homes = []
    for s in (-2.0, -0.8):
        d = Drive(mechanics=_mech(s), inputs={8: True},
                  params=IO | {"P1.001": 0x01, "P5.004": 0x126, "P5.005": 2000,
                               "P5.006": 300, "P6.000": 2 << 12, "P5.022": 3000})
        d.set_di(1, True)  # SON
        d.advance(100 * MS)
        d.set_di(10, True)  # SHOM
        _run(d)
        homes.append(d.homing.home_counts / COUNTS + s)
    assert all(abs(h - HI) <= TOL for h in homes), homes
    assert max(homes) - min(homes) <= TOL, homes
