"""The ground truth's schemas declare what the model produces (issue 28 item 1): a field added
to `Drive.snapshot()` or to a model event without its schema fails here, fast, before the
shipped-plan recordings (tests/test_plans_hil.py) show it."""

from __future__ import annotations

import dataclasses

from hil.model import events
from hil.model.drive import Drive
from hil.record.schemas import SCHEMAS, message_problems


def test_drive_snapshot_matches_hil_drive_state() -> None:
    snap = Drive(inputs={8: True}).snapshot() | {"periodic": True}
    assert message_problems("hil.DriveState", snap) == []
    assert set(SCHEMAS["hil.DriveState"]["properties"]) == set(snap)


def test_every_model_event_field_is_declared() -> None:
    props = SCHEMAS["hil.DriveEvent"]["properties"]
    for cls in vars(events).values():
        if dataclasses.is_dataclass(cls) and isinstance(cls, type):
            missing = {f.name for f in dataclasses.fields(cls)} - set(props)
            assert not missing, f"{cls.__name__}: {sorted(missing)} not in hil.DriveEvent"


def test_the_checker_finds_an_undeclared_field_and_a_wrong_type() -> None:
    assert message_problems("hil.PlanStep", {"step": "x", "event": "start", "new": 1}) == [
        "hil.PlanStep: undeclared field 'new'"]
    assert message_problems("hil.DioLevel", {"level": 1}) == [
        "hil.DioLevel: 'level' is int, not boolean"]
