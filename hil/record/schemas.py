"""JSON schemas of the recording's channels (schema encoding `jsonschema`, message `json`).

Each `hil.*` schema is generated from its message's one definition, a TypedDict in
`hil/record/messages.py` (field names, JSON types, required fields, descriptions, enums).
`foxglove.Log` follows Foxglove's own schema so the Log panel reads `/log` without
configuration.
"""

from __future__ import annotations

import json
import types
from typing import Annotated, Any, Literal, NotRequired, Union, get_args, get_origin, get_type_hints

from hil.record import topics
from hil.record.messages import CLOSED, MESSAGES

_JSON = {int: "integer", float: "number", bool: "boolean", str: "string", type(None): "null"}


def _obj(title: str, props: dict[str, Any], required: list[str], extra: bool = True) -> dict:
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": title,
        "type": "object",
        "properties": props,
        "required": required,
        "additionalProperties": extra,
    }


# https://docs.foxglove.dev/docs/visualization/message-schemas/log (Foxglove's own)
def _schema_of(name: str, cls: type, closed: bool) -> dict:
    """The JSON Schema of one message TypedDict (hil/record/messages.py)."""
    props: dict[str, Any] = {}
    required: list[str] = []
    for key, tp in get_type_hints(cls, include_extras=True).items():
        if get_origin(tp) is NotRequired:
            (tp,) = get_args(tp)
        else:
            required.append(key)
        props[key] = _type_schema(tp)
    return _obj(name, props, required, extra=not closed)


def _type_schema(tp: Any) -> dict[str, Any]:
    """The JSON Schema of one field's annotation (Annotated carries description and extras)."""
    desc, extra = "", {}
    if get_origin(tp) is Annotated:
        base, *meta = get_args(tp)
        for m in meta:
            if hasattr(m, "description"):
                desc = m.description or desc
                extra |= m.extra
        out = _type_schema(base)
    else:
        origin = get_origin(tp)
        if origin in (Union, types.UnionType):
            parts = [_type_schema(a) for a in get_args(tp)]
            names, enum = [], None
            for p in parts:
                t = p["type"]
                for n in (t if isinstance(t, list) else [t]):
                    if n not in names:
                        names.append(n)
                if "enum" in p:
                    enum = (enum or []) + p["enum"]
            out = {"type": names if len(names) > 1 else names[0]}
            if enum is not None:
                if "null" in names:
                    enum = [*enum, None]
                out["enum"] = enum
            for p in parts:
                if "items" in p:
                    out["items"] = p["items"]
        elif origin is Literal:
            vals = list(get_args(tp))
            out = {"type": _JSON[type(vals[0])], "enum": vals}
        elif origin is list:
            (item,) = get_args(tp) or (Any,)
            out = {"type": "array"}
            if item is not Any:
                out["items"] = _type_schema(item)
        elif origin is dict:
            _k, v = get_args(tp) or (str, Any)
            out = {"type": "object"}
            if v is not Any:
                out["additionalProperties"] = _type_schema(v)
        elif tp in _JSON:
            out = {"type": _JSON[tp]}
        else:
            raise TypeError(f"no JSON type for {tp!r}")
    if desc:
        out["description"] = desc
    out |= extra
    return out


SCHEMAS: dict[str, dict] = {
    name: _schema_of(name, cls, name in CLOSED) for name, cls in MESSAGES.items()
}
SCHEMAS["foxglove.Log"] = _obj(
    "foxglove.Log",
    {
        "timestamp": {
            "type": "object",
            "title": "time",
            "properties": {
                "sec": {"type": "integer", "minimum": 0},
                "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999},
            },
            "description": "Timestamp of log message",
        },
        "level": {
            "title": "foxglove.LogLevel",
            "description": "Log level",
            "oneOf": [
                {"title": "UNKNOWN", "const": 0},
                {"title": "DEBUG", "const": 1},
                {"title": "INFO", "const": 2},
                {"title": "WARNING", "const": 3},
                {"title": "ERROR", "const": 4},
                {"title": "FATAL", "const": 5},
            ],
        },
        "message": {"type": "string", "description": "Log message"},
        "name": {"type": "string", "description": "Process or node name"},
        "file": {"type": "string", "description": "Filename"},
        "line": {"type": "integer", "minimum": 0, "description": "Line number in the file"},
    },
    ["timestamp", "level", "message", "name", "file", "line"],
)


SCHEMA_BYTES: dict[str, bytes] = {k: json.dumps(v).encode() for k, v in SCHEMAS.items()}


def schema_for_topic(topic: str) -> str:
    """The schema name a topic gets when written through the generic `write()`."""

    fixed = {
        topics.LOG: "foxglove.Log",
        topics.PLAN_STEPS: "hil.PlanStep",
        topics.TIMING_VERDICTS: "hil.TimingVerdict",
        topics.SAFETY: "hil.SafetyAction",
        topics.FAULTS: "hil.Fault",
    }
    if topic in fixed:
        return fixed[topic]
    parts = topic.split("/")
    if topic.startswith("/can/") and topic.endswith("/raw"):
        return "hil.CanFrame"
    if topic.startswith("/canopen/"):
        return "hil.SdoTransaction" if topic.endswith("/sdo") else "hil.CanOpenFrame"
    if topic.startswith("/rs485/") and topic.endswith("/raw"):
        return "hil.SerialChunk"
    if topic.startswith("/modbus/"):
        return "hil.ModbusAdu"
    if topic.startswith("/dio/") and len(parts) == 4:
        return "hil.DioLevel"
    if topic.startswith("/pulse/") and len(parts) == 4:
        return "hil.PulseSegment"
    if topic in ("/group/axes/cycle", "/group/axes/capture"):
        return "hil.GroupCycle" if parts[-1] == "cycle" else "hil.GroupCapture"
    if topic.startswith("/plc/") and len(parts) == 4 and parts[-1] == "status":
        return "hil.PlcStatus"
    if topic.startswith("/drive/"):
        return {
            "state": "hil.DriveState",
            "events": "hil.DriveEvent",
            "params": "hil.DriveParams",
            "inputs": "hil.InputDelivery",
        }.get(parts[-1], "hil.Json")
    return "hil.Json"


_JSON_TYPES = {"boolean": bool, "integer": int, "number": (int, float), "string": str,
               "array": list, "object": dict, "null": type(None)}


def _type_ok(value: Any, want: Any) -> bool:
    names = want if isinstance(want, list) else [want]
    for n in names:
        t = _JSON_TYPES[n]
        if isinstance(value, t) and not (isinstance(value, bool) and n in ("integer", "number")):
            return True
    return False


def message_problems(schema_name: str, message: Any) -> list[str]:
    """What a decoded message has that its channel's schema does not say: undeclared fields,
    wrong types, missing required fields (the test over every shipped plan's recording)."""
    schema = SCHEMAS.get(schema_name)
    if schema is None or schema_name == "hil.Json":
        return []
    if not isinstance(message, dict):
        return [f"{schema_name}: not an object"]
    props = schema["properties"]
    out = [f"{schema_name}: undeclared field {k!r}" for k in message if k not in props]
    out += [f"{schema_name}: missing {k!r}" for k in schema["required"] if k not in message]
    for k, v in message.items():
        want = props.get(k, {}).get("type")
        if want is not None and not _type_ok(v, want):
            out.append(f"{schema_name}: {k!r} is {type(v).__name__}, not {want}")
    return out
