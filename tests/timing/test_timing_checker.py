"""The checker on synthetic traces built with the manual's numbers (a3-timing §1, §3, §4)."""

from __future__ import annotations

import pytest

from hil.timing.checker import check, summary
from hil.timing.spec import load_spec, loads_spec, shipped_specs

from .trace import STATE, by_name, dio, source

SPECS = {p.stem: load_spec(p) for p in shipped_specs()}
BRAKE_ON = "BRKR rises P1.042 after servo on"


def servo_on(brkr_ms: list[float | None], p1042: float = 150, srdy: bool = True):
    """SON closes at 100 ms (+500 ms per further servo-on); servo on after P2.009 = 2 ms
    (L9229); BRKR rises `brkr_ms` after that; SON opens 400 ms later."""
    son, on, brkr = [(0, False)], [(0, False)], [(0, False)]
    for i, b in enumerate(brkr_ms):
        t0 = 100 + 500 * i
        son += [(t0, True), (t0 + 400, False)]
        on += [(t0 + 2, True), (t0 + 402, False)]
        if b is not None:
            brkr += [(t0 + 2 + b, True), (t0 + 402, False)]
    return source({
        (dio("DI1"), "level"): son, (dio("DO1"), "level"): [(0, srdy)],
        (dio("DO6"), "level"): brkr, (STATE, "servo_on"): on, (STATE, "alarms"): [(0, [])],
    }, params={"P1.042": p1042, "P2.009": 2})


def test_brake_release_at_p1042_passes():
    vs = check(SPECS["servo_on_brake"], servo_on([150]))
    assert summary(vs)["pass"] == 3, [v.message for v in vs]
    v = by_name(vs, BRAKE_ON)[0]
    assert v.measured_ms == 150.0 and v.window_ms == (149.0, 151.0)
    assert v.window_expr == "[P1.042 - tol, P1.042 + tol] ms" and v.values["P1.042"] == 150


def test_brake_release_5ms_late_fails_naming_the_window():
    v = by_name(check(SPECS["servo_on_brake"], servo_on([155])), BRAKE_ON)[0]
    assert v.status == "fail"
    assert v.message == ("BRKR rose 155.0 ms after servo on; allowed 150.0 ± 1.0 ms "
                         "(P1.042 = 150): 4.0 ms late")
    assert v.margin_ms == pytest.approx(-4.0)


def test_resolution_straddling_the_limit_is_inconclusive():
    # BRKR seen at 152 ms on a 1 ms DO tick: it really rose in [151, 152] -> limit 151 straddled
    v = by_name(check(SPECS["servo_on_brake"], servo_on([152])), BRAKE_ON)[0]
    assert v.status == "inconclusive" and "straddles the upper limit" in v.message
    assert v.uncertainty_ms == (1.0, 0.0)


def test_resolution_from_the_source_wins_over_the_spec_default():
    src = servo_on([150])
    src._res = {"/dio/*/DO*": 3_000_000}  # recorded channel says 3 ms
    v = by_name(check(SPECS["servo_on_brake"], src), BRAKE_ON)[0]
    assert v.status == "inconclusive"
    v = by_name(check(SPECS["servo_on_brake"], src, resolution={"/dio/*": 0}), BRAKE_ON)[0]
    assert v.status == "pass"  # explicit override (hil check --resolution) wins


def test_missing_brkr_fails_with_a_clear_message():
    v = by_name(check(SPECS["servo_on_brake"], servo_on([None])), BRAKE_ON)[0]
    assert v.status == "fail"
    assert v.message.startswith("expected BRKR to rise after servo on; it never did in ")


def test_for_each_judges_every_servo_on():
    vs = by_name(check(SPECS["servo_on_brake"], servo_on([150, 155, 150])), BRAKE_ON)
    assert [(v.occurrence, v.status) for v in vs] == [(0, "pass"), (1, "fail"), (2, "pass")]


def test_parameter_override_and_missing_parameter():
    src = servo_on([100])
    assert by_name(check(SPECS["servo_on_brake"], src), BRAKE_ON)[0].status == "fail"
    v = by_name(check(SPECS["servo_on_brake"], src, params={"P1.042": 100}), BRAKE_ON)[0]
    assert v.status == "pass"
    bare = source({(dio("DI1"), "level"): [(0, False), (10, True)],
                   (dio("DO1"), "level"): [(0, True)], (STATE, "alarms"): [(0, [])],
                   (STATE, "servo_on"): [(0, False), (12, True)]})
    v = by_name(check(SPECS["servo_on_brake"], bare), "SON accepted after the P2.009 filter")[0]
    assert v.status == "inconclusive" and "P2.009" in v.message and "--param" in v.message


def test_when_false_is_skipped_not_failed():
    vs = check(SPECS["servo_on_brake"], servo_on([300], srdy=False))
    assert by_name(vs, BRAKE_ON)[0].status == "skipped"
    assert by_name(vs, "SRDY is On before servo on")[0].status == "fail"


# --- servo off: earliest of P1.043 and speed < P1.038 (L1361-1362, L8512-8516) --------------


def servo_off(brkr_after: float, slow_at: float | None, p1043: float = 100,
              alarm: str | None = None):
    """Servo off at 100 ms; |speed| drops below P1.038 = 100 (10 rpm) `slow_at` ms later."""
    speed = [(0, 1500.0)] + ([(100 + slow_at, 5.0)] if slow_at is not None else [])
    alarms = [(0, [])] + ([(100, [alarm])] if alarm else [])
    return source({
        (STATE, "servo_on"): [(0, True), (100, False)], (STATE, "speed_rpm"): speed,
        (STATE, "alarms"): alarms, (dio("DO6"), "level"): [(0, True), (100 + brkr_after, False)],
    }, params={"P1.043": p1043, "P1.038": 100})


NORMAL = "normal servo off, BRKR at the earlier of P1.043 and speed < P1.038"
FAULT = "alarm/EMGS servo off, negative P1.043 acts as 0"


@pytest.mark.parametrize("brkr,slow,status", [
    (40, 40, "pass"),     # speed below P1.038 first (L1362)
    (100, None, "pass"),  # P1.043 expired first, still fast (L1361)
    (100, 40, "fail"),    # waited for P1.043 although already slow
    (40, None, "fail"),   # engaged early while still fast
])
def test_earliest_of_p1043_and_speed(brkr, slow, status):
    v = by_name(check(SPECS["servo_off_brake"], servo_off(brkr, slow)), NORMAL)[0]
    assert v.status == status, v.message


def test_negative_p1043_acts_as_zero_on_alarm_servo_off():
    vs = check(SPECS["servo_off_brake"], servo_off(0, None, p1043=-50, alarm="AL013"))
    assert by_name(vs, FAULT)[0].status == "pass"
    assert by_name(vs, NORMAL)[0].status == "skipped"
    vs = check(SPECS["servo_off_brake"], servo_off(50, None, p1043=-50, alarm="AL500"))
    assert by_name(vs, FAULT)[0].status == "fail"


# --- STO (L2474-2493) -------------------------------------------------------------------


def sto(a_low: tuple[float, float] | None, b_low: tuple[float, float] | None,
        alarms: list[tuple[float, list[str]]], torque_off: float | None = None,
        arst: list[tuple[float, bool]] | None = None):
    def line(low):
        return [(0, True)] + ([(low[0], False), (low[1], True)] if low else [])

    first = min(x[0] for x in (a_low, b_low) if x)
    return source({
        (dio("STO_A"), "level"): line(a_low), (dio("STO_B"), "level"): line(b_low),
        (STATE, "alarms"): [(0, []), *alarms],
        (STATE, "torque_enabled"): [(0, True), (torque_off or first + 5, False)],
        (dio("DI5"), "level"): [(0, False), *(arst or [])],
    }, params={"P2.009": 2})


def test_al500_after_10ms_both_lost_passes():
    vs = check(SPECS["sto"], sto((100, 5000), (100, 5000), [(110, ["AL500"])]))
    assert by_name(vs, "AL500 when both channels lost for 10 ms")[0].status == "pass"
    assert by_name(vs, "no AL500 before both channels lost for 10 ms")[0].status == "pass"
    assert by_name(vs, "torque off within 20 ms of a channel lost")[0].status == "pass"


def test_al500_after_9ms_fails():
    vs = check(SPECS["sto"], sto((100, 5000), (100, 5000), [(109, ["AL500"])]))
    v = by_name(vs, "no AL500 before both channels lost for 10 ms")[0]
    assert v.status == "fail" and v.measured_ms == 9.0
    assert v.message.startswith("AL500 raised 9.0 ms after both STO channels lost")
    assert by_name(vs, "AL500 when both channels lost for 10 ms")[0].status == "fail"


def test_torque_off_later_than_20ms_fails():
    vs = check(SPECS["sto"], sto((100, 5000), None, [], torque_off=125))
    v = by_name(vs, "torque off within 20 ms of a channel lost")[0]
    assert v.status == "fail" and "5.0 ms late" in v.message


@pytest.mark.parametrize("at,status", [(1099, "fail"), (1100, "pass")])
def test_al501_needs_sto_a_lost_alone_for_1s(at, status):
    vs = check(SPECS["sto"], sto((100, 5000), None, [(at, ["AL501"])]))
    assert by_name(vs, "no AL501 before STO_A lost for 1 s")[0].status == status
    assert by_name(vs, "AL501 when STO_A lost for 1 s")[0].status == status


def test_al502_for_sto_b_and_no_alarm_for_a_short_loss():
    vs = check(SPECS["sto"], sto(None, (100, 5000), [(1100, ["AL502"])]))
    assert by_name(vs, "AL502 when STO_B lost for 1 s")[0].status == "pass"
    vs = check(SPECS["sto"], sto(None, (100, 600), []))  # back after 500 ms: no AL502 due
    assert by_name(vs, "AL502 when STO_B lost for 1 s")[0].status == "skipped"


def test_al502_while_both_channels_are_lost_fails():
    """STO_B lost at 100, STO_A at 1095: at STO_B's second (1100) both are lost, so the two
    are not out of step (L20209): AL500 alone (helper-105, helper-108: the spec had let a
    drive raise AL502 there)."""
    bad = sto((1095, 5000), (100, 5000), [(1100, ["AL502"]), (1105, ["AL502", "AL500"])])
    vs = by_name(check(SPECS["sto"], bad), "no AL502 while both channels are lost")
    assert [v.status for v in vs] == ["fail"]
    good = sto((1095, 5000), (100, 5000), [(1105, ["AL500"])])
    vs = by_name(check(SPECS["sto"], good), "no AL502 while both channels are lost")
    assert [v.status for v in vs] == ["pass"]


def test_restored_channels_do_not_clear_al500():
    good = sto((100, 200), (100, 200), [(110, ["AL500"]), (302, [])], arst=[(300, True)])
    v = by_name(check(SPECS["sto"], good), "AL500 stays until a reset after both channels are back")
    assert v[0].status == "pass"
    bad = sto((100, 200), (100, 200), [(110, ["AL500"]), (250, [])])
    v = by_name(check(SPECS["sto"], bad), "AL500 stays until a reset after both channels are back")
    assert v[0].status == "fail" and "AL500 cleared" in v[0].message


# --- resets (L2493, L15082, L20199-20211) ----------------------------------------------


def test_arst_clears_al500_but_not_al501():
    ok = sto((100, 200), (100, 200), [(110, ["AL500"]), (302, [])],
             arst=[(300, True), (350, False)])
    vs = check(SPECS["sto_reset"], ok)
    assert by_name(vs, "ARST rising edge clears AL500 once both channels are back")[0].status \
        == "pass"
    bad = sto((100, 2000), None, [(1100, ["AL501"]), (2302, [])],
              arst=[(2300, True), (2350, False)])
    v = by_name(check(SPECS["sto_reset"], bad), "AL501 survives ARST")[0]
    assert v.status == "fail" and "AL501 cleared 2.0 ms after ARST rose" in v.message


def test_alarm_clears_on_the_rising_edge_only():
    rise = sto((100, 200), (100, 200), [(110, ["AL500"]), (302, [])],
               arst=[(300, True), (400, False)])
    assert all(v.status in ("pass", "skipped") for v in check(SPECS["alarm_reset"], rise))
    fall = sto((100, 200), (100, 200), [(110, ["AL500"]), (402, [])],
               arst=[(300, True), (400, False)])
    vs = check(SPECS["alarm_reset"], fall)
    assert by_name(vs, "the falling edge of ARST does not clear")[0].status == "fail"
    v = by_name(vs, "every clear follows an ARST rising edge by P2.009")[0]
    assert v.status == "fail" and "alarm cleared 102.0 ms after ARST rose" in v.message


def test_alarm_reset_binding_selects_the_alarm():
    src = source({(dio("DI5"), "level"): [(0, False), (10, True)],
                  (STATE, "alarms"): [(0, ["AL020"]), (12, [])]}, params={"P2.009": 2})
    vs = check(SPECS["alarm_reset"], src, binding={"alarm": "AL020"})
    assert by_name(vs, "every clear follows an ARST rising edge by P2.009")[0].status == "pass"


# --- EMGS (L15184, L19338, L19557, L8516) ------------------------------------------------


def test_emgs_sequence():
    src = source({
        (dio("DI8"), "level"): [(0, True), (100, False), (500, True)],  # b-contact: open = EMGS
        (STATE, "alarms"): [(0, []), (102, ["AL013"]), (502, [])],
        (STATE, "servo_on"): [(0, True), (102, False)],
        (STATE, "torque_enabled"): [(0, True), (102, False)],
        (STATE, "speed_rpm"): [(0, 1000.0), (150, 0.0)],
        (dio("DO6"), "level"): [(0, True), (102, False)],
    }, params={"P2.009": 2, "P1.043": -20, "P1.038": 100})
    vs = check(SPECS["emgs"], src)
    assert [v.status for v in vs] == ["pass"] * 7, [v.message for v in vs]


# --- CiA 402 (L18243-18331) -------------------------------------------------------------


def test_cia402_transitions_within_bound():
    src = source({
        ("/canopen/can0", "controlword"): [(0, 0x00), (10, 0x06), (20, 0x07), (30, 0x0F)],
        ("/canopen/can0", "statusword"): [(0, 0x0250), (14, 0x0231), (22, 0x0233),
                                          (45, 0x0237)],
    })
    vs = check(SPECS["cia402_transitions"], src)
    st = {v.constraint.split(":")[0]: v.status for v in vs}
    assert st["transitions 2/6/8"] == "pass" and st["transition 3"] == "pass"
    v = by_name(vs, "transition 4 (3+4): Enable operation -> OPERATION ENABLED")[0]
    assert v.status == "fail" and "15.0 ms after Enable operation written" in v.message
    vs = check(SPECS["cia402_transitions"], src, constants={"cia402_max": 20})
    assert by_name(vs, "transition 4 (3+4): Enable operation -> OPERATION ENABLED")[0].status \
        == "pass"


# --- format features on small specs ------------------------------------------------------


MINI = """\
id: mini
title: mini
source: "L1"
signals:
  A: {topic: /a, field: v}
  B: {topic: /b, field: v}
  C: {topic: /c, field: v}
events:
  a: {rise: A}
  b: {rise: B, after: a}
  c: {rise: C, after: a}
  first: {earliest_of: [b, c]}
  last: {latest_of: [b, c]}
constraints:
  - {name: first, from: a, to: first, window: {max: 10}}
  - {name: last, from: a, to: last, window: {max: 10}}
  - {name: no B, forbid: b, from: a, window: {min: 0, max: 3}}
  - {name: A held, present: A, from: a, window: {min: 0, max: 20}}
"""


def test_earliest_latest_forbid_present():
    src = source({("/a", "v"): [(0, 0), (10, 1), (35, 0)], ("/b", "v"): [(0, 0), (15, 1)],
                  ("/c", "v"): [(0, 0), (40, 1)]})
    vs = {v.constraint: v for v in check(loads_spec(MINI), src)}
    assert vs["first"].status == "pass" and vs["first"].measured_ms == 5.0
    assert vs["last"].status == "fail" and vs["last"].measured_ms == 30.0
    assert vs["no B"].status == "pass"
    assert vs["A held"].status == "pass"
    src = source({("/a", "v"): [(0, 0), (10, 1), (20, 0)], ("/b", "v"): [(0, 0), (12, 1)],
                  ("/c", "v"): [(0, 0)]})
    vs = {v.constraint: v for v in check(loads_spec(MINI), src)}
    assert vs["first"].status == "pass" and vs["last"].status == "fail"
    assert "never did" in vs["last"].message
    assert vs["no B"].status == "fail" and vs["A held"].status == "fail"


ROOTED = """
id: rooted
title: a constraint with no for_each whose start event is a plain edge
source: "-"
signals:
  A: {topic: /a, field: v}
  B: {topic: /b, field: v}
events:
  a: {rise: A}
  b: {rise: B, after: a, within: 100}
  a_plus: {at: a, plus: 5}
constraints:
  - name: B after A
    from: a
    to: b
    window: {max: 10}
  - name: B after A + 5
    from: a_plus
    to: b
    window: {max: 10}
"""


def test_a_start_event_that_never_happens_is_not_applicable():
    """No rise of A at all: the scenario is not in the recording, as for a for_each with no
    trigger ("not applicable", skipped); A that rises with no B after it is a failure, and
    "never did" counts from the recording's start, not from the epoch."""
    spec = loads_spec(ROOTED)
    t0 = 1_700_000_000_000  # ms: epoch-stamped like a real recording
    src = source({("/a", "v"): [(t0, 0)], ("/b", "v"): [(t0, 0), (t0 + 50, 1)]})
    vs = check(spec, src)
    assert [v.status for v in vs] == ["skipped", "skipped"], [v.message for v in vs]
    assert all(v.message.startswith("not applicable: expected A to rise") for v in vs)
    assert all("never did in 50.0 ms" in v.message for v in vs), [v.message for v in vs]
    src = source({("/a", "v"): [(t0, 0), (t0 + 10, 1)], ("/b", "v"): [(t0, 0)]})
    assert [v.status for v in check(spec, src)] == ["fail", "fail"]


WIRE = """
id: wire
title: events on frames recorded on the wire
source: "-"
signals:
  SYNC: {topic: /canopen/can0, field: kind, where: {dir: tx, kind: sync}}
  GO: {topic: /go, field: v}
  DONE: {topic: /done, field: v}
events:
  go: {rise: GO}
  sync: {message: SYNC}
  first: {message: SYNC, after: go, label: the first SYNC after GO}
  last: {message: SYNC, before: go, label: the last SYNC before GO}
  done: {rise: DONE, after: go}
constraints:
  - {name: done after the first SYNC, from: first, to: done, window: {max: 5}}
  - {name: done after the last SYNC, from: last, to: done, window: {max: 50}}
  - {name: each SYNC, for_each: sync, forbid: done, from: sync, window: {min: 0, max: 1}}
  - {name: no SYNC soon after GO, forbid: first, from: go, window: {min: 0, max: 20}}
"""


def _wire_source(syncs_ms, go_ms, done_ms):
    from hil.timing.source import MemorySource
    src = MemorySource()
    frames = [(t, {"dir": "tx", "kind": "sync"}) for t in syncs_ms]
    frames += [(t + 0.5, {"dir": "rx", "kind": "tpdo1"}) for t in syncs_ms]  # others ignored
    for t, m in sorted(frames, key=lambda x: x[0]):
        src.add("/canopen/can0", round(t * 1e6), m)
    for topic, t in (("/go", go_ms), ("/done", done_ms)):
        src.add(topic, 0, {"v": False})
        src.add(topic, round(t * 1e6), {"v": True})
    return src


def test_message_events_are_every_recorded_frame_even_with_the_same_value():
    """`message:` is each message of its signal (a SYNC frame every 20 ms, each "sync"):
    `rise`/`first_true` would see one value and no edge. `after`/`before` pick the frame
    next to the anchor; under `for_each` each frame is judged; `forbid` finds one."""
    spec = loads_spec(WIRE)
    src = _wire_source([0, 20, 40, 60, 80], go_ms=45, done_ms=62)
    vs = {v.constraint: v for v in check(spec, src) if v.constraint != "each SYNC"}
    assert vs["done after the first SYNC"].status == "pass"
    assert vs["done after the first SYNC"].measured_ms == 2.0  # SYNC at 60, not GO at 45
    assert "the first SYNC after GO" in vs["done after the first SYNC"].message
    assert vs["done after the last SYNC"].measured_ms == 22.0  # the SYNC at 40
    assert vs["no SYNC soon after GO"].status == "fail"  # the one at 60 is 15 ms after GO
    each = [v for v in check(spec, src) if v.constraint == "each SYNC"]
    assert [v.status for v in each] == ["pass"] * 5  # one verdict per frame
    late = _wire_source([0, 20, 40, 90], go_ms=45, done_ms=97)  # the SYNC producer ran late
    vs = {v.constraint: v for v in check(spec, late)}
    assert vs["done after the first SYNC"].status == "fail"  # 7 ms after the SYNC at 90
    assert vs["no SYNC soon after GO"].status == "pass"


def test_message_event_needs_a_topic_signal():
    bad = WIRE.replace("  first: {message: SYNC,", "  first: {message: GO_NOT,")
    with pytest.raises(Exception, match=r":12: events.first.message: unknown signal 'GO_NOT'"):
        loads_spec(bad)
    bad = WIRE.replace("  DONE: {topic: /done, field: v}",
                       "  DONE: {topic: /done, field: v}\n  NOT_GO: {not: GO}").replace(
        "  first: {message: SYNC,", "  first: {message: NOT_GO,")
    with pytest.raises(Exception, match=r"not read from a topic"):
        loads_spec(bad)


def test_a_brake_release_lost_with_a_damaged_chunk_is_inconclusive_not_a_fail():
    """A recording damaged at 150 ms (hil.timing.source: `cut_ns`): BRKR's rise, due after
    SON accepted at 102 ms, may be in the part that could not be read. Unknown, not absent."""
    src = servo_on([None])
    assert by_name(check(SPECS["servo_on_brake"], src), BRAKE_ON)[0].status == "fail"
    src.cut_ns = 150_000_000
    v = by_name(check(SPECS["servo_on_brake"], src), BRAKE_ON)[0]
    assert v.status == "inconclusive" and "could not be read" in v.message


def test_a_when_is_judged_without_a_signal_it_does_not_need():
    """`and`/`or` stop at the first operand that decides: cia402_transitions' transition 4
    reads the ground truth's alarms only when statusword bit 7 warns, so a recording of the
    wire alone is judged while no warning shows, and inconclusive when one does."""
    def src(sw_enabled: int):
        return source({
            ("/canopen/can0", "controlword"): [(0, 0x00), (10, 0x06), (20, 0x07), (30, 0x0F)],
            ("/canopen/can0", "statusword"): [(0, 0x0250), (14, 0x0231), (22, sw_enabled),
                                              (35, 0x0237)],
        })
    rule = "transition 4 (3+4): Enable operation -> OPERATION ENABLED"
    assert by_name(check(SPECS["cia402_transitions"], src(0x0233)), rule)[0].status == "pass"
    v = by_name(check(SPECS["cia402_transitions"], src(0x02B3)), rule)[0]  # bit 7 set
    assert v.status == "inconclusive" and "HOLD unknown" in v.message, v.message


def test_a_servo_on_shorter_than_p1042_leaves_the_brake_alone():
    """Servo on, then off 50 ms later with P1.042 = 150 (servo_brake_settings step 5: the
    servo comes back when AL013 clears with SON held, then SON opens): BRKR never rises, as
    it should; the brake rule had failed it ("never did"). helper-96 F7."""
    src = source({(dio("DI1"), "level"): [(0, False), (100, True), (400, False)],
                  (dio("DO1"), "level"): [(0, True)], (dio("DO6"), "level"): [(0, False)],
                  (STATE, "servo_on"): [(0, False), (102, True), (152, False), (600, False)],
                  (STATE, "alarms"): [(0, [])]}, params={"P1.042": 150, "P2.009": 2})
    vs = check(SPECS["servo_on_brake"], src)
    assert not [v for v in vs if v.status == "fail"], [v.message for v in vs]


def test_a_servo_on_without_son_is_judged_too():
    """P1.042 counts from the servo on (L8499), however it came: a CiA 402 enable with no SON
    edge, BRKR 40 ms late, fails."""
    src = source({(dio("DI1"), "level"): [(0, False)], (dio("DO1"), "level"): [(0, True)],
                  (dio("DO6"), "level"): [(0, False), (292, True)],
                  (STATE, "servo_on"): [(0, False), (102, True), (800, True)],
                  (STATE, "alarms"): [(0, [])]}, params={"P1.042": 150, "P2.009": 2})
    [v] = by_name(check(SPECS["servo_on_brake"], src), BRAKE_ON)
    assert v.status == "fail" and "190.0 ms after servo on" in v.message, v.message
