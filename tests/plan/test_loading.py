"""Shipped benches and plans load and fit together; durations; wiring helpers."""

from __future__ import annotations

import pytest

from hil.bench.bench import load_bench
from hil.bench.yamlio import MS, S, parse_duration
from hil.paths import fixture
from hil.plan.plan import check_plan, find_plans, load_plan
from hil.plan.runner import timing_specs


def test_durations():
    assert parse_duration("150ms") == 150 * MS
    assert parse_duration("1.5s") == 1_500_000_000
    assert parse_duration("20 us") == 20_000
    assert parse_duration("2min") == 120 * S
    for bad in ("150", 150, "1.5 parsecs", True):
        with pytest.raises(ValueError):
            parse_duration(bad)
    # finer than 1 ns is refused (helper-86: `wait: 0.5ns` silently became 0); a float's own
    # error in a whole number of ns is not
    assert parse_duration("0.1us") == 100 and parse_duration("2.3s") == 2_300_000_000
    assert parse_duration("1.000000001s") == 1_000_000_001
    for bad in ("0.5ns", "0.0000001ms", "1.5ns", "1.0000000005s"):
        with pytest.raises(ValueError, match="finer than 1 ns"):
            parse_duration(bad)


def test_virtual_bench_wiring_sets_mapping_parameters():
    from hil.virtual.world import initial_params

    b = load_bench()
    d = b.drives["drive1"]
    assert b.virtual and b.process == "inproc"
    assert d.di["EMGS"].binding == "DI8:b" and d.di["EMGS"].level_for(True) is False
    p = initial_params(d)
    assert p["P2.041"] == 0x0108  # BRKR on DO6, a-contact
    assert p["P2.017"] == 0x0021  # EMGS on DI8, b-contact (L6981)
    assert p["P2.010"] == 0x0101  # SON on DI1 (L1860)


def test_example_real_bench_is_valid_and_motion_free():
    b = load_bench(fixture("benches", "example-asda-a3-socketcan.yaml"))
    assert not b.virtual and not b.motion_allowed
    assert b.can == {"can0": "socketcan:can0"}
    assert b.drives["axis1"].dio.startswith("modbus-tcp://")
    assert b.safe_state.sto == {"A": False, "B": False}


@pytest.mark.parametrize("path", find_plans(), ids=lambda p: p.stem)
def test_shipped_plans_fit_the_virtual_bench(path):
    check_plan(load_plan(path), load_bench(), timing_specs())
