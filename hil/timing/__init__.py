"""Timing diagrams of the manual as executable specs, judged on recorded signals.

    spec = load_spec("fixtures/timing/servo_on_brake.yaml")
    verdicts = check(spec, source, params={"P1.042": 150})   # source: a SignalSource

See docs/timing.md for the spec format.
"""

from hil.timing.checker import Verdict, check, check_all, summary
from hil.timing.source import MemorySource, ParamTimeline, RecordingSource, SignalSource
from hil.timing.spec import Spec, SpecError, load_spec, loads_spec, shipped_specs

__all__ = [
    "MemorySource", "ParamTimeline", "RecordingSource", "SignalSource", "Spec", "SpecError",
    "Verdict", "check", "check_all", "load_spec", "loads_spec", "shipped_specs", "summary",
]
