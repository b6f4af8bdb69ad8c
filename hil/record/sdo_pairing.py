"""Pair CiA 301 SDO requests (0x600+node) with responses (0x580+node) into transactions.

Feeds on raw frames, needs no object dictionary. A transaction ends on the final response
(ok), an abort from either side (abort code), or a new request for the same node before the
answer came (`timeout`). Latency is from the first request frame to the last response frame.
Block transfers are recognised but not reassembled.
"""

from __future__ import annotations

import functools
import logging
from dataclasses import dataclass, field

from hil.protocol.canopen import SDO_REQUEST, SDO_RESPONSE, object_value


@functools.cache
def signed_parameter_objects() -> frozenset[int]:
    """The 2xxxh objects of the A3's signed P-parameters (a negative minimum in the chapter 8
    table: P1.043 at 212Bh, P6.001 at 2601h; P1.044 -> 212Ch, L18154-18156), read once:
    their SDO values read signed in the record."""
    try:
        from hil.profile.params import ParamTable

        return frozenset(p.od_index for p in ParamTable.load() if p.signed)
    except Exception:  # no table: unsigned, as before; never a recorder that stops
        logging.getLogger(__name__).warning("parameter table unreadable: P-parameters over "
                                            "SDO are recorded unsigned", exc_info=True)
        return frozenset()


@dataclass
class _Txn:
    node: int
    t0: int
    index: int
    sub: int
    access: str  # upload | download
    transfer: str  # expedited | segmented | block
    data: bytearray = field(default_factory=bytearray)
    size: int | None = None
    frames: int = 1
    last_segment: bool = False


def _result(txn: _Txn, status: str, t: int | None, **extra) -> dict:
    data = bytes(txn.data)
    latency = None if t is None else t - txn.t0
    out = {
        "node": txn.node,
        "index": txn.index,
        "sub": txn.sub,
        "object": f"{txn.index:04X}h:{txn.sub:02X}",
        "access": txn.access,
        "transfer": txn.transfer,
        "status": status,
        # signed for a CiA 402 object of a signed type (607Ah -4300000, not 4290667296)
        "value": (object_value(txn.index, txn.sub, data, signed_parameter_objects())
                  if 0 < len(data) <= 8 else None),
        "data": data.hex(),
        "size": len(data),
        "abort_code": None,
        "abort_by": None,
        "latency_ns": latency,
        "latency_us": None if latency is None else latency / 1000.0,
        "frames": txn.frames,
        "t_request": txn.t0,
    }
    out.update(extra)
    return out


class SdoPairing:
    """Stateful pairer for one bus. `feed()` returns the transactions a frame completes."""

    def __init__(self) -> None:
        self._open: dict[int, _Txn] = {}

    @staticmethod
    def is_sdo(can_id: int) -> bool:
        return (
            SDO_RESPONSE < can_id <= SDO_RESPONSE + 127
            or SDO_REQUEST < can_id <= SDO_REQUEST + 127
        )

    def feed(self, can_id: int, data: bytes, t: int) -> list[dict]:
        if SDO_REQUEST < can_id <= SDO_REQUEST + 127:
            return self._client(can_id - SDO_REQUEST, bytes(data), t)
        if SDO_RESPONSE < can_id <= SDO_RESPONSE + 127:
            return self._server(can_id - SDO_RESPONSE, bytes(data), t)
        return []

    def pending(self) -> list[dict]:
        """Close every open transaction as `timeout` (call at the end of a recording)."""
        out = [_result(txn, "timeout", None) for txn in self._open.values()]
        self._open.clear()
        return out

    # -- client (request) side -----------------------------------------------------------------
    def _client(self, node: int, d: bytes, t: int) -> list[dict]:
        out: list[dict] = []
        if len(d) < 1:
            return [self._error(node, d, t, "empty SDO request frame")]
        cs = d[0] >> 5
        txn = self._open.get(node)
        if cs in (1, 2, 5, 6):  # initiate download / upload / block upload / block download
            if txn is not None:
                out.append(_result(self._open.pop(node), "timeout", None, error="no response"))
            if len(d) < 4:
                out.append(self._error(node, d, t, "SDO initiate frame shorter than 4 bytes"))
                return out
            index = d[1] | d[2] << 8
            new = _Txn(node, t, index, d[3], "download" if cs in (1, 6) else "upload", "")
            if cs == 1:
                e, s, n = d[0] >> 1 & 1, d[0] & 1, d[0] >> 2 & 3
                if e:
                    new.transfer = "expedited"
                    new.data += d[4 : 8 - n] if s else d[4:8]
                else:
                    new.transfer = "segmented"
                    if s and len(d) >= 8:
                        new.size = int.from_bytes(d[4:8], "little")
            elif cs == 2:
                new.transfer = ""  # known from the response
            else:
                new.transfer = "block"
            self._open[node] = new
        elif cs == 0:  # download segment
            if txn is None or txn.access != "download":
                return [self._error(node, d, t, "download segment without a transfer")]
            n = d[0] >> 1 & 7
            txn.data += d[1 : 8 - n]
            txn.frames += 1
            txn.last_segment = bool(d[0] & 1)
        elif cs == 3:  # upload segment request
            if txn is None or txn.access != "upload":
                return [self._error(node, d, t, "upload segment request without a transfer")]
            txn.frames += 1
        elif cs == 4:  # abort by the client
            out.append(self._abort(node, d, t, txn, "client"))
        else:
            out.append(self._error(node, d, t, f"unknown SDO client command specifier {cs}"))
        return out

    def _abort(self, node: int, d: bytes, t: int, txn: _Txn | None, by: str) -> dict:
        """An abort frame (cs 4) from the client or the server ends the node's transfer."""
        code = int.from_bytes(d[4:8], "little") if len(d) >= 8 else None
        if txn is None:
            index = d[1] | d[2] << 8 if len(d) >= 3 else 0
            txn = _Txn(node, t, index, d[3] if len(d) >= 4 else 0, "unknown", "")
        else:
            del self._open[node]
            txn.frames += 1
        return _result(txn, "abort", t, abort_code=code, abort_by=by)

    # -- server (response) side ---------------------------------------------------------------
    def _server(self, node: int, d: bytes, t: int) -> list[dict]:
        txn = self._open.get(node)
        if len(d) < 1:
            return [self._error(node, d, t, "empty SDO response frame")]
        cs = d[0] >> 5
        if cs == 4:  # abort by the server
            return [self._abort(node, d, t, txn, "server")]
        if txn is None:
            return [self._error(node, d, t, f"SDO response (scs {cs}) without a request")]
        txn.frames += 1
        if txn.transfer == "block":
            return []  # not reassembled; closed by abort or the next request
        if cs in (2, 3) and len(d) >= 4 and (d[1] | d[2] << 8, d[3]) != (txn.index, txn.sub):
            del self._open[node]
            return [
                _result(txn, "error", t, error=f"response names {d[2]:02X}{d[1]:02X}h:{d[3]:02X}")
            ]
        if cs == 3 and txn.access == "download":  # initiate download response
            if txn.transfer == "expedited":
                del self._open[node]
                return [_result(txn, "ok", t)]
            return []
        if cs == 1 and txn.access == "download":  # download segment response
            if txn.last_segment:
                del self._open[node]
                return [_result(txn, "ok", t)]
            return []
        if cs == 2 and txn.access == "upload":  # initiate upload response
            e, s, n = d[0] >> 1 & 1, d[0] & 1, d[0] >> 2 & 3
            if e:
                txn.transfer = "expedited"
                txn.data += d[4 : 8 - n] if s else d[4:8]
                del self._open[node]
                return [_result(txn, "ok", t)]
            txn.transfer = "segmented"
            if s and len(d) >= 8:
                txn.size = int.from_bytes(d[4:8], "little")
            return []
        if cs == 0 and txn.access == "upload":  # upload segment response
            n = d[0] >> 1 & 7
            txn.data += d[1 : 8 - n]
            if d[0] & 1:
                del self._open[node]
                return [_result(txn, "ok", t)]
            return []
        del self._open[node]
        return [_result(txn, "error", t, error=f"unexpected SDO server command specifier {cs}")]

    @staticmethod
    def _error(node: int, d: bytes, t: int, why: str) -> dict:
        return {
            "node": node,
            "status": "error",
            "error": why,
            "data": d.hex(),
            "latency_ns": None,
            "t_request": t,
        }
