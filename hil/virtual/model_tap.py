"""Record a model drive on its own injected clock (no buses, no wall clock).

Used to judge the timing specs against the model deterministically: what the harness would
see on a virtual bench's lines (DI/DO/STO levels, CiA 402 control and status words) plus the
model's ground truth, all stamped with model time (+ a fixed epoch), so `hil check` reads the
file like any other recording.

    tap = ModelTap(drive, recorder)
    tap.set_di(1, True)           # records DI1 and drives the model
    tap.advance(200 * MS)         # advances in 1 ms steps, recording state changes
"""

from __future__ import annotations

from typing import Any

from hil.model.events import (
    AlarmChanged,
    AlarmReset,
    DoChanged,
    FdbkChanged,
    ParamChanged,
    StateChanged,
)
from hil.record import topics
from hil.units import MS

EPOCH_NS = 1_700_000_000_000_000_000  # a fixed, plausible wall time for model t = 0
# 0.2 ms, like an expedited SDO on a virtual bus (docs/dev/feasibility.md §3)
SDO_ROUND_TRIP_NS = 200_000


class ModelTap:
    """Drives a `Drive` and records everything a virtual bench would record."""

    def __init__(
        self,
        drive: Any,
        recorder: Any,
        *,
        drive_name: str | None = None,
        dio: str | None = None,
        bus: str = "can0",
        step_ns: int = MS,
    ) -> None:
        self.drive = drive
        self.rec = recorder
        self.name = drive_name or drive.name
        self.dio_name = dio or self.name
        self.bus = bus
        self.step_ns = step_ns
        self._last_state: dict[str, Any] | None = None
        self._di: dict[int, bool] = {}  # last recorded DI terminal levels
        for topic in (topics.drive_state(self.name), topics.drive_events(self.name)):
            recorder.declare_source(topic, "model")
        # exact model timestamps (1 µs: the checker treats 0 as "not declared")
        recorder.declare_source(topics.canopen(bus), "model", resolution_ns=1000)
        t = self._t()
        values = {spec.param: drive.params.get(spec.param) for spec in drive.params.table}
        recorder.drive_params(self.name, values, snapshot=True, t=t, source_t=t)
        for n in range(1, 11):
            self._di_line(n, drive.dio.input_level(n))
        for n in range(1, 7):
            self._line(f"DO{n}", drive.do(n))
        self._line("STO_A", drive.sto.a)
        self._line("STO_B", drive.sto.b)
        self._line("FDBK", drive.fdbk())
        self._state()
        self._unsub = drive.subscribe(self._on_event)

    # -- stimuli -----------------------------------------------------------------------------
    def set_di(self, n: int, closed: bool) -> None:
        self._di_line(n, closed)
        self.drive.set_di(n, closed)
        self._state()

    def set_sto(self, channel: str, on: bool) -> None:
        self._line(f"STO_{channel[-1].upper()}", on)
        self.drive.set_sto(channel, on)
        self._state()

    def write_object(self, index: int, sub: int, value: int) -> None:
        """An SDO download as the bus would carry it (recorded as decoded CANopen)."""
        t = self._t()
        msg = {"kind": "sdo_rx", "index": index, "sub": sub, "value": value}
        if (index, sub) == (0x6040, 0):
            msg["controlword"] = value
        self.rec.write(topics.canopen(self.bus), msg, log_time=t, publish_time=t)
        self.drive.write_object(index, sub, value)
        self.drive.advance(SDO_ROUND_TRIP_NS)  # the master reads 6041h back after a round trip
        self._statusword()

    def advance(self, dt: int) -> None:
        """Let `dt` ns pass in `step_ns` steps, recording every change of the state."""
        end = self.drive.now + dt
        while self.drive.now < end:
            self.drive.advance_to(min(end, self.drive.now + self.step_ns))
            self._state()

    def close(self) -> None:
        self._unsub()

    # -- recording ---------------------------------------------------------------------------
    def _t(self) -> int:
        return EPOCH_NS + self.drive.now

    def _line(self, line: str, level: bool) -> None:
        t = self._t()
        self.rec.dio(self.dio_name, line, bool(level), t, t)

    def _di_line(self, n: int, level: bool) -> None:
        if self._di.get(n) != bool(level):
            self._di[n] = bool(level)
            self._line(f"DI{n}", level)

    def _statusword(self) -> None:
        t = self._t()
        sw = self.drive.read_object(0x6041, 0)
        msg = {"kind": "sdo_tx", "index": 0x6041, "sub": 0, "value": sw, "statusword": sw}
        self.rec.write(topics.canopen(self.bus), msg, log_time=t, publish_time=t)

    def _state(self) -> None:
        snap = self.drive.snapshot()
        snap.pop("t", None)
        if snap != self._last_state:
            self._last_state = snap
            # DI levels the model drives itself (bench sensors ORGP/NL/PL follow the axis)
            for n, level in enumerate(snap.get("di", ()), start=1):
                self._di_line(n, level)
            t = self._t()
            self.rec.drive_state(self.name, snap, t=t, source_t=t)

    def _on_event(self, event: Any) -> None:
        t = EPOCH_NS + event.t
        if isinstance(event, DoChanged):
            self.rec.dio(self.dio_name, f"DO{event.n}", event.level, t, t)
            self._state()
        elif isinstance(event, FdbkChanged):
            self.rec.dio(self.dio_name, "FDBK", event.closed, t, t)
        elif isinstance(event, ParamChanged):
            self.rec.drive_params(self.name, {event.name: event.value}, t=t, source_t=t)
        elif isinstance(event, AlarmChanged | StateChanged):
            self.rec.drive_event(self.name, event, t=t, source_t=t)
            self._state()
        elif isinstance(event, AlarmReset):
            self.rec.drive_event(self.name, event, t=t, source_t=t)
