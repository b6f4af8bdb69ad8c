"""CANopen (CiA 301) frame vocabulary: COB-ID classes, SDO command specifiers, frame decoding.

Pure: no bus import. `describe_frame` is what the recorder uses to decode a raw frame; it
never raises, whatever the bytes (a malformed frame is described with an `error` field).
"""

from __future__ import annotations

import struct
from collections.abc import Container

# Function codes (COB-ID bits 10..7) -- L16873-L16899.
NMT = 0x000
SYNC = 0x080
EMCY = 0x080
TPDO_BASE = (0x180, 0x280, 0x380, 0x480)
RPDO_BASE = (0x200, 0x300, 0x400, 0x500)
# SDO COB-ID bases, named from the client's side: the client sends its REQUEST on 0x600+node,
# the server answers with its RESPONSE on 0x580+node. (CiA 301 and canopen call these from
# the server's side: "SDO rx" = 0x600, "SDO tx" = 0x580; recorded `kind`s keep that:
# "sdo_rx" = request, "sdo_tx" = response.)
SDO_REQUEST = 0x600  # client -> server
SDO_RESPONSE = 0x580  # server -> client
HEARTBEAT = 0x700

# NMT command specifiers (CiA 301; the manual's NMT figure is missing).
NMT_START = 0x01
NMT_STOP = 0x02
NMT_PRE_OPERATIONAL = 0x80
NMT_RESET_NODE = 0x81
NMT_RESET_COMMUNICATION = 0x82
NMT_COMMANDS = {
    NMT_START: "start",
    NMT_STOP: "stop",
    NMT_PRE_OPERATIONAL: "enter pre-operational",
    NMT_RESET_NODE: "reset node",
    NMT_RESET_COMMUNICATION: "reset communication",
}

# NMT states as heartbeat / guarding byte (L17105-L17111).
STATE_BOOTUP = 0
STATE_STOPPED = 4
STATE_OPERATIONAL = 5
STATE_PRE_OPERATIONAL = 127
NMT_STATES = {
    STATE_BOOTUP: "BOOTUP",
    STATE_STOPPED: "STOPPED",
    STATE_OPERATIONAL: "OPERATIONAL",
    STATE_PRE_OPERATIONAL: "PRE-OPERATIONAL",
}

# SDO command specifiers (bits 7..5 of byte 0).
CCS_DOWNLOAD_SEGMENT = 0
CCS_INITIATE_DOWNLOAD = 1
CCS_INITIATE_UPLOAD = 2
CCS_UPLOAD_SEGMENT = 3
CCS_ABORT = 4
CCS_BLOCK_UPLOAD = 5
CCS_BLOCK_DOWNLOAD = 6
SCS_UPLOAD_SEGMENT = 0
SCS_DOWNLOAD_SEGMENT = 1
SCS_INITIATE_UPLOAD = 2
SCS_INITIATE_DOWNLOAD = 3
SCS_ABORT = 4
SCS_BLOCK_DOWNLOAD = 5
SCS_BLOCK_UPLOAD = 6
CCS_NAMES = {
    0: "download segment",
    1: "initiate download",
    2: "initiate upload",
    3: "upload segment",
    4: "abort",
    5: "block upload",
    6: "block download",
}
SCS_NAMES = {
    0: "upload segment",
    1: "download segment",
    2: "initiate upload",
    3: "initiate download",
    4: "abort",
    5: "block download",
    6: "block upload",
}

# CiA 301 table 22 abort texts (the manual's list, L17024-L17042, is a subset).
# CiA 301 SDO abort codes (the model, the OD and the CANopen face raise them).
ABORT_TOGGLE = 0x05030000
ABORT_TIMEOUT = 0x05040000
ABORT_COMMAND = 0x05040001
ABORT_UNSUPPORTED_ACCESS = 0x06010000
ABORT_WRITE_ONLY = 0x06010001
ABORT_READ_ONLY = 0x06010002
ABORT_NO_OBJECT = 0x06020000
ABORT_NOT_MAPPABLE = 0x06040041
ABORT_PDO_LENGTH = 0x06040042
ABORT_LENGTH = 0x06070010
ABORT_LENGTH_HIGH = 0x06070012
ABORT_LENGTH_LOW = 0x06070013
ABORT_NO_SUBINDEX = 0x06090011
ABORT_VALUE_RANGE = 0x06090030
ABORT_VALUE_HIGH = 0x06090031
ABORT_VALUE_LOW = 0x06090032
ABORT_GENERAL = 0x08000000
ABORT_DATA_STORE = 0x08000020
ABORT_DATA_STATE = 0x08000022

ABORT_TEXTS = {
    0x05030000: "Toggle bit not alternated",
    0x05040000: "SDO protocol timed out",
    0x05040001: "Client/server command specifier not valid or unknown",
    0x05040002: "Invalid block size",
    0x05040003: "Invalid sequence number",
    0x05040004: "CRC error",
    0x05040005: "Out of memory",
    0x06010000: "Unsupported access to an object",
    0x06010001: "Attempt to read a write only object",
    0x06010002: "Attempt to write a read only object",
    0x06020000: "Object does not exist in the object dictionary",
    0x06040041: "Object cannot be mapped to the PDO",
    0x06040042: "The number and length of the objects to be mapped would exceed PDO length",
    0x06040043: "General parameter incompatibility reason",
    0x06040047: "General internal incompatibility in the device",
    0x06060000: "Access failed due to a hardware error",
    0x06070010: "Data type does not match, length of service parameter does not match",
    0x06070012: "Data type does not match, length of service parameter too high",
    0x06070013: "Data type does not match, length of service parameter too low",
    0x06090011: "Sub-index does not exist",
    0x06090030: "Invalid value for parameter (download only)",
    0x06090031: "Value of parameter written too high (download only)",
    0x06090032: "Value of parameter written too low (download only)",
    0x06090036: "Maximum value is less than minimum value",
    0x060A0023: "Resource not available: SDO connection",
    0x08000000: "General error",
    0x08000020: "Data cannot be transferred or stored to the application",
    0x08000021: "Data cannot be transferred or stored to the application because of local control",
    0x08000022: "Data cannot be transferred or stored to the application because of the present "
    "device state",
    0x08000023: "Object dictionary dynamic generation fails or no object dictionary is present",
    0x08000024: "No data available",
}


def abort_text(code: int) -> str:
    """CiA 301 text of an SDO abort code ("unknown abort code" if not in the table)."""
    return ABORT_TEXTS.get(code, "unknown abort code")


# CANopen functions by COB-ID span (CiA 301 pre-defined connection set, L16873-L16899): the
# one classification the fault matcher, the recorder and the plans use
FUNCTION_SPANS: dict[str, tuple[tuple[int, int], ...]] = {
    "nmt": ((0x000, 0x000),),
    "sync": ((0x080, 0x080),),
    "emcy": ((0x081, 0x0FF),),
    "pdo": ((0x180, 0x57F),),
    "tpdo": ((0x180, 0x1FF), (0x280, 0x2FF), (0x380, 0x3FF), (0x480, 0x4FF)),
    "rpdo": ((0x200, 0x27F), (0x300, 0x37F), (0x400, 0x47F), (0x500, 0x57F)),
    "sdo": ((0x580, 0x67F),),
    "sdo_rx": ((0x600, 0x67F),),
    "heartbeat": ((0x700, 0x77F),),
}


def is_function(name: str, can_id: int) -> bool:
    """True if `can_id` belongs to CANopen function `name` (a key of FUNCTION_SPANS)."""
    return any(lo <= can_id <= hi for lo, hi in FUNCTION_SPANS[name])


def is_pdo(can_id: int) -> bool:
    return 0x180 <= can_id <= 0x57F


def is_sdo(can_id: int) -> bool:
    """An SDO request or response (0x581-0x67F: 0x580 itself is no node's)."""
    return 0x580 < can_id <= 0x67F


def classify(can_id: int) -> tuple[str, int | None]:
    """(kind, node) of an 11-bit COB-ID per the CiA 301 pre-defined connection set."""
    node = can_id & 0x7F
    fc = can_id & 0x780
    if can_id == NMT:
        return "nmt", None
    if can_id == SYNC:
        return "sync", None
    if can_id == 0x100:
        return "time", None
    if fc == 0x080:
        return "emcy", node
    for i, base in enumerate(TPDO_BASE):
        if fc == base:
            return f"tpdo{i + 1}", node
    for i, base in enumerate(RPDO_BASE):
        if fc == base:
            return f"rpdo{i + 1}", node
    if fc == SDO_RESPONSE:
        return "sdo_tx", node
    if fc == SDO_REQUEST:
        return "sdo_rx", node
    if fc == HEARTBEAT:
        return "heartbeat", node
    return "unknown", None


# --- SDO frame builders (8 bytes each) ---------------------------------------------------


def sdo_abort(index: int, sub: int, code: int) -> bytes:
    return struct.pack("<BHBI", 0x80, index & 0xFFFF, sub & 0xFF, code & 0xFFFFFFFF)


def sdo_expedited_upload_response(index: int, sub: int, data: bytes) -> bytes:
    """43h/47h/4Bh/4Fh + data (4/3/2/1 bytes) -- L17011-L17016."""
    n = 4 - len(data)
    return bytes([0x43 | (n << 2), index & 0xFF, index >> 8, sub]) + data + bytes(n)


def sdo_download_response(index: int, sub: int) -> bytes:
    """60h -- L16972."""
    return struct.pack("<BHBI", 0x60, index, sub, 0)


def sdo_expedited_download(index: int, sub: int, data: bytes) -> bytes:
    """23h/27h/2Bh/2Fh request (L16960-L16964)."""
    n = 4 - len(data)
    return bytes([0x23 | (n << 2), index & 0xFF, index >> 8, sub]) + data + bytes(n)


def sdo_upload_request(index: int, sub: int) -> bytes:
    """40h request (L17003-L17005)."""
    return struct.pack("<BHBI", 0x40, index, sub, 0)


def _u32(data: bytes, at: int = 4) -> int:
    return int.from_bytes(data[at : at + 4].ljust(4, b"\0"), "little")


def _describe_sdo(data: bytes, client: bool,
                  signed_params: Container[int] = frozenset()) -> dict:
    out: dict = {}
    if not data:
        out["error"] = "empty SDO frame"
        return out
    cs = data[0] >> 5
    if len(data) != 8:
        out["error"] = f"SDO frame with DLC {len(data)} (expected 8)"
    if client:
        out["ccs"] = cs
        out["command"] = CCS_NAMES.get(cs, "unknown")
    else:
        out["scs"] = cs
        out["command"] = SCS_NAMES.get(cs, "unknown")
    has_mux = (client and cs in (1, 2, 4, 5, 6)) or (not client and cs in (2, 3, 4))
    if has_mux and len(data) >= 4:
        out["index"] = data[1] | data[2] << 8
        out["sub"] = data[3]
    if cs == 4:
        code = _u32(data)
        out["abort_code"] = code
        out["abort_text"] = abort_text(code)
        return out
    initiate = (client and cs == 1) or (not client and cs == 2)
    if initiate:
        e, s = bool(data[0] & 2), bool(data[0] & 1)
        out["expedited"] = e
        if e:
            n = 4 - ((data[0] >> 2) & 3) if s else 4
            raw = bytes(data[4 : 4 + n])
            out["data"] = raw.hex()
            out["value"] = object_value(out.get("index", 0), out.get("sub", 0), raw,
                                        signed_params)
            # flat fields the timing specs address (cia402_transitions.yaml)
            if client and out.get("index") == 0x6040 and out.get("sub") == 0:
                out["controlword"] = out["value"]
            elif not client and out.get("index") == 0x6041 and out.get("sub") == 0:
                out["statusword"] = out["value"]
        elif s:
            out["size"] = _u32(data)
    elif (client and cs == 0) or (not client and cs == 0):
        n = (data[0] >> 1) & 7
        out["toggle"] = (data[0] >> 4) & 1
        out["last"] = bool(data[0] & 1)
        out["data"] = bytes(data[1 : 8 - n]).hex()
    elif (client and cs == 3) or (not client and cs == 1):
        out["toggle"] = (data[0] >> 4) & 1
    return out


def describe_frame(can_id: int, data: bytes, *, remote: bool = False,
                   signed_params: Container[int] = frozenset()) -> dict:
    """Decode one CAN frame into a flat dict (kind, node and the fields of its protocol);
    `signed_params`: manufacturer objects whose SDO values read signed (`object_value`)."""
    try:
        data = bytes(data)
        kind, node = classify(can_id)
        out: dict = {"kind": kind, "node": node, "cob_id": can_id, "dlc": len(data)}
        if remote:
            out["remote"] = True
            if kind == "heartbeat":
                out["kind"] = "node_guard_request"
            return out
        if kind == "nmt":
            if len(data) >= 2:
                out["command"] = NMT_COMMANDS.get(data[0], "unknown")
                out["cs"] = data[0]
                out["target"] = data[1]
            else:
                out["error"] = f"NMT frame with DLC {len(data)} (expected 2)"
        elif kind == "heartbeat":
            if data:
                state = data[0] & 0x7F
                out["state"] = NMT_STATES.get(state, f"unknown ({state})")
                out["toggle"] = data[0] >> 7
            else:
                out["error"] = "heartbeat without data"
        elif kind == "emcy":
            if len(data) >= 3:
                out["error_code"] = data[0] | data[1] << 8
                out["error_register"] = data[2]
                alarm = int.from_bytes(data[3:5].ljust(2, b"\0"), "little")
                out["alarm"] = f"AL{alarm:03X}" if alarm else ""
                out["manufacturer"] = bytes(data[3:8]).hex()
            else:
                out["error"] = f"EMCY frame with DLC {len(data)} (expected 8)"
        elif kind == "sync":
            if data:
                out["counter"] = data[0]
        elif kind in ("sdo_rx", "sdo_tx"):
            out.update(_describe_sdo(data, client=kind == "sdo_rx",
                                     signed_params=signed_params))
        elif kind.startswith(("tpdo", "rpdo")):
            out["data"] = data.hex()
        return out
    except Exception as exc:  # the recorder must never crash on a frame
        return {"kind": "unknown", "node": None, "cob_id": can_id, "error": repr(exc)}


# -- PDOs as configured on the bus (CiA 301 7.5.2.35-7.5.2.38; A3 manual L17940-18124) -----

# Objects a reviewer plots, by their CiA 402 names (A3 manual 6xxxh list, L18200 ff.)
PDO_NAMES: dict[tuple[int, int], str] = {
    (0x6040, 0): "controlword", (0x6041, 0): "statusword",
    (0x6060, 0): "modes_of_operation", (0x6061, 0): "modes_of_operation_display",
    (0x6064, 0): "position_actual", (0x606C, 0): "velocity_actual",
    (0x6077, 0): "torque_actual", (0x607A, 0): "target_position",
    (0x60FF, 0): "target_velocity", (0x6071, 0): "target_torque",
    (0x60C1, 1): "ip_position", (0x60F4, 0): "following_error_actual",
    (0x603F, 0): "error_code",
}
# The CiA 402 objects of a signed type (INTEGER8/16/32, CiA 402-2; the A3's EDS agrees on
# those it has): their values are decoded signed, in a PDO and in an SDO transfer alike
SIGNED_OBJECTS: frozenset[tuple[int, int]] = frozenset({
    (0x605A, 0), (0x605B, 0), (0x605C, 0), (0x605D, 0), (0x605E, 0),  # option codes
    (0x6060, 0), (0x6061, 0), (0x6062, 0), (0x6063, 0), (0x6064, 0), (0x606B, 0),
    (0x606C, 0), (0x6071, 0), (0x6074, 0), (0x6077, 0), (0x6078, 0), (0x607A, 0),
    (0x607C, 0), (0x607D, 1), (0x607D, 2), (0x6098, 0), (0x60B0, 0), (0x60B1, 0),
    (0x60B2, 0), (0x60BA, 0), (0x60BB, 0), (0x60BC, 0), (0x60BD, 0), (0x60C0, 0),
    (0x60C1, 1), (0x60C1, 2), (0x60C2, 2), (0x60F4, 0), (0x60FC, 0), (0x60FF, 0),
})


def object_value(index: int, sub: int, raw: bytes,
                 signed_params: Container[int] = frozenset()) -> int:
    """An object's value from its little-endian bytes: signed for `SIGNED_OBJECTS`, and for
    the manufacturer objects (sub 0) in `signed_params` (a drive profile's signed
    parameters: the A3's P1.043 at 212Bh, hil.record.sdo_pairing.signed_parameter_objects)."""
    signed = (index, sub) in SIGNED_OBJECTS or (sub == 0 and index in signed_params)
    return int.from_bytes(raw, "little", signed=signed)


class PdoMaps:
    """Each node's PDOs as the bus configured them, for decoding PDO payloads.

    Starts from the pre-defined connection set (TPDO n at 180h/280h/380h/480h + node, RPDO n
    at 200h/... + node) with no mapping, as the A3 ships (L17980-18024), or from `defaults`
    ((node, "tpdo"|"rpdo", n) -> [(index, sub, bits)], e.g. an EDS). Learns from SDO
    downloads the bus carries: 1400h-1403h / 1800h-1803h sub 1 (COB-ID, bit 31 = invalid),
    1600h-1603h / 1A00h-1A03h (sub 0 = count, sub k = index << 16 | sub << 8 | bits). An NMT
    reset of a node forgets what it learnt for that node."""

    def __init__(self, defaults: dict[tuple[int, str, int], list[tuple[int, int, int]]]
                 | None = None) -> None:
        self._defaults = dict(defaults or {})
        self._cob: dict[tuple[int, str, int], int] = {}
        self._entries: dict[tuple[int, str, int], dict[int, int]] = {}
        self._count: dict[tuple[int, str, int], int] = {}
        # COB-ID -> (PDO, mapping) or None, until the configuration changes: a recorder
        # decodes every PDO frame of the bus with it
        self._resolved: dict[int, tuple[tuple[int, str, int], list] | None] = {}

    @staticmethod
    def _which(index: int) -> tuple[str, int, str] | None:
        for base, kind, what in ((0x1400, "rpdo", "cob"), (0x1600, "rpdo", "map"),
                                 (0x1800, "tpdo", "cob"), (0x1A00, "tpdo", "map")):
            if base <= index < base + 4:
                return kind, index - base + 1, what
        return None

    def sdo_download(self, node: int, index: int, sub: int, value: int) -> None:
        """A download the node accepted (an SDO transaction that ended well)."""
        which = self._which(index)
        if which is None:
            return
        kind, n, what = which
        key = (node, kind, n)
        self._resolved.clear()
        if what == "cob":
            if sub == 1:
                self._cob[key] = value
        elif sub == 0:
            self._count[key] = value & 0xFF
        else:
            self._entries.setdefault(key, {})[sub] = value & 0xFFFFFFFF

    def nmt_reset(self, node: int) -> None:
        """Reset node / communication: the communication objects go back to their defaults."""
        for store in (self._cob, self._entries, self._count):
            for key in [k for k in store if node in (0, k[0])]:
                del store[key]
        self._resolved.clear()

    def _mapping(self, key: tuple[int, str, int]) -> list[tuple[int, int, int]]:
        if key in self._count or key in self._entries:
            entries = self._entries.get(key, {})
            count = self._count.get(key, len(entries))
            out = []
            for sub in range(1, count + 1):
                e = entries.get(sub)
                if e is None:
                    return []
                out.append((e >> 16, (e >> 8) & 0xFF, e & 0xFF))
            return out
        return list(self._defaults.get(key, []))

    def _find(self, cob_id: int) -> tuple[int, str, int] | None:
        for key, cob in self._cob.items():
            if not cob & 0x80000000 and cob & 0x7FF == cob_id:
                return key
        kind, node = classify(cob_id)
        if kind[:4] in ("tpdo", "rpdo") and node is not None:
            key = (node, kind[:4], int(kind[4:]))
            cob = self._cob.get(key)
            if cob is None or (not cob & 0x80000000 and cob & 0x7FF == cob_id):
                return key
        return None

    def decode(self, cob_id: int, data: bytes) -> dict | None:
        """The mapped objects of a PDO frame (None: not a PDO this map knows), e.g.
        {"pdo": "TPDO1", "objects": {"6041h:00": 0x1637, ...}, "statusword": 0x1637}."""
        try:
            found = self._resolved[cob_id]
        except KeyError:
            key = self._find(cob_id)
            mapping = self._mapping(key) if key is not None else []
            found = self._resolved[cob_id] = (key, mapping) if key and mapping else None
        if found is None:
            return None
        key, mapping = found
        out: dict = {"pdo": f"{key[1].upper()}{key[2]}", "objects": {}}
        bit = 0
        raw = int.from_bytes(bytes(data), "little")
        for index, sub, bits in mapping:
            if bits == 0 or bit + bits > 8 * len(data):
                out["error"] = (f"PDO mapping of {bit + bits} bits is longer than the "
                                f"{len(data)}-byte frame")
                break
            v = (raw >> bit) & ((1 << bits) - 1)
            if (index, sub) in SIGNED_OBJECTS and v >> (bits - 1):
                v -= 1 << bits
            bit += bits
            out["objects"][f"{index:04X}h:{sub:02X}"] = v
            name = PDO_NAMES.get((index, sub))
            if name:
                out[name] = v
        return out
