"""The ground truth's schemas declare what the model produces (issue 28 item 1): a field added
to `Drive.snapshot()` or to a model event without its schema fails here, fast, before the
shipped-plan recordings (tests/test_plans_hil.py) show it."""

from __future__ import annotations

import dataclasses
import typing
from typing import Annotated, Literal, NotRequired, TypedDict

from hil.model import events
from hil.model.drive import Drive
from hil.record.messages import CLOSED, MESSAGES, F
from hil.record.schemas import SCHEMAS, _schema_of, message_problems


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


def test_schemas_are_generated_from_the_message_definitions() -> None:
    # each hil.* schema is its TypedDict in hil/record/messages.py: the same fields, required
    # exactly where the definition does not say NotRequired, closed where CLOSED says
    for name, cls in MESSAGES.items():
        hints = typing.get_type_hints(cls, include_extras=True)
        schema = SCHEMAS[name]
        assert list(schema["properties"]) == list(hints), name
        optional = {k for k, tp in hints.items() if typing.get_origin(tp) is typing.NotRequired}
        assert set(schema["required"]) == set(hints) - optional, name
        assert schema["additionalProperties"] is (name not in CLOSED), name


class Demo(TypedDict):
    a: Annotated[int, F("ns")]
    b: NotRequired[Literal["x", "y"] | None]
    c: NotRequired[list[int] | None]
    d: dict[str, int]
    e: str | int
    f: float


def test_the_generator_maps_python_types_to_json_schema() -> None:
    s = _schema_of("hil.Demo", Demo, closed=True)
    assert s["properties"] == {
        "a": {"type": "integer", "description": "ns"},
        "b": {"type": ["string", "null"], "enum": ["x", "y", None]},
        "c": {"type": ["array", "null"], "items": {"type": "integer"}},
        "d": {"type": "object", "additionalProperties": {"type": "integer"}},
        "e": {"type": ["string", "integer"]},
        "f": {"type": "number"},
    }
    assert s["required"] == ["a", "d", "e", "f"] and s["additionalProperties"] is False
