"""The model's per-step shortcuts give what the full computation gives: parameters read through
`ParameterStore.cached` (looked up again only after a change), the AL009 window test that
skips the exact PUU difference far from the limit, the PUU-overflow test that skips the PUU
far from its range (docs/performance.md, session 12)."""

from __future__ import annotations

import random

from hil.model.absolute import PUU_MAX, PUU_MIN, AbsoluteEncoder, _trunc_div
from hil.model.cia402 import PP, Cia402
from hil.model.motion import Axis
from hil.model.params import ParameterStore
from hil.model.timebase import Scheduler

NAMES = ("P1.038", "P1.001", "P2.035", "P6.001", "P0.001")


def _now(store: ParameterStore) -> tuple[int, ...]:
    return tuple(store.get(n) for n in NAMES)


def test_cached_values_follow_every_kind_of_change(tmp_path):
    store = ParameterStore(retained_path=tmp_path / "params.json")
    values = store.cached(*NAMES)
    assert values() == _now(store)
    store.write("P1.038", 250)  # in effect at once
    assert values() == _now(store) and values()[0] == 250
    store.write("P1.001", 0x0C)  # ●: in effect after a power cycle (L6722)
    assert values() == _now(store) and values()[1] != 0x0C
    store.power_cycle()
    assert values() == _now(store) and values()[1] == 0x0C
    store.set_internal("P0.001", 0x500)  # a drive-side update
    assert values() == _now(store) and values()[4] == 0x500
    store.write("P6.001", 7)
    assert values() == _now(store)
    store.reset_defaults()
    assert values() == _now(store)
    store.write("P2.035", 1234)
    again = ParameterStore(retained_path=tmp_path / "params.json")  # retained values loaded
    assert again.cached(*NAMES)() == _now(again)


def test_a_parameter_with_a_read_hook_is_read_at_every_call():
    store = ParameterStore()
    values = store.cached("P1.038", "P0.002")
    ticks = iter(range(100, 200))
    store.on_read("P0.002", lambda: next(ticks))
    assert [values()[1] for _ in range(3)] == [100, 101, 102]


def test_the_al009_window_shortcut_agrees_with_the_exact_puu_difference():
    """60F4h = round(demand PUU) - round(feedback PUU); AL009 when |60F4h| > 6065h (L18452)."""
    rng = random.Random(7)
    axis = Axis()
    cia = Cia402(axis, clock=lambda: 0)
    cia.power_on()
    cia.write(0x6060, 0, PP)
    for cw in (0x06, 0x07, 0x0F):
        cia.write(0x6040, 0, cw)
    assert cia.servo_enable_requested
    for _ in range(5000):
        num, den = rng.choice([(1, 1), (16777216, 100000), (3, 7), (1, 536870911)])
        cia._num, cia._den = num, den
        limit = rng.choice([0, 1, 2, 3, 50, 3000, 2**31 - 1])
        cia._v[(0x6065, 0)] = limit
        base = rng.choice([0.0, 1e9, -3.3e10, 12345.678])
        axis.position = base + rng.uniform(-1e6, 1e6)
        err = limit * num / den * rng.uniform(0.0, 1.5) + rng.choice([0.0, 0.49, 0.5, 1.0])
        axis.demand = axis.position + rng.choice([1, -1]) * err
        assert cia.following_error_exceeded == (abs(cia._fe_puu()) > limit)


def test_the_puu_overflow_shortcut_never_hides_an_overflow():
    """PUU = ±pulse × P1.045/P1.044 + P6.001 (L16408-16410), in range -2^31..2^31-1 (L16417)."""
    rng = random.Random(11)
    store = ParameterStore()
    enc = AbsoluteEncoder(Scheduler(), store, set_cause=lambda c, p: None,
                          set_output=lambda s, a: None, hook_params=False)
    for _ in range(300):
        n, m = rng.choice([(1, 1), (100000, 16777216), (7, 3), (536870911, 1)])
        store.set_internal("P1.045", n)
        store.set_internal("P1.044", m)
        store.set_internal("P6.001", rng.choice([0, 5, -(2**31), 2**31 - 1, 10**9]))
        for _ in range(40):
            edge = (PUU_MAX - store.get("P6.001")) * m // n
            pulse = rng.choice([0, edge, edge + 1, -edge, rng.randint(-(2**40), 2**40)])
            pulse += rng.randint(-3, 3)
            sign = -1 if enc.cw_positive else 1
            exact = _trunc_div(sign * pulse * n, m) + store.get("P6.001")
            if enc._puu_surely_inside(pulse):
                assert PUU_MIN <= exact <= PUU_MAX
