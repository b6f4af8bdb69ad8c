"""The CiA 402 driver's SDO transfers (CiA 301 §7.2.4.3), on canopen's SdoClient queue.

canopen's client takes the first frame on 580h+node as the answer: a late download
acknowledgement of an earlier write (one that timed out) is success for the next write, an
abort for another object is this object's abort, and an upload whose segments never end is
read for ever. Here an initiate answer or an abort counts only with this transfer's index and
sub-index and kind (a frame for another object, or a download ack while uploading, is dropped
and the wait goes on, within the timeout; a late ack of an earlier write to the same object
cannot be told from this one's: SDO answers carry no transaction id),
and a segmented upload ends at `MAX_UPLOAD` bytes with abort 0504 0005h. Transfers longer
than 4 bytes down are left to canopen's client (the A3's objects are at most 4 bytes).
"""

from __future__ import annotations

import queue
import struct
from typing import Any

from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

from hil import clock

MAX_UPLOAD = 4096  # bytes: the A3's longest object is a short string (1008h-100Ah)

_MUX = struct.Struct("<BHB")
_ABORT = 0x80
_ABORT_TIMEOUT = 0x05040000  # SDO protocol timed out
_ABORT_COMMAND = 0x05040001  # client/server command specifier not valid
_ABORT_TOGGLE = 0x05030000  # toggle bit not alternated
_ABORT_MEMORY = 0x05040005  # out of memory


class SdoMalformedError(SdoCommunicationError):
    """An answer that is no valid answer to this transfer."""


def download(sdo: Any, index: int, sub: int, data: bytes) -> None:
    """Expedited download of 1-4 bytes; longer data through canopen's segmented download."""
    if not 1 <= len(data) <= 4:
        sdo.download(index, sub, data)
        return
    command = 0x23 | ((4 - len(data)) << 2)  # initiate, expedited, size indicated
    answer = _exchange(sdo, _MUX.pack(command, index, sub) + data.ljust(4, b"\0"), (index, sub),
                       0x60)
    if answer[0] & 0xE0 != 0x60:  # as canopen: the x bits of a download answer are free
        sdo.abort(_ABORT_COMMAND)
        raise SdoMalformedError(f"answer {answer.hex(' ')} to an initiate download")


def upload(sdo: Any, index: int, sub: int) -> bytes:
    """Expedited or segmented upload of at most `MAX_UPLOAD` bytes."""
    answer = _exchange(sdo, _MUX.pack(0x40, index, sub) + bytes(4), (index, sub), 0x40)
    command = answer[0]
    if command & 0xE0 != 0x40:
        sdo.abort(_ABORT_COMMAND)
        raise SdoMalformedError(f"answer {answer.hex(' ')} to an initiate upload")
    if command & 0x02:  # expedited
        size = 4 - ((command >> 2) & 0x3) if command & 0x01 else 4
        if len(answer) < 4 + size:
            raise SdoMalformedError(f"expedited answer {answer.hex(' ')}: shorter than its size")
        return bytes(answer[4:4 + size])
    declared = _u32(answer) if command & 0x01 else None
    if declared is not None and declared > MAX_UPLOAD:
        sdo.abort(_ABORT_MEMORY)
        raise SdoMalformedError(f"segmented upload of {declared} bytes: above {MAX_UPLOAD}")
    return _segments(sdo)


def _segments(sdo: Any) -> bytes:
    out = bytearray()
    toggle = 0
    while True:
        answer = _exchange(sdo, bytes([0x60 | toggle]) + bytes(7), None, None)
        command = answer[0]
        if command & 0xE0 != 0x00:
            sdo.abort(_ABORT_COMMAND)
            raise SdoMalformedError(f"answer {answer.hex(' ')} to an upload segment")
        if command & 0x10 != toggle:
            sdo.abort(_ABORT_TOGGLE)
            raise SdoMalformedError("upload segment: toggle bit not alternated")
        out += answer[1:8 - ((command >> 1) & 0x7)]
        if command & 0x01:  # no more segments
            return bytes(out)
        if len(out) > MAX_UPLOAD:
            sdo.abort(_ABORT_MEMORY)
            raise SdoMalformedError(f"segmented upload past {MAX_UPLOAD} bytes without an end")
        toggle ^= 0x10


def _exchange(sdo: Any, request: bytes, mux: tuple[int, int] | None,
              scs: int | None) -> bytes:
    """Send `request`; the answer is the first frame for `mux` (any frame when None) whose
    server command is `scs` (or an abort) within the client's timeout. Frames for another
    object, or of another kind for this one (a late download ack while uploading), are
    dropped; an abort for this object raises."""
    if not sdo.responses.empty():
        sdo.responses = queue.Queue()  # canopen's own rule: stale answers before a request
    sdo.send_request(bytearray(request))
    deadline = clock.monotonic() + sdo.RESPONSE_TIMEOUT
    while True:
        remaining = deadline - clock.monotonic()
        try:
            answer = bytes(sdo.responses.get(block=True, timeout=max(remaining, 0.0)))
        except queue.Empty:
            sdo.abort(_ABORT_TIMEOUT)
            raise SdoCommunicationError("No SDO response received") from None
        if len(answer) < (4 if mux is not None else 1):
            raise SdoMalformedError(f"answer of {len(answer)} bytes")
        if mux is not None:
            _, a_index, a_sub = _MUX.unpack_from(answer)
            if (a_index, a_sub) != mux and not (answer[0] == _ABORT and (a_index, a_sub) == (0, 0)):
                continue  # a late answer to an earlier transfer, or another client's
            if scs is not None and answer[0] != _ABORT and answer[0] & 0xE0 != scs:
                continue  # this object's, but of another transfer (a late write ack)
        if answer[0] == _ABORT:
            if len(answer) < 8:
                raise SdoMalformedError(f"abort of {len(answer)} bytes")
            raise SdoAbortedError(_u32(answer))
        return answer


def _u32(answer: bytes) -> int:
    if len(answer) < 8:
        raise SdoMalformedError(f"answer of {len(answer)} bytes: no 32-bit data")
    return int.from_bytes(answer[4:8], "little")
