"""P5.016 and the 32-bit status monitor registers, from the manual (seed 002; found by an
outside probe, helper-127)."""

from __future__ import annotations

from hil.model.drive import Drive
from hil.units import MS

REV = 16_777_216


def _at(d: Drive, counts: float) -> None:
    d.axis.position = d.axis.demand = float(counts)
    d.advance(2 * MS)


def test_p5016_is_the_cn2_feedback_plus_an_offset() -> None:
    """L11284-11286: read, the CN2 feedback position, monitor 000 + an offset; a write of
    any value only adjusts the offset. It held a fixed value."""
    d = Drive(inputs={8: True}, params={"P1.001": 0x0001})
    d.advance(5 * MS)
    d.params.write("P0.017", 0)  # P0.009 shows monitor 000, Fb_PUU
    _at(d, REV)  # one turn: 100 000 PUU with the factory gear
    assert d.params.read("P0.009") == 100_000
    assert d.params.read("P5.016") == 100_000
    d.params.write("P5.016", 500)
    assert d.params.read("P5.016") == 500
    _at(d, REV * 1.5)
    assert d.params.read("P5.016") == 500 + 50_000
    assert d.params.read("P0.009") == 150_000  # monitor 000 untouched


def test_a_status_monitor_register_wraps_at_32_bits() -> None:
    """P0.009 is 32-bit (L7150); PUU wraps 2147483647 -> -2147483648 (L16417). It read
    2147488648 where 6064h read -2147478648."""
    d = Drive(inputs={8: True}, params={"P1.001": 0x0001})
    d.advance(5 * MS)
    d.params.write("P0.017", 0)
    _at(d, (2**31 + 5000) * REV / 100_000)
    v = d.params.read("P0.009")
    assert -(2**31) <= v < 2**31
    assert v == -(2**31) + 5000
