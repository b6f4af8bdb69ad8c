"""The CAPTURE and COMPARE axes as the manual gives them, written from the manual (helper-95):

- P5.037 and P5.057 are 32-bit registers, -2147483648 .. +2147483647 (L11482, L11705), and so
  is each data-array entry (L5097): past +2^31 - 1 the axis reads -2^31, and a compare point
  there fires when the axis passes it.
- COMPARE fires when the axis passes a point ("通過", L5093; "運行至", L5215). Setting the
  axis past a point (CAPTURE bit1's first-point reset to P5.076, L5157; a write of P5.037)
  passes nothing: the point fires when the axis itself later reaches it.
"""

from __future__ import annotations

from hil.model.drive import Drive
from hil.units import MS

I32_MAX = 2**31 - 1


def make() -> Drive:
    """DO4 mapped to nothing (P2.021 = 0): COMPARE's output alone."""
    return Drive(inputs={8: True, 6: True, 7: True}, params={"P2.021": 0})


def pv(d: Drive, rpm: float) -> None:
    """CiA 402 profile velocity (L17299) at `rpm`, past its ramp."""
    d.write_object(0x6060, 0, 3)
    for cw in (6, 7, 15):
        d.write_object(0x6040, 0, cw)
        d.advance(2 * MS)
    d.write_object(0x60FF, 0, round(rpm * 10))
    d.advance(400 * MS)


def compare_on_capture_axis(d: Drive, point: int) -> None:
    """P5.059.Y = 0 (the capture axis, L11744), one point from Arr[50], started."""
    d.params.write("P5.059", 0x00010000)
    d.array[50] = point
    d.params.write("P5.056", 50)
    d.params.write("P5.058", 1)
    d.params.write("P5.059", 0x00010001)


def capture_edge(d: Drive) -> None:
    d.set_di(7, False)  # NO contact: the closing edge latches (L5150)
    d.advance(1 * MS)
    d.set_di(7, True)
    d.advance(1 * MS)


def reset_run(start: int, reset: int) -> Drive:
    """The capture axis on CN5 at `start`, a COMPARE point at 20000 on it, the axis moving
    forward at 10000 PUU/s, and CAPTURE armed with bit1: its first point resets the axis to
    P5.076 = `reset` (L5157)."""
    d = make()
    d.params.write("P5.039", 0x0010)  # capture axis CN5, stopped
    d.params.write("P5.037", start)
    compare_on_capture_axis(d, 20000)
    pv(d, 6.0)
    d.params.write("P5.076", reset)
    d.params.write("P5.038", 1)
    d.params.write("P5.039", 0x0013)
    return d


def test_a_first_point_reset_over_a_pending_point_does_not_fire_it() -> None:
    d = reset_run(40000, 0)
    before = d.params.read("P5.037")
    capture_edge(d)
    after = d.params.read("P5.037")
    assert before > 40000 and 0 <= after < 100, (before, after)  # set back over 20000
    assert d.compare.fired == []
    d.advance(3000 * MS)  # the axis now runs through 20000 itself
    assert [g for _t, _i, g in d.compare.fired] == [20000]


def test_a_first_point_reset_up_over_a_pending_point_does_not_fire_it() -> None:
    d = reset_run(0, 50000)
    capture_edge(d)
    assert 50000 <= d.params.read("P5.037") < 50100
    d.advance(500 * MS)
    assert d.compare.fired == []  # 20000 lies behind the axis now


def test_a_write_of_p5037_over_a_pending_point_does_not_fire_it() -> None:
    d = make()
    d.params.write("P5.039", 0x0010)
    d.params.write("P5.037", 0)
    compare_on_capture_axis(d, 20000)
    pv(d, 6.0)
    d.params.write("P5.037", 50000)  # capture stopped: writable (L11485)
    d.advance(50 * MS)
    assert d.compare.fired == []


def test_the_capture_axis_and_its_array_entries_wrap_at_32_bits() -> None:
    d = make()
    d.params.write("P5.039", 0x0010)
    d.params.write("P5.037", I32_MAX - 1000)
    pv(d, 6.0)  # 10000 PUU/s: past +2^31 - 1 within the settle
    axis = d.params.read("P5.037")
    assert -(2**31) <= axis < -(2**31) + 5000, axis
    d.params.write("P5.036", 0)
    d.params.write("P5.038", 1)
    d.params.write("P5.039", 0x0011)
    capture_edge(d)
    value = d.array[0]
    assert -(2**31) <= value < -(2**31) + 5000, value
    assert d.params.read("P5.037") - value < 100  # the same axis, read a moment later


def test_a_compare_point_past_the_wrap_fires_when_the_axis_gets_there() -> None:
    d = make()
    d.params.write("P5.039", 0x0010)
    d.params.write("P5.037", I32_MAX - 6000)  # 0.6 s below the wrap at 10000 PUU/s
    point = -(2**31) + 2296
    compare_on_capture_axis(d, point)
    pv(d, 6.0)
    assert d.compare.fired == []  # still below +2^31 - 1 (the ramp and 400 ms)
    d.advance(1000 * MS)
    assert [g for _t, _i, g in d.compare.fired] == [point]
    assert d.params.read("P5.057") > point


def test_after_a_power_cycle_cap_ok_is_off_and_the_counts_read_as_written() -> None:
    """CAP_OK means a capture is done (L15323): a drive just powered up has done none. The
    counts P5.038 / P5.058 count down as the points come (L5155, L11496, L11724): a running
    count, not a new setting, so a power cycle reads back what was written and the capture
    can be armed again at once (helper-95: CAP_OK stayed on, P5.038 read 0 and refused)."""
    d = make()
    d.params.write("P5.038", 2)
    d.params.write("P5.039", 0x0031)  # CN2, start
    capture_edge(d)
    capture_edge(d)
    assert d.params.read("P5.038") == 0 and d.dio.do_function_state("CAP_OK")
    d.params.write("P5.058", 1)
    compare_on_capture_axis(d, 10**6)  # P5.058 1, started: not reached
    d.power_cycle(off_for=100 * MS)
    d.advance(50 * MS)
    assert not d.dio.do_function_state("CAP_OK")
    assert d.params.read("P5.038") == 2 and d.params.read("P5.058") == 1
    d.params.write("P5.039", 0x0031)  # armed again with the count as written
    assert d.capture.running


def test_the_masking_range_works_past_the_wrap() -> None:
    """P1.020 masks a capture within that many pulses of the last (L8156). Past the 32-bit
    wrap the last value is stored wrapped: the distance is taken on the 32-bit axis too
    (helper-99: two edges 120 PUU apart were both stored)."""
    for start in (0, I32_MAX - 1000):
        d = make()
        d.params.write("P5.039", 0x0010)
        d.params.write("P5.037", start)
        pv(d, 6.0)
        d.params.write("P1.020", 1000)
        d.params.write("P5.036", 0)
        d.params.write("P5.038", 3)
        d.params.write("P5.039", 0x0011)
        capture_edge(d)
        d.advance(10 * MS)
        capture_edge(d)
        assert len(d.capture.values) == 1, (start, d.capture.values)
