"""The virtual bench's drive side: model drive(s), host, faces, ground truth.

`VirtualWorld(bench, recorder)` resolves the bench's `auto` transport targets to unique names,
creates one `Drive` per bench drive (in process, `process: inproc`) behind a `DriveHost`, puts
the CANopen face on the CAN bus, the Modbus face on the RS-485 line (a pty pair with line
timing) and a DI/DO adapter on the DI/DO lines, and records ground truth (drive state every
`state_publish_ms`, model events, parameter changes). `harness_urls()` gives the harness-side
URLs to open. `process: subprocess` spawns `hil drive` instead (see `SubprocessWorld`).

Seams (thin adapters, replace when the owning room ships them):
- `drive_factory(options, mechanics)`: default `hil.model.drive.Drive`.
- `DioFace`: drive-side DI/DO adapter; replace by hil.faces' DI/DO face when it exists.
"""

from __future__ import annotations

import contextlib
import itertools
import os
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from hil.plan.bench import Bench, DriveSpec

_seq = itertools.count()
DriveFactory = Callable[[Any, Any], Any]


def default_drive_factory(options: Any, mechanics: Any) -> Any:
    from hil.model.drive import Drive  # the lead's module (docs/architecture.md)

    return Drive(options=options, mechanics=mechanics)


def _auto_name(kind: str) -> str:
    return f"hil-{os.getpid()}-{next(_seq)}-{kind}"


def resolve_auto(bench: Bench, tmpdir: Path) -> dict[str, str]:
    """URL of each transport with `auto` targets made unique: keys `can:<bus>`,
    `rs485:<line>`, `dio:<drive>`."""
    out: dict[str, str] = {}

    def fix(url: str, kind: str) -> str:
        scheme, _, rest = url.partition(":")
        target, q, query = rest.partition("?")
        if target != "auto":
            return url
        target = str(tmpdir / f"{kind}-{next(_seq)}") if scheme == "pty" else _auto_name(kind)
        return f"{scheme}:{target}{q}{query}"

    for b, url in bench.can.items():
        out[f"can:{b}"] = fix(url, "can")
    for ln, url in bench.rs485.items():
        out[f"rs485:{ln}"] = fix(url, "rs485")
    for dn, d in bench.drives.items():
        if d.dio:
            out[f"dio:{dn}"] = fix(d.dio, "dio")
    return out


def harness_side(url: str) -> str:
    """The URL the harness opens for a drive-side URL: a pty's far end as a serial port."""
    if url.startswith("pty:"):
        return "serial:" + url[4:]
    return url


def initial_params(spec: DriveSpec) -> dict[str, int]:
    """Wiring mapping parameters (P2.010-P2.022, P2.036-P2.041) then the bench's params."""
    out = {}
    for w in (*spec.di.values(), *spec.do.values()):
        p, value = w.mapping_param()
        out[p] = value
    out.update(spec.params)
    return out


class DioFace:
    """Drive-side DI/DO adapter: harness input levels -> Drive.set_di/set_sto, model DO and
    FDBK changes -> output lines. (Seam: hil.faces' DI/DO face replaces this.)"""

    def __init__(self, drive: Any, host: Any, port: Any) -> None:
        self.drive, self.host, self.port = drive, host, port
        self._unsub_port = port.subscribe(self._on_line)
        self._unsub_drive = drive.subscribe(self._on_event)
        with host.lock:
            for n in range(1, 7):
                port.set(f"DO{n}", bool(drive.do(n)))
            port.set("FDBK", bool(drive.fdbk()))

    def _on_line(self, line: str, level: bool, t: int) -> None:
        if line.startswith("DI"):
            self.host.call(self.drive.set_di, int(line[2:]), level)
        elif line in ("STO_A", "STO_B"):
            self.host.call(self.drive.set_sto, line[-1], level)

    def _on_event(self, ev: Any) -> None:
        name = type(ev).__name__
        if name == "DoChanged":
            self.port.set(f"DO{ev.n}", bool(ev.level))
        elif name == "FdbkChanged":
            self.port.set("FDBK", bool(ev.closed))

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self._unsub_port()
        with contextlib.suppress(Exception):
            self._unsub_drive()


class GroundTruth:
    """Records the model's own view: state every period, events, parameter changes."""

    def __init__(self, name: str, drive: Any, host: Any, recorder: Any,
                 period_ms: float = 10.0) -> None:
        self.name, self.drive, self.host, self.rec = name, drive, host, recorder
        self.period_ns = int(period_ms * 1_000_000)
        self._next = 0
        self._unsub = drive.subscribe(self._on_event)
        host.add_tick(self._tick)
        self.snapshot_params()

    def snapshot_params(self) -> None:
        params = self.drive.params
        values = {}
        table = getattr(params, "table", None)
        names = [s.name for s in getattr(table, "specs", [])] if table is not None else []
        if not names:
            names = list(getattr(params, "_stored", {}))
        for n in names:
            with contextlib.suppress(Exception):
                values[n] = params.get(n)
        t = self.drive.now
        self.rec.drive_params(self.name, values, snapshot=True, source_t=self.host.wall_ns(t))

    def _tick(self, now: int) -> None:
        if now >= self._next:
            self._next = now + self.period_ns
            self.rec.drive_state(self.name, self.drive.snapshot(), source_t=self.host.wall_ns(now))

    def _on_event(self, ev: Any) -> None:
        t = getattr(ev, "t", self.drive.now)
        wall = self.host.wall_ns(t)
        if type(ev).__name__ == "ParamChanged":
            self.rec.drive_params(self.name, {ev.name: ev.value}, source_t=wall)
        self.rec.drive_event(self.name, {"type": type(ev).__name__, **_fields(ev)},
                             source_t=wall)
        # a state sample at every event, so transitions are exact rather than 10 ms late
        with contextlib.suppress(Exception):
            self.rec.drive_state(self.name, self.drive.snapshot(), source_t=wall)

    def close(self) -> None:
        self.host.remove_tick(self._tick)
        with contextlib.suppress(Exception):
            self._unsub()


def _fields(ev: Any) -> dict:
    slots = getattr(ev, "__slots__", None) or getattr(ev, "__dataclass_fields__", {})
    return {k: getattr(ev, k) for k in slots}


class VirtualDrive:
    """One in-process virtual drive with its faces."""

    def __init__(self, spec: DriveSpec, urls: dict[str, str], recorder: Any,
                 factory: DriveFactory, bench: Bench) -> None:
        from hil.faces.host import DriveHost
        from hil.model.mechanics import Mechanics
        from hil.model.options import ModelOptions

        self.spec = spec
        self.closers: list[Callable[[], None]] = []
        options = ModelOptions.from_dict(dict(spec.options), where=f"drives.{spec.name}.options")
        self.drive = factory(options, Mechanics.from_dict(dict(spec.mechanics)))
        for name, value in initial_params(spec).items():
            self._set_param(name, value)
        self.drive.power_cycle(battery=True)  # mapping parameters take effect (L9256, L9339)
        self.host = DriveHost(self.drive)
        self.truth = GroundTruth(spec.name, self.drive, self.host, recorder,
                                 getattr(options, "state_publish_ms", 10.0))
        self.closers.append(self.truth.close)
        if spec.can:
            self._can(urls[f"can:{spec.can}"])
        if spec.rs485:
            self._rs485(urls[f"rs485:{spec.rs485}"])
        if spec.dio:
            self._dio(urls[f"dio:{spec.name}"])
        self.host.start()
        self.closers.insert(0, self.host.stop)

    def _set_param(self, name: str, value: int) -> None:
        store = self.drive.params
        try:
            store.write(name, value)
        except Exception:
            store.set_internal(name, value)

    def _can(self, url: str) -> None:
        from hil.faces.canopen_slave import CanopenSlave
        from hil.transport.can_bus import open_can

        bus = open_can(url)
        slave = CanopenSlave(bus, self.drive, node_id=self.spec.node_id, lock=self.host.lock,
                             own_timer=False, clock=self.host.model_now)
        self.host.add_tick(slave.tick)
        slave.start()
        self.closers += [slave.close, bus.shutdown]

    def _rs485(self, url: str) -> None:
        from hil.faces.modbus_slave import ModbusSlave, ModbusSlaveRunner
        from hil.transport.serial_line import open_serial

        line = open_serial(url)
        slave = ModbusSlave(self.drive.params, station=self.spec.station, lock=self.host.lock,
                            mode=self.spec.modbus_mode)  # type: ignore[arg-type]
        runner = ModbusSlaveRunner(slave, line).start()
        self.closers += [runner.stop, line.close]

    def _dio(self, url: str) -> None:
        from hil.transport.dio import open_dio

        port = open_dio(url, role="drive", name=f"{self.spec.name}-face")
        face = DioFace(self.drive, self.host, port)
        self.closers += [face.close, port.close]

    def close(self) -> None:
        for fn in self.closers:
            with contextlib.suppress(Exception):
                fn()


class VirtualWorld:
    """Drive side of a virtual bench, in process."""

    def __init__(self, bench: Bench, recorder: Any, *,
                 drive_factory: DriveFactory | None = None) -> None:
        self.bench = bench
        self._tmp = tempfile.TemporaryDirectory(prefix="hil-bench-")
        self.urls = resolve_auto(bench, Path(self._tmp.name))
        self.drives: dict[str, VirtualDrive] = {}
        factory = drive_factory or default_drive_factory
        try:
            for name, spec in bench.drives.items():
                self.drives[name] = VirtualDrive(spec, self.urls, recorder, factory, bench)
        except BaseException:
            self.close()
            raise

    def harness_urls(self) -> dict[str, str]:
        return {k: harness_side(u) for k, u in self.urls.items()}

    def power_cycle(self, drive: str, battery: bool = True, off_ns: int = 0) -> None:
        vd = self.drives[drive]
        if off_ns:
            time.sleep(off_ns / 1e9)
        vd.host.call(vd.drive.power_cycle, battery=battery)

    def inject(self, drive: str, options: dict | None = None, alarm: str | None = None) -> None:
        vd = self.drives[drive]
        with vd.host.lock:
            if options:
                target = vd.drive.options
                for k, x in options.items():
                    setattr(target, k, x)
            if alarm:
                vd.drive.alarms.raise_alarm(alarm)

    def snapshot(self, drive: str) -> dict:
        vd = self.drives[drive]
        return vd.host.call(vd.drive.snapshot)

    def close(self) -> None:
        for vd in self.drives.values():
            vd.close()
        self.drives.clear()
        with contextlib.suppress(Exception):
            self._tmp.cleanup()


class SubprocessWorld:
    """Drive side as `hil drive` processes (one per drive), for zenoh/socketcan benches.

    Seam: the `hil drive` command line is the faces room's; this passes
    `--can URL --node-id N --rs485 URL --station N --dio URL --bench FILE --drive NAME`
    and waits for a line containing `ready` (DESIGN.md)."""

    def __init__(self, bench: Bench, recorder: Any, *, ready_timeout_s: float = 10.0) -> None:
        self.bench = bench
        self._tmp = tempfile.TemporaryDirectory(prefix="hil-bench-")
        self.urls = resolve_auto(bench, Path(self._tmp.name))
        self.procs: dict[str, subprocess.Popen] = {}
        try:
            for name, spec in bench.drives.items():
                cmd = [sys.executable, "-m", "hil.cli", "drive", "--bench", bench.path,
                       "--drive", name]
                if spec.can:
                    cmd += ["--can", self.urls[f"can:{spec.can}"], "--node-id", str(spec.node_id)]
                if spec.rs485:
                    cmd += ["--rs485", self.urls[f"rs485:{spec.rs485}"],
                            "--station", str(spec.station)]
                if spec.dio:
                    cmd += ["--dio", self.urls[f"dio:{name}"]]
                p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                     text=True)
                self.procs[name] = p
                self._wait_ready(name, p, ready_timeout_s)
        except BaseException:
            self.close()
            raise

    @staticmethod
    def _wait_ready(name: str, p: subprocess.Popen, timeout_s: float) -> None:
        seen: list[str] = []
        done = threading.Event()

        def pump() -> None:
            assert p.stdout is not None
            for line in p.stdout:
                seen.append(line.rstrip())
                if "ready" in line:
                    done.set()
            done.set()

        threading.Thread(target=pump, daemon=True).start()
        if not done.wait(timeout_s) or p.poll() is not None:
            raise RuntimeError(f"virtual drive {name}: `hil drive` not ready within "
                               f"{timeout_s:g} s; output: {' | '.join(seen[-5:]) or 'none'}")

    def harness_urls(self) -> dict[str, str]:
        return {k: harness_side(u) for k, u in self.urls.items()}

    def power_cycle(self, drive: str, battery: bool = True, off_ns: int = 0) -> None:
        raise NotImplementedError("power_cycle on a subprocess drive: not wired yet")

    def inject(self, drive: str, options: dict | None = None, alarm: str | None = None) -> None:
        raise NotImplementedError("inject on a subprocess drive: not wired yet")

    def snapshot(self, drive: str) -> dict:
        return {}

    def close(self) -> None:
        for p in self.procs.values():
            if p.poll() is None:
                p.terminate()
                try:
                    p.wait(5)
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait(5)
        with contextlib.suppress(Exception):
            self._tmp.cleanup()
