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
DriveFactory = Callable[..., Any]  # Drive(**kwargs) stand-in (tests)


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
    """One in-process virtual drive with its faces (`hil.faces.stack`) and ground truth."""

    def __init__(self, spec: DriveSpec, urls: dict[str, str], recorder: Any,
                 factory: DriveFactory | None, bench: Bench) -> None:
        from hil.faces.stack import DriveSpec as StackSpec
        from hil.faces.stack import VirtualDriveStack
        from hil.model.mechanics import Mechanics
        from hil.model.options import ModelOptions

        self.spec = spec
        options = ModelOptions.from_dict(dict(spec.options), where=f"drives.{spec.name}.options")
        self.stack = VirtualDriveStack(StackSpec(
            name=spec.name,
            can=urls[f"can:{spec.can}"] if spec.can else None,
            rs485=urls[f"rs485:{spec.rs485}"] if spec.rs485 else None,
            dio=urls[f"dio:{spec.name}"] if spec.dio else None,
            node_id=spec.node_id,
            station=spec.station,
            params=initial_params(spec),  # applied, then power cycled (L9256, L9339)
            options=options,
            mechanics=Mechanics.from_dict(dict(spec.mechanics)),
            inputs=idle_inputs(spec),
            modbus_mode=spec.modbus_mode,
        ), drive_factory=factory)
        self.drive, self.host = self.stack.drive, self.stack.host
        self.truth = GroundTruth(spec.name, self.drive, self.host, recorder,
                                 options.state_publish_ms)
        if spec.dio:
            declare = getattr(recorder, "declare_source", None)
            if declare is not None:  # DO levels carry the model's own time (exact to 1 µs)
                for n in range(1, 7):
                    declare(f"/dio/{spec.name}/DO{n}", "model", resolution_ns=1000)
                declare(f"/dio/{spec.name}/FDBK", "model", resolution_ns=1000)
        try:
            self.stack.start()
        except BaseException:
            self.truth.close()
            raise

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self.stack.stop()
        with contextlib.suppress(Exception):
            self.truth.close()


def idle_inputs(spec: DriveSpec) -> dict[int, bool]:
    """DI contacts at power-up as an idle bench's wiring leaves them: b-contacts closed."""
    return {int(w.line[2:]): True for w in spec.di.values()
            if w.contact == "b" and w.line.startswith("DI")}


class VirtualWorld:
    """Drive side of a virtual bench, in process."""

    def __init__(self, bench: Bench, recorder: Any, *,
                 drive_factory: DriveFactory | None = None) -> None:
        self.bench = bench
        self._tmp = tempfile.TemporaryDirectory(prefix="hil-bench-")
        self.urls = resolve_auto(bench, Path(self._tmp.name))
        self.drives: dict[str, VirtualDrive] = {}
        factory = drive_factory
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
