"""A model drive behind its CANopen and Modbus faces, faults injected on the injected clock.

Like `ModelTap` (which it wraps), but the harness side is the real fault layer
(`FaultyCanBus`, `FaultySerial`) with its /faults records stamped in model time, and the
frames reach the faces at model time: a frame the harness sends is queued and handed to
the slave at the next delivery (a burst arrives together, as on a bus). Frame sender stamps
(`msg.timestamp`, what the faces read for AL111/AL112/AL301/AL3E2) are model time mapped to
a wall epoch in the past (`WALL0`): intervals between frames are model intervals, and every
frame counts as sent before the face's (wall-clock) "answered / processed" stamps, so in
this rig AL111/AL112 turn on the 1 ms window alone (the scenarios space ordinary requests
>= 1 ms apart). Everything is deterministic: no wall-clock sleeps.
"""

from __future__ import annotations

import time
from collections import deque
from pathlib import Path
from typing import Any

import can

from hil.faces.canopen_slave import CanopenSlave
from hil.faces.modbus_slave import ModbusSlave
from hil.model.drive import Drive
from hil.model.mechanics import Mechanics
from hil.model.options import ModelOptions
from hil.paths import fixture
from hil.protocol import modbus as mb
from hil.record.recorder import Recorder
from hil.timing.checker import check
from hil.timing.source import RecordingSource
from hil.timing.spec import load_spec
from hil.transport.faults import CanMatch, FaultyCanBus, FaultyDio, FaultySerial
from hil.units import MS
from hil.virtual.model_tap import EPOCH_NS, ModelTap

NODE = 1
MASTER = 0x7F
BUS = "can0"
PORT = "rs485"
WALL0 = time.time() - 1e5  # s: the wall time of model t = 0 for frame sender stamps
FRAME_NS = 111_000  # one 8-byte standard frame at 1 Mbit/s occupies the bus ~111 bit times


class _Wire(can.BusABC):
    """One side of the rig's CAN wire: `send` hands the frame to `on_send`; nothing is
    ever received (the rig delivers frames itself, at model time)."""

    def __init__(self, on_send: Any) -> None:
        self._on_send = on_send
        super().__init__(channel="rig")

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self._on_send(msg)

    def _recv_internal(self, timeout: float | None) -> tuple[None, bool]:
        time.sleep(min(timeout if timeout is not None else 0.05, 0.05))
        return None, False


class _Line:
    """The harness's RS-485 line: a request reaches the Modbus face at model time."""

    def __init__(self, rig: FaultRig) -> None:
        self.rig = rig

    def write(self, data: bytes, **_kw: Any) -> None:
        self.rig.rec.serial(PORT, bytes(data), "tx", self.rig.t())
        self.rig.modbus.feed(bytes(data), self.rig.drive.now)


class _Dio:
    """The harness's DI lines: a level reaches the drive's terminal at model time."""

    def __init__(self, rig: FaultRig) -> None:
        self.rig = rig

    def set(self, line: str, level: bool) -> None:
        self.rig.tap.set_di(int(line.removeprefix("DI")), level)

    def get(self, line: str) -> bool:
        return self.rig.drive.dio.input_level(int(line.removeprefix("DI")))


class _ModelSink:
    """`Recorder.fault` with the model time as the record time."""

    def __init__(self, rig: FaultRig) -> None:
        self.rig = rig

    def fault(self, *args: Any, t: int | None = None, **detail: Any) -> None:
        self.rig.rec.fault(*args, t=self.rig.model_t_of(t), **detail)


class FaultRig:
    def __init__(self, path: Path, options: ModelOptions | None = None,
                 mechanics: Mechanics | None = None, **params: int) -> None:
        self.path = path
        self.drive = Drive(options=options, mechanics=mechanics, inputs={8: True},
                           params={"P2.041": 0x0108} | params)
        self.rec = Recorder(path)
        self.tap = ModelTap(self.drive, self.rec, bus=BUS)
        self._queue: list[can.Message] = []
        # (wall ns, model record time) of the last frames sent
        self._sent: deque[tuple[int, int]] = deque(maxlen=64)
        sink = _ModelSink(self)
        self.bus = FaultyCanBus(_Wire(self._harness_sent), BUS, sink=sink, seed=1)
        self.slave = CanopenSlave(_Wire(self._drive_sent), self.drive, node_id=NODE,
                                  own_timer=False, clock=lambda: self.drive.now)
        self.slave.start()
        self.modbus = ModbusSlave(self.drive.params, station=1,
                                  send=lambda adu: self.rec.serial(PORT, adu, "rx", self.t()),
                                  on_timeout=lambda _t: self.drive.raise_alarm("AL020"),
                                  on_comm_error=lambda c, _m: self.drive.modbus_comm_error(c))
        self.serial = FaultySerial(_Line(self), "rs485", sink=sink, seed=1,
                                   sleep=lambda s: self.run(s * 1e3))  # gaps in model time
        self.dio = FaultyDio(_Dio(self), "drive1", sink=sink, seed=1)  # stuck (no sleeps)
        self.producers: dict[str, tuple[int, int, Any]] = {}  # name -> (period, next, send)

    # -- time --------------------------------------------------------------------------
    def t(self) -> int:
        return EPOCH_NS + self.drive.now

    def model_t_of(self, wall_ns: int | None) -> int:
        """The record time of a fault stamped `wall_ns` after the fact (a burst's start,
        taken before its first frame): the model time that frame went out; else now."""
        if wall_ns is not None:
            for wall, model in self._sent:
                if wall >= wall_ns:
                    return model
        return self.t()

    def run(self, ms: float) -> None:
        """Let `ms` pass: cyclic producers, frame delivery, drive and face timers per 1 ms."""
        end = self.drive.now + round(ms * MS)
        while self.drive.now < end:
            for name, (period, nxt, send) in list(self.producers.items()):
                if self.drive.now >= nxt:
                    send()
                    self.producers[name] = (period, nxt + period, send)
            self.deliver()
            self.tap.advance(min(MS, end - self.drive.now))
            self.slave.tick(self.drive.now)
            self.modbus.tick(self.drive.now)

    def close(self) -> Path:
        self.run(50)
        self.tap.close()
        self.slave.close()
        self.slave.bus.shutdown()
        self.bus.shutdown()
        self.rec.close()
        return self.path

    # -- CAN -----------------------------------------------------------------------------
    def _harness_sent(self, msg: can.Message) -> None:
        self._sent.append((time.time_ns(), self.t()))
        self.drive.advance(FRAME_NS)  # a burst takes bus time: its start and end differ
        msg.timestamp = WALL0 + self.drive.now / 1e9
        self.rec.can(BUS, msg, "tx", self.t())
        self._queue.append(msg)

    def _drive_sent(self, msg: can.Message) -> None:
        self.rec.can(BUS, msg, "rx", self.t())

    def deliver(self) -> None:
        queue, self._queue = self._queue, []
        for msg in queue:
            with self.slave.lock:
                self.slave.handle_frame(msg)

    def send(self, cid: int, data: bytes = b"", *, remote: bool = False) -> None:
        self.bus.send(can.Message(arbitration_id=cid, data=data, is_extended_id=False,
                                  is_remote_frame=remote))
        self.deliver()

    def sdo_write(self, index: int, sub: int, value: int, size: int = 4) -> None:
        cs = 0x23 | (4 - size) << 2
        self.send(0x600 + NODE, bytes([cs]) + index.to_bytes(2, "little") + bytes([sub])
                  + value.to_bytes(size, "little").ljust(4, b"\0"))
        self.run(1)

    def nmt(self, cs: int) -> None:
        self.send(0x000, bytes([cs, NODE]))
        self.run(1)

    def produce(self, name: str, period_ms: float, cid: int, data: bytes = b"",
                remote: bool = False) -> None:
        def send() -> None:
            self.send(cid, data, remote=remote)
        self.producers[name] = (round(period_ms * MS), self.drive.now, send)

    def drop(self, function: str) -> Any:
        """Drop the harness's `function` frames (heartbeat, sync, ...) until `stop(f)`."""
        return self.bus.inject("drop", match=CanMatch(functions=(function,)))

    def stop(self, fault: Any) -> None:
        self.bus.faults.stop(fault)

    # -- RS-485 --------------------------------------------------------------------------
    def modbus_read(self, address: int = 0x0308) -> None:
        self.serial.write(mb.rtu_encode(1, mb.read_request(address, 1)))
        self.run(5)

    def modbus_write(self, address: int, value: int) -> None:
        self.serial.write(mb.rtu_encode(1, mb.write_single_request(address, value)))
        self.run(5)

    # -- DI/DO -------------------------------------------------------------------------------
    def bounce(self, n: int, level: bool, *, bounces: int = 3, period_ms: float = 1.0) -> None:
        """DI `n` set to `level` through a contact that bounces, as `FaultyDio` does it
        (level, period, not level, period, ... then level), with the /faults record, in
        model time."""
        sink = _ModelSink(self)
        sink.fault("bounce", "dio:drive1", True, 900 + n, line=f"DI{n}", bounces=bounces,
                   period_ms=period_ms)
        for _ in range(bounces):
            self.tap.set_di(n, level)
            self.run(period_ms)
            self.tap.set_di(n, not level)
            self.run(period_ms)
        self.tap.set_di(n, level)
        sink.fault("bounce", "dio:drive1", False, 900 + n, line=f"DI{n}", bounces=bounces,
                   period_ms=period_ms)

    @property
    def alarms(self) -> tuple[str, ...]:
        return self.drive.alarms.active


def verdicts(path: Path, spec_id: str, constants: dict[str, float] | None = None) -> list:
    spec = load_spec(fixture("timing", f"{spec_id}.yaml"))
    return check(spec, RecordingSource(path), binding={"drive": "drive1", "bus": BUS},
                 constants=constants)
