"""Modbus RTU/ASCII as the Delta ASDA-A3 speaks it (manual ch. 9, L15525-L16049). Pure code.

Shared by the drive's face (`hil.faces.modbus_slave`), the harness master
(`hil.drivers.delta_modbus`) and the recorder (`describe_adu`). No I/O, no clock: times are
integer ns computed from the baud rate and the character format.

Layers:
- checks: `crc16` (RTU, L15899-L15946), `lrc` (ASCII, L15891-L15895);
- ADU: `rtu_encode/rtu_decode`, `ascii_encode/ascii_decode` (frame layout L15605-L15630);
- PDU: requests and responses of functions 03h, 06h, 10h (L15568) and exception responses;
- timing: character time, t1.5/t3.5, the manual's 10 ms frame silence (L15703);
- `describe_adu(data, mode)` -> dict for recordings; never raises.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

Mode = Literal["rtu", "ascii"]

# Function codes the A3 supports (L15568).
READ_HOLDING = 0x03
WRITE_SINGLE = 0x06
WRITE_MULTIPLE = 0x10
SUPPORTED_FUNCTIONS = (READ_HOLDING, WRITE_SINGLE, WRITE_MULTIPLE)
FUNCTION_NAMES = {
    READ_HOLDING: "read holding registers (03h)",
    WRITE_SINGLE: "write single register (06h)",
    WRITE_MULTIPLE: "write multiple registers (10h)",
}

MAX_READ_WORDS = 10  # "最大允許單次讀出的筆數為 10 筆", L15634
MAX_WRITE_WORDS = 8  # "最大允許單次寫入的筆數為 8 筆", L15781

BROADCAST = 0x00  # standard Modbus broadcast; the A3 manual does not mention it (⚠ gap)
AUTO_REPLY = 0xFF  # "局號為 0xFF 時，具有自動回覆功能" (P3.000, L10507)

# Exception codes (Modbus Application Protocol v1.1b3 §7; the A3 manual documents none).
ILLEGAL_FUNCTION = 0x01
ILLEGAL_DATA_ADDRESS = 0x02
ILLEGAL_DATA_VALUE = 0x03
SERVER_DEVICE_FAILURE = 0x04
SERVER_DEVICE_BUSY = 0x06
EXCEPTION_NAMES = {
    ILLEGAL_FUNCTION: "illegal function",
    ILLEGAL_DATA_ADDRESS: "illegal data address",
    ILLEGAL_DATA_VALUE: "illegal data value",
    SERVER_DEVICE_FAILURE: "server device failure",
    0x05: "acknowledge",
    SERVER_DEVICE_BUSY: "server device busy",
    0x08: "memory parity error",
    0x0A: "gateway path unavailable",
    0x0B: "gateway target failed to respond",
}

MAX_RTU_ADU = 256  # Modbus over serial line v1.02 §2.5.1
MAX_ASCII_ADU = 513  # ':' + 2 x 255 + CR LF

MANUAL_SILENCE_NS = 10_000_000  # "RTU 模式下的傳輸前與傳輸完成後，需有 10 ms 的靜止時段" L15703


def exception_name(code: int) -> str:
    return EXCEPTION_NAMES.get(code, f"exception code 0x{code:02X}")


def function_name(function: int) -> str:
    return FUNCTION_NAMES.get(function & 0x7F, f"function 0x{function & 0x7F:02X}")


# --------------------------------------------------------------------------- checks


def _crc_table() -> list[int]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
        table.append(crc)
    return table


_CRC_TABLE = _crc_table()


def crc16(data: bytes) -> int:
    """Modbus CRC-16: init FFFFh, reflected poly A001h (L15903-L15909, `crc_chk` L15931)."""
    crc = 0xFFFF
    for byte in data:
        crc = (crc >> 8) ^ _CRC_TABLE[(crc ^ byte) & 0xFF]
    return crc


def lrc(data: bytes) -> int:
    """LRC: sum the bytes, drop the carries, two's complement (L15891-L15895)."""
    return (-sum(data)) & 0xFF


# --------------------------------------------------------------------------- ADU


class FrameError(ValueError):
    """An ADU that is not a well-formed frame (names the rule it breaks)."""


def rtu_encode(station: int, pdu: bytes) -> bytes:
    """Station + PDU + CRC, CRC low byte first (L15911)."""
    _check_station(station)
    body = bytes([station]) + pdu
    crc = crc16(body)
    return body + bytes([crc & 0xFF, crc >> 8])


def rtu_decode(adu: bytes) -> tuple[int, bytes]:
    """(station, pdu) of an RTU ADU; raises FrameError on length or CRC."""
    if len(adu) < 4:
        raise FrameError(f"RTU frame of {len(adu)} bytes: shorter than 4 (station, fn, CRC)")
    if len(adu) > MAX_RTU_ADU:
        raise FrameError(f"RTU frame of {len(adu)} bytes: longer than {MAX_RTU_ADU}")
    got = adu[-2] | adu[-1] << 8
    want = crc16(adu[:-2])
    if got != want:
        raise FrameError(f"RTU CRC {got:04X}h, computed {want:04X}h")
    return adu[0], bytes(adu[1:-2])


def ascii_encode(station: int, pdu: bytes) -> bytes:
    """':' + hex (upper case, L15574-L15581) + LRC + CR LF (L15605-L15617)."""
    _check_station(station)
    body = bytes([station]) + pdu
    return b":" + (body + bytes([lrc(body)])).hex().upper().encode() + b"\r\n"


def ascii_decode(adu: bytes) -> tuple[int, bytes]:
    """(station, pdu) of an ASCII ADU; raises FrameError on framing, hex or LRC."""
    if len(adu) > MAX_ASCII_ADU:
        raise FrameError(f"ASCII frame of {len(adu)} chars: longer than {MAX_ASCII_ADU}")
    if not adu.startswith(b":"):
        raise FrameError("ASCII frame does not start with ':' (3Ah)")
    if not adu.endswith(b"\r\n"):
        raise FrameError("ASCII frame does not end with CR LF")
    text = adu[1:-2]
    if len(text) % 2 or len(text) < 6:
        raise FrameError(f"ASCII frame body of {len(text)} chars: needs an even count >= 6")
    if not all(c in b"0123456789ABCDEFabcdef" for c in text):
        raise FrameError("ASCII frame body has a non-hex character")
    raw = bytes.fromhex(text.decode())
    if lrc(raw[:-1]) != raw[-1]:
        raise FrameError(f"ASCII LRC {raw[-1]:02X}h, computed {lrc(raw[:-1]):02X}h")
    return raw[0], raw[1:-1]


def encode_adu(station: int, pdu: bytes, mode: Mode) -> bytes:
    return rtu_encode(station, pdu) if mode == "rtu" else ascii_encode(station, pdu)


def decode_adu(adu: bytes, mode: Mode) -> tuple[int, bytes]:
    return rtu_decode(adu) if mode == "rtu" else ascii_decode(adu)


def _check_station(station: int) -> None:
    if not 0 <= station <= 0xFF:
        raise ValueError(f"station {station}: must be 0..255")


# --------------------------------------------------------------------------- PDU


class PduError(ValueError):
    """A request PDU the slave must refuse; `code` is the Modbus exception code to answer."""

    def __init__(self, code: int, message: str) -> None:
        super().__init__(f"{exception_name(code)} ({code:02X}h): {message}")
        self.code = code


@dataclass(frozen=True)
class Request:
    """A decoded request: function, first register, word count, values (for writes)."""

    function: int
    address: int
    count: int
    values: tuple[int, ...] = ()

    def encode(self) -> bytes:
        if self.function == READ_HOLDING:
            return read_request(self.address, self.count)
        if self.function == WRITE_SINGLE:
            return write_single_request(self.address, self.values[0])
        if self.function == WRITE_MULTIPLE:
            return write_multiple_request(self.address, self.values)
        raise ValueError(f"function {self.function:02X}h: not 03h/06h/10h")


@dataclass(frozen=True)
class Response:
    """A decoded response; `exception` is the code of an exception response, else None."""

    function: int
    address: int | None = None
    count: int | None = None
    values: tuple[int, ...] = field(default=())
    exception: int | None = None


def _word(value: int, what: str) -> bytes:
    if not 0 <= value <= 0xFFFF:
        raise ValueError(f"{what} {value}: must be 0..65535")
    return value.to_bytes(2, "big")


def read_request(address: int, count: int) -> bytes:
    """03h PDU: address, word count (L15680-L15689)."""
    return bytes([READ_HOLDING]) + _word(address, "address") + _word(count, "count")


def write_single_request(address: int, value: int) -> bytes:
    """06h PDU: address, value (L15755-L15764)."""
    return bytes([WRITE_SINGLE]) + _word(address, "address") + _word(value, "value")


def write_multiple_request(address: int, values: tuple[int, ...] | list[int]) -> bytes:
    """10h PDU: address, word count, byte count, words (L15838-L15852)."""
    if not 1 <= len(values) <= 123:
        raise ValueError(f"10h with {len(values)} words: must be 1..123")
    data = b"".join(_word(v, "value") for v in values)
    return (
        bytes([WRITE_MULTIPLE])
        + _word(address, "address")
        + _word(len(values), "count")
        + bytes([len(data)])
        + data
    )


def read_response(values: list[int] | tuple[int, ...]) -> bytes:
    """03h reply: byte count, words (L15691-L15701)."""
    data = b"".join(_word(v, "value") for v in values)
    return bytes([READ_HOLDING, len(data)]) + data


def write_multiple_response(address: int, count: int) -> bytes:
    """10h reply: address, word count (L15854-L15863)."""
    return bytes([WRITE_MULTIPLE]) + _word(address, "address") + _word(count, "count")


def exception_response(function: int, code: int) -> bytes:
    """Function | 80h, exception code."""
    return bytes([(function | 0x80) & 0xFF, code & 0xFF])


def decode_request(
    pdu: bytes, *, max_read: int = MAX_READ_WORDS, max_write: int = MAX_WRITE_WORDS
) -> Request:
    """Parse a request PDU; raises PduError with the exception code a slave answers.

    Order of checks as in the Modbus application protocol state diagrams: function (01h),
    quantity / byte count (03h), then the address range (02h). The A3 limits 10 / 8 words
    are L15634 / L15781.
    """
    if not pdu:
        raise PduError(ILLEGAL_FUNCTION, "empty PDU")
    fn = pdu[0]
    if fn not in SUPPORTED_FUNCTIONS:
        raise PduError(ILLEGAL_FUNCTION, f"function {fn:02X}h: the A3 supports 03h, 06h, 10h")
    if fn in (READ_HOLDING, WRITE_SINGLE):
        if len(pdu) != 5:
            raise PduError(ILLEGAL_DATA_VALUE, f"{fn:02X}h PDU of {len(pdu)} bytes: needs 5")
        address = int.from_bytes(pdu[1:3], "big")
        word = int.from_bytes(pdu[3:5], "big")
        if fn == WRITE_SINGLE:
            return Request(fn, address, 1, (word,))
        if not 1 <= word <= max_read:
            raise PduError(ILLEGAL_DATA_VALUE, f"03h reads {word} words: 1..{max_read} (L15634)")
        if address + word > 0x10000:
            raise PduError(ILLEGAL_DATA_ADDRESS, f"03h {address:04X}h+{word} passes FFFFh")
        return Request(fn, address, word)
    if len(pdu) < 6:
        raise PduError(ILLEGAL_DATA_VALUE, f"10h PDU of {len(pdu)} bytes: shorter than 6")
    address = int.from_bytes(pdu[1:3], "big")
    count = int.from_bytes(pdu[3:5], "big")
    nbytes = pdu[5]
    if not 1 <= count <= max_write:
        raise PduError(ILLEGAL_DATA_VALUE, f"10h writes {count} words: 1..{max_write} (L15781)")
    if nbytes != 2 * count or len(pdu) != 6 + nbytes:
        raise PduError(
            ILLEGAL_DATA_VALUE,
            f"10h byte count {nbytes} for {count} words with {len(pdu) - 6} data bytes",
        )
    if address + count > 0x10000:
        raise PduError(ILLEGAL_DATA_ADDRESS, f"10h {address:04X}h+{count} passes FFFFh")
    values = tuple(int.from_bytes(pdu[6 + 2 * i : 8 + 2 * i], "big") for i in range(count))
    return Request(fn, address, count, values)


def decode_response(pdu: bytes) -> Response:
    """Parse a response PDU (03h / 06h / 10h / exception); raises FrameError if malformed."""
    if len(pdu) < 2:
        raise FrameError(f"response PDU of {len(pdu)} bytes: shorter than 2")
    fn = pdu[0]
    if fn & 0x80:
        if len(pdu) != 2:
            raise FrameError(f"exception PDU of {len(pdu)} bytes: needs 2")
        return Response(fn & 0x7F, exception=pdu[1])
    if fn == READ_HOLDING:
        n = pdu[1]
        if n % 2 or len(pdu) != 2 + n:
            raise FrameError(f"03h reply byte count {n} with {len(pdu) - 2} data bytes")
        values = tuple(int.from_bytes(pdu[2 + 2 * i : 4 + 2 * i], "big") for i in range(n // 2))
        return Response(fn, count=n // 2, values=values)
    if fn in (WRITE_SINGLE, WRITE_MULTIPLE):
        if len(pdu) != 5:
            raise FrameError(f"{fn:02X}h reply PDU of {len(pdu)} bytes: needs 5")
        address = int.from_bytes(pdu[1:3], "big")
        word = int.from_bytes(pdu[3:5], "big")
        if fn == WRITE_SINGLE:
            return Response(fn, address, 1, (word,))
        return Response(fn, address, word)
    raise FrameError(f"response function {fn:02X}h: not 03h/06h/10h")


def rtu_request_length(buf: bytes) -> int | None:
    """Length of the RTU request that starts `buf`, once knowable; None if not (yet) known.

    03h/06h requests are 8 bytes; 10h is 9 + byte count. Unknown functions: None (only the
    silent interval ends them).
    """
    if len(buf) < 2:
        return None
    fn = buf[1]
    if fn in (READ_HOLDING, WRITE_SINGLE):
        return 8
    if fn == WRITE_MULTIPLE:
        return 9 + buf[6] if len(buf) >= 7 else None
    return None


def rtu_response_length(buf: bytes) -> int | None:
    """Length of the RTU response that starts `buf`, once knowable (exception: 5 bytes)."""
    if len(buf) < 2:
        return None
    fn = buf[1]
    if fn & 0x80:
        return 5
    if fn == READ_HOLDING:
        return 5 + buf[2] if len(buf) >= 3 else None
    if fn in (WRITE_SINGLE, WRITE_MULTIPLE):
        return 8
    return None


# --------------------------------------------------------------------------- line timing

# P3.001 digit X -> RS-485 baud (L10524-L10527).
P3001_BAUD = {0: 4800, 1: 9600, 2: 19200, 3: 38400, 4: 57600, 5: 115200}


@dataclass(frozen=True)
class CharFormat:
    """Data bits, parity ('N', 'E', 'O'), stop bits; one start bit is implied."""

    data_bits: int = 8
    parity: str = "N"
    stop_bits: int = 2

    @property
    def bits(self) -> int:
        """Bits on the wire per character: 10 for 7-bit, 11 for 8-bit formats (L15589-L15593)."""
        return 1 + self.data_bits + (self.parity != "N") + self.stop_bits

    def __str__(self) -> str:
        return f"{self.data_bits}{self.parity}{self.stop_bits}"


# P3.002 value -> (mode, character format) (L10553-L10557). 8N1 is not offered.
P3002_PROTOCOLS: dict[int, tuple[Mode, CharFormat]] = {
    0: ("ascii", CharFormat(7, "N", 2)),
    1: ("ascii", CharFormat(7, "E", 1)),
    2: ("ascii", CharFormat(7, "O", 1)),
    3: ("ascii", CharFormat(8, "N", 2)),
    4: ("ascii", CharFormat(8, "E", 1)),
    5: ("ascii", CharFormat(8, "O", 1)),
    6: ("rtu", CharFormat(8, "N", 2)),
    7: ("rtu", CharFormat(8, "E", 1)),
    8: ("rtu", CharFormat(8, "O", 1)),
}


def uart_for_line(baud: int, fmt: CharFormat, mode: str) -> tuple[int | None, int | None]:
    """P3.001 digit X and P3.002 of an A3 UART that reads a line of `baud` and `fmt` in `mode`
    (None where the A3 offers none: L10524-L10527, L10553-L10557). The stop bits decide only
    between two that fit: a receiver checks the first stop bit only."""
    x = next((k for k, b in P3001_BAUD.items() if b == baud), None)
    fits = [(f.stop_bits != fmt.stop_bits, n) for n, (m, f) in P3002_PROTOCOLS.items()
            if m == mode and (f.data_bits, f.parity) == (fmt.data_bits, fmt.parity)]
    return x, (min(fits)[1] if fits else None)


def uart_mismatch(line_baud: int, line_fmt: CharFormat, uart_baud: int,
                  uart_fmt: CharFormat) -> str | None:
    """Why a UART at `uart_baud`/`uart_fmt` garbles a line at `line_baud`/`line_fmt` (None: it
    reads it): another baud, data bits or parity. ⚠ The stop bits are not compared (a receiver
    checks the first only: an 8N1 sender is read at 8N2; the manual does not say)."""
    if line_baud == uart_baud and (line_fmt.data_bits, line_fmt.parity) == (
            uart_fmt.data_bits, uart_fmt.parity):
        return None
    return (f"the line runs {line_baud} baud {line_fmt}, the drive's UART {uart_baud} baud "
            f"{uart_fmt}")


def protocol_from_p3002(value: int) -> tuple[Mode, CharFormat]:
    """P3.002 -> (mode, format); raises ValueError outside 0..8 (L10548)."""
    try:
        return P3002_PROTOCOLS[value]
    except KeyError:
        raise ValueError(f"P3.002 = {value}: must be 0..8 (L10548)") from None


def baud_from_p3001(value: int) -> int:
    """RS-485 baud from P3.001 digit X (L10524-L10527); raises ValueError on X > 5."""
    x = value & 0xF
    if x not in P3001_BAUD:
        raise ValueError(f"P3.001 = 0x{value:04X}: digit X = {x} must be 0..5 (L10522)")
    return P3001_BAUD[x]


def char_time_ns(baud: int, fmt: CharFormat | int = CharFormat()) -> int:
    """Time one character takes on the wire, ns."""
    bits = fmt if isinstance(fmt, int) else fmt.bits
    if baud <= 0:
        raise ValueError(f"baud {baud}: must be > 0")
    return round(bits * 1_000_000_000 / baud)


def silent_intervals_ns(
    baud: int, fmt: CharFormat | int = CharFormat(), *, fixed_above_19200: bool = True
) -> tuple[int, int]:
    """(t1.5, t3.5) in ns. Modbus over serial line v1.02 §2.5.1.1: 1.5 / 3.5 character
    times, fixed at 750 µs / 1750 µs above 19200 baud. The A3 manual itself only asks for a
    10 ms silence before and after an RTU frame (L15703, L15777, L15865): `MANUAL_SILENCE_NS`.
    """
    if fixed_above_19200 and baud > 19200:
        return 750_000, 1_750_000
    bits = fmt if isinstance(fmt, int) else fmt.bits
    return round(1.5e9 * bits / baud), round(3.5e9 * bits / baud)


def frame_time_ns(nbytes: int, baud: int, fmt: CharFormat | int = CharFormat()) -> int:
    """Wire time of `nbytes` back-to-back characters."""
    return nbytes * char_time_ns(baud, fmt)


# --------------------------------------------------------------------------- recorder


def describe_adu(data: bytes, mode: Mode = "rtu", direction: str | None = None) -> dict[str, Any]:
    """Decode one ADU for a recording. Never raises.

    Keys: mode, raw (hex or text), length, station, function, function_name, kind
    ("request", "response", "exception", "request_or_echo" for 06h, "unknown"), address,
    count, values, exception, exception_name, check_ok (CRC/LRC), error (text or None).
    `direction` ("request"/"tx" from the master, "response"/"rx" from the slave) resolves
    what the bytes alone cannot.
    """
    data = bytes(data) if isinstance(data, (bytes, bytearray, memoryview)) else b""
    out: dict[str, Any] = {
        "mode": mode,
        "raw": data.hex(" ") if mode == "rtu" else data.decode("latin-1"),
        "length": len(data),
        "station": None,
        "function": None,
        "function_name": None,
        "kind": "unknown",
        "address": None,
        "count": None,
        "values": [],
        "exception": None,
        "exception_name": None,
        "check_ok": False,
        "error": None,
    }
    try:
        _describe(data, mode, direction, out)
    except Exception as exc:  # never raise: a recorder must survive any bytes
        out["error"] = str(exc) or type(exc).__name__
    return out


def _describe(data: bytes, mode: str, direction: str | None, out: dict[str, Any]) -> None:
    if mode not in ("rtu", "ascii"):
        raise FrameError(f"mode {mode!r}: must be 'rtu' or 'ascii'")
    if mode == "rtu":
        if len(data) >= 2:
            out["station"], out["function"] = data[0], data[1]
        station, pdu = rtu_decode(data)
    else:
        station, pdu = ascii_decode(data)
    out["check_ok"] = True
    out["station"] = station
    if not pdu:
        raise FrameError("frame has no function code")
    fn = pdu[0]
    out["function"] = fn
    out["function_name"] = function_name(fn)
    is_req = {"request": True, "tx": True, "response": False, "rx": False}.get(direction or "")
    if fn & 0x80:
        rsp = decode_response(pdu)
        out.update(kind="exception", exception=rsp.exception)
        out["exception_name"] = exception_name(rsp.exception or 0)
        return
    if is_req is None:
        if fn == READ_HOLDING:
            is_req = len(pdu) == 5
        elif fn == WRITE_MULTIPLE:
            is_req = len(pdu) != 5
    if is_req is None and fn == WRITE_SINGLE:
        req = decode_request(pdu)
        out.update(kind="request_or_echo", address=req.address, count=1, values=list(req.values))
        return
    if is_req:
        try:
            req = decode_request(pdu, max_read=125, max_write=123)
        except PduError as exc:
            out["kind"] = "request"
            out["error"] = str(exc)
            return
        out.update(kind="request", address=req.address, count=req.count, values=list(req.values))
        return
    rsp = decode_response(pdu)
    out.update(kind="response", address=rsp.address, count=rsp.count, values=list(rsp.values))
