"""pfqs.yaml on the model: the PFQS quick stop (L15253; AL35F L20141-20145, AL3CF
L20153-20157; P5.003.C L11084-11100) passes on the faithful drive and fails on a drive that
ramps with the wrong time (`dev_pfqs_ramp_ms`)."""

from __future__ import annotations

from pathlib import Path

from hil.model.options import ModelOptions
from hil.units import MS
from hil.virtual.model_tap import ModelTap
from tests.timing.test_specs_on_model import assert_all_pass, assert_fails, run, verdicts

PFQS_DI10 = {"P2.037": 0x0147}  # DI10 = PFQS, a-contact: the spec's binding


def pfqs_at_1500_rpm(tap: ModelTap) -> None:
    tap.write_object(0x6060, 0, 3)  # PV
    for cw in (0x06, 0x07, 0x0F):
        tap.write_object(0x6040, 0, cw)
        tap.advance(5 * MS)
    tap.write_object(0x6083, 0, 200)
    tap.write_object(0x60FF, 0, 15000)  # 1500 rpm (spec constant v0)
    tap.advance(300 * MS)
    tap.set_di(10, True)
    tap.advance(100 * MS)
    tap.set_di(10, False)


def test_pfqs_spec_passes_on_the_model(tmp_path: Path) -> None:
    assert_all_pass(verdicts(run(tmp_path, pfqs_at_1500_rpm, **PFQS_DI10), "pfqs"))


def test_pfqs_spec_fails_on_a_wrong_ramp(tmp_path: Path) -> None:
    path = run(tmp_path, pfqs_at_1500_rpm, ModelOptions(dev_pfqs_ramp_ms=100.0), **PFQS_DI10)
    assert_fails(verdicts(path, "pfqs"), "AL3CF when the P5.003.C ramp reached 0")
