"""PT mode under random use, on the injected clock (wave 3, session 9): segments of every
form, frequency and length interleaved with SON, INHP (DI8), PL (DI5), CCLR (DI2), GNUM0
(DI3) and PT-PR (DI4) edges, parameter writes and P5.018 presets, at random instants off
the 1 ms grid. Whatever happened, the model never raises, the limit is never run into, and
afterwards, alarms reset and inputs idle, a clean segment moves the motor exactly."""

from __future__ import annotations

import math
import random

import pytest

from hil.model.drive import Drive
from hil.model.errors import ModelError
from hil.model.mechanics import COUNTS_PER_REV
from hil.units import MS

PARAMS = {
    "P2.041": 0x0108,  # BRKR on DO6
    "P1.001": 0x000D,  # PT-PR
    "P2.011": 0x0104,  # DI2 = CCLR (factory)
    "P2.012": 0x0143,  # DI3 = GNUM0
    "P2.013": 0x012B,  # DI4 = PT-PR
    "P2.014": 0x0123,  # DI5 = PL, a contact
    "P2.017": 0x0145,  # DI8 = INHP, a contact (EMGS moved off)
    "P1.044": 16777216, "P1.045": 10000, "P2.060": 8388608,
    "P2.035": 50 * COUNTS_PER_REV,  # room for a pile-up of pulses at the limit
}
WRITES = {"P1.008": [0, 2, 10], "P1.068": [1, 4, 20], "P2.065": [0, 0x0800, 0x0040],
          "P2.050": [0, 1], "P5.018": [0, 7, -5]}


ON_CHANCE = {1: 0.85, 2: 0.2, 3: 0.5, 4: 0.25, 5: 0.3, 8: 0.25}  # SON mostly on


def _op(d: Drive, rnd: random.Random) -> None:
    k = rnd.random()
    if k < 0.4:
        d.pulse.segment(rnd.choice([0, 500, 10_000, 10_000, 150_000, 1_500_000, 5_000_000]
                                   if rnd.random() < 0.1 else [500, 10_000, 80_000]),
                        rnd.choice([1, -1]), rnd.choice([0, 1, 37, 1000, 20_000]),
                        form=rnd.choice(["pulse_sign"] * 6 + ["ab", "cw_ccw"]),
                        logic=rnd.choice([0, 0, 0, 1]))
    elif k < 0.75:
        n = rnd.choice(list(ON_CHANCE))
        d.set_di(n, rnd.random() < ON_CHANCE[n])
    elif k < 0.8:
        d.params.write("P0.001", 0)  # alarm reset (L7079-7083)
    else:
        name = rnd.choice(list(WRITES))
        try:
            d.params.write(name, rnd.choice(WRITES[name]))
        except ModelError:
            pass  # refused (servo on, range): the protocol's answer


@pytest.mark.parametrize("seed", range(1, 7))
def test_random_pt_use_never_breaks_the_model_and_a_clean_move_is_exact(seed: int) -> None:
    rnd = random.Random(seed)
    d = Drive(inputs={}, params=PARAMS)
    d.set_di(1, True)
    d.advance(10 * MS)
    pl_since = None
    for _ in range(150):
        _op(d, rnd)
        for _ in range(rnd.randint(1, 4)):
            d.advance(rnd.choice([1, 250_000, 3 * MS, 17 * MS + 333, 60 * MS]))
            if not d.dio.function_active("PL"):
                pl_since = None
            elif pl_since is None:
                pl_since = d.now
            elif d.now - pl_since > 300 * MS:  # past any P5.003 ramp stop (L15190)
                assert d.axis.velocity <= 0, "runs forward into PL"
            assert math.isfinite(d.axis.position) and math.isfinite(d.pulse.error())
    # idle: no pulses, inputs off (PT), alarms reset, servo on
    d.pulse.stop()
    for n in (2, 3, 4, 5, 8):
        d.set_di(n, False)
    d.set_di(1, False)
    d.advance(50 * MS)
    d.params.write("P0.001", 0)  # alarm reset (L7079-7083)
    d.set_di(1, True)
    d.advance(500 * MS)
    assert d.servo_on and d.difunc.control_mode() == "PT", d.alarms.active
    start, accepted = d.axis.position, d.pulse.accepted
    d.params.write("P2.065", 0)
    d.pulse.segment(20_000, -1, 3000, form=d.pulse.form)
    d.advance(3000 * MS)  # 150 ms of pulses, then P1.008 (up to 100 ms) settles
    counts = d.pulse.accepted - accepted
    assert abs(counts) == 3000 * (4 if d.pulse.form == "ab" else 1)
    assert d.axis.position - start == pytest.approx(counts * COUNTS_PER_REV / 10_000, abs=2)
    assert abs(d.pulse.error()) < COUNTS_PER_REV / 10_000
