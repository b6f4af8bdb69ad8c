"""One virtual drive with all its faces on transports: what `hil drive` and the virtual bench run.

    stack = VirtualDriveStack(DriveSpec(name="drive1", can="virtual:bench-can",
                                        rs485="pty:/tmp/ttyA3", dio="virtual:bench-dio"))
    stack.start()      # model + real-time host + CANopen slave + Modbus slave + DI/DO face
    ...
    stack.stop()       # faces and transports closed, retained parameters saved

The faces only adapt protocols; the drive decides (docs/architecture.md).
"""

from __future__ import annotations

import contextlib
import json
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hil import clock
from hil.faces.canopen_slave import CanopenSlave
from hil.faces.dio_face import DioFace
from hil.faces.modbus_slave import ModbusFaceOptions, ModbusSlave, ModbusSlaveRunner
from hil.faces.pulse_face import PulseFace
from hil.model.drive import Drive
from hil.model.events import AlarmChanged, ParamChanged, PowerCycled
from hil.model.mechanics import Mechanics
from hil.model.options import ModelOptions
from hil.profile.params import ParamTable, canonical
from hil.protocol import modbus as mb
from hil.record.topics import CAN_LATE_NS, can_line
from hil.transport.can_bus import open_can
from hil.transport.dio import open_dio
from hil.transport.inline import can_inline, inline_pump
from hil.transport.pulse import open_pulse
from hil.transport.serial_line import open_serial
from hil.transport.sim import pump
from hil.transport.urls import parse_url
from hil.virtual.host import ClockHost, DriveHost

log = logging.getLogger(__name__)

RETRY_NS = 5_000_000  # after a failing tick (ModbusSlaveRunner.poll_s)


class ClockModbusPump:
    """`ModbusSlaveRunner` on a virtual clock: each chunk the line delivers is fed to the
    slave inside its delivery event, and the slave's next deadline (t3.5, P3.004) is a clock
    event, so the face answers exactly when a real line lets it."""

    def __init__(self, slave: ModbusSlave, line: Any, clk: clock.VirtualClock) -> None:
        self.slave, self.line, self._clock = slave, line, clk
        self.error: BaseException | None = None
        self._event: Any = None
        if slave.send is None:
            slave.send = line.write

    def clock(self) -> int:
        return self._clock.monotonic_ns()

    def start(self) -> ClockModbusPump:
        self.line.on_rx = self._rx
        self._arm()
        return self

    def stop(self) -> None:
        self.line.on_rx = None
        if self._event is not None:
            self._event.cancel()
            self._event = None

    def rearm(self, _now: int = 0) -> None:
        """Follow the slave's next deadline (host tick: P3.004 may change by SDO)."""
        self._arm()

    def _rx(self) -> None:
        try:
            while True:  # everything the line has handed over by now
                frame = self.line.read_timed(511, 0)
                if frame is None or not frame.data:
                    break
                self.slave.feed_timed(frame.data, tuple(frame.times_ns))
        except Exception as exc:  # last resort: log once, keep serving the line
            self.error = exc
            self.slave.last_resort("runner", exc)
        self._arm()

    def _arm(self) -> None:
        deadline = self.slave.next_deadline()
        if self._event is not None:
            if deadline is not None and self._event.t == deadline:
                return
            self._event.cancel()
            self._event = None
        if deadline is not None and self.line.on_rx is not None:
            self._event = self._clock.at(deadline, self._deadline)

    def _deadline(self) -> None:
        self._event = None
        try:
            self.slave.tick(self._clock.monotonic_ns())
        except Exception as exc:  # as the real runner: retry after a pause, never spin
            self.error = exc
            self.slave.last_resort("runner", exc)
            if self.line.on_rx is not None:
                self._event = self._clock.after(RETRY_NS, self._deadline)
            return
        self._arm()


@dataclass
class DriveSpec:
    """What to build: the drive, its identity and the transports of its faces."""

    name: str = "drive1"
    can: str | None = None  # e.g. "virtual:can0", "zenoh:lab/bench1/can?connect=..."
    rs485: str | None = None  # e.g. "pty:/tmp/ttyA3?baud=115200"
    dio: str | None = None  # e.g. "virtual:dio0", "zenoh:lab/bench1/dio?listen=..."
    pulse: str | None = None  # pulse line, e.g. "virtual:p0", "zenoh:lab/b1/pulse?listen=..."
    pulse_wiring: dict[str, str] | None = None  # PulseFace wiring (None: its defaults)
    node_id: int | None = None  # P3.000 for CANopen (default: the parameter)
    station: int | None = None  # P3.000 for Modbus (default: the parameter)
    params: dict[str, int] = field(default_factory=dict)
    options: ModelOptions = field(default_factory=ModelOptions)
    mechanics: Mechanics = field(default_factory=Mechanics)
    inputs: dict[int, bool] = field(default_factory=dict)  # DI levels at power-up
    state_path: Path | None = None  # retained parameters / battery-backed data
    modbus_mode: str | None = None  # "rtu" / "ascii": sets P3.002 with the URL (`line_params`)
    modbus_baud: int | None = None  # the face's fixed baud (tests); default P3.001 X
    tpdo_defaults: str = "manual"  # CANopen PDO defaults: none, as printed (L17940-18124)


def line_params(params: dict[str, int], url: str, mode: str | None,
                state_path: Path | str | None = None) -> dict[str, int]:
    """`params` with the drive's RS-485 settings, P3.001 digit X (baud) and P3.002 (protocol),
    set to the line the bench declares (`url`'s baud and character format, `mode` RTU or
    ASCII, default RTU) where `params` does not set them: a bench's drive is configured for its
    line (L10509-L10557). A line the A3 cannot run (a baud P3.001 X does not offer, 7 data bits
    in RTU) leaves them at their defaults, and the drive then reads garbage, as a real one would
    (`ModbusSlave` `wire`). A value the drive retained (`state_path`'s params.json) is its own
    setting, and stays."""
    out = dict(params)
    given = set()
    for name in params:  # any spelling the drive takes ("P3-2", "p3.002")
        with contextlib.suppress(Exception):
            given.add(canonical(name))
    if state_path is not None:
        with contextlib.suppress(Exception):
            data = json.loads((Path(state_path) / "params.json").read_text())["parameters"]
            given |= {canonical(n) for n in data}
    try:
        st = parse_url(url, "serial").serial()
    except Exception:  # a bad URL is opening the line's to report
        return out
    want = mode or "rtu"
    x, p3002 = mb.uart_for_line(st.baud, mb.CharFormat(st.bytesize, st.parity,
                                                       int(st.stopbits)), want)
    if "P3.001" not in given:
        if x is None:
            log.warning("RS-485 line %s: the A3 offers %s baud (P3.001 X, L10524-L10527); its "
                        "drive cannot read this line", url,
                        "/".join(map(str, mb.P3001_BAUD.values())))
        else:
            out["P3.001"] = (ParamTable.load().spec("P3.001").default & ~0xF) | x
    if "P3.002" not in given:
        if p3002 is None:
            log.warning("RS-485 line %s: no P3.002 protocol is %s %d%s (L10553-L10557); its "
                        "drive cannot read this line", url, want.upper(), st.bytesize,
                        st.parity)
        else:
            out["P3.002"] = p3002
    return out


class VirtualDriveStack:
    """A running virtual drive: `Drive` + `DriveHost` + faces."""

    def __init__(self, spec: DriveSpec, *, drive_factory: Any = None) -> None:
        self.spec = spec
        params = dict(spec.params)
        ident = spec.node_id or spec.station
        if ident is not None:
            params.setdefault("P3.000", ident)
        if spec.rs485:
            params = line_params(params, spec.rs485, spec.modbus_mode, spec.state_path)
        self.drive = (drive_factory or Drive)(
            name=spec.name,
            options=spec.options,
            mechanics=spec.mechanics,
            state_path=spec.state_path,
            inputs=spec.inputs,
            params=params,
        )
        clk = clock.current()
        self.clock = clk if isinstance(clk, clock.VirtualClock) else None
        self.host = DriveHost(self.drive) if self.clock is None else ClockHost(self.drive, clk)
        self.can_bus: Any = None
        self.canopen: Any = None
        self.serial: Any = None
        self.modbus: Any = None
        self.modbus_runner: Any = None
        self.dio_port: Any = None
        self.dio_face: DioFace | None = None
        self.pulse_port: Any = None
        self.pulse_face: PulseFace | None = None
        self._closers: list[Any] = []
        self._unsub: Any = None
        # (line, level, sent_ns, model_t) per input edge the DI/DO face applied (GroundTruth)
        self.on_input: Any = None

    # -- lifecycle ---------------------------------------------------------------------------
    def start(self) -> VirtualDriveStack:
        """Open every configured face; on any failure, close what was opened and re-raise."""
        try:
            self._start()
        except BaseException:
            self.stop()
            raise
        return self

    def _start(self) -> None:
        spec, drive, host = self.spec, self.drive, self.host
        if spec.dio:

            self.dio_port = open_dio(spec.dio, role="drive", name=f"{spec.name}-dio")
            self._closers.append(self.dio_port.close)
            self.dio_face = DioFace(self.dio_port, host, self._input_applied)
            self._closers.append(self.dio_face.close)
        if spec.pulse:
            self.pulse_port = open_pulse(spec.pulse, role="drive", name=f"{spec.name}-pulse")
            self._closers.append(self.pulse_port.close)
            self.pulse_face = PulseFace(self.pulse_port, host, spec.pulse_wiring)
            self._closers.append(self.pulse_face.close)
        if spec.can:

            self.can_bus = open_can(spec.can, name=f"{spec.name}-can")
            self._closers.append(self.can_bus.shutdown)
            self.canopen = CanopenSlave(
                self.can_bus,
                drive,
                node_id=spec.node_id,
                lock=host.synced,  # frames act at their arrival time, not the last tick
                own_timer=False,
                clock=host.model_now,
                pdo_defaults=spec.tpdo_defaults,
                on_frame=self._frame_applied,
            )
            self._closers.append(self.canopen.close)  # after its frames stop (closers: LIFO)
            # frames handed over inside the clock's delivery events (virtual clock), or in the
            # thread that delivers them (inline.py); else the face's own receive thread
            feed = (pump if self.clock is not None
                    else inline_pump if can_inline(self.can_bus) else None)
            if feed is None:
                self.canopen.start()
            else:
                self.canopen.start(thread=False)
                self._closers.append(feed(self.can_bus, self.canopen.feed))
            host.add_tick(self.canopen.tick)
        if spec.rs485:

            self.serial = open_serial(spec.rs485, name=f"{spec.name}-rs485")
            self._closers.append(self.serial.close)
            st = getattr(self.serial, "settings", None)  # the line's own format (its URL)
            self.modbus = ModbusSlave(
                drive.params,
                station=spec.station,
                baud=spec.modbus_baud,  # else P3.001 X, set to the line's (`line_params`)
                wire=None if st is None else (st.baud, mb.CharFormat(
                    st.bytesize, st.parity, int(st.stopbits))),
                lock=host.synced,
                on_timeout=lambda _t: host.call(drive.raise_alarm, "AL020"),  # P3.004, L10571
                # AL019 on an incorrect address / value (L19592-19596); the drive decides
                on_comm_error=lambda code, _m: host.call(drive.modbus_comm_error, code),
                # the face's choices (docs/manual-choices.md#modbus): options.extra.modbus
                options=ModbusFaceOptions.from_dict(spec.options.extra.get("modbus")),
            )
            if self.clock is None:
                self.modbus_runner = ModbusSlaveRunner(self.modbus, self.serial)
            else:
                self.modbus_runner = ClockModbusPump(self.modbus, self.serial, self.clock)
                host.add_tick(self.modbus_runner.rearm)  # P3.004 written by any face
            self.modbus_runner.start()
            self._closers.append(self.modbus_runner.stop)
        self._unsub = drive.subscribe(self._on_event)
        host.start()
        self._closers.append(host.stop)

    def refusals(self) -> dict[str, tuple[int, str]]:
        """What the pulse and DI/DO faces refused so far, without an answer on the wire (a
        CANopen or Modbus face answers with an abort or an exception): {what: (how many in
        all, the last reason)}. `hil drive` prints them as they come."""
        out: dict[str, tuple[int, str]] = {}
        for what, obj in ((f"malformed message(s) on the pulse line {self.spec.pulse}",
                           self.pulse_port),
                          ("pulse segment(s) the drive refused", self.pulse_face),
                          ("DI/DO level(s) the drive refused", self.dio_face)):
            n = getattr(obj, "refused", 0)
            if n:
                errors = getattr(obj, "errors", None) or [""]
                out[what] = (n, errors[-1])
        return out

    def stop(self) -> None:
        """Close faces and transports (newest first) and save retained state."""
        while self._closers:
            closer = self._closers.pop()
            with contextlib.suppress(Exception):
                closer()
        if self._unsub:
            self._unsub()
            self._unsub = None
        with self.host.lock:
            self.drive.close()

    def __enter__(self) -> VirtualDriveStack:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -- helpers -----------------------------------------------------------------------------
    def _input_applied(self, line: str, level: bool, sent_ns: int, model_t: int) -> None:
        if self.on_input is not None:
            self.on_input(line, level, sent_ns, model_t)

    def _frame_applied(self, msg: Any, sent_ns: int, model_t: int) -> None:
        """A CAN frame the CANopen face acted on: reported like an input edge (line
        `CAN 080h`) when it reached the model CAN_LATE_NS or more after its sender stamp."""
        if self.on_input is not None and self.host.wall_ns(model_t) - sent_ns >= CAN_LATE_NS:
            self.on_input(can_line(msg.arbitration_id), True, sent_ns, model_t)

    def _on_event(self, event: object) -> None:
        if isinstance(event, PowerCycled) and self.modbus is not None:
            self.modbus.power_cycle()
        if (isinstance(event, ParamChanged) and event.name in ("P3.001", "P3.002")
                and self.modbus is not None):
            self.modbus.params_written()  # an SDO's too: the next frame (L16035, L16037)
        if isinstance(event, ParamChanged) and event.name == "P3.000" and self.modbus is not None:
            self.modbus.station_written()  # at the next power cycle (●, L7014)
        if (isinstance(event, AlarmChanged) and event.code == "AL020" and not event.active
                and self.modbus is not None and self.drive.options.al020_rearm == "reset"):
            # P3.004 counts again from the reset, on the face's own (line) clock
            runner = self.modbus_runner
            self.modbus.rearm_timeout(runner.clock() if runner is not None else event.t)

    def describe(self) -> str:
        """One line naming the faces, for `hil drive`'s ready line."""
        parts = [f"drive {self.spec.name}"]
        if self.canopen is not None:
            parts.append(f"CANopen node {self.canopen.node_id} on {self.spec.can}")
        if self.modbus is not None:
            parts.append(
                f"Modbus station {self.modbus.station} ({self.modbus.line.mode}) on "
                f"{self.spec.rs485}"
            )
        if self.dio_port is not None:
            parts.append(f"DI/DO on {self.spec.dio}")
        if self.pulse_port is not None:
            parts.append(f"pulse line on {self.spec.pulse}")
        return ", ".join(parts)
