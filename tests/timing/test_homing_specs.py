"""The homing timing specs pass on the faithful drive and fail on its deviation knobs.

Each run homes the virtual axis on the injected clock; `ModelTap` records what a virtual
bench records (DI/DO lines incl. the sensor levels the mechanics drive, decoded 6040h
writes, the ground truth with `homing_phase`), and the checker reads the MCAP file back.

Bench as in tests/model/test_homing.py: a short axis (NL/PL at -4/+4 rev, home cam ORGP
[-0.5, +0.5] rev on DI9, Z at k + 0.25 rev). A start case at rev `s` shifts the bench by -s.
The per-method constants (first direction, reference edge direction, Z direction) are
written here from CiA 402 / the PR sequences L4331-4368, independently of the model's tables.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from hil.model.drive import Drive
from hil.model.mechanics import Mechanics
from hil.model.options import ModelOptions
from hil.paths import fixture
from hil.record.recorder import Recorder
from hil.timing.checker import check
from hil.timing.source import RecordingSource
from hil.timing.spec import load_spec
from hil.units import MS
from hil.virtual.model_tap import ModelTap

NL, PL, LO, HI, Z0 = -4.0, 4.0, -0.5, 0.5, 0.25
STARTS = {"neg": -2.0, "on": 0.0, "pos": 2.0, "on_NL": -4.2, "on_PL": 4.2}
# DI9 = ORGP (a), DI10 = SHOM (a); EMGS (DI8, b) closed; DO3 = HOME (factory).
BENCH = {"P2.036": 0x0124, "P2.037": 0x0127, "P1.001": 0x0001}  # PR mode (L15197)
V1, V2 = 120, 30  # rpm: 6099h sub1/sub2 = 1200/300, P5.005/P5.006 = 1200/300 (0.1 rpm)
OFFSET = 1234

# CiA 402 method -> (first search direction d0, reference edge crossing, Z search direction)
CIA = {
    1: (-1, 1, 1), 2: (1, -1, -1), 3: (1, -1, -1), 4: (1, 1, 1), 5: (-1, 1, 1),
    6: (-1, -1, -1), 7: (1, -1, -1), 8: (1, 1, 1), 9: (1, -1, -1), 10: (1, 1, 1),
    11: (-1, 1, 1), 12: (-1, -1, -1), 13: (-1, 1, 1), 14: (-1, -1, -1),
    33: (0, 0, -1), 34: (0, 0, 1), 35: (0, 0, 0),
}  # fmt: skip
for _m in range(17, 31):
    _d0, _ref, _ = CIA[_m - 16]
    CIA[_m] = (_d0, _ref, 0)  # 17-30: the edge itself, no Z (L18919-18966)


# the edge of the reference sensor's active region each method homes on: +1 the edge at the
# lower position (entered moving +), -1 the one at the upper position. L18871-18966 name it
# "上緣" / "下緣": 3/4 上緣 (a positive home switch), 5/6 下緣, 7/8 上緣, 9/10 下緣, 12 下緣,
# 13/14 上緣, and for the same methods without Z 19/20 上緣 ... 27/28 下緣, 29/30 上緣; 11 is
# printed 上緣 where 27, the same method without Z, and CiA 402 have the right (upper) edge:
# read as 下緣. The limits: NL active below it (-1), PL active above it (+1).
CIA_EDGE = {1: -1, 2: 1, 3: 1, 4: 1, 5: -1, 6: -1, 7: 1, 8: 1, 9: -1, 10: -1, 11: -1, 12: -1,
            13: 1, 14: 1, 33: 0, 34: 0, 35: 0}  # fmt: skip
for _m in range(17, 31):
    CIA_EDGE[_m] = CIA_EDGE[_m - 16]
# P5.004.X (L4229-4236): 0 PL, 1 NL; 2 forward ORG OFF->ON, 3 reverse OFF->ON, 6 forward
# ON->OFF, 7 reverse ON->OFF (a cam's lower edge is OFF->ON moving forward)
PR_EDGE = {0: 1, 1: -1, 2: 1, 3: -1, 6: -1, 7: 1}


def cia_ref_line(method: int) -> str:
    base = method - 16 if method > 16 else method
    return {1: "DI6:b", 2: "DI7:b"}.get(base, "DI9")


def cia_fails(method: int, start: str) -> bool:
    """Methods 3-6 / 19-22: half-space home switch, a limit ahead is a homing error."""
    base = method if method <= 14 else method - 16
    return (base in (3, 4) and start in ("pos", "on_PL")) or (
        base in (5, 6) and start in ("neg", "on_NL")
    )


# PR P5.004 X, Y -> (d0, reference crossing, Z direction), L4331-4368
def pr_dirs(x: int, y: int) -> tuple[int, int, int]:
    if x in (4, 5):  # the next Z forward / reverse (L4348)
        return 0, 0, 1 if x == 4 else -1
    if x in (9, 0xA):  # torque: into the hard stop, Y=0 back to Z, Y=2 the bump (L4364)
        d = 1 if x == 9 else -1
        return d, 0, -d if y == 0 else 0
    d = 1 if x in (0, 2, 6) else -1
    if x in (0, 1, 2, 3):  # limit / ORG off->on: Y=0 back to the edge, back on to Z
        ref = -d if y in (0, 2) else d
        return d, ref, {0: -d, 1: d, 2: 0}[y]
    return d, d, {0: -d, 1: d, 2: 0}[y]  # X 6/7: far edge crossed forward


def pr_ref_line(x: int) -> str:
    return {0: "DI7:b", 1: "DI6:b"}.get(x, "DI9")


def mech(s: float) -> Mechanics:
    return Mechanics(
        nl_rev=NL - s, pl_rev=PL - s, hard_stop_neg_rev=-5.0 - s, hard_stop_pos_rev=5.0 - s,
        home_lo_rev=LO - s, home_hi_rev=HI - s, index_angle=(Z0 - s) % 1.0,
    )  # fmt: skip


def record(tmp_path: Path, s: float, scenario, homing: dict | None = None, *,
           torque: bool = False, **params: int) -> Path:  # fmt: skip
    path = tmp_path / "homing.mcap"
    opts = ModelOptions(extra={"homing": homing or {}})
    # torque homing: limits not wired (NL/PL closed), the hard stop is the reference
    inputs, sensors = ({6: True, 7: True, 8: True}, {"ORGP": (9, "no")}) if torque else (
        {8: True}, None)  # fmt: skip
    drive = Drive(
        options=opts, mechanics=mech(s), inputs=inputs, sensors=sensors, params=BENCH | params
    )
    with Recorder(path) as rec:
        tap = ModelTap(drive, rec)
        tap.advance(10 * MS)
        scenario(tap)
        tap.close()
    return path


def run_until_home(tap: ModelTap, limit_ms: int = 20_000) -> None:
    h = tap.drive.homing
    for _ in range(limit_ms // 50):
        tap.advance(50 * MS)
        if not h.active and not tap.drive.axis.moving:
            break
    tap.advance(20 * MS)


def canopen_scenario(method: int):
    def scenario(tap: ModelTap) -> None:
        for idx, sub, value in (
            (0x6060, 0, 6), (0x6098, 0, method), (0x6099, 1, V1 * 10), (0x6099, 2, V2 * 10),
            (0x607C, 0, OFFSET),
        ):  # fmt: skip
            tap.write_object(idx, sub, value)
        for cw in (0x06, 0x07, 0x0F):
            tap.write_object(0x6040, 0, cw)
        tap.advance(100 * MS)  # brake released
        tap.write_object(0x6040, 0, 0x1F)  # bit 4 rising edge (L17267)
        run_until_home(tap)

    return scenario


def pr_scenario(tap: ModelTap) -> None:
    tap.set_di(1, True)  # SON
    tap.advance(100 * MS)
    tap.set_di(10, True)  # SHOM rising edge (L15197)
    run_until_home(tap)


def verdicts(path: Path, spec_id: str, binding: dict, constants: dict) -> list:
    spec = load_spec(fixture("timing", f"{spec_id}.yaml"))
    b = {"drive": "drive1", "dio": "drive1", "bus": "can0", **binding}
    return check(spec, RecordingSource(path), binding=b, constants=constants)


def problems(vs: list) -> list[str]:
    return [f"{v.constraint}: {v.status}: {v.message}" for v in vs if v.status != "pass"
            and v.status != "skipped"]  # fmt: skip


def canopen_verdicts(tmp_path: Path, method: int, start: str, homing: dict | None = None,
                     edge: int | None = None):
    path = record(tmp_path, STARTS[start], canopen_scenario(method), homing)
    d0, ref, z = CIA[method]
    consts = {"v1": V1, "v2": V2, "d0": d0, "ref_dir": ref, "z_dir": z, "offset": OFFSET,
              "ref_edge": CIA_EDGE[method] if edge is None else edge}
    return verdicts(path, "homing_canopen", {"REF": cia_ref_line(method)}, consts)


def pr_verdicts(tmp_path: Path, x: int, y: int, start: str, homing: dict | None = None,
                edge: int | None = None):
    p5004 = 0x100 | y << 4 | x  # Z = 1: reverse at a limit
    params = {"P5.004": p5004, "P5.005": V1 * 10, "P5.006": V2 * 10, "P6.001": 2000}
    torque = x in (9, 0xA)
    if torque:
        params |= {"P1.087": 50, "P1.088": 100}  # L4372-4392
    path = record(tmp_path, STARTS[start], pr_scenario, homing, torque=torque, **params)
    d0, ref, z = pr_dirs(x, y)
    consts = {"d0": d0, "ref_dir": ref, "z_dir": z,
              "ref_edge": PR_EDGE.get(x, 0) if edge is None else edge}
    return verdicts(path, "homing_pr", {"REF": pr_ref_line(x)}, consts)


# -- faithful drive ---------------------------------------------------------------------------
CANOPEN_CASES = [
    (m, s)
    for m in (*range(1, 15), *range(17, 31))
    for s in (
        ["neg", "on", "pos", "on_NL", "on_PL"] if m in (1, 2, 3, 7, 11, 14) else ["neg", "pos"]
    )
    if not cia_fails(m, s)
] + [(m, s) for m in (33, 34, 35) for s in ("neg", "on")]


@pytest.mark.parametrize(("method", "start"), CANOPEN_CASES)
def test_canopen_method_passes_its_spec(tmp_path: Path, method: int, start: str) -> None:
    vs = canopen_verdicts(tmp_path, method, start)
    assert [v for v in vs if v.status == "pass"], "nothing was judged"
    assert not problems(vs), problems(vs)


PR_CASES = [
    (x, y, s)
    for x in (0, 1, 2, 3, 6, 7)
    for y in (0, 1, 2)
    for s in (
        ["neg", "on", "pos", "on_NL", "on_PL"]
        if (x, y) in ((0, 0), (2, 0), (7, 0))
        else ["neg", "pos"]
    )
] + [(4, 0, "neg"), (5, 0, "on"), (9, 0, "pos"), (9, 2, "pos"), (0xA, 0, "neg")]


@pytest.mark.parametrize(("x", "y", "start"), PR_CASES)
def test_pr_mode_passes_its_spec(tmp_path: Path, x: int, y: int, start: str) -> None:
    vs = pr_verdicts(tmp_path, x, y, start)
    assert [v for v in vs if v.status == "pass"], "nothing was judged"
    assert not problems(vs), problems(vs)


# -- deviating drives: the matching spec fails and names the violated rule --------------------
DEVIATIONS = [
    ("canopen", 3, "neg", {"ignore_index": True}, "phase 2 - Z search after the reference edge"),
    ("canopen", 8, "on", {"ignore_index": True}, "phase 2 - Z search after the reference edge"),
    ("canopen", 1, "on", {"ignore_index": True}, "phase 2 - Z search after the reference edge"),
    ("canopen", 3, "neg", {"wrong_direction": True}, "reference edge crossed towards -"),
    ("canopen", 11, "pos", {"wrong_direction": True}, "Z found moving + at sub2"),
    ("canopen", 24, "neg", {"wrong_direction": True}, "reference edge crossed towards +"),
    ("canopen", 33, "neg", {"wrong_direction": True}, "Z found moving - at sub2"),
    ("canopen", 4, "neg", {"home_early_ms": 5}, "bit 12 only at standstill"),
    ("pr", (2, 0), "neg", {"ignore_index": True}, "phase 2 - Z search after the reference edge"),
    ("pr", (6, 1), "pos", {"wrong_direction": True}, "Z found moving + at P5.006"),
    ("pr", (0, 2), "neg", {"wrong_direction": True}, "reference edge crossed towards -"),
    ("pr", (2, 1), "neg", {"home_early_ms": 5}, "DO.HOME only at standstill"),
]


@pytest.mark.parametrize(
    ("route", "mode", "start", "knob", "rule"),
    DEVIATIONS,
    ids=[f"{r}-{m}-{s}-{next(iter(k))}" for r, m, s, k, _ in DEVIATIONS],
)
def test_deviation_knob_fails_the_matching_rule(tmp_path, route, mode, start, knob, rule) -> None:
    if route == "canopen":
        vs = canopen_verdicts(tmp_path, mode, start, knob)
    else:
        vs = pr_verdicts(tmp_path, *mode, start, knob)
    failed = {v.constraint: v.message for v in vs if v.status == "fail"}
    assert rule in failed, [(v.constraint, v.status, v.message) for v in vs]
    assert failed[rule]  # the message names what was seen (e.g. "rev was false at ...")


def test_homing_pr_places_the_coordinate_at_the_reference_not_within_a_turn(tmp_path):
    """P6.001 is the coordinate of the reference (L12641): judged against a P6.001 half a
    turn away from what the drive set, the spec fails at the reference. It had checked only
    "within a turn when HOME comes on", which that passes too (an outside audit, helper-64)."""
    x, y = 2, 0
    params = {"P5.004": 0x100 | y << 4 | x, "P5.005": V1 * 10, "P5.006": V2 * 10,
              "P6.001": 2000}
    path = record(tmp_path, STARTS["neg"], pr_scenario, None, **params)
    d0, ref, z = pr_dirs(x, y)
    spec = load_spec(fixture("timing", "homing_pr.yaml"))
    b = {"drive": "drive1", "dio": "drive1", "bus": "can0", "REF": pr_ref_line(x)}
    consts = {"d0": d0, "ref_dir": ref, "z_dir": z}
    rule = "coordinate P6.001 at the reference"
    good = {v.constraint: v.status for v in check(spec, RecordingSource(path), binding=b,
                                                   constants=consts)}
    assert good[rule] == "pass", good
    off = {v.constraint: v.status for v in check(spec, RecordingSource(path), binding=b,
                                                  constants=consts,
                                                  params={"P6.001": 2000 + 50_000})}
    assert off[rule] == "fail", off
    assert off["coordinate P6.001 at the reference (within a turn when HOME comes on)"] \
        == "pass", off


def test_homing_canopen_starts_only_in_homing_mode():
    """6040h bit 4 is "new set-point" in PP and a homing start only in HM (6060h = 6): a PP
    move's bit 4 is no homing start (every constraint "not applicable"), in HM it is."""
    from hil.timing import MemorySource, check, load_spec

    ms = 1_000_000

    def src(mode: str) -> MemorySource:
        return MemorySource({
            "/canopen/can0": [(0, {"dir": "tx", "controlword": 0x0F}),
                              (10 * ms, {"dir": "tx", "controlword": 0x1F})],
            "/drive/drive1/state": [(0, {"mode": mode, "speed_rpm": 0.0, "statusword": 0x0637,
                                         "homing_phase": "", "position_puu": 0})],
        })

    spec = load_spec(fixture("timing", "homing_canopen.yaml"))
    bind = {"drive": "drive1", "dio": "drive1", "bus": "can0"}
    pp = check(spec, src("PP"), binding=bind)
    assert pp and all(v.status == "skipped" for v in pp), [(v.status, v.message) for v in pp]
    hm = check(spec, src("HM"), binding=bind)
    assert [v for v in hm if v.status != "skipped"]  # judged (this stub has no motion: fails)


@pytest.mark.parametrize(("route", "mode", "start", "edge"), [
    ("canopen", 7, "neg", -1), ("canopen", 12, "pos", 1), ("canopen", 1, "neg", 1),
    ("pr", (2, 0), "neg", -1), ("pr", (7, 0), "pos", -1)])
def test_a_drive_homing_on_the_other_edge_fails(tmp_path, route, mode, start, edge) -> None:
    """Methods 7 and 9 (and 11/13, 8/10, ...) search and cross in the same directions; only
    the edge of the cam differs (上緣 / 下緣, L18877-18883). Judged as if it had been asked
    for the other edge, a drive's homing fails: the spec had passed whichever edge a drive
    took (helper-97)."""
    if route == "canopen":
        vs = canopen_verdicts(tmp_path, mode, start, edge=edge)
    else:
        vs = pr_verdicts(tmp_path, *mode, start, edge=edge)
    failed = [v.constraint for v in vs if v.status == "fail"]
    assert any("the reference is the mode's edge of the sensor" in c for c in failed), [
        (v.constraint, v.status, v.message) for v in vs]
