"""The model's parts work on a small core of their own, without a whole `Drive` (core.py).

The rules are the manual's: CAPTURE latches the motor position (CN2) into the data array at
the DI7 edge, 5 µs later (L5150), counts P5.038 down and sets CAP_OK at the last point
(L5155); COMPARE reads its targets from the same data array (L5186-5190).
"""

from __future__ import annotations

import ast
from pathlib import Path
from types import SimpleNamespace

from hil.model.alarms import AlarmManager, AlarmOptions
from hil.model.capture import attach_capture
from hil.model.compare import attach_compare
from hil.model.core import Hooks, new_data_array
from hil.model.dio import DigitalIO
from hil.model.mechanics import Mechanics
from hil.model.motion import Axis
from hil.model.options import ModelOptions
from hil.model.params import ParameterStore
from hil.model.timebase import Scheduler
from hil.units import MS

MODEL = Path(__file__).resolve().parents[2] / "hil" / "model"


class SmallCore:
    """Only what CAPTURE and COMPARE use: no CiA 402, no PR engine, no homing."""

    def __init__(self) -> None:
        self.name = "core"
        self.options = ModelOptions()
        self.sched = Scheduler()
        self.params = ParameterStore()
        self.dio = DigitalIO(self.params, self.sched)
        self.mech = Mechanics()
        self.axis = Axis(self.mech)
        self.alarms = AlarmManager(None, self.sched, self.params, lambda *a: None,
                                   AlarmOptions({}))
        self.hooks = Hooks()
        self.array = new_data_array()
        self.events: list = []
        self.servo_on = self.powered = True
        self.step_ns = MS

    @property
    def now(self) -> int:
        return self.sched.now

    def emit(self, event) -> None:
        self.events.append(event)

    def feedback_counts(self) -> float:
        return self.axis.position


def _core_with_capture():
    core = SmallCore()
    pr = SimpleNamespace(capture_puu=0, triggered=[])
    pr.trigger = lambda n, why: pr.triggered.append((n, why))
    cap = attach_capture(core, pr=pr)
    return core, pr, cap


def test_capture_on_a_small_core_latches_into_the_shared_array() -> None:
    core, pr, cap = _core_with_capture()
    core.axis.position = 16777216 * 2.5  # 2.5 rev: 250000 PUU at P1.044/P1.045 = 16777216/100000
    core.params.write("P5.036", 10)
    core.params.write("P5.038", 2)
    core.params.write("P5.039", 0x0031 | 0x8)  # CN2, NO, start; bit3: PR#50 at the end
    assert cap.running
    core.dio.set_input(7, True)  # DI7 closes: latch 5 µs later (L5150)
    core.sched.advance_to(10_000)
    assert core.array[10] == 250000
    assert pr.capture_puu == 250000  # base of CAP commands (L4471)
    assert core.params.read("P5.038") == 1
    core.dio.set_input(7, False)
    core.sched.advance_to(2 * MS)
    core.axis.position += 16777216  # one more revolution
    core.dio.set_input(7, True)
    core.sched.advance_to(3 * MS)
    assert core.array[11] == 350000
    assert core.dio.do_function_state("CAP_OK")  # the last point (L5155)
    assert pr.triggered == [(50, "CAPTURE")]  # bit3 (L5158)
    assert [type(e).__name__ for e in core.events] == ["CaptureLatched", "CaptureLatched"]


def test_compare_on_a_small_core_reads_its_target_from_the_shared_array() -> None:
    core, pr, cap = _core_with_capture()
    cmp_ = attach_compare(core, capture=cap, pr=pr)
    assert cap.compare is cmp_
    core.array[20] = 1234
    core.params.write("P5.056", 20)
    assert cmp_.target() == 1234 + core.params.get("P1.023") + core.params.get("P1.024")


def test_no_part_of_the_model_imports_the_drive() -> None:
    """Each part gets a DriveCore and its collaborators; only drive.py composes them."""
    offenders = []
    for path in sorted(MODEL.glob("*.py")):
        if path.name == "drive.py":
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            if any(n == "hil.model.drive" for n in names):
                offenders.append(path.name)
    assert offenders == []
