"""Homing moves the virtual axis (CANopen 6098h and PR P5.004), on the injected clock.

Bench: a short axis (limits at -4 / +4 rev, hard stops at -5 / +5 rev, home cam ORGP on
[-0.5, +0.5] rev, Z pulse at k + 0.25 rev) so that every switch edge is >= 0.25 rev away
from a Z pulse. A start case at rev `s` shifts the whole bench by -s (the axis starts at 0).
Expected home points are written from the CiA 402 method definitions (the manual's figures
are missing, L18856-18972) and from the PR sequences of L4331-4368, independently of the
implementation.
"""

from __future__ import annotations

import pytest

from hil.model.drive import Drive
from hil.model.errors import OutOfRange
from hil.model.mechanics import Mechanics
from hil.model.motion import counts_to_puu
from hil.model.options import ModelOptions
from hil.units import MS

NL, PL, LO, HI, Z0 = -4.0, 4.0, -0.5, 0.5, 0.25
STARTS = {"neg": -2.0, "on": 0.0, "pos": 2.0, "on_NL": -4.2, "on_PL": 4.2}
# DI9 = ORGP (a), DI10 = SHOM (a), DI2 = CTRG (a), DI3 = POS0 (a); EMGS (DI8, b) closed.
BENCH = {"P2.036": 0x0124, "P2.037": 0x0127, "P2.011": 0x0108, "P2.012": 0x0111,
         "P1.001": 0x0001}  # PR mode: SHOM, CTRG, P5.007 are PR triggers (L11168, L15197)


def mech(s: float, **kw: float | None) -> Mechanics:
    values: dict = dict(
        nl_rev=NL - s, pl_rev=PL - s, hard_stop_neg_rev=-5.0 - s, hard_stop_pos_rev=5.0 - s,
        home_lo_rev=LO - s, home_hi_rev=HI - s, index_angle=(Z0 - s) % 1.0,
    )  # fmt: skip
    values.update(kw)
    return Mechanics(**values)


def make(s: float = 0.0, homing: dict | None = None, m: Mechanics | None = None, **params: int):
    opts = ModelOptions(extra={"homing": homing or {}})
    drive = Drive(options=opts, mechanics=m or mech(s), inputs={8: True}, params=BENCH | params)
    return drive, drive.homing  # the drive's own engine (a second one ran beside it before)


def home_rev(h, s: float) -> float:
    return h.home_counts / COUNTS + s


COUNTS = 16_777_216


def run_until_done(drive: Drive, h, limit_s: float = 20.0) -> None:
    for _ in range(int(limit_s * 20)):
        drive.advance(50 * MS)
        if not h.active and not drive.axis.moving:
            return
    raise AssertionError(f"homing did not end: phase {h.phase}")


# ---------------------------------------------------------------- CANopen
def canopen_home(method: int, s: float, offset: int = 1234, **kw):
    drive, h = make(s, **kw)
    drive.write_object(0x6060, 0, 6)  # L17255
    drive.write_object(0x6098, 0, method)
    drive.write_object(0x6099, 1, 1200)  # 120 rpm switch search (0.1 rpm, L18998)
    drive.write_object(0x6099, 2, 300)  # 30 rpm zero search (L19007)
    drive.write_object(0x607C, 0, offset)
    for cw in (0x06, 0x07, 0x0F):
        drive.write_object(0x6040, 0, cw)
    drive.advance(100 * MS)  # brake released
    drive.write_object(0x6040, 0, 0x1F)  # bit 4 rising edge (L17267)
    run_until_done(drive, h)
    return drive, h


# Home point (rev) per method from CiA 402: (reference edge, side of the index).
def cia_expected(method: int) -> float:
    idx = {
        1: NL + 0.25, 2: PL - 0.75, 3: LO - 0.25, 4: LO + 0.75, 5: HI + 0.75, 6: HI - 0.25,
        7: LO - 0.25, 8: LO + 0.75, 9: HI - 0.25, 10: HI + 0.75,
        11: HI + 0.75, 12: HI - 0.25, 13: LO + 0.75, 14: LO - 0.25,
    }  # fmt: skip
    edge = {1: NL, 2: PL, 3: LO, 4: LO, 5: HI, 6: HI, 7: LO, 8: LO, 9: HI, 10: HI}
    edge |= {11: HI, 12: HI, 13: LO, 14: LO}
    return idx[method] if method <= 14 else edge[method - 16]


def cia_fails(method: int, start: str) -> bool:
    """Methods 3-6 / 19-22 assume a half-space home switch: a limit ahead is an error."""
    base = method if method <= 14 else method - 16
    if base in (3, 4):
        return start in ("pos", "on_PL")
    if base in (5, 6):
        return start in ("neg", "on_NL")
    return False


EDGE_TOL = 0.01  # rev: an edge is latched after the P2.009 filter (2 ms at <= 2 rev/s)


@pytest.mark.parametrize("start", list(STARTS))
@pytest.mark.parametrize("method", [*range(1, 15), *range(17, 31)])
def test_canopen_switch_methods(method: int, start: str) -> None:
    s = STARTS[start]
    drive, h = canopen_home(method, s)
    sw = drive.read_object(0x6041)
    if cia_fails(method, start):
        assert sw & 0x2000 and not sw & 0x1000  # bit 13 homing error (L18338)
        assert not drive.do(3) and "limit" in h.last_error
        return
    assert sw & 0x1000 and not sw & 0x2000, h.last_error  # bit 12 attained (L18337)
    assert sw & 0x0400  # target reached
    assert drive.read_object(0x6064) == 1234  # 6064h = 607Ch at the home point
    assert drive.do(3)  # DO3 = HOME (P2.020 = 0x0109, L15290)
    tol = 1e-6 if method <= 14 else EDGE_TOL
    assert home_rev(h, s) == pytest.approx(cia_expected(method), abs=tol)


@pytest.mark.parametrize("method", range(17, 31))
def test_canopen_edge_methods_home_at_one_point_from_every_start(method: int) -> None:
    """Without a Z after it the edge is the home: found at the zero-search speed (6099h sub2)
    from every start, not latched at the switch-search speed (sub1) when the search happens
    to enter through it (helper-91: methods 20, 22, 24, 25, 28, 29 moved with the start by
    sub1 x the P2.009 filter). The origin is the same whatever the start (L4336): here
    within the 30 rpm zero search x the 2 ms filter (0.001 rev)."""
    homes = [home_rev(canopen_home(method, s)[1], s) for start, s in STARTS.items()
             if not cia_fails(method, start)]
    assert max(homes) - min(homes) <= 0.0012, homes


@pytest.mark.parametrize("start", ["neg", "on", "pos"])
@pytest.mark.parametrize(("method", "step"), [(33, -1), (34, 1), (35, 0)])
def test_canopen_index_and_here(method: int, step: int, start: str) -> None:
    s = STARTS[start]
    drive, h = canopen_home(method, s, offset=-500)
    assert drive.read_object(0x6041) & 0x1000
    assert drive.read_object(0x6064) == -500
    expected = s if step == 0 else (s + (0.25 if step > 0 else -0.75))  # next Z from s
    assert home_rev(h, s) == pytest.approx(expected, abs=1e-6)


@pytest.mark.parametrize("method", [0, 15, 16, 31, 32])
def test_canopen_reserved_methods_are_homing_errors(method: int) -> None:
    drive, _ = canopen_home(method, 0.0)
    sw = drive.read_object(0x6041)
    assert sw & 0x2000 and not sw & 0x1000
    assert drive.axis.position == 0.0 and not drive.do(3)


def test_canopen_bit4_falling_edge_aborts() -> None:
    drive, h = make(2.0)
    for idx, sub, v in ((0x6060, 0, 6), (0x6098, 0, 7), (0x6099, 1, 1200)):
        drive.write_object(idx, sub, v)
    for cw in (0x06, 0x07, 0x0F, 0x1F):
        drive.write_object(0x6040, 0, cw)
    drive.advance(500 * MS)
    assert h.active and abs(drive.axis.velocity_rpm) > 100  # moving: no fixed delay
    drive.write_object(0x6040, 0, 0x0F)
    drive.advance(500 * MS)
    sw = drive.read_object(0x6041)
    assert not h.active and not sw & 0x3000 and not drive.axis.moving and not drive.do(3)


def test_canopen_start_edge_while_halted_moves_nothing() -> None:
    # controlword bit 8 Halt (L18232): a halted axis does not move; the homing start edge
    # with Halt set starts nothing (an outside review: the axis ran at 120 rpm to PL)
    drive, h = make(2.0)
    for idx, sub, v in ((0x6060, 0, 6), (0x6098, 0, 7), (0x6099, 1, 1200), (0x6099, 2, 300)):
        drive.write_object(idx, sub, v)
    for cw in (0x06, 0x07, 0x0F, 0x10F):
        drive.write_object(0x6040, 0, cw)
    drive.advance(100 * MS)
    drive.write_object(0x6040, 0, 0x11F)  # bit 4 rises while halted
    drive.advance(1500 * MS)
    assert not h.active and not drive.axis.moving
    assert drive.axis.position == 0.0
    drive.write_object(0x6040, 0, 0x10F)
    drive.write_object(0x6040, 0, 0x00F)  # halt released, then a new start edge homes
    drive.write_object(0x6040, 0, 0x01F)
    run_until_done(drive, h)
    assert drive.read_object(0x6041) & 0x1000


@pytest.mark.parametrize("method", [3, 34])
def test_a_homing_error_at_a_limit_is_the_limits_quick_stop(method: int) -> None:
    # transition 11 (L18260): a positive/negative limit switch is a quick stop, in every
    # mode; a method that meets a limit it does not use ends in a homing error (bit 13) and
    # the limit's quick stop, as PV does there (an outside review: OPERATION ENABLED)
    drive, _ = canopen_home(method, 2.0 if method == 3 else 3.9)
    sw = drive.read_object(0x6041)
    assert sw & 0x2000 and not sw & 0x1000  # homing error
    assert sw & 0x6F == 0x07, hex(sw)  # QUICK STOP ACTIVE


def test_canopen_home_offset_sign_option() -> None:
    drive, _ = canopen_home(35, 0.0, offset=300, homing={"offset_sign": -1})
    assert drive.read_object(0x6064) == -300


# ---------------------------------------------------------------- PR
def pr_home(p5004: int, s: float, m: Mechanics | None = None, homing: dict | None = None,
            **params: int):  # fmt: skip
    p = {"P5.004": p5004, "P5.005": 1200, "P5.006": 300, "P6.001": 2000} | params
    drive, h = make(s, homing=homing, m=m, **p)
    drive.set_di(1, True)  # SON
    drive.advance(100 * MS)
    drive.set_di(10, True)  # SHOM rising edge (L15197)
    run_until_done(drive, h)
    return drive, h


# (X, Y) -> expected home point (rev), from L4331-4368 (mirror for reverse modes).
PR_EXPECTED = {
    (0, 0): PL - 0.75, (0, 1): PL + 0.25, (0, 2): PL,
    (1, 0): NL + 0.25, (1, 1): NL - 0.75, (1, 2): NL,
    (2, 0): LO - 0.25, (2, 1): LO + 0.75, (2, 2): LO,
    (3, 0): HI + 0.75, (3, 1): HI - 0.25, (3, 2): HI,
    (6, 0): HI - 0.25, (6, 1): HI + 0.75, (6, 2): HI,
    (7, 0): LO + 0.75, (7, 1): LO - 0.25, (7, 2): LO,
}  # fmt: skip


@pytest.mark.parametrize("start", list(STARTS))
@pytest.mark.parametrize(("x", "y"), list(PR_EXPECTED))
def test_pr_modes_same_origin_from_every_start(x: int, y: int, start: str) -> None:
    s = STARTS[start]
    drive, h = pr_home(0x100 | y << 4 | x, s)  # Z = 1: reverse at a limit
    assert drive.do(3) and h.homed, h.last_error
    tol = EDGE_TOL if y == 2 else 1e-6
    assert home_rev(h, s) == pytest.approx(PR_EXPECTED[(x, y)], abs=tol)
    # P6.001 is the coordinate of the reference; the motor stops a little past it (L4280)
    g = drive.params.get
    ref_puu = counts_to_puu(h.home_counts - drive.axis.origin, g("P1.044"), g("P1.045"))
    assert ref_puu == pytest.approx(2000, abs=1e-6)
    past = counts_to_puu(drive.axis.user_position, g("P1.044"), g("P1.045")) - 2000
    assert 0 < abs(past) < 200


@pytest.mark.parametrize(("x", "start"), [(2, "pos"), (3, "neg"), (6, "pos"), (7, "neg")])
def test_pr_limit_with_z0_is_an_error(x: int, start: str) -> None:
    drive, h = pr_home(0x000 | x, STARTS[start])  # Z = 0: "show error" at a limit (L4229)
    assert not h.homed and not drive.do(3) and "limit" in h.last_error
    assert "AL015" in drive.alarms.active or "AL014" in drive.alarms.active


@pytest.mark.parametrize(("value", "step"), [(0x004, 1), (0x005, -1)])
def test_pr_z_directly(value: int, step: int) -> None:
    _, h = pr_home(value, 2.0)
    assert home_rev(h, 2.0) == pytest.approx(2.25 if step > 0 else 1.25, abs=1e-6)


def test_pr_current_position() -> None:
    drive, _ = pr_home(0x008, 1.3)
    g = drive.params.get
    assert counts_to_puu(drive.axis.user_position, g("P1.044"), g("P1.045")) == 2000
    assert drive.do(3) and drive.axis.position == 0.0  # no motion (L4360)


# ---------------------------------------------------------------- torque homing
def torque_bench(s: float) -> tuple[Mechanics, dict[str, tuple[int, str]]]:
    return mech(s), {"ORGP": (9, "no")}  # limits not wired: the hard stop is the reference


@pytest.mark.parametrize(("y", "expected"), [(0, 4.25), (2, 5.0)])
def test_torque_homing_into_the_hard_stop(y: int, expected: float) -> None:
    s = 1.0
    p = {"P5.004": 0x009 | y << 4, "P5.005": 1200, "P5.006": 300, "P6.001": 0}
    p |= {"P1.087": 50, "P1.088": 100}  # L4372-4392
    drive = Drive(
        options=ModelOptions(), mechanics=mech(s), inputs={6: True, 7: True, 8: True},
        sensors={"ORGP": (9, "no")}, params=BENCH | p,
    )  # fmt: skip
    h = drive.homing
    drive.set_di(1, True)
    drive.advance(100 * MS)
    drive.set_di(10, True)
    peak = 0.0
    drive.advance(10 * MS)  # the trigger starts the run on the next PR tick
    for _ in range(8000):
        drive.advance(MS)
        if h.active:  # the torque phase and after it, while the command still pushes
            peak = max(peak, abs(drive.axis.torque))
        if not h.active and not drive.axis.moving:
            break
    assert h.homed and drive.do(3)
    # max torque = P1.087 + 10 % (L4383), a harder impact may damage the machine (L8960-8971):
    # also while the reversal to Z begins, still pushing into the stop (helper-91: 300 %)
    assert peak <= 600.0 + 1e-6
    assert home_rev(h, s) == pytest.approx(expected, abs=1e-6)
    contact = next(t for t, p in h.trace if p == "torque")
    found = [t for t, p in h.trace if p in ("index", "stop")][-1]
    assert found - contact >= 100 * MS  # held >= P1.088 before it counts (L8973-8984)


# ---------------------------------------------------------------- triggers and HOME
def pr_ready(**params: int):
    p = {"P5.004": 0x008, "P6.001": 777} | params
    drive, h = make(0.0, **p)
    drive.set_di(1, True)
    drive.advance(100 * MS)
    return drive, h


def test_home_drops_at_trigger_and_rises_when_done() -> None:
    drive, h = pr_ready(**{"P5.004": 0x102, "P5.005": 1200, "P5.006": 300})
    drive.set_di(10, True)
    run_until_done(drive, h)
    assert drive.do(3)
    drive.set_di(10, False)
    drive.advance(10 * MS)
    drive.set_di(10, True)  # second homing: HOME off as soon as the filter passes SHOM
    drive.advance(2 * MS)  # P2.009 = 2 ms
    assert not drive.do(3)
    run_until_done(drive, h)
    assert drive.do(3)


@pytest.mark.parametrize("how", ["SHOM", "CTRG", "P5.007"])
def test_pr_triggers(how: str) -> None:
    drive, h = pr_ready()
    if how == "SHOM":
        drive.set_di(10, True)
    elif how == "CTRG":
        drive.set_di(2, True)  # POS0 (DI3) off -> PR#0 (L4701)
    else:
        drive.params.write("P5.007", 0)  # L11174
    drive.advance(5 * MS)
    assert h.homed and drive.do(3)
    assert h.trace[0][1] == f"trigger:{how}"


def test_ctrg_with_pos0_on_is_not_homing() -> None:
    drive, h = pr_ready()
    drive.set_di(3, True)  # POS0 on: PR#1, not PR#0
    drive.advance(5 * MS)
    drive.set_di(2, True)
    drive.advance(5 * MS)
    assert not h.homed and not drive.do(3)


def test_trigger_waits_for_the_1ms_pr_tick() -> None:
    drive, h = pr_ready()
    drive.advance(MS // 2)
    t = drive.now
    drive.params.write("P5.007", 0)
    assert not drive.do(3) and not h.homed
    drive.advance(MS)
    homed = next(tt for tt, p in h.trace if p == "homed")
    assert homed == (t // MS + 1) * MS


@pytest.mark.parametrize("p1001", [0x0000, 0x0002, 0x000C])  # PT, S, CANopen
def test_boot_homing_only_in_pr_mode(p1001: int) -> None:
    """P6.000 is a PR-mode parameter ("控制模式：PR", L12600-12601): its BOOT digit homes at the
    first servo on in PR mode only, not an axis commanded by pulses, speed or CANopen
    (helper-91: a CANopen servo on moved the axis on its own)."""
    drive, h = make(0.0, **{"P5.004": 0x102, "P6.000": 0x10000000, "P1.001": p1001})
    drive.set_di(1, True)
    drive.advance(200 * MS)
    assert not h.active and not h.homed
    assert drive.axis.position == 0.0


def test_boot_homing_at_first_servo_on_only() -> None:
    drive, h = make(0.0, **{"P5.004": 0x008, "P6.000": 0x10000000})  # D = BOOT (L12635)
    drive.set_di(1, True)
    drive.advance(10 * MS)
    assert h.homed and drive.do(3)
    drive.set_di(1, False)
    drive.advance(10 * MS)
    n = len(h.trace)
    drive.set_di(1, True)
    drive.advance(10 * MS)
    assert len(h.trace) == n  # not again until the next power-up
    drive.power_cycle()
    assert not drive.do(3) and not h.homed  # HOME off at power-up (L15290)
    drive.advance(10 * MS)
    drive.set_di(1, True)
    drive.advance(10 * MS)
    assert h.homed


def test_p5004_digits_validated() -> None:
    drive, _ = make(0.0)
    for bad in (0x00B, 0x030, 0x019, 0x200):
        with pytest.raises(OutOfRange, match=r"P5\.004"):
            drive.params.write("P5.004", bad)


# ---------------------------------------------------------------- deviation knobs
def test_knob_ignore_index_stops_at_the_switch_edge() -> None:
    _, h = canopen_home(7, 2.0, homing={"ignore_index": True})
    assert home_rev(h, 2.0) == pytest.approx(LO, abs=EDGE_TOL)


def test_knob_wrong_direction_moves_the_home_one_index() -> None:
    _, h = canopen_home(7, -2.0, homing={"wrong_direction": True})
    assert home_rev(h, -2.0) == pytest.approx(LO + 0.75, abs=1e-6)


def test_knob_home_early_reports_before_standstill() -> None:
    drive, _ = make(-2.0, homing={"home_early_ms": 0})
    for idx, sub, v in ((0x6060, 0, 6), (0x6098, 0, 7), (0x6099, 1, 1200), (0x6099, 2, 300)):
        drive.write_object(idx, sub, v)
    for cw in (0x06, 0x07, 0x0F, 0x1F):
        drive.write_object(0x6040, 0, cw)
    for _ in range(4000):
        drive.advance(MS)
        if drive.do(3):
            break
    assert drive.axis.moving and drive.read_object(0x6041) & 0x1000


def test_cmd_e_follows_cmd_o_during_pr_homing_then_reads_the_reference() -> None:
    """L4396: while PR homing runs Cmd_E (monitor 064) equals Cmd_O (001), the coordinate
    not yet defined; once the reference is found Cmd_E is its coordinate (P6.001) while Cmd_O
    runs on through the deceleration (figure 7.1.3.3; helper-91: Cmd_E kept its old value)."""
    drive, h = make(0.0, **{"P5.004": 0x002, "P6.001": 2000})  # X=2: ORG, Y=0: back to Z
    drive.set_di(1, True)
    drive.advance(100 * MS)
    drive.params.write("P5.007", 0)
    seen_running = seen_found = False
    for _ in range(20000):
        drive.advance(MS)
        if h.active and h.home_counts is None and drive.axis.moving:
            assert drive.pr.monitor(64) == drive.pr.monitor(1)
            seen_running = True
        elif h.active and h.home_counts is not None:
            assert drive.pr.monitor(64) == 2000
            seen_found = True
        if h.homed and not h.active:
            break
    assert seen_running and seen_found and drive.pr.monitor(64) == 2000
