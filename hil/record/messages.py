"""The recording's messages, one `TypedDict` each: the one definition of every `hil.*` channel.

`hil/record/schemas.py` generates each channel's JSON Schema from these classes (field names,
JSON types, which are required, descriptions, enums), so a schema cannot say something the
definition does not. Producers build their messages as these types, and
`tests/test_plans_hil.py` validates every message of every shipped plan's recording against
the generated schema (no undeclared field, no wrong type, nothing required missing).

A field's description and JSON-only details ride in `Annotated[T, F(...)]`; `NotRequired`
marks what a message may leave out. `CLOSED` lists the messages whose schema forbids any
other field (`additionalProperties: false`).
"""

from __future__ import annotations

from typing import Annotated, Any, Literal, NotRequired, TypedDict


class F:
    """Field metadata for the schema: a description, and `extra` (more JSON Schema keys)."""

    def __init__(self, description: str = "", **extra: Any) -> None:
        self.description = description
        self.extra = extra


Ns = Annotated[int, F("ns")]
Dir = Annotated[Literal["rx", "tx"], F("as seen by the harness")]
Hex = Annotated[str, F("payload as lowercase hex")]


class CanFrame(TypedDict):
    id: Annotated[int, F("arbitration id")]
    ext: Annotated[bool, F("29-bit id")]
    rtr: bool
    err: Annotated[bool, F("error frame")]
    fd: bool
    brs: NotRequired[bool]
    esi: NotRequired[bool]
    dlc: int
    data: Hex
    dir: Dir


class CanOpenFrame(TypedDict):
    dir: Dir
    kind: NotRequired[Annotated[str, F("nmt, sync, emcy, tpdo1, rpdo1, sdo_rx, sdo_tx, "
                                       "heartbeat, ... (CiA 301 pre-defined connection set)")]]
    node: NotRequired[int | None]
    cob_id: NotRequired[int]
    dlc: NotRequired[int]
    data: NotRequired[Hex]
    remote: NotRequired[bool]
    command: NotRequired[Annotated[str, F("NMT command")]]
    target: NotRequired[Annotated[int, F("NMT target node (0 = all)")]]
    state: NotRequired[Annotated[str, F("NMT state of a heartbeat")]]
    toggle: NotRequired[Annotated[int, F("node guarding toggle bit")]]
    ccs: NotRequired[Annotated[int, F("SDO client command specifier")]]
    scs: NotRequired[Annotated[int, F("SDO server command specifier")]]
    cs: NotRequired[Annotated[int, F("SDO command byte")]]
    index: NotRequired[Annotated[int, F("object index")]]
    sub: NotRequired[int]
    expedited: NotRequired[bool]
    value: NotRequired[int]
    abort_code: NotRequired[int]
    abort_text: NotRequired[str]
    error_code: NotRequired[Annotated[int, F("EMCY error code")]]
    error_register: NotRequired[Annotated[int, F("EMCY 1001h")]]
    manufacturer: NotRequired[Annotated[str, F("EMCY bytes 3-7 as hex")]]
    alarm: NotRequired[Annotated[str, F("the Delta alarm of an EMCY")]]
    controlword: NotRequired[int]
    statusword: NotRequired[int]
    error: NotRequired[Annotated[str, F("why the frame could not be decoded")]]
    # a PDO decoded with the mapping the bus configured (hil.protocol.canopen.PdoMaps)
    pdo: NotRequired[Annotated[str, F("TPDO1..4 / RPDO1..4 of the frame")]]
    objects: NotRequired[Annotated[dict[str, int], F("mapped objects: '6041h:00' -> value")]]
    modes_of_operation: NotRequired[Annotated[int, F("6060h from a PDO")]]
    modes_of_operation_display: NotRequired[Annotated[int, F("6061h")]]
    position_actual: NotRequired[Annotated[int, F("6064h from a PDO")]]
    velocity_actual: NotRequired[Annotated[int, F("606Ch from a PDO")]]
    torque_actual: NotRequired[Annotated[int, F("6077h from a PDO")]]
    target_position: NotRequired[Annotated[int, F("607Ah from a PDO")]]
    target_velocity: NotRequired[Annotated[int, F("60FFh from a PDO")]]
    target_torque: NotRequired[Annotated[int, F("6071h from a PDO")]]
    ip_position: NotRequired[Annotated[int, F("60C1h sub 1 from a PDO")]]
    following_error_actual: NotRequired[Annotated[int, F("60F4h from a PDO")]]


class SdoTransaction(TypedDict):
    node: int
    index: NotRequired[int]
    sub: NotRequired[int]
    object: NotRequired[Annotated[str, F("e.g. 6041h:00")]]
    access: NotRequired[Literal["upload", "download", "unknown"]]
    transfer: NotRequired[Literal["expedited", "segmented", "block", ""]]
    status: Literal["ok", "abort", "timeout", "error"]
    value: NotRequired[int | None]
    data: NotRequired[str]
    size: NotRequired[int]
    abort_code: NotRequired[int | None]
    abort_by: NotRequired[Literal["client", "server"] | None]
    latency_ns: NotRequired[int | None]
    latency_us: NotRequired[float | None]
    frames: NotRequired[int]
    t_request: NotRequired[Annotated[int, F("ns of the request's first frame")]]
    error: NotRequired[str]


class SerialChunk(TypedDict):
    dir: Dir
    data: Annotated[str, F("bytes as lowercase hex")]
    n: int
    gaps_us: NotRequired[list[int] | None]


class ModbusAdu(TypedDict):
    dir: Dir
    mode: Literal["rtu", "ascii"]
    raw: str
    role: Literal["request", "response", "exception", "unknown"]
    unit: NotRequired[int | None]
    function: NotRequired[int | None]
    exception_code: NotRequired[int | None]
    rtt_ns: NotRequired[int | None]
    rtt_us: NotRequired[float | None]
    unanswered: NotRequired[bool]
    t_request: NotRequired[Annotated[int, F("ns of the request")]]
    adu: NotRequired[Annotated[dict[str, Any], F("the decoded ADU (function_name, address, "
                                                  "values, exception, ...)")]]
    error: NotRequired[str]


class DioLevel(TypedDict):
    level: Annotated[bool, F("electrical level, True = closed")]


class PulseSegment(TypedDict):
    freq: NotRequired[Annotated[float, F("pulses per second")]]
    direction: NotRequired[Annotated[int, F("+1 forward, -1 reverse")]]
    count: NotRequired[Annotated[int, F("pulses (0: until the next)")]]
    total: NotRequired[Annotated[int, F("signed pulses before this one")]]
    form: NotRequired[Annotated[str, F("ab, cw_ccw, pulse_sign")]]
    logic: NotRequired[int]
    width_ns: NotRequired[Annotated[int, F("Z pulse width (oz)")]]


class DriveState(TypedDict):
    """The fields of `hil.model.drive.Drive.snapshot()` (the virtual bench's ground truth)."""

    t: NotRequired[Annotated[int, F("model time, ns")]]
    periodic: NotRequired[Annotated[bool, F("a periodic sample (not an event)")]]
    state: NotRequired[Annotated[str, F("CiA 402 state name")]]
    mode: NotRequired[Annotated[str | int, F("mode of operation")]]
    servo_on: NotRequired[bool]
    torque_enabled: NotRequired[bool]
    position_puu: NotRequired[Annotated[int, F("feedback, PUU")]]
    position_counts: NotRequired[Annotated[int, F("feedback, encoder counts")]]
    speed_rpm: NotRequired[float]
    torque_pct: NotRequired[Annotated[float, F("% of rated torque")]]
    following_error_counts: NotRequired[int]
    brkr: NotRequired[Annotated[bool, F("DO BRKR function")]]
    brake_released: NotRequired[Annotated[bool, F("the mechanical brake")]]
    sto_a: NotRequired[bool]
    sto_b: NotRequired[bool]
    alarms: NotRequired[list[str]]
    abs_turns: NotRequired[int]
    abs_single_turn: NotRequired[int]
    statusword: NotRequired[Annotated[int, F("6041h")]]
    do: NotRequired[Annotated[list[bool], F("DO1..DO6")]]
    di: NotRequired[Annotated[list[bool], F("DI1..DI10")]]
    homing_phase: NotRequired[str]
    gain_switched: NotRequired[bool]
    pt_count: NotRequired[Annotated[int, F("PT pulses counted (signed)")]]
    pt_freq_kpps: NotRequired[Annotated[float, F("PT pulse frequency, kpps")]]
    pt_command: NotRequired[Annotated[int, F("PT command position, counts")]]
    pt_pending: NotRequired[Annotated[int, F("pulses still to come")]]
    pt_error: NotRequired[Annotated[int, F("PT command - feedback, counts")]]


class DriveEvent(TypedDict):
    """The fields of the events in `hil.model.events`, and `type`, the event class."""

    type: Annotated[str, F("event class")]
    t: NotRequired[Annotated[int, F("model time, ns")]]
    n: NotRequired[Annotated[int, F("DO / DI line")]]
    level: NotRequired[bool]
    function: NotRequired[str]
    closed: NotRequired[bool]
    code: NotRequired[Annotated[str, F("alarm code")]]
    source: NotRequired[Annotated[str, F("what asked for an alarm reset: di, p0001, 6040h")]]
    active: NotRequired[bool]
    emcy_code: NotRequired[int]
    name: NotRequired[Annotated[str, F("parameter name")]]
    value: NotRequired[int]
    old: NotRequired[str]
    new: NotRequired[str]
    battery: NotRequired[bool]
    clamped: NotRequired[bool]
    phase: NotRequired[Annotated[str, F("homing phase")]]
    index: NotRequired[Annotated[int, F("capture / compare point")]]
    address: NotRequired[Annotated[int, F("data array address")]]
    target: NotRequired[int]
    position_puu: NotRequired[float]


class InputDelivery(TypedDict):
    line: Annotated[str, F("DI<n>, STO_A, STO_B, or CAN <cob>h for a late frame")]
    level: Annotated[bool, F("electrical level, True = closed")]
    sent_ns: Annotated[int, F("the harness's stamp of the edge")]
    applied_ns: Annotated[int, F("when the model applied it")]
    delay_ns: Annotated[int, F("applied_ns - sent_ns")]


class DriveParams(TypedDict):
    snapshot: NotRequired[bool]
    values: dict[str, Any]
    source: NotRequired[str]


class PlanStep(TypedDict):
    plan: NotRequired[str | None]
    step: str
    index: NotRequired[int | None]
    event: Literal["start", "end"]
    status: NotRequired[str | None]
    message: NotRequired[str]
    kind: NotRequired[Annotated[str, F("step kind")]]
    drive: NotRequired[str]
    file: NotRequired[str]
    line: NotRequired[int]
    duration_ns: NotRequired[int]


class TimingVerdict(TypedDict):
    status: Literal["pass", "fail", "inconclusive", "skipped"]
    spec: NotRequired[str]
    constraint: NotRequired[str]
    kind: NotRequired[str]
    message: NotRequired[str]
    source: NotRequired[Annotated[str, F("the manual lines")]]
    plan: NotRequired[str]
    step: NotRequired[int]
    occurrence: NotRequired[int]
    measured_ms: NotRequired[float | None]
    margin_ms: NotRequired[float | None]
    window_ms: NotRequired[list[Any]]
    window_expr: NotRequired[str]
    uncertainty_ms: NotRequired[list[Any]]
    from_ns: NotRequired[int]
    to_ns: NotRequired[int | None]
    t_ns: NotRequired[int]
    values: NotRequired[dict[str, Any]]
    binding: NotRequired[dict[str, Any]]
    check_constants: NotRequired[dict[str, Any]]
    check_params: NotRequired[dict[str, Any]]
    check_since_ns: NotRequired[int | None]
    check_until_ns: NotRequired[int]
    latch: NotRequired[dict[str, Any]]
    tolerance_counts: NotRequired[float]


class SafetyAction(TypedDict):
    action: str
    reason: str
    source: NotRequired[str]
    drive: NotRequired[str]
    ok: NotRequired[bool]
    detail: NotRequired[str]
    duration_ms: NotRequired[float]
    timeout_ms: NotRequired[float]


class Fault(TypedDict):
    fault: Annotated[str, F("drop, delay, corrupt, sdo_flood, ...")]
    transport: Annotated[str, F("can:<bus>, rs485:<port>, dio:<drive>")]
    active: Annotated[bool, F("true at the start, false at the end")]
    id: Annotated[int, F("pairs a start with its end")]
    detail: NotRequired[dict[str, Any]]


class Json(TypedDict):
    """Any JSON object (a topic without its own schema)."""


PerAxis = Annotated[dict[str, Any], F("per axis name")]


class GroupCycle(TypedDict):
    """One axis-group cycle (docs/group.md): the set-points sent and the feedback judged."""

    cycle: Annotated[int, F("the cycle's number, from 1")]
    missed: Annotated[list[str], F("axes whose TPDO of the last cycle did not come")]
    held: Annotated[list[str], F("followers holding their gear input (master lost/faulted)")]
    heartbeat_lost: Annotated[list[str], F("axes whose heartbeat is older than the consumer time")]
    status: Annotated[dict[str, Any], F("Servo.Status per axis (004:254): -1 lost, 0 never, "
                                        "1 fault, 2 ready without torque, 3 under torque")]
    bus_load_pct: Annotated[float, F("the cycle's frames over the bit rate, %")]
    write_position: PerAxis
    position: PerAxis
    position_error: Annotated[dict[str, Any], F("WritePosition - Position per axis (004:254)")]
    speed: PerAxis
    mode: Annotated[dict[str, Any], F("Servo.Mode per axis: 1 PG, 3 GEA, 4 PG + GEA")]
    offset: PerAxis
    correction: PerAxis
    follow_error: Annotated[dict[str, Any], F("the set-point the feedback answers minus the "
                                              "feedback, per axis")]
    max_follow_error: int
    cam_follow_error: Annotated[int, F("the largest follow error of the axes on a cam, 0 "
                                       "when none is (`cam_axes`)")]
    cam_axes: Annotated[int, F("axes on a cam this cycle (GEA mode 2)")]
    gear_phase_error: Annotated[dict[str, Any], F("a geared follower's drift from its master")]
    gear_judged: Annotated[int, F("geared followers whose phase this cycle judged (the "
                                  "reference taken, docs/group.md)")]
    gear_ratio_judged: Annotated[int, F("geared followers whose ratio this cycle judged (In/Out "
                                        "x the master's travel since the reference is 1000 "
                                        "increments or more)")]
    max_gear_phase_error: int
    max_gear_ratio_error: float


class GroupCapture(TypedDict):
    """A CAPTURE interface's registers (004:252) when they were taken."""

    axis: str
    cycle: int
    typ_ext_capture: Annotated[int, F("Typ_ExtCapture bits")]
    p_position: Annotated[int, F("PPosition")]
    n_position: Annotated[int, F("NPosition")]
    zero_position: int
    write_position: Annotated[int, F("Write_Position")]
    captures: Annotated[int, F("captures taken so far")]


class PlcStatus(TypedDict):
    """The PLC program's status registers at an event (docs/pulse.md)."""

    event: Annotated[str, F("step, done, drvz, zero, homed, ext, error, end")]
    step: Annotated[int, F("R4064: the step running")]
    ready: Annotated[bool, F("M1992: the axis is ready")]
    done: Annotated[bool, F("M1996: the last step finished")]
    position: Annotated[int, F("DR4088: the current position, pulses")]
    remaining: Annotated[int, F("DR4072: the pulses left")]
    error: Annotated[int, F("R4060: the latest error code")]
    homed: bool
    drvz: Annotated[str, F("the DRVZ mode running or completed; empty before any, and after "
                           "one that failed")]


MESSAGES: dict[str, type] = {
    "hil.CanFrame": CanFrame,
    "hil.CanOpenFrame": CanOpenFrame,
    "hil.SdoTransaction": SdoTransaction,
    "hil.SerialChunk": SerialChunk,
    "hil.ModbusAdu": ModbusAdu,
    "hil.DioLevel": DioLevel,
    "hil.PulseSegment": PulseSegment,
    "hil.DriveState": DriveState,
    "hil.DriveEvent": DriveEvent,
    "hil.InputDelivery": InputDelivery,
    "hil.DriveParams": DriveParams,
    "hil.PlanStep": PlanStep,
    "hil.TimingVerdict": TimingVerdict,
    "hil.SafetyAction": SafetyAction,
    "hil.Fault": Fault,
    "hil.GroupCycle": GroupCycle,
    "hil.GroupCapture": GroupCapture,
    "hil.PlcStatus": PlcStatus,
    "hil.Json": Json,
}
# their schemas forbid any field the definition does not name
CLOSED = frozenset({"hil.CanFrame", "hil.SerialChunk", "hil.DriveState", "hil.DriveEvent",
                    "hil.PlanStep", "hil.TimingVerdict", "hil.SafetyAction"})
