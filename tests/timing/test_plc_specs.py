"""The pulse-train specs (issue 26) judge what the seed and the manual say, on recordings
built by hand: a right one passes, each wrong one fails the constraint that names the rule.
Seed 001:40 (DRVC), 001:42-44 (EXT), 001:62/110-116 (zero point), 001:122-124 (CLR);
A3 L8689 (TPOS), L15269 (ZSPD), L9556 (AL009)."""

from __future__ import annotations

from hil.paths import fixture
from hil.timing import check, load_spec
from hil.timing.source import MemorySource
from hil.units import MS

SEG = "/pulse/drive1/seg"
OZ = "/pulse/drive1/oz"
STATUS = "/plc/drive1/status"
STATE = "/drive/drive1/state"
PARAMS = "/drive/drive1/params"
BIND = {"drive": "drive1", "dio": "drive1"}


def judge(spec_id: str, msgs: dict, params: dict | None = None,
          constants: dict | None = None) -> dict[str, str]:
    spec = load_spec(fixture("timing", f"{spec_id}.yaml"))
    src = MemorySource(msgs | {PARAMS: [(0, {"snapshot": True, "values": params or {}})]})
    out: dict[str, str] = {}
    for v in check(spec, src, binding=BIND, constants=constants):
        out[v.constraint] = "fail" if "fail" in (v.status, out.get(v.constraint)) else v.status
    return out


def level(ms: float, on: bool) -> tuple[int, dict]:
    return (round(ms * MS), {"level": on})


def seg(ms: float, freq: float, count: int = 0, direction: int = 1) -> tuple[int, dict]:
    return (round(ms * MS), {"freq": freq, "direction": direction, "count": count})


def status(ms: float, event: str, drvz: str = "MD0", homed: bool = False) -> tuple[int, dict]:
    return (round(ms * MS), {"event": event, "drvz": drvz, "homed": homed})


def clr_case(width_ms: float, done_ms: float) -> dict:
    return {
        SEG: [seg(0, 2000), seg(100, 0)],
        "/dio/drive1/Y8": [level(0, False), level(100, True), level(100 + width_ms, False)],
        STATUS: [status(100, "zero"), status(done_ms, "homed", homed=True)],
    }


def test_clr_longer_than_20_ms_then_homing_complete():
    assert set(judge("plc_clr", clr_case(30, 130)).values()) == {"pass"}
    short = judge("plc_clr", clr_case(15, 115))
    assert short["CLR pulse lasts more than 20 ms"] == "fail"  # 001:124
    exactly = judge("plc_clr", clr_case(20, 120))
    assert exactly["CLR pulse lasts more than 20 ms"] == "fail"  # "> 20 ms", not ">="
    early = clr_case(30, 130)
    early[STATUS] = [status(100, "zero"), status(110, "homed", homed=True)]
    assert judge("plc_clr", early)["homing is not complete while CLR is on"] == "fail"


def test_a_clr_line_rise_outside_a_homing_is_not_judged():
    """Y8 driven as an ordinary output (before any DRVZ, or after the homing completed) is no
    homing CLR: not judged, rather than measured against the last stop seen (helper-97)."""
    msgs = {
        SEG: [seg(0, 2000), seg(100, 0), seg(300, 2000), seg(400, 0)],
        "/dio/drive1/Y8": [level(0, False), level(50, True), level(60, False),
                           level(500, True), level(505, False)],
        STATUS: [status(0, "step", drvz=""), status(200, "drvz"),
                 status(400, "zero"), status(450, "homed", homed=True)],
    }
    assert set(judge("plc_clr", msgs).values()) == {"skipped"}
    homing = clr_case(30, 130)
    assert set(judge("plc_clr", homing).values()) == {"pass"}


def dog_case(stop_ms: float) -> dict:
    return {
        "/dio/drive1/X0": [level(0, False), level(50, True), level(150, False)],
        SEG: [seg(0, 20_000), seg(60, 2000), seg(stop_ms, 0)],
        STATUS: [status(stop_ms, "zero", "MD0")],
    }


def test_zero_point_at_the_dog_off_edge():
    assert set(judge("plc_zero_dog", dog_case(150)).values()) == {"pass"}
    late = judge("plc_zero_dog", dog_case(155))
    assert late["the pulses stop at the DOG OFF edge"] == "fail"  # 001:110-114
    assert late["the zero point is the DOG OFF edge"] == "fail"


def pg0_case(oz_ms: list[float], zero_ms: float) -> dict:
    return {
        "/dio/drive1/X0": [level(0, False), level(50, True)],
        OZ: [(round(t * MS), {"width_ns": 100_000}) for t in oz_ms],
        SEG: [seg(0, 20_000), seg(60, 2000), seg(zero_ms, 0)],
        STATUS: [status(zero_ms, "zero", "MD2")],
    }


def test_zero_point_at_a_pg0_pulse_counted_after_dog():
    assert set(judge("plc_zero_pg0", pg0_case([30, 80], 80)).values()) == {"pass", "skipped"}
    no_pulse = judge("plc_zero_pg0", pg0_case([30, 80], 90))  # stopped between pulses
    assert no_pulse["the zero point is a PG0 pulse"] == "fail"
    before_dog = judge("plc_zero_pg0", pg0_case([30], 30.5))
    assert before_dog["the Z pulse that ended the count came after DOG on"] == "fail"


def test_a_trailing_edge_count_starts_at_dog_off():
    """001:116: with a trailing-edge count the PG0 pulses are counted from DOG OFF; a PLC
    that counted from DOG ON passed the spec (an outside audit, helper-64)."""
    def case(zero_ms: float) -> dict:
        c = pg0_case([30, 80, 130], zero_ms)
        c["/dio/drive1/X0"] = [level(0, False), level(50, True), level(100, False)]
        return c

    ok = judge("plc_zero_pg0", case(130), constants={"trailing": 1})
    assert set(ok.values()) == {"pass"}, ok
    early = judge("plc_zero_pg0", case(80), constants={"trailing": 1})  # DOG still on
    rule = "the Z pulse that ended the count came after DOG off (trailing-edge count)"
    assert early[rule] == "fail", early
    assert judge("plc_zero_pg0", case(80))[rule] == "skipped"  # a leading-edge count
    # DOG off at 100 belongs to an earlier pass: DOG on again at 120, zero at 130 (still on)
    again = case(130)
    again["/dio/drive1/X0"] = [level(0, False), level(50, True), level(100, False),
                               level(120, True)]
    got = judge("plc_zero_pg0", again, constants={"trailing": 1})
    assert got["DOG was off at the zero point (trailing-edge count)"] == "fail", got


def drvc_case(freqs: list[float], stop_between: bool = False) -> dict:
    segs = [seg(10 * i, f, 100) for i, f in enumerate(freqs)]
    if stop_between:
        segs.insert(1, seg(15, 0))
    return {SEG: [*segs, seg(10 * len(freqs), 0)]}


def test_each_drvc_segment_at_its_frequency():
    ok = judge("plc_drvc", drvc_case([5000, 10_000, 30_000, 50_000, 20_000, 3000]))
    assert set(ok.values()) == {"pass"}
    wrong = judge("plc_drvc", drvc_case([10_000, 48_000, 3000]))
    assert wrong["the second segment runs at its frequency after the first"] == "fail"
    stopped = judge("plc_drvc", drvc_case([10_000, 50_000, 3000], stop_between=True))
    assert stopped["no stop between the segments"] == "fail"


def ext_case(stop_ms: float, again_ms: float | None = None) -> dict:
    segs = [seg(0, 20_000, 50_000), seg(stop_ms, 0)]
    if again_ms is not None:
        segs.append(seg(again_ms, 20_000, 100))
    return {
        "/dio/drive1/X0": [level(0, False), level(100, True)],
        SEG: segs,
        STATUS: [status(stop_ms, "ext")],
        STATE: [(round(t * MS), {"pt_pending": p}) for t, p in
                ((0, 50_000), (100, 48_000), (stop_ms, 0), (stop_ms + 1, 0))],
    }


def test_ext_abandons_the_remaining_pulses():
    assert set(judge("plc_ext", ext_case(100)).values()) == {"pass"}
    late = judge("plc_ext", ext_case(104))
    assert late["the pulses stop at the EXT edge"] == "fail"  # 001:42-44
    resumed = judge("plc_ext", ext_case(100, again_ms=150))
    assert resumed["no new pulses right after the jump"] == "fail"


def tpos_case(tpos_ms: float, err_in_ms: float) -> dict:
    return {
        STATUS: [status(100, "done")],
        "/dio/drive1/DO4": [level(0, True), level(10, False), level(tpos_ms, True)],
        "/dio/drive1/DO2": [level(0, True), level(10, False), level(130, True)],
        STATE: [(0, {"pt_error": 0, "speed_rpm": 0.0}), (round(10 * MS), {"pt_error": 5000,
                 "speed_rpm": 300.0}), (round(err_in_ms * MS), {"pt_error": 500,
                                                                  "speed_rpm": 300.0}),
                (round(130 * MS), {"pt_error": 0, "speed_rpm": 0.0})],
    }


def test_tpos_after_the_last_pulse_inside_p1054():
    params = {"P1.054": 1000, "P1.038": 100, "P1.068": 4, "P1.008": 0}
    assert set(judge("plc_tpos", tpos_case(120, 120), params).values()) == {"pass"}
    early = judge("plc_tpos", tpos_case(110, 120), params)  # TPOS before the error is in
    assert early["TPOS comes on when the error is inside P1.054"] == "fail"  # L8689


def al009_case(raised_ms: float) -> dict:
    return {STATE: [(round(t * MS), {"following_error_counts": e, "alarms": a, "pt_count": c})
                    for t, e, a, c in ((0, 0, [], 0), (10, 2_000_000, [], 900),
                                       (20, 3_100_000, [], 1800),
                                       (raised_ms, 3_200_000, ["AL009"], 2000))]}


def test_al009_when_the_error_passes_p2035():
    params = {"P2.035": 3_000_000}
    assert set(judge("plc_al009", al009_case(21), params).values()) == {"pass"}
    assert set(judge("plc_al009", al009_case(30), params).values()) == {"fail"}  # L9556


def test_a_drive_that_never_raises_al009_fails():
    """L9556: an error past P2.035 gives AL009. The spec had looped over the AL009s raised,
    so a drive that never raised one was "nothing judged", never a failure (an outside
    audit, helper-64)."""
    never = {STATE: [(round(t * MS), {"following_error_counts": e, "alarms": [],
                                      "pt_count": c})
                     for t, e, c in ((0, 0, 0), (10, 2_000_000, 900), (20, 3_100_000, 1800),
                                     (40, 3_300_000, 2000))]}
    got = judge("plc_al009", never, {"P2.035": 3_000_000})
    assert got["AL009 when the error passes P2.035"] == "fail", got
