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
            "kind": {"type": "string", "description": "nmt, sync, emcy, tpdo1, rpdo1, sdo_rx, "
                     "sdo_tx, heartbeat, ... (CiA 301 pre-defined connection set)"},
            "node": {"type": ["integer", "null"]},
            "cob_id": {"type": "integer"},
            "dlc": {"type": "integer"},
            "data": {"type": "string", "description": "payload as lowercase hex"},
            "remote": {"type": "boolean"},
            "command": {"type": "string", "description": "NMT command"},
            "target": {"type": "integer", "description": "NMT target node (0 = all)"},
            "state": {"type": "string", "description": "NMT state of a heartbeat"},
            "toggle": {"type": "integer", "description": "node guarding toggle bit"},
            "ccs": {"type": "integer", "description": "SDO client command specifier"},
            "scs": {"type": "integer", "description": "SDO server command specifier"},
            "cs": {"type": "integer", "description": "SDO command byte"},
            "index": {"type": "integer", "description": "object index"},
            "sub": {"type": "integer"},
            "expedited": {"type": "boolean"},
            "value": {"type": "integer"},
            "abort_code": {"type": "integer"},
            "abort_text": {"type": "string"},
            "error_code": {"type": "integer", "description": "EMCY error code"},
            "error_register": {"type": "integer", "description": "EMCY 1001h"},
            "manufacturer": {"type": "string", "description": "EMCY bytes 3-7 as hex"},
            "alarm": {"type": "string", "description": "the Delta alarm of an EMCY"},
            "controlword": {"type": "integer"},
            "statusword": {"type": "integer"},
            "error": {"type": "string", "description": "why the frame could not be decoded"},
            # a PDO decoded with the mapping the bus configured (hil.protocol.canopen.PdoMaps)
            "pdo": {"type": "string", "description": "TPDO1..4 / RPDO1..4 of the frame"},
            "objects": {"type": "object", "description": "mapped objects: '6041h:00' -> value",
                        "additionalProperties": {"type": "integer"}},
            "modes_of_operation": {"type": "integer", "description": "6060h from a PDO"},
            "modes_of_operation_display": {"type": "integer", "description": "6061h"},
            "position_actual": {"type": "integer", "description": "6064h from a PDO"},
            "velocity_actual": {"type": "integer", "description": "606Ch from a PDO"},
            "torque_actual": {"type": "integer", "description": "6077h from a PDO"},
            "target_position": {"type": "integer", "description": "607Ah from a PDO"},
            "target_velocity": {"type": "integer", "description": "60FFh from a PDO"},
            "target_torque": {"type": "integer", "description": "6071h from a PDO"},
            "ip_position": {"type": "integer", "description": "60C1h sub 1 from a PDO"},
            "following_error_actual": {"type": "integer", "description": "60F4h from a PDO"},
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
            "t_request": {"type": "integer", "description": "ns of the request's first frame"},
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
            "t_request": {"type": "integer", "description": "ns of the request"},
            "adu": {"type": "object", "description": "the decoded ADU (function_name, address, "
                    "values, exception, ...)"},
            "error": {"type": "string"},
        },
        ["dir", "mode", "raw", "role"],
    ),
    "hil.DioLevel": _obj(
        "hil.DioLevel",
        {"level": {"type": "boolean", "description": "electrical level, True = closed"}},
        ["level"],
    ),
    "hil.PulseSegment": _obj(
        "hil.PulseSegment",
        {
            "freq": {"type": "number", "description": "pulses per second"},
            "direction": {"type": "integer", "description": "+1 forward, -1 reverse"},
            "count": {"type": "integer", "description": "pulses (0: until the next)"},
            "total": {"type": "integer", "description": "signed pulses before this one"},
            "form": {"type": "string", "description": "ab, cw_ccw, pulse_sign"},
            "logic": {"type": "integer"},
            "width_ns": {"type": "integer", "description": "Z pulse width (oz)"},
        },
        [],
    ),
    "hil.DriveState": _obj(
        "hil.DriveState",
        {  # the fields of hil.model.drive.Drive.snapshot() (ground truth)
            "t": {"type": "integer", "description": "model time, ns"},
            "periodic": {"type": "boolean", "description": "a periodic sample (not an event)"},
            "state": {"type": "string", "description": "CiA 402 state name"},
            "mode": {"type": ["string", "integer"], "description": "mode of operation"},
            "servo_on": {"type": "boolean"},
            "torque_enabled": {"type": "boolean"},
            "position_puu": {"type": "integer", "description": "feedback, PUU"},
            "position_counts": {"type": "integer", "description": "feedback, encoder counts"},
            "speed_rpm": {"type": "number"},
            "torque_pct": {"type": "number", "description": "% of rated torque"},
            "following_error_counts": {"type": "integer"},
            "brkr": {"type": "boolean", "description": "DO BRKR function"},
            "brake_released": {"type": "boolean", "description": "the mechanical brake"},
            "sto_a": {"type": "boolean"},
            "sto_b": {"type": "boolean"},
            "alarms": {"type": "array", "items": {"type": "string"}},
            "abs_turns": {"type": "integer"},
            "abs_single_turn": {"type": "integer"},
            "statusword": {"type": "integer", "description": "6041h"},
            "do": {"type": "array", "items": {"type": "boolean"}, "description": "DO1..DO6"},
            "di": {"type": "array", "items": {"type": "boolean"}, "description": "DI1..DI10"},
            "homing_phase": {"type": "string"},
            "gain_switched": {"type": "boolean"},
            "pt_count": {"type": "integer", "description": "PT pulses counted (signed)"},
            "pt_freq_kpps": {"type": "number", "description": "PT pulse frequency, kpps"},
            "pt_command": {"type": "integer", "description": "PT command position, counts"},
            "pt_pending": {"type": "integer", "description": "pulses still to come"},
            "pt_error": {"type": "integer", "description": "PT command - feedback, counts"},
        },
        [],
        extra=False,
    ),
    "hil.DriveEvent": _obj(
        "hil.DriveEvent",
        {  # the fields of the events in hil.model.events
            "type": {"type": "string", "description": "event class"},
            "t": {"type": "integer", "description": "model time, ns"},
            "n": {"type": "integer", "description": "DO / DI line"},
            "level": {"type": "boolean"},
            "function": {"type": "string"},
            "closed": {"type": "boolean"},
            "code": {"type": "string", "description": "alarm code"},
            "active": {"type": "boolean"},
            "emcy_code": {"type": "integer"},
            "name": {"type": "string", "description": "parameter name"},
            "value": {"type": "integer"},
            "old": {"type": "string"},
            "new": {"type": "string"},
            "battery": {"type": "boolean"},
            "clamped": {"type": "boolean"},
            "phase": {"type": "string", "description": "homing phase"},
            "index": {"type": "integer", "description": "capture / compare point"},
            "address": {"type": "integer", "description": "data array address"},
            "target": {"type": "integer"},
            "position_puu": {"type": "number"},
        },
        ["type"],
        extra=False,
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
            "kind": {"type": "string", "description": "step kind"},
            "drive": {"type": "string"},
            "file": {"type": "string"},
            "line": {"type": "integer"},
            "duration_ns": {"type": "integer"},
        },
        ["step", "event"],
        extra=False,
    ),
    "hil.TimingVerdict": _obj(
        "hil.TimingVerdict",
        {
            "status": {"type": "string",
                       "enum": ["pass", "fail", "inconclusive", "skipped"]},
            "spec": {"type": "string"},
            "constraint": {"type": "string"},
            "kind": {"type": "string"},
            "message": {"type": "string"},
            "source": {"type": "string", "description": "the manual lines"},
            "plan": {"type": "string"},
            "step": {"type": "integer"},
            "occurrence": {"type": "integer"},
            "measured_ms": {"type": ["number", "null"]},
            "margin_ms": {"type": ["number", "null"]},
            "window_ms": {"type": "array"},
            "window_expr": {"type": "string"},
            "uncertainty_ms": {"type": "array"},
            "from_ns": {"type": "integer"},
            "to_ns": {"type": ["integer", "null"]},
            "t_ns": {"type": "integer"},
            "values": {"type": "object"},
            "binding": {"type": "object"},
            "check_constants": {"type": "object"},
            "check_params": {"type": "object"},
            "check_since_ns": {"type": ["integer", "null"]},
            "check_until_ns": {"type": "integer"},
            "latch": {"type": "object"},
            "tolerance_counts": {"type": "number"},
        },
        ["status"],
        extra=False,
    ),
    "hil.SafetyAction": _obj(
        "hil.SafetyAction",
        {
            "action": {"type": "string"},
            "reason": {"type": "string"},
            "source": {"type": "string"},
            "drive": {"type": "string"},
            "ok": {"type": "boolean"},
            "detail": {"type": "string"},
            "duration_ms": {"type": "number"},
            "timeout_ms": {"type": "number"},
        },
        ["action", "reason"],
        extra=False,
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
    if topic.startswith("/pulse/") and len(parts) == 4:
        return "hil.PulseSegment"
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
