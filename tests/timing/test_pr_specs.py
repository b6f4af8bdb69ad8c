"""The PR timing specs pass on the faithful drive and fail on each PR deviation knob
(A3 chapter 7: completion L4195-4201, L8596-8633, L15319; DLY L4934-4947; jump L4505-4527,
L4982; speed DLY L4934, L4951; overlap L5051-5057; software limit L11191-11198,
L20105-20109, L11084-11100)."""

from __future__ import annotations

import pytest

from hil.model.options import ModelOptions
from hil.paths import fixture
from hil.profile.pr import encode
from hil.timing.checker import check
from hil.timing.source import RecordingSource
from hil.timing.spec import load_spec
from hil.units import MS
from tests.timing.test_specs_on_model import assert_all_pass, assert_fails, run

PARAMS = {
    "P1.001": 0x0001,  # PR mode
    "P2.011": 0x0108,  # DI2 CTRG
    "P2.012": 0x0111,  # DI3 POS0
    "P2.013": 0x0112,  # DI4 POS1
    "P2.019": 0x0115,  # DO2 Cmd_OK
    "P2.020": 0x0117,  # DO3 MC_OK
}
SOFT_LIMIT = PARAMS | {
    "P2.020": 0x0114,  # DO3 SPL (L15316)
    "P2.021": 0x0113,  # DO4 SNL (L15313)
    "P5.008": 100000,  # positive software limit, PUU (L11191)
    "P5.009": -100000,  # negative software limit, PUU (L11200)
}


def table(tap, paths: dict[int, tuple]) -> None:
    for n, (args, kw) in paths.items():
        definition, data = encode(*args, **kw)
        tap.drive.params.write(f"P6.{2 * n:03d}", definition)
        tap.drive.params.write(f"P6.{2 * n + 1:03d}", data)


def ctrg(tap, n: int, run_ms: int) -> None:
    """POS0/POS1 = n, then a CTRG pulse (L4834-4840, L15098); let it run `run_ms`."""
    tap.set_di(3, bool(n & 1))
    tap.set_di(4, bool(n & 2))
    tap.advance(5 * MS + 300_000)
    tap.set_di(2, True)
    tap.advance(run_ms * MS)
    tap.set_di(2, False)


def servo_on(tap) -> None:
    tap.set_di(1, True)
    tap.advance(300 * MS)


# -- scenarios ------------------------------------------------------------------------------
def pr_move(tap) -> None:
    """One SINGLE move with DLY #1 = P5.041 = 100 ms: TPOS before Cmd_OK (figure 7.1.2.4)."""
    table(tap, {1: (("single", 50000), {"spd": 4, "dly": 1})})
    servo_on(tap)
    ctrg(tap, 1, 800)


def pr_move_no_dly(tap) -> None:
    """No DLY and P1.054 = 1000 pulses: Cmd_OK before TPOS, MC_OK waits for TPOS (L4201)."""
    tap.drive.params.write("P1.054", 1000)
    table(tap, {1: (("single", 50000), {"spd": 4})})
    servo_on(tap)
    ctrg(tap, 1, 800)


def pr_two_paths_no_dly_b(tap) -> None:
    """PR#1 AUTO with DLY #1 (100 ms) -> PR#2 SINGLE without DLY: Cmd_OK comes as PR#2's
    command ends (L15319), before the feedback has settled there; the spec's absent rule ran
    to the feedback at rest and failed the drive (helper-97)."""
    table(tap, {
        1: (("auto", 50000), {"cmd": "INC", "spd": 4, "dly": 1}),
        2: (("single", 30000), {"cmd": "INC", "spd": 4}),
    })
    servo_on(tap)
    ctrg(tap, 1, 1200)


def pr_two_paths(tap) -> None:
    """PR#1 AUTO with DLY #1 (100 ms) -> PR#2 SINGLE with DLY #2 (200 ms) (L4934-4947)."""
    table(tap, {
        1: (("auto", 50000), {"cmd": "INC", "spd": 4, "dly": 1}),
        2: (("single", 30000), {"cmd": "INC", "spd": 4, "dly": 2}),
    })
    servo_on(tap)
    ctrg(tap, 1, 1200)


def pr_overlapping_paths(tap) -> None:
    """PR#1 AUTO with OVLP -> PR#2, both 300 rpm, 20 ms ramps (figure 7.1.6.11(b))."""
    table(tap, {
        1: (("auto", 50000), {"cmd": "INC", "spd": 4, "ovlp": True}),
        2: (("single", 30000), {"cmd": "INC", "spd": 4}),
    })
    servo_on(tap)
    ctrg(tap, 1, 800)


def pr_speed_paths(tap) -> None:
    """SPEED 300 rpm (DLY #1) -> 600 rpm (DLY #1) -> 0, ACC #0 = 200 ms (figure 7.1.6.3(b))."""
    table(tap, {
        1: (("speed", 3000), {"auto": True, "dly": 1}),
        2: (("speed", 6000), {"auto": True, "dly": 1}),
        3: (("speed", 0), {}),
    })
    servo_on(tap)
    ctrg(tap, 1, 600)


def pr_jump_chain(tap) -> None:
    """PR#1 AUTO -> PR#2 JUMP to PR#4 with DLY #1 (100 ms); PR#3 (to 250000) is skipped."""
    table(tap, {
        1: (("auto", 50000), {"cmd": "INC", "spd": 4}),
        2: (("jump", 4), {"dly": 1}),
        3: (("single", 200000), {"cmd": "INC", "spd": 4}),
        4: (("single", -50000), {"cmd": "INC", "spd": 4}),
    })
    servo_on(tap)
    ctrg(tap, 1, 1500)


def pr_soft_limit(tap) -> None:
    """P5.008 = 100000: to 200000 (AL283), back to 0, to 99990 (only the feedback passes)."""
    table(tap, {
        1: (("single", 200000), {"spd": 4}),
        2: (("single", 0), {"spd": 4}),
        3: (("single", 99990), {"spd": 4}),
    })
    servo_on(tap)
    for n in (1, 2, 3):
        ctrg(tap, n, 600)


def pr_soft_limit_negative(tap) -> None:
    """P5.009 = -100000: to -200000 (AL285), back to 0, to -99990 (only the feedback passes)."""
    table(tap, {
        1: (("single", -200000), {"spd": 4}),
        2: (("single", 0), {"spd": 4}),
        3: (("single", -99990), {"spd": 4}),
    })
    servo_on(tap)
    for n in (1, 2, 3):
        ctrg(tap, n, 600)


def verdicts(path, spec_id: str, **constants: float) -> list:
    spec = load_spec(fixture("timing", f"{spec_id}.yaml"))
    return check(spec, RecordingSource(path), constants=constants or None)


def options(**dev) -> ModelOptions:
    return ModelOptions(state_publish_ms=1, extra={"pr": dev})


# command times (pr_delay notes): 50000 PUU at 300 rpm = 100 ms + (20 + 20) / 2 ms ramps
MOVE_50K, MOVE_30K = 120, 80
CASES = {  # spec id -> (scenario, params, constants)
    "pr_completion": (pr_move, PARAMS, {"dly": 100, "move": MOVE_50K}),
    "pr_completion/no_dly": (pr_move_no_dly, PARAMS, {"dly": 0, "move": MOVE_50K}),
    "pr_delay": (pr_two_paths, PARAMS, {"move_a": MOVE_50K, "move_b": MOVE_30K}),
    "pr_delay/no_dly_b": (pr_two_paths_no_dly_b, PARAMS,
                          {"move_a": MOVE_50K, "move_b": MOVE_30K, "dly_b": 0}),
    "pr_jump": (pr_jump_chain, PARAMS, {"move_a": MOVE_50K}),
    "pr_speed_delay": (pr_speed_paths, PARAMS, {}),
    "pr_overlap": (pr_overlapping_paths, PARAMS, {"move_a": MOVE_50K, "move_b": MOVE_30K}),
    "pr_soft_limit": (pr_soft_limit, SOFT_LIMIT, {}),
    "pr_soft_limit_negative": (pr_soft_limit_negative, SOFT_LIMIT, {}),
}


def judge(tmp_path, case: str, **dev) -> list:
    scenario, params, constants = CASES[case]
    path = run(tmp_path, scenario, options(**dev), **params)
    return verdicts(path, case.split("/")[0], **constants)


def assert_constraint_fails(vs: list, constraint: str) -> None:
    """A presence/absence rule: its verdict (not another one) is a failure."""
    assert any(v.status == "fail" and constraint in v.constraint for v in vs), [
        (v.constraint, v.status, v.message) for v in vs
    ]


@pytest.mark.parametrize("case", list(CASES))
def test_faithful_drive_passes(tmp_path, case) -> None:
    assert_all_pass(judge(tmp_path, case))


@pytest.mark.parametrize("case", ["pr_soft_limit", "pr_soft_limit_negative"])
def test_soft_limit_scenario_overshoots_the_limit_with_the_feedback(tmp_path, case) -> None:
    """Move 3 is the case L20107-20108 is about: the feedback passes the limit, the command
    not."""
    vs = judge(tmp_path, case)
    pre = [v for v in vs if v.constraint.startswith("the feedback of move 3")]
    assert pre and pre[0].status == "pass", pre
    assert not any(v.status == "fail" for v in vs)


DEVIATIONS = [  # (case, knob, the constraint it breaks)
    ("pr_completion", {"dev_start_delay_ms": 5}, "motion starts after the P2.009 filter"),
    ("pr_completion", {"dev_cmd_ok_ignores_dly": True}, "Cmd_OK rises DLY after"),
    ("pr_completion", {"dev_dly_offset_ms": 7}, "Cmd_OK rises DLY after the command time"),
    ("pr_completion", {"dev_dly_offset_ms": 40}, "Cmd_OK rises DLY after the command ends"),
    ("pr_completion/no_dly", {"dev_mc_ok_ignores_tpos": True},
     "MC_OK rises once Cmd_OK and TPOS are both on"),
    ("pr_delay", {"dev_dly_offset_ms": 5}, "PR b starts PR a's command time plus DLY a"),
    ("pr_delay", {"dev_dly_offset_ms": 50}, "PR b starts DLY a after PR a arrived"),
    ("pr_delay", {"dev_dly_from_start": True}, "PR b starts DLY a after PR a arrived"),
    ("pr_delay", {"dev_cmd_ok_ignores_dly": True}, "Cmd_OK rises DLY b after"),
    ("pr_delay", {"dev_cmd_ok_ignores_dly": True}, "Cmd_OK rises PR b's command time"),
    ("pr_jump", {"dev_jump_ignores_dly": True}, "PR b starts the jump's DLY"),
    ("pr_jump", {"dev_dly_offset_ms": 5}, "PR b starts PR a's command time plus the jump"),
    ("pr_jump", {"dev_dly_offset_ms": 50}, "PR b starts the jump's DLY"),
    ("pr_speed_delay", {"dev_dly_from_start": True}, "PR c starts DLY b after PR b's command"),
    ("pr_speed_delay", {"dev_dly_offset_ms": 8}, "PR b starts DLY a after PR a's command"),
    ("pr_overlap", {"dev_ovlp_ignored": True}, "the axis slows down only at the end of PR b"),
    ("pr_overlap", {"dev_ovlp_ignored": True}, "Cmd_OK rises the overlapped ramp earlier"),
    ("pr_soft_limit", {"dev_soft_limit_on_feedback": True},
     "no AL283 while only the feedback is past P5.008"),
    ("pr_soft_limit", {"dev_soft_limit_decel_ms": 5000},
     "the motor stops with the P5.003.Z deceleration"),
    ("pr_soft_limit_negative", {"dev_soft_limit_on_feedback": True},
     "no AL285 while only the feedback is past P5.009"),
    ("pr_soft_limit_negative", {"dev_soft_limit_decel_ms": 5000},
     "the motor stops with the P5.003.U deceleration"),
]


@pytest.mark.parametrize(("case", "rule"), [
    ("pr_soft_limit", "the motor stops with the P5.003.Z deceleration"),
    ("pr_soft_limit_negative", "the motor stops with the P5.003.U deceleration")])
def test_a_soft_limit_stop_sooner_than_its_ramp_fails(tmp_path, case, rule) -> None:
    """P5.003.Z/U pick the stop's deceleration (P5.034 for the default E, L11091-11100). With
    P5.034 = 1500 ms per 3000 rpm the stop from 300 rpm ramps 150 ms: a drive that stops at
    once fails (the window had no lower limit; at 50 ms per 3000 rpm the 5 ms ramp hides in
    the feedback's settling, helper-97)."""
    scenario, params, constants = CASES[case]
    params = params | {"P5.034": 1500}
    constants = constants | {"decel": 1500}
    good = verdicts(run(tmp_path / "good", scenario, options(), **params), case, **constants)
    assert [v.status for v in good if v.constraint == rule] == ["pass"], [
        v.message for v in good if v.constraint == rule]
    bad = verdicts(run(tmp_path / "bad", scenario, options(dev_soft_limit_decel_ms=0.001),
                       **params), case, **constants)
    assert [v.status for v in bad if v.constraint == rule] == ["fail"], [
        v.message for v in bad if v.constraint == rule]


@pytest.mark.parametrize(
    ("case", "knob", "constraint"), DEVIATIONS,
    ids=lambda x: next(iter(x)) if isinstance(x, dict) else x,
)
def test_deviating_drive_fails(tmp_path, case, knob, constraint) -> None:
    assert_fails(judge(tmp_path, case, **knob), constraint)


@pytest.mark.parametrize(
    ("case", "knob", "constraint"),
    [
        ("pr_completion/no_dly", {"dev_mc_ok_ignores_tpos": True},
         "MC_OK rises with Cmd_OK when TPOS is on"),
        ("pr_jump", {"dev_jump_falls_through": True},
         "the paths between the jump and its target never run"),
    ],
    ids=lambda x: next(iter(x)) if isinstance(x, dict) else x,
)
def test_deviating_drive_breaks_a_state_rule(tmp_path, case, knob, constraint) -> None:
    assert_constraint_fails(judge(tmp_path, case, **knob), constraint)


def test_every_pr_spec_has_a_model_case_a_knob_and_a_plan() -> None:
    """A new fixtures/timing/pr_*.yaml needs a scenario and a deviation knob here and a plan
    that checks it (issue 14: each spec can fail; plans use the specs)."""
    from hil.plan.plan import find_plans

    specs = {p.stem for p in fixture("timing").glob("pr_*.yaml")}
    assert specs == {c.partition("/")[0] for c in CASES}
    knobbed = {c.partition("/")[0] for c, _k, _n in DEVIATIONS}
    assert specs <= knobbed
    checked = "".join(p.read_text() for p in find_plans() if p.stem.startswith("pr_"))
    assert all(f"check_timing: {s}" in checked or f"spec: {s}" in checked for s in specs)
