"""The drive's pulse face: CN1's pulse input and OA/OB/OZ output, and the machine's
sensors wired to the PLC, on a pulse line (role "drive", docs/pulse.md).

* `seg` from the line -> `drive.pulse.segment(...)` (the model counts and follows);
* the model's OA/OB windows and OZ pulses -> `oab` / `oz` on the line;
* the machine's DOG cam and NL/PL switches -> the PLC inputs `X<n>` named in `wiring`;
* the PLC's CLR output `Y<n>` -> the drive DI terminal named in `wiring` (CCLR).

A malformed segment is refused by the port (`PulsePort.errors`); one the model refuses is
kept in `errors`. Neither stops the face.
"""

from __future__ import annotations

from typing import Any

from hil.faces import ERRORS_KEPT
from hil.profile.dio import DEFAULT_PULSE_WIRING


class PulseFace:
    """Connects a `PulsePort(role="drive")` to a `Drive` owned by a `DriveHost`."""

    def __init__(self, port: Any, host: Any, wiring: dict[str, str] | None = None) -> None:
        self.port = port
        self.host = host
        self.wiring = dict(DEFAULT_PULSE_WIRING if wiring is None else wiring)
        self.errors: list[str] = []  # the last ERRORS_KEPT reasons of the segments refused
        self.refused = 0  # how many in all (`hil drive` reports them as they come)
        self._oab_total = 0
        with host.lock:
            pt = host.drive.pulse
            pt.listeners.append(self._on_model)
            for name, level in pt.machine_lines().items():
                self._set_x(name, level)
        self._unsub = port.subscribe(self._on_line)

    # -- model -> line -------------------------------------------------------------------
    def _set_x(self, name: str, level: bool, t: int | None = None) -> None:
        line = self.wiring.get(name)
        if line:
            self.port.set(line, level, source_t=t)

    def _on_model(self, kind: str, data: dict[str, Any]) -> None:
        if kind == "X":
            self._set_x(data["name"], data["level"])
        elif kind == "OAB":
            body = {k: data[k] for k in ("freq", "direction", "count")}
            body["total"] = self._oab_total
            self._oab_total += data["direction"] * data["count"]
            self.port.send("oab", body, source_t=self.host.wall_ns(data["t"]))
        elif kind == "OZ":
            self.port.send("oz", {"width_ns": data["width_ns"]},
                           source_t=self.host.wall_ns(data["t"]))

    # -- line -> model -------------------------------------------------------------------
    def _on_line(self, kind: str, data: dict[str, Any], t: int, source_t: int | None) -> None:
        if kind == "seg":
            self.host.call(self._segment, data)
        elif kind == "level":
            di = self.wiring.get(data["line"], "")
            if di.startswith("DI") and di[2:].isdigit():
                self.host.call(self.host.drive.set_di, int(di[2:]), data["level"])

    def _segment(self, data: dict[str, Any]) -> None:
        try:
            self.host.drive.pulse.segment(
                data["freq"], data["direction"], data["count"], form=data["form"],
                logic=data["logic"], total=data.get("total"))
        except ValueError as e:
            self.refused += 1
            self.errors.append(str(e))
            del self.errors[:-ERRORS_KEPT]

    def close(self) -> None:
        self._unsub()
        with self.host.lock:
            listeners = self.host.drive.pulse.listeners
            if self._on_model in listeners:
                listeners.remove(self._on_model)
