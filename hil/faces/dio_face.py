"""The drive's DI/DO face: its digital lines on a DI/DO transport (role "drive").

Inputs seen on the port (`DI<n>`, `STO_A`, `STO_B`, electrical levels) go to the model;
the model's DO and FDBK changes are published on the port. a/b-contact logic stays inside
the drive, as on hardware (docs/transports.md, DI/DO over zenoh).

Each input edge the harness stamped is reported to `on_input(line, level, sent_ns,
model_t)`: the harness's stamp (wall ns) and the model time the drive applied it, so the
delivery delay of a loaded machine is on the record (docs/timing.md, "Under load").
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from hil.faces import ERRORS_KEPT
from hil.model.events import DoChanged, FdbkChanged

InputHook = Callable[[str, bool, int, int], None]

N_DO = 6


class DioFace:
    """Connects a `DioPort(role="drive")` to a `Drive` owned by a `DriveHost`."""

    def __init__(self, port: Any, host: Any, on_input: InputHook | None = None) -> None:
        self.port = port
        self.host = host
        self.on_input = on_input
        self.errors: list[str] = []  # the last ERRORS_KEPT reasons of the levels refused
        self.refused = 0  # how many in all (`hil drive` reports them as they come)
        with host.lock:
            drive = host.drive
            for n in range(1, N_DO + 1):
                port.set(f"DO{n}", drive.do(n))
            port.set("FDBK", drive.fdbk())
            self._unsub_drive = drive.subscribe(self._on_event)
            for line, level in port.levels().items():
                if not port.owns(line):
                    self._apply(line, level)
        self._unsub_port = port.subscribe(self._on_line, source=True)

    def _on_event(self, event: Any) -> None:
        t = self.host.wall_ns(event.t)  # the model's own time of the change
        if isinstance(event, DoChanged):
            self.port.set(f"DO{event.n}", event.level, source_t=t)
        elif isinstance(event, FdbkChanged):
            self.port.set("FDBK", event.closed, source_t=t)

    def _on_line(self, line: str, level: bool, t: int, source_t: int | None = None) -> None:
        self.host.call(self._apply, line, level, source_t)

    def _apply(self, line: str, level: bool, sent_ns: int | None = None) -> None:
        drive = self.host.drive
        try:
            if line in ("STO_A", "STO_B"):
                drive.set_sto(line[-1], level)
            elif line.startswith("DI"):
                drive.set_di(int(line[2:]), level)
            else:
                return
        except (ValueError, KeyError) as exc:  # e.g. DI11 on the wire: not a terminal
            self.refused += 1
            self.errors.append(f"{line}: {exc}")
            del self.errors[:-ERRORS_KEPT]
            return
        if sent_ns is not None and self.on_input is not None:
            self.on_input(line, level, sent_ns, drive.now)

    def close(self) -> None:
        self._unsub_port()
        with self.host.lock:
            self._unsub_drive()
