"""A vertical axis on the model drive (helper-105, session 28): gravity acts on a shaft at
rest too. The brake exists because "垂直軸 ... 因重力而下滑" (§2.9 L1351); after STO the drive
"將無法保證馬達不受到外力影響而移動" (L2427). The drive skipped its motion steps at
standstill, so a load never moved a resting shaft and a holding servo showed 0 % torque.
Injected clock."""

from __future__ import annotations

from hil.model.drive import Drive
from hil.model.mechanics import Mechanics
from hil.units import MS

REV = 2 ** 24  # encoder counts a revolution (the model's motor)


def _holding(gravity: float) -> Drive:
    d = Drive(mechanics=Mechanics(gravity_torque=gravity), inputs={8: True},
              params={"P1.042": 0, "P1.043": 0, "P2.041": 0x0108})  # DO6 = BRKR
    d.set_di(1, True)  # SON
    d.advance(100 * MS)
    assert d.servo_on and not d.holding_brake.clamped
    return d


def test_a_holding_servo_carries_the_load():
    """0.8 N·m of a 1.27 N·m rated motor: about 63 % torque while it holds position."""
    d = _holding(0.8)
    assert abs(d.snapshot()["torque_pct"] - 0.8 / 1.27 * 100) < 1
    assert abs(d.feedback_counts()) < REV / 1000


def test_the_shaft_sags_between_brkr_off_and_the_brake_gripping():
    """SON off at rest, P1.043 = 0: BRKR goes off at once (L8503-8516), the brake grips
    `brake_engage_ms` (50) later; in between neither torque nor brake holds the load."""
    d = _holding(0.8)
    p0 = d.feedback_counts()
    d.set_di(1, False)
    d.advance(200 * MS)
    assert d.holding_brake.clamped
    sag = (d.feedback_counts() - p0) / REV
    assert sag < -0.1  # fell towards negative counts (gravity's sign, mechanics.py)
    held = d.feedback_counts()
    d.advance(200 * MS)
    assert d.feedback_counts() == held  # the brake holds it from then on


def test_no_load_no_motion_at_rest():
    d = _holding(0.0)
    p0 = d.feedback_counts()
    d.set_di(1, False)
    d.advance(200 * MS)
    assert d.feedback_counts() == p0


def test_a_load_friction_holds_is_not_stepped_at_rest():
    """Gravity below static friction moves nothing with the torque off: no motion steps."""
    d = Drive(mechanics=Mechanics(gravity_torque=0.01, friction_torque=0.03), inputs={8: True})
    d.advance(10 * MS)
    assert not d.axis.pulled and not d._needs_steps()
    assert Drive(mechanics=Mechanics(gravity_torque=0.8), inputs={8: True}).axis.pulled
