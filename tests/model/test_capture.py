"""CAPTURE (A3 §7.2.2, L5148-5176, P5.036-P5.039 L11471-11542) and COMPARE (§7.2.3,
L5186-5215, P5.056-P5.059 L11692-11781) on the injected clock."""

from __future__ import annotations

import itertools

import pytest

from hil.model.drive import Drive
from hil.model.errors import OutOfRange, ParamError
from hil.model.options import ModelOptions
from hil.profile.pr import encode
from hil.units import MS

PUU_PER_REV = 100000  # factory gear (L6879-6880)


def make(capture: dict | None = None, **params: int) -> Drive:
    opts = ModelOptions(extra={"capture": capture} if capture else {})
    return Drive(options=opts, inputs={8: True, 6: True, 7: True}, params=params or None)


def make_cmp(capture: dict | None = None) -> Drive:
    """DO4 mapped to nothing: after COMPARE it is low (not TPOS, the factory function)."""
    return make(capture, **{"P2.021": 0})


def pv(d: Drive, rpm: float) -> None:
    """CiA 402 profile velocity (L17299): enable, 60FFh in 0.1 rpm, run to speed."""
    d.write_object(0x6060, 0, 3)
    for cw in (6, 7, 15):
        d.write_object(0x6040, 0, cw)
        d.advance(2 * MS)
    assert d.servo_on
    d.write_object(0x60FF, 0, round(rpm * 10))
    d.advance(400 * MS)  # past the ramp: constant speed


def fb_puu(d: Drive) -> float:
    """The motor position now, as the encoder reads it between two motion steps too."""
    return (d.feedback_counts() - d.axis.origin) * 100000 / 16777216


def arm(d: Drive, start: int = 0, count: int = 1, ctrl: int = 0x0031) -> None:
    """P5.036 start, P5.038 count, P5.039 (default: CN2, NO, U = 0, start)."""
    d.params.write("P5.036", start)
    d.params.write("P5.038", count)
    d.params.write("P5.039", ctrl)


def test_di7_capture_latches_position_5us_after_the_edge() -> None:
    """L5150: DI7 in hardware, 5 µs; L5155: P5.038 counts down, CAP_OK, bit0 clears."""
    d = make()
    pv(d, 300.0)
    arm(d, start=100, count=2)
    assert not d.dio.do_function_state("CAP_OK")
    d.advance(123_456)
    d.set_di(7, False)  # NO: the closing edge latches, opening does nothing
    d.advance(3 * MS)
    v = d.axis.velocity * 100000 / 16777216  # PUU/s
    want = fb_puu(d) + v * 5e-6
    t_edge = d.now
    d.set_di(7, True)
    assert d.pr.array[100] == 0  # not yet: the latch acts 5 µs after the edge
    d.advance(10_000)
    assert d.pr.array[100] == round(want)
    assert d.capture.values[0][0] == t_edge + 5000
    assert d.params.read("P5.038") == 1 and d.params.read("P5.039") & 1
    d.advance(7 * MS)
    d.set_di(7, False)
    d.advance(3 * MS)
    d.set_di(7, True)
    d.advance(MS)
    assert d.pr.array[101] != 0 and d.pr.array[101] > d.pr.array[100]
    assert d.dio.do_function_state("CAP_OK")
    assert not d.params.read("P5.039") & 1  # bit0 cleared at the last point
    assert d.pr.capture_puu == d.pr.array[101]  # base of CAP commands (L4471)


def test_nc_trigger_and_di7_function_masked() -> None:
    """P5.039.Z = 1 NC latches on the opening (L11530); DI7 feeds no function while CAPTURE
    runs (L5150): the PL limit (DI7 b-contact) does not trip AL015."""
    d = make()
    pv(d, 100.0)
    arm(d, count=2, ctrl=0x0131)
    d.set_di(7, False)  # opening: the NC trigger, and without CAPTURE it would be PL
    d.advance(20 * MS)
    assert "AL015" not in d.alarms.active
    assert len(d.capture.values) == 1
    d.set_di(7, True)
    d.advance(5 * MS)
    d.set_di(7, False)  # second point: CAPTURE ends, DI7 is PL again (open: the limit)
    d.advance(20 * MS)
    assert len(d.capture.values) == 2 and d.dio.do_function_state("CAP_OK")
    assert "AL015" in d.alarms.active


def test_minimum_interval_and_masking_range() -> None:
    """P5.039.U (ms, L11531) and P1.020 masking range when P5.038 > 1 (L8156)."""
    d = make()
    pv(d, 300.0)  # 500 000 PUU/s
    arm(d, count=3, ctrl=0x2031)  # U = 2 ms
    for _ in range(2):
        d.set_di(7, False)
        d.advance(500_000)
        d.set_di(7, True)  # the second closing is 0.5 ms after the first: ignored
        d.advance(500_000)
    assert len(d.capture.values) == 1
    d.params.write("P5.039", 0)
    d.params.write("P1.020", 5000)  # 10 ms of travel
    arm(d, count=3, ctrl=0x0031)
    for _ in range(3):
        d.set_di(7, False)
        d.advance(4 * MS)
        d.set_di(7, True)  # 4 ms apart = 2000 PUU < 5000: masked after the first
    assert len(d.capture.values) == 2


def test_first_point_reset_cyclic_and_pr50() -> None:
    """The manual's example (L5172-5176): start #100, 3 points, P5.076 = 0, cyclic, reset
    the CN2 axis at the first point, PR#50 after each cycle (bit3)."""
    d = make(**{"P1.001": 0x0001})
    d.set_di(1, True)
    d.advance(10 * MS)
    definition, data = encode("speed", 500)  # PR#1: 50 rpm
    d.params.write("P6.002", definition)
    d.params.write("P6.003", data)
    d.params.write("P5.007", 1)
    d.advance(300 * MS)
    d.params.write("P5.076", 0)
    d.params.write("P1.019", 0x0001)
    arm(d, start=100, count=3, ctrl=0x003B)  # bit0 + bit1 + bit3, CN2
    for _ in range(4):
        d.set_di(7, False)
        d.advance(5 * MS)
        d.set_di(7, True)
        d.advance(5 * MS)
    assert d.capture.values[0][2] == 0  # reset to P5.076
    assert abs(fb_puu(d) - 4 * 10 * MS * 83.333e-6) < 5e3  # the motor axis was redefined
    assert d.pr.array[101] > 0 and d.pr.array[102] > d.pr.array[101]
    assert d.pr.array[100] > d.pr.array[102]  # 4th point: overwrote #100, no reset (L5176)
    assert any("trigger:CAPTURE:50" in w for _t, w in d.pr.trace)
    assert d.params.read("P5.039") & 1  # cyclic: still armed


def test_refusals_while_running_and_pr_write_alarm() -> None:
    """Only 0 may be written to P5.039 while bit0 = 1 (L5155); P5.036/P5.037 only while
    stopped (L11476, L11485); CN2: P5.037 = Fb_PUU, not writable. A PR WRITE of a refused
    value raises AL213 (L20044-20081)."""
    d = make(**{"P1.001": 0x0001})
    arm(d, count=2)
    for name, value in (("P5.039", 0x0031), ("P5.036", 5), ("P5.038", 3)):
        with pytest.raises(ParamError):
            d.params.write(name, value)
    d.params.write("P5.039", 0x0030)  # stop, CN2 stays
    with pytest.raises(ParamError):
        d.params.write("P5.037", 7)  # CN2
    d.params.write("P5.039", 0x0010)  # CN5, stopped: writable
    d.params.write("P5.037", 7)
    assert d.params.read("P5.037") == 7
    arm(d, count=2, ctrl=0x0011)
    d.set_di(1, True)
    d.advance(10 * MS)
    definition, data = encode("write", 0x0011, dest="P5.039", source="constant")
    d.params.write("P6.004", definition)
    d.params.write("P6.005", data)
    d.params.write("P5.007", 2)
    d.advance(5 * MS)
    assert "AL213" in d.alarms.active


def test_z_trigger_latches_the_index_positions() -> None:
    """`trigger: Z` (bench choice): one capture per motor revolution at the Z mark."""
    d = make({"trigger": "Z"})
    pv(d, 600.0)
    truth: list[float] = []
    d.subscribe(lambda e: type(e).__name__ == "ZPulse" and truth.append(e.position_puu))
    arm(d, start=10, count=3)
    d.advance(350 * MS)  # 10 rev/s: 3 Z pulses in 300 ms
    vals = [v for _t, _a, v in d.capture.values]
    assert len(vals) == 3 and len(truth) == 3
    assert [b - a for a, b in itertools.pairwise(vals)] == [PUU_PER_REV] * 2
    # 1 000 000 PUU/s x 5 µs = 5 PUU after the mark
    assert all(abs(v - z - 5) <= 1 for v, z in zip(vals, truth, strict=True))


def test_capture_delay_knob() -> None:
    """Deviation `dev_capture_delay_us`: the latch lags the edge."""
    d = make({"dev_capture_delay_us": 1000})
    pv(d, 300.0)
    arm(d)
    want = fb_puu(d)
    d.set_di(7, False)
    d.set_di(7, True)
    d.advance(2 * MS)
    assert d.pr.array[0] - want > 400  # 1 ms at 500 000 PUU/s


# ---- COMPARE -----------------------------------------------------------------------------

def arm_compare(d: Drive, points: list[int], ctrl: int = 0x00640001, start: int = 50) -> None:
    """Array[start..] = points, P5.058 = len, P5.059 (default: 100 ms, capture axis, start)."""
    for i, x in enumerate(points):
        d.pr.array[start + i] = x
    d.params.write("P5.056", start)
    d.params.write("P5.058", len(points))
    d.params.write("P5.059", ctrl)


def do4_edges(d: Drive, dt_ms: int) -> list[tuple[int, bool]]:
    edges: list[tuple[int, bool]] = []
    d.subscribe(lambda e: getattr(e, "n", None) == 4 and type(e).__name__ == "DoChanged"
                and edges.append((e.t, e.level)))
    d.advance(dt_ms * MS)
    return edges


@pytest.mark.parametrize("rpm", [60.0, 300.0, -300.0])
def test_compare_pulses_at_the_table_positions(rpm: float) -> None:
    """L5188: DO4 in 5 µs when the compare axis equals Array[P5.056+i]; CBA ms wide
    (L11770); example Arr[50..52] = 20000/30000/40000 (L5213-5215), both directions."""
    d = make_cmp()
    d.params.write("P5.039", 0x0030)  # capture axis on CN2 (Fb_PUU), not running
    pv(d, rpm)
    here = d.compare.position()
    sign = 1 if rpm > 0 else -1
    pts = [round(here) + sign * k for k in (20000, 30000, 40000)]
    arm_compare(d, pts, ctrl=0x000A0001)  # 10 ms pulses
    v = d.compare.velocity()
    t0 = d.now
    edges = do4_edges(d, 1000)
    rises = [t for t, lv in edges if lv]
    falls = [t for t, lv in edges if not lv]
    assert len(rises) == 3 and len(falls) == 3
    for tgt, t in zip(pts, rises, strict=True):
        want = t0 + abs(tgt - here) / abs(v) * 1e9 + 5000
        assert abs(t - want) < 2000, (t, want)  # exact instant, not the 1 ms step grid
    assert all(f - r == 10 * MS for r, f in zip(rises, falls, strict=True))
    assert not d.params.read("P5.059") & 1  # bit0 cleared after the last point
    assert d.params.read("P5.058") == 0  # "直到數目為 0" (L11722)


def test_compare_shift_autozero_and_last_point_actions() -> None:
    """CMP_DATA = Array + P1.023 + P1.024, P1.024 once with P1.019.Z (L8217-8240); bit3
    zeroes P5.057 after the last point (L11746), NC polarity (L11758)."""
    d = make_cmp()
    d.params.write("P5.039", 0x0030)
    d.params.write("P1.023", 40)
    d.params.write("P1.024", 1000)
    d.params.write("P1.019", 0x0100)
    pv(d, 60.0)  # 100 000 PUU/s
    here = round(d.compare.position())
    arm_compare(d, [here + 2000, here + 5000], ctrl=0x00050109)  # 5 ms, NC, bit3
    assert d.do(4)  # NC: conducts while idle
    d.advance(100 * MS)
    hits = [tgt for _t, _i, tgt in d.compare.fired]
    assert hits == [here + 3040, here + 5040]  # P1.024 used once
    assert d.params.read("P1.024") == 0
    assert abs(d.params.read("P5.057")) < 100 * 1000  # zeroed at the last point
    assert d.params.read("P5.057") < here


def test_compare_knobs() -> None:
    """Deviations: late match, longer pulse, positive direction only."""
    d = make_cmp({"dev_compare_late": 500, "dev_compare_width_extra_ms": 3})
    d.params.write("P5.039", 0x0030)
    pv(d, 60.0)
    here = round(d.compare.position())
    t0 = d.now
    arm_compare(d, [here + 1000], ctrl=0x000A0001)
    edges = do4_edges(d, 100)
    assert edges[1][0] - edges[0][0] == 13 * MS
    assert edges[0][0] - t0 > 14 * MS  # 1500 PUU at 100 000 PUU/s
    d = make_cmp({"dev_compare_positive_only": True})
    d.params.write("P5.039", 0x0030)
    pv(d, -60.0)
    arm_compare(d, [round(d.compare.position()) - 1000])
    assert not do4_edges(d, 100)


def test_count_ends_at_zero_and_must_be_rewritten() -> None:
    """P5.038 counts down to 0, where CAPTURE ends (L5155); it must be > 0 for CAPTURE to act
    (L5153): bit0 = 1 with P5.038 = 0 is refused, a new count re-arms."""
    d = make()
    arm(d, count=1)
    d.set_di(7, False)
    d.set_di(7, True)
    d.advance(MS)
    assert d.params.read("P5.038") == 0 and not d.params.read("P5.039") & 1
    with pytest.raises(ParamError, match=r"P5\.038 is 0"):
        d.params.write("P5.039", 0x0031)
    arm(d, count=1)
    assert d.capture.running


def test_set_di_edge_is_ground_truth() -> None:
    """Every terminal edge set through `Drive.set_di` is an `InputChanged` event at its
    instant (the virtual world records a state sample there: the latch's ground truth)."""
    d = make()
    seen: list = []
    d.subscribe(lambda e: type(e).__name__ == "InputChanged" and seen.append((e.t, e.n,
                                                                               e.closed)))
    d.advance(1_234_567)
    d.set_di(7, False)
    d.set_di(7, False)  # no edge
    d.set_di(3, True)
    assert seen == [(1_234_567, 7, False), (1_234_567, 3, True)]


def test_compare_cyclic_pr45_and_capture_chain() -> None:
    """P5.059 bit1 cyclic reload (L11742), bit2 starts CAPTURE after the last point with its
    previous count (L11744), U bit0 PR#45 (L11762); P5.039 bit2 starts COMPARE at the first
    capture (L5157)."""
    d = make(**{"P2.021": 0, "P1.001": 0x0001})  # PR mode: PR#45 may start (L11168)
    d.params.write("P5.039", 0x0030)
    d.params.write("P5.038", 2)
    pv(d, 60.0)  # 100 000 PUU/s
    here = round(d.compare.position())
    d.pr.array[50] = here + 1000
    d.pr.array[51] = here + 2000
    d.params.write("P5.056", 50)
    d.params.write("P5.058", 2)
    d.params.write("P5.059", 0x00011007)  # 1 ms, PR#45, start capture, cyclic, start
    d.advance(25 * MS)
    assert len(d.compare.fired) == 2
    assert d.capture.running and d.params.read("P5.038") == 2  # started by COMPARE
    assert d.compare.running and d.params.read("P5.058") == 2  # cyclic: reloaded
    assert any("trigger:COMPARE:45" in w for _t, w in d.pr.trace)
    d.params.write("P5.059", 0x00011006)  # stop COMPARE (0 in bit0)
    d.params.write("P5.039", 0x0030)
    d.params.write("P5.058", 1)
    d.params.write("P5.039", 0x0035)  # capture with bit2: its first point starts COMPARE
    assert not d.compare.running
    d.set_di(7, False)
    d.set_di(7, True)
    d.advance(MS)
    assert d.compare.running and d.params.read("P5.058") == 1


def test_capture_starts_pr50_cap_move() -> None:
    """P5.039 bit3: PR#50 after the last point (L5158); a CAP position command goes to the
    last capture + data (L4471): the axis stops 30000 PUU after the mark."""
    d = make(**{"P1.001": 0x0001, "P2.016": 0})  # PR mode; DI7 no function of its own
    d.set_di(1, True)
    d.advance(10 * MS)
    for pair, (kind, data, kw) in ((("P6.002", "P6.003"), ("speed", 1000, {})),
                                   (("P7.000", "P7.001"), ("single", 30000,
                                                           {"cmd": "CAP", "spd": 4}))):
        definition, word = encode(kind, data, **kw)
        d.params.write(pair[0], definition)
        d.params.write(pair[1], word)
    d.params.write("P5.007", 1)
    d.advance(400 * MS)
    arm(d, count=1, ctrl=0x0139)  # CN2, NC, bit3
    d.set_di(7, False)
    d.advance(3 * MS)
    d.set_di(7, True)
    d.advance(2000 * MS)
    cap = d.capture.values[0][2]
    assert round(fb_puu(d)) == cap + 30000
    assert d.params.read("P5.007") == 20050  # PR#50 done (n + 20000, L11185)


def test_a_cyclic_compare_of_one_point_fires_once_per_passage() -> None:
    """Cyclic COMPARE (P5.059 bit1): P5.058 goes back to its count after the last point and
    comparing starts again (L5194, L11751). One point: it fires when the axis passes it, and
    again only when it passes it again (the model looped at the same instant for ever)."""
    d = make_cmp()
    d.params.write("P5.059", 0x00010010)  # capture axis, stopped
    d.params.write("P5.057", 0)
    arm_compare(d, [500], ctrl=0x00040013)  # 4 ms, cyclic, start
    pv(d, 6.0)
    assert len(d.compare.fired) == 1 and d.compare.running
    assert d.params.read("P5.058") == 1  # reloaded


def test_a_capture_started_by_compare_past_the_array_does_not_start() -> None:
    """P5.038 may be at most P5.010 - P5.036 (L11491); COMPARE bit2 starts CAPTURE with the
    previous count (L5195). 799 + 4 is past the 800 entries: CAPTURE is not started (as a
    bit0 write with them is refused), and nothing raises."""
    d = make_cmp()
    d.params.write("P5.039", 0x10)
    d.params.write("P5.038", 4)
    d.params.write("P5.036", 799)
    d.params.write("P5.059", 0x10010)
    d.params.write("P5.057", 0)
    arm_compare(d, [100], ctrl=0x10015)  # bit2: start CAPTURE at the end
    pv(d, 6.0)
    for _ in range(2):
        d.set_di(7, False)
        d.advance(5 * MS)
        d.set_di(7, True)
        d.advance(5 * MS)
    assert not d.capture.running and not d.params.read("P5.039") & 1


@pytest.mark.parametrize("param,value", [("P5.039", 0x0041), ("P5.039", 0x0200),
                                         ("P5.059", 0x00010040), ("P5.059", 0x00014010),
                                         ("P1.019", 0x0010)])
def test_capture_and_compare_digits_outside_their_ranges_are_refused(param, value) -> None:
    """P5.039: Y 0-3, Z 0-1 (L11500-L11531); P5.059: Y 0-3, Z 0-1, U 0-3 (L11726-L11770);
    P1.019: X, Z 0-1, Y and U 0 (L8122-L8132): inside the table's range, outside a digit's."""
    d = make()
    with pytest.raises(OutOfRange, match="digit"):
        d.params.write(param, value)


def _moved_and_stopped(d: Drive) -> int:
    """600 rpm for 1 s, then stopped: 6064h ~ 1 000 000 PUU."""
    pv(d, 600.0)
    d.advance(600 * MS)
    d.write_object(0x60FF, 0, 0)
    d.advance(400 * MS)
    return d.read_object(0x6064, 0)


def test_a_cn2_capture_axis_is_the_feedback_whatever_another_source_left() -> None:
    """L11487: with P5.039.Y = CN2 the capture axis equals the motor feedback position
    (monitor 00h). A P5.037 written while the source was CN5 had stayed as an offset: the
    capture stored 5 for a feedback of 1 000 000 (an outside review, helper-63)."""
    d = make_cmp()
    fb = _moved_and_stopped(d)
    d.params.write("P5.039", 0x0010)  # CN5, stopped
    d.params.write("P5.037", 5)
    d.params.write("P5.039", 0x0030)  # CN2
    assert abs(d.params.read("P5.037") - fb) <= 1
    arm(d, start=10)
    d.set_di(7, False)  # NO: the closing edge (set_di True) latches
    d.advance(5 * MS)
    d.set_di(7, True)
    d.advance(5 * MS)
    assert abs(d.pr.array[10] - fb) <= 1


def test_the_compare_axis_on_the_capture_axis_and_on_cn2() -> None:
    """P5.059.Y = 0: the compare axis is the capture axis (L11708): a P5.057 written while
    the source was CN5 is no offset there. Y = 3 (CN2): P5.057 is reset to the motor feedback
    position, monitor 00h, when Y is set (L11712), and a later homing that redefines the
    feedback leaves it (the two differ until Y is set again). Both had kept CN5's offset."""
    d = make_cmp()
    fb = _moved_and_stopped(d)
    d.params.write("P5.039", 0x0030)  # capture axis on CN2
    d.params.write("P5.059", 0x00640010)  # compare on CN5, stopped
    d.params.write("P5.057", 123)
    d.params.write("P5.059", 0x00640000)  # compare on the capture axis
    assert d.params.read("P5.057") == d.params.read("P5.037")
    d.params.write("P5.059", 0x00640010)
    d.params.write("P5.057", 777)
    d.params.write("P5.059", 0x00640030)  # compare on CN2
    assert abs(d.params.read("P5.057") - fb) <= 1
    d.write_object(0x607C, 0, 0)  # homing method 35: the feedback becomes 0 here
    d.write_object(0x6098, 0, 35)
    d.write_object(0x6060, 0, 6)
    d.advance(5 * MS)
    d.write_object(0x6040, 0, 0x1F)
    d.advance(200 * MS)
    assert abs(d.read_object(0x6064, 0)) <= 1
    assert abs(d.params.read("P5.057") - fb) <= 1
    d.params.write("P5.059", 0x00640000)
    d.params.write("P5.059", 0x00640030)  # set again: monitor 00h now
    assert abs(d.params.read("P5.057")) <= 1


@pytest.mark.parametrize(("key", "kept"), [(0, False), (30, True), (35, True)])
def test_the_data_array_is_ram_unless_p2008_stores_it(key: int, kept: bool) -> None:
    """L5097: the data array is kept in RAM and lost at power-off; only P2.008 = 30 or 35
    (L9225) writes it to EEPROM too. It had survived every power cycle (helper-63)."""
    d = make()
    d.params.write("P5.011", 100)
    d.params.write("P5.012", 4242)
    if key:
        d.params.write("P2.008", key)
    d.pr.array[101] = 17  # written after the store: RAM only
    d.power_cycle(off_for=100 * MS)
    d.advance(20 * MS)
    assert d.pr.array[100] == (4242 if kept else 0)
    assert d.pr.array[101] == 0
    assert d.pr.array is d.array  # PR, CAPTURE and COMPARE still share one array


def test_monitors_037_and_043_read_the_compare_data_and_the_last_capture() -> None:
    """Monitor 043 is the latest CAP value (L15481), 037 CMP_DATA = Array + P1.023 + P1.024
    (L15476, L8240); both read through P0.009/P0.010 (P0.017/P0.018) and as a PR WRITE's
    monitor source. They read 0 and raised AL231 (helper-63)."""
    d = make_cmp()
    pv(d, 300.0)
    arm(d, start=0, count=1)
    d.set_di(7, False)
    d.advance(2 * MS)
    d.set_di(7, True)
    d.advance(2 * MS)
    cap = d.pr.array[0]
    assert cap != 0
    d.params.write("P0.017", 43)
    assert d.params.read("P0.009") == cap
    assert d.pr.monitor(43) == cap
    d.pr.array[5] = 123000
    d.params.write("P5.056", 5)
    d.params.write("P1.023", 400)
    d.params.write("P1.024", 96)
    d.params.write("P0.018", 37)
    assert d.params.read("P0.010") == 123496
