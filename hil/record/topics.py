"""Topic names of a recording: the contract between recorder, checker, reports and Foxglove.

Every channel is JSON with a JSON schema. `log_time` is when the harness saw the message;
`publish_time` is the source's own timestamp (model clock, adapter hardware time, gateway
capture time) or equal to `log_time` where the source has none. Names below are fixed: the
timing specs and the reports address signals by them.
"""

from __future__ import annotations


def can_raw(bus: str) -> str:
    """Every CAN frame seen on `bus`, both directions: id, flags, dlc, data (hex), dir."""
    return f"/can/{bus}/raw"


def canopen(bus: str) -> str:
    """Decoded CANopen per frame: NMT, SYNC, EMCY, heartbeat, PDO (mapped values), SDO."""
    return f"/canopen/{bus}"


def canopen_sdo(bus: str) -> str:
    """SDO transactions: node, index, sub, upload/download, value, abort code, latency."""
    return f"/canopen/{bus}/sdo"


def rs485_raw(port: str) -> str:
    """Raw RS-485 bytes with direction and inter-byte gaps."""
    return f"/rs485/{port}/raw"


def modbus(port: str) -> str:
    """Decoded Modbus transactions: request, response or exception, round-trip time."""
    return f"/modbus/{port}"


def dio(name: str, line: str) -> str:
    """Level of one DI/DO/STO line (`line` like DI1, DO3, STO_A, FDBK): {"level": bool}."""
    return f"/dio/{name}/{line}"


def pulse(name: str, kind: str) -> str:
    """A pulse line's messages: `seg` (command segments), `oab` (encoder output), `oz`."""
    return f"/pulse/{name}/{kind}"


def drive_state(drive: str) -> str:
    """Virtual-bench ground truth: CiA 402 state, mode, position, velocity, torque, brake."""
    return f"/drive/{drive}/state"


def drive_events(drive: str) -> str:
    """Virtual-bench ground truth events from the model (DO changes, alarms, states)."""
    return f"/drive/{drive}/events"


def drive_inputs(drive: str) -> str:
    """Virtual-bench input delivery: per DI/STO edge the harness's stamp (`sent_ns`), when
    the model applied it (`applied_ns`) and the difference (`delay_ns`), docs/timing.md;
    also per CAN frame that reached the model CAN_LATE_NS or more late (`line` = can_line)."""
    return f"/drive/{drive}/inputs"


CAN_LATE_NS = 500_000  # a CAN frame's delivery is recorded from 0.5 ms late (under load)


def can_line(cob_id: int) -> str:
    """The `line` of a CAN frame's delivery record: `CAN 080h`."""
    return f"CAN {cob_id:03X}h"


def drive_params(drive: str) -> str:
    """Parameter values as the drive reports them (snapshot at start, changes after)."""
    return f"/drive/{drive}/params"


PLAN_STEPS = "/plan/steps"  # step start/end with status and message
LOG = "/log"  # harness log lines in the foxglove.Log shape
TIMING_VERDICTS = "/timing/verdicts"  # one message per judged constraint
FAULTS = "/faults"  # injected faults: start/end, kind, transport, match (docs/faults.md)
SAFETY = "/safety"  # safe-state actions taken by the runner or gateway
