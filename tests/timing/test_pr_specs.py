"""The PR timing spec passes on the faithful drive and fails on each PR deviation knob
(A3 §7.1.6; completion L4195-4201, L8596-8633, L15319)."""

from __future__ import annotations

import pytest

from hil.model.options import ModelOptions
from hil.model.timebase import MS
from hil.paths import fixture
from hil.profile.pr import encode
from hil.timing.checker import check
from hil.timing.source import RecordingSource
from hil.timing.spec import load_spec
from tests.timing.test_specs_on_model import assert_all_pass, assert_fails, run

PARAMS = {
    "P1.001": 0x0001,  # PR mode
    "P2.011": 0x0108,  # DI2 CTRG
    "P2.012": 0x0111,  # DI3 POS0
    "P2.019": 0x0115,  # DO2 Cmd_OK
    "P2.020": 0x0117,  # DO3 MC_OK
}


def pr_move(tap) -> None:
    definition, data = encode("single", 50000, spd=4, dly=1)  # P5.041 = 100 ms
    tap.drive.params.write("P6.002", definition)
    tap.drive.params.write("P6.003", data)
    tap.set_di(1, True)
    tap.advance(300 * MS)
    tap.set_di(3, True)
    tap.advance(5 * MS + 300_000)
    tap.set_di(2, True)
    tap.advance(800 * MS)
    tap.set_di(2, False)


def verdicts(path) -> list:
    spec = load_spec(fixture("timing", "pr_completion.yaml"))
    return check(spec, RecordingSource(path), constants={"dly": 100})


def options(**dev) -> ModelOptions:
    return ModelOptions(state_publish_ms=1, extra={"pr": dev})


def test_faithful_drive_passes(tmp_path) -> None:
    path = run(tmp_path, pr_move, options(), **PARAMS)
    assert_all_pass(verdicts(path))


@pytest.mark.parametrize(
    ("knob", "constraint"),
    [
        ({"dev_start_delay_ms": 5}, "motion starts after the P2.009 filter"),
        ({"dev_cmd_ok_ignores_dly": True}, "Cmd_OK rises DLY after the command ends"),
        ({"dev_dly_offset_ms": 30}, "Cmd_OK rises DLY after the command ends"),
    ],
    ids=lambda x: next(iter(x)) if isinstance(x, dict) else None,
)
def test_deviating_drive_fails(tmp_path, knob, constraint) -> None:
    path = run(tmp_path, pr_move, options(**knob), **PARAMS)
    assert_fails(verdicts(path), constraint)
