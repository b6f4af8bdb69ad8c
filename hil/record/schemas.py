"""JSON schemas of the recording's channels (schema encoding `jsonschema`, message `json`).

Each channel's schema is named here (`hil.CanFrame`, `foxglove.Log`, ...). `foxglove.Log`
follows Foxglove's own schema so the Log panel reads `/log` without configuration.
"""

from __future__ import annotations

import json
from typing import Any

from hil.record import topics

_T = {"type": "integer", "description": "ns"}
_DIR = {"type": "string", "enum": ["rx", "tx"], "description": "as seen by the harness"}


def _obj(title: str, props: dict[str, Any], required: list[str], extra: bool = True) -> dict:
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": title,
        "type": "object",
        "properties": props,
        "required": required,
        "additionalProperties": extra,
    }


SCHEMAS: dict[str, dict] = {
    "hil.CanFrame": _obj(
        "hil.CanFrame",
        {
            "id": {"type": "integer", "description": "arbitration id"},
            "ext": {"type": "boolean", "description": "29-bit id"},
            "rtr": {"type": "boolean"},
            "err": {"type": "boolean", "description": "error frame"},
            "fd": {"type": "boolean"},
            "brs": {"type": "boolean"},
            "esi": {"type": "boolean"},
            "dlc": {"type": "integer"},
            "data": {"type": "string", "description": "payload as lowercase hex"},
            "dir": _DIR,
        },
        ["id", "ext", "rtr", "err", "fd", "dlc", "data", "dir"],
        extra=False,
    ),
    "hil.CanOpenFrame": _obj(
        "hil.CanOpenFrame",
        {
            "dir": _DIR,
            "error": {"type": "string", "description": "why the frame could not be decoded"},
        },
        ["dir"],
    ),
    "hil.SdoTransaction": _obj(
        "hil.SdoTransaction",
        {
            "node": {"type": "integer"},
            "index": {"type": "integer"},
            "sub": {"type": "integer"},
            "object": {"type": "string", "description": "e.g. 6041h:00"},
            "access": {"type": "string", "enum": ["upload", "download", "unknown"]},
            "transfer": {"type": "string", "enum": ["expedited", "segmented", "block", ""]},
            "status": {"type": "string", "enum": ["ok", "abort", "timeout", "error"]},
            "value": {"type": ["integer", "null"]},
            "data": {"type": "string"},
            "size": {"type": "integer"},
            "abort_code": {"type": ["integer", "null"]},
            "abort_by": {"type": ["string", "null"], "enum": ["client", "server", None]},
            "latency_ns": {"type": ["integer", "null"]},
            "latency_us": {"type": ["number", "null"]},
            "frames": {"type": "integer"},
            "error": {"type": "string"},
        },
        ["node", "status"],
    ),
    "hil.SerialChunk": _obj(
        "hil.SerialChunk",
        {
            "dir": _DIR,
            "data": {"type": "string", "description": "bytes as lowercase hex"},
            "n": {"type": "integer"},
            "gaps_us": {"type": ["array", "null"], "items": {"type": "integer"}},
        },
        ["dir", "data", "n"],
        extra=False,
    ),
    "hil.ModbusAdu": _obj(
        "hil.ModbusAdu",
        {
            "dir": _DIR,
            "mode": {"type": "string", "enum": ["rtu", "ascii"]},
            "raw": {"type": "string"},
            "role": {"type": "string", "enum": ["request", "response", "exception", "unknown"]},
            "unit": {"type": ["integer", "null"]},
            "function": {"type": ["integer", "null"]},
            "exception_code": {"type": ["integer", "null"]},
            "rtt_ns": {"type": ["integer", "null"]},
            "rtt_us": {"type": ["number", "null"]},
            "unanswered": {"type": "boolean"},
            "error": {"type": "string"},
        },
        ["dir", "mode", "raw", "role"],
    ),
    "hil.DioLevel": _obj(
        "hil.DioLevel",
        {"level": {"type": "boolean", "description": "electrical level, True = closed"}},
        ["level"],
    ),
    "hil.DriveState": _obj(
        "hil.DriveState",
        {
            "state": {"type": "string", "description": "CiA 402 state name"},
            "mode": {"type": ["string", "integer"]},
            "position": {"type": "number"},
            "velocity": {"type": "number"},
            "torque": {"type": "number"},
            "brake": {"type": ["boolean", "string"]},
            "alarms": {"type": "array"},
        },
        [],
    ),
    "hil.DriveEvent": _obj(
        "hil.DriveEvent", {"type": {"type": "string", "description": "event class"}}, ["type"]
    ),
    "hil.InputDelivery": _obj(
        "hil.InputDelivery",
        {
            "line": {"type": "string",
                     "description": "DI<n>, STO_A, STO_B, or CAN <cob>h for a late frame"},
            "level": {"type": "boolean", "description": "electrical level, True = closed"},
            "sent_ns": {"type": "integer", "description": "the harness's stamp of the edge"},
            "applied_ns": {"type": "integer", "description": "when the model applied it"},
            "delay_ns": {"type": "integer", "description": "applied_ns - sent_ns"},
        },
        ["line", "level", "sent_ns", "applied_ns", "delay_ns"],
    ),
    "hil.DriveParams": _obj(
        "hil.DriveParams",
        {"snapshot": {"type": "boolean"}, "values": {"type": "object"},
         "source": {"type": "string"}},
        ["values"],
    ),
    "hil.PlanStep": _obj(
        "hil.PlanStep",
        {
            "plan": {"type": ["string", "null"]},
            "step": {"type": "string"},
            "index": {"type": ["integer", "null"]},
            "event": {"type": "string", "enum": ["start", "end"]},
            "status": {"type": ["string", "null"]},
            "message": {"type": "string"},
        },
        ["step", "event"],
    ),
    "hil.TimingVerdict": _obj(
        "hil.TimingVerdict",
        {
            "status": {"type": "string", "enum": ["pass", "fail", "inconclusive"]},
            "spec": {"type": "string"},
            "constraint": {"type": "string"},
            "measured": {},
            "limit": {},
            "margin": {},
        },
        ["status"],
    ),
    "hil.SafetyAction": _obj(
        "hil.SafetyAction",
        {
            "action": {"type": "string"},
            "reason": {"type": "string"},
            "source": {"type": "string"},
        },
        ["action", "reason"],
    ),
    "hil.Fault": _obj(
        "hil.Fault",
        {
            "fault": {"type": "string", "description": "drop, delay, corrupt, sdo_flood, ..."},
            "transport": {"type": "string", "description": "can:<bus>, rs485:<port>, dio:<drive>"},
            "active": {"type": "boolean", "description": "true at the start, false at the end"},
            "id": {"type": "integer", "description": "pairs a start with its end"},
            "detail": {"type": "object"},
        },
        ["fault", "transport", "active", "id"],
    ),
    "hil.Json": _obj("hil.Json", {}, []),
    # https://docs.foxglove.dev/docs/visualization/message-schemas/log
    "foxglove.Log": _obj(
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
    ),
}

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
    if topic.startswith("/drive/"):
        return {
            "state": "hil.DriveState",
            "events": "hil.DriveEvent",
            "params": "hil.DriveParams",
            "inputs": "hil.InputDelivery",
        }.get(parts[-1], "hil.Json")
    return "hil.Json"
