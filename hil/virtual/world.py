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
import json
import math
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

from hil import clock
from hil.bench.bench import Bench, DriveSpec
from hil.model.mechanics import Mechanics
from hil.model.options import ModelOptions
from hil.virtual.options import model_options
from hil.virtual.stack import DriveSpec as StackSpec
from hil.virtual.stack import VirtualDriveStack

_seq = itertools.count()
DriveFactory = Callable[..., Any]  # Drive(**kwargs) stand-in (tests)


def _auto_name(kind: str) -> str:
    return f"hil-{os.getpid()}-{next(_seq)}-{kind}"


def free_loopback_port() -> int:
    """A TCP port free on 127.0.0.1 right now (the OS picks it)."""

    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _auto_endpoints(query: str, ports: dict[str, int]) -> str:
    """`listen=tcp/127.0.0.1:auto` -> a free loopback port (the same endpoint written twice
    in one URL gets the same port)."""
    out = []
    for item in query.split("&") if query else []:
        k, eq, v = item.partition("=")
        if k in ("listen", "connect"):
            eps = []
            for ep in v.split(","):
                if ep.endswith(":auto"):
                    if not ep.startswith("tcp/127.0.0.1:"):
                        raise ValueError(f"{ep!r}: an auto port is only for tcp/127.0.0.1")
                    ports.setdefault(ep, free_loopback_port())
                    ep = f"{ep[:-5]}:{ports[ep]}"
                eps.append(ep)
            v = ",".join(eps)
        out.append(f"{k}{eq}{v}")
    return "&".join(out)


def resolve_auto(bench: Bench, tmpdir: Path) -> dict[str, str]:
    """URL of each transport with `auto` targets made unique (schemes in lower case, as
    `parse_url` reads them: `PTY:auto` is a pty too): keys `can:<bus>`,
    `rs485:<line>`, `dio:<drive>`, `pulse:<drive>`. `virtual:auto` gets a unique name,
    `pty:auto` a link in `tmpdir`, `zenoh:auto` a unique key (`hil/<pid>-<n>/<kind>`), and a
    zenoh endpoint `tcp/127.0.0.1:auto` a free loopback port."""
    out: dict[str, str] = {}

    def fix(url: str, kind: str) -> str:
        scheme, _, rest = url.strip().partition(":")
        scheme = scheme.lower()  # as `parse_url` reads it: `PTY:auto` is a pty too
        url = f"{scheme}:{rest}"
        target, q, query = rest.partition("?")
        if scheme == "zenoh":
            query = _auto_endpoints(query, {})  # each URL its own port(s)
            if target == "auto":
                target = f"hil/{os.getpid()}-{next(_seq)}/{kind}"
            return f"{scheme}:{target}{q}{query}"
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
        if d.pulse:
            out[f"pulse:{dn}"] = fix(d.pulse, "pulse")
    return out


def bus_mesh(url: str, n: int) -> tuple[list[str], str]:
    """The URLs of `n` drive processes on one zenoh bus whose URL listens on loopback, and the
    URL whose `harness_side` reaches them all. One port takes one listener, and zenoh peers do
    not route for each other, so drive i listens on a port of its own (the first keeps the
    bus's) and connects to the drives before it: every pair of processes is linked."""
    head, _, query = url.partition("?")
    items = query.split("&") if query else []
    listen = [ep for i in items if i.startswith("listen=") for ep in i[7:].split(",") if ep]
    if n < 2 or not url.startswith("zenoh:") or len(listen) != 1 \
            or not listen[0].startswith("tcp/127.0.0.1:"):
        return [url] * n, url
    rest = [i for i in items if not i.startswith(("listen=", "connect="))]
    eps = listen + [f"tcp/127.0.0.1:{free_loopback_port()}" for _ in range(n - 1)]
    drives = [f"{head}?" + "&".join([f"listen={ep}",
                                     *([f"connect={','.join(eps[:i])}"] if i else []), *rest])
              for i, ep in enumerate(eps)]
    return drives, f"{head}?" + "&".join([f"listen={','.join(eps)}", *rest])


def harness_side(url: str) -> str:
    """The URL the harness opens for a drive-side URL: a pty's far end as a serial port; for
    zenoh, the drive's `listen=` endpoints become the harness's `connect=` ones."""
    if url.startswith("pty:"):
        return "serial:" + url[4:]
    if url.startswith("zenoh:"):
        head, _, query = url.partition("?")
        items = query.split("&") if query else []
        listen = [i.partition("=")[2] for i in items if i.startswith("listen=")]
        if not listen:
            return url
        rest = [i for i in items if not i.startswith(("listen=", "connect="))]
        connect = [i.partition("=")[2] for i in items if i.startswith("connect=")]
        return f"{head}?" + "&".join([f"connect={','.join(listen + connect)}", *rest])
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
    """Records the model's own view: state every period, events, parameter changes.

    The periodic samples are timers of the model's scheduler, so they fall every `period_ms`
    of model time even when the host advances the model by several ms at once (a loaded
    machine): a 1 ms ground truth stays 1 ms (timing specs rely on it)."""

    def __init__(self, name: str, drive: Any, host: Any, recorder: Any,
                 period_ms: float = 10.0) -> None:
        self.name, self.drive, self.host, self.rec = name, drive, host, recorder
        self.period_ns = int(period_ms * 1_000_000)
        self._next = 0
        self._timer: Any = None
        self._last_event_state: dict[str, Any] | None = None
        self._unsub = drive.subscribe(self._on_event)
        host.add_tick(self._tick)
        self.snapshot_params()

    def snapshot_params(self) -> None:
        params = self.drive.params
        values = {}
        table = getattr(params, "table", None)
        names = [s.param for s in table] if table is not None else []
        if not names:
            names = list(getattr(params, "_stored", {}))
        for n in names:
            with contextlib.suppress(Exception):
                values[n] = params.get(n)
        t = self.drive.now
        self.rec.drive_params(self.name, values, snapshot=True, source_t=self.host.wall_ns(t))

    def sample(self) -> None:
        """One state sample now (call under the host lock): what a check reads is current."""
        snap = self.drive.snapshot()  # a new dict each time
        snap["periodic"] = True
        self.rec.drive_state(self.name, snap, source_t=self.host.wall_ns(self.drive.now))

    def input_applied(self, line: str, level: bool, sent_ns: int, model_t: int) -> None:
        """An input edge the drive applied at `model_t`, stamped `sent_ns` by the harness."""
        record = getattr(self.rec, "input_delivery", None)  # test doubles may lack it
        if record is not None:
            record(self.name, line, level, sent_ns, self.host.wall_ns(model_t))

    def _tick(self, now: int) -> None:
        """Host tick (under the host lock): arm the model-time sampler once."""
        if self._timer is None:
            sched = getattr(self.drive, "sched", None)
            if sched is None:  # not a model drive: sample at the host's ticks
                if now >= self._next:
                    self._next = now + self.period_ns
                    self.sample()
                return
            first = max(now, self._next)
            grid = getattr(self.host, "next_grid", None)  # the virtual host's (ClockHost)
            if grid is None:  # the real-time host: as before, at once through its wake-up
                self._timer = sched.at(first, self._on_timer)
                return
            first = grid(first)  # on the host's grid: a sample's log time is its model time
            if first <= self.drive.now:  # due at this tick: now, not a tick late
                self._on_timer()
            else:
                self._timer = sched.at(first, self._on_timer)

    def _on_timer(self) -> None:
        now = self.drive.now
        self._next = now + self.period_ns
        self.sample()
        self._timer = self.drive.sched.at(self._next, self._on_timer)

    def _on_event(self, ev: Any) -> None:
        t = getattr(ev, "t", self.drive.now)
        wall = self.host.wall_ns(t)
        if type(ev).__name__ == "ParamChanged":
            self.rec.drive_params(self.name, {ev.name: ev.value}, source_t=wall)
        self.rec.drive_event(self.name, {"type": type(ev).__name__, **_fields(ev)},
                             source_t=wall)
        # a state sample at every event that changed it, so transitions are exact rather
        # than a period late (several events at one instant share one sample)
        with contextlib.suppress(Exception):
            snap = self.drive.snapshot()
            key = {k: v for k, v in snap.items() if k != "t"}
            if key != self._last_event_state:
                self._last_event_state = key
                self.rec.drive_state(self.name, snap, source_t=wall)

    def close(self) -> None:
        self.host.remove_tick(self._tick)
        if self._timer is not None:
            self._timer.cancel()
        with contextlib.suppress(Exception):
            self._unsub()


def _fields(ev: Any) -> dict:
    slots = getattr(ev, "__slots__", None) or getattr(ev, "__dataclass_fields__", {})
    return {k: getattr(ev, k) for k in slots}


class VirtualDrive:
    """One in-process virtual drive with its faces (`hil.virtual.stack`) and ground truth."""

    def __init__(self, spec: DriveSpec, urls: dict[str, str], recorder: Any,
                 factory: DriveFactory | None, bench: Bench) -> None:

        self.spec = spec
        options = model_options(spec.options, where=f"drives.{spec.name}.options")
        self.stack = VirtualDriveStack(StackSpec(
            name=spec.name,
            can=urls[f"can:{spec.can}"] if spec.can else None,
            rs485=urls[f"rs485:{spec.rs485}"] if spec.rs485 else None,
            dio=urls[f"dio:{spec.name}"] if spec.dio else None,
            pulse=urls[f"pulse:{spec.name}"] if spec.pulse else None,
            pulse_wiring=spec.pulse_wiring,
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
        self.stack.on_input = self.truth.input_applied
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


TMP_PREFIX = "hil-bench-"


def bench_tmpdir() -> tempfile.TemporaryDirectory:
    """The run's scratch folder for its ptys and sockets, `hil-bench-<pid>-...` in the temp
    folder. A run killed by SIGKILL cannot remove its own: the folders of this user whose
    process is gone are removed first."""
    root = Path(tempfile.gettempdir())
    with contextlib.suppress(OSError):
        for d in root.glob(f"{TMP_PREFIX}*-*"):
            pid = d.name[len(TMP_PREFIX):].split("-", 1)[0]
            if not pid.isdigit() or int(pid) == os.getpid() or _alive(int(pid)):
                continue
            with contextlib.suppress(OSError):
                if d.is_dir() and not d.is_symlink() and d.stat().st_uid == os.getuid():
                    shutil.rmtree(d, ignore_errors=True)
    return tempfile.TemporaryDirectory(prefix=f"{TMP_PREFIX}{os.getpid()}-")


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


class VirtualWorld:
    """Drive side of a virtual bench, in process."""

    def __init__(self, bench: Bench, recorder: Any, *,
                 drive_factory: DriveFactory | None = None) -> None:
        self.bench = bench
        self._tmp = bench_tmpdir()
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

    def dead(self) -> dict[str, str]:
        """Drives whose model raised while advancing: name -> what happened. Its outputs are
        frozen since, so a plan must not go on as if it were a drive (the runner errors)."""
        out = {}
        for name, vd in self.drives.items():
            exc = getattr(vd.host, "model_failed", None)
            if exc is not None:
                out[name] = (f"virtual drive {name!r}: its model failed "
                             f"({type(exc).__name__}: {exc}); see the log")
        return out

    def power_cycle(self, drive: str, battery: bool = True, off_ns: int = 0) -> None:
        vd = self.drives[drive]
        if off_ns:
            clock.sleep(off_ns / 1e9)
        vd.host.call(vd.drive.power_cycle, battery=battery)

    def inject(self, drive: str, options: dict | None = None, alarm: str | None = None) -> None:
        vd = self.drives[drive]
        with vd.host.lock:
            if options:
                apply_options(vd.drive, options)
            if alarm:
                vd.drive.alarms.raise_alarm(alarm)

    def snapshot(self, drive: str) -> dict:
        vd = self.drives[drive]
        return vd.host.call(vd.drive.snapshot)

    def sample_truth(self) -> None:
        """Record every drive's ground truth as of now (before a timing check reads it)."""
        for vd in self.drives.values():
            vd.host.call(vd.truth.sample)

    def close(self) -> None:
        for vd in self.drives.values():
            vd.close()
        self.drives.clear()
        with contextlib.suppress(Exception):
            self._tmp.cleanup()


CTL = "hil-ctl "  # prefix of control-channel lines on a `hil drive --control stdio` stdout


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, list | tuple | set):
        return [_jsonable(v) for v in x]
    if isinstance(x, int | float | str | bool) or x is None:
        return x
    return str(x)


TRUTH_METHODS = frozenset(("drive_state", "drive_event", "drive_params", "input_delivery"))


class _LineRecorder:
    """What `GroundTruth` records, as `hil-ctl` JSON lines (the parent records them)."""

    def __init__(self, write: Callable[[dict], None]) -> None:
        self._write = write

    def __getattr__(self, method: str) -> Callable[..., None]:
        if method not in TRUTH_METHODS:
            raise AttributeError(method)

        def call(*args: Any, **kw: Any) -> None:
            self._write({"truth": method, "args": _jsonable(list(args)), "kw": _jsonable(kw)})

        return call


MAX_OFF_NS = 60 * 1_000_000_000  # a control power cycle's off time


def apply_options(drive: Any, given: Any) -> None:
    """Set model options on a running drive (`inject`), each checked as a bench's are
    (a text where a time belongs, an unknown option: ValueError, nothing set)."""
    if not isinstance(given, dict):
        raise ValueError("options: a mapping of model options")
    checked = ModelOptions.from_dict(given, where="inject.options")
    for k in given:
        setattr(drive.options, k, getattr(checked, k))


def _reply_id(cmd: Any) -> Any:
    """The id a reply carries: the command's own if it is a JSON-safe number or text."""
    rid = cmd.get("id") if isinstance(cmd, dict) else None
    if isinstance(rid, float) and not math.isfinite(rid):
        return None
    return rid if isinstance(rid, int | float | str) or rid is None else None


class StdioControl:
    """Drive side of a subprocess bench's control channel (`hil drive --control stdio`).

    stdin: one JSON command per line, `{"id": n, "op": "power_cycle", "battery": true,
    "off_ns": 0}` | `{"id": n, "op": "inject", "options": {...}, "alarm": "AL009"}` |
    `{"id": n, "op": "snapshot"}`; stdout: `hil-ctl {"reply": n, "ok": true, "result": ...}`
    and the ground truth (`hil-ctl {"truth": "drive_state", ...}`) as `GroundTruth` records
    it in process. EOF on stdin (the runner went away) stops the drive."""

    def __init__(self, stack: Any, stop: threading.Event, stdin: Any = None,
                 stdout: Any = None) -> None:
        self.stack, self.stop = stack, stop
        self._in = stdin or sys.stdin
        self._out = stdout or sys.stdout
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self.truth: GroundTruth | None = None

    def write(self, msg: dict) -> None:
        line = CTL + json.dumps(msg, separators=(",", ":"))
        with self._lock:
            self._out.write(line + "\n")
            self._out.flush()

    def start(self) -> None:
        st = self.stack
        self.truth = GroundTruth(st.spec.name, st.drive, st.host, _LineRecorder(self.write),
                                 st.spec.options.state_publish_ms)
        st.on_input = self.truth.input_applied
        self._thread = threading.Thread(target=self._serve, name="hil-drive-ctl", daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        # bytes, decoded line by line: an invalid UTF-8 byte is one bad command, not the
        # end of the channel (a strict text stream raised in the loop itself)
        src = getattr(self._in, "buffer", None) or self._in
        for raw in src:
            line = (raw.decode("utf-8", "replace") if isinstance(raw, bytes) else raw).strip()
            if not line:
                continue
            cmd: Any = None
            try:
                cmd = json.loads(line)
                result = self.execute(cmd)
                self.write({"reply": _reply_id(cmd), "ok": True, "result": _jsonable(result)})
            except Exception as e:  # a bad command must not kill the drive
                self.write({"reply": _reply_id(cmd), "ok": False,
                            "error": f"{type(e).__name__}: {e}"[:2000]})
        self.stop.set()

    def execute(self, cmd: dict) -> Any:
        drive, host = self.stack.drive, self.stack.host
        op = cmd.get("op")
        if op == "power_cycle":
            off = int(cmd.get("off_ns") or 0)
            if not 0 <= off <= MAX_OFF_NS:  # the channel waits it out: bounded
                raise ValueError(f"off_ns {off}: 0 ~ {MAX_OFF_NS} (60 s)")
            if off:
                clock.sleep(off / 1e9)
            host.call(drive.power_cycle, battery=bool(cmd.get("battery", True)))
            return None
        if op == "inject":
            with host.lock:
                apply_options(drive, cmd.get("options") or {})
                if cmd.get("alarm"):
                    drive.alarms.raise_alarm(cmd["alarm"])
            return None
        if op == "snapshot":
            return host.call(drive.snapshot)
        raise ValueError(f"unknown control op {op!r}; known: power_cycle, inject, snapshot")

    def close(self) -> None:
        if self.truth is not None:
            self.truth.close()


class SubprocessWorld:
    """Drive side as `hil drive` processes (one per drive), for zenoh/socketcan benches.

    Each process gets `--bench FILE --drive NAME --control stdio` plus its transports
    (`--can URL --node-id N --rs485 URL --station N --dio URL`, `auto` targets resolved
    here) and prints a line containing `ready` (docs/benches.md). Through the control channel the
    runner power-cycles, injects and snapshots the drive, and records the ground truth the
    process streams (same topics as in process)."""

    def __init__(self, bench: Bench, recorder: Any, *, ready_timeout_s: float | None = None,
                 reply_timeout_s: float = 5.0) -> None:
        self.bench, self.rec = bench, recorder
        self.reply_timeout_s = reply_timeout_s
        ready = ready_timeout_s or bench.timeouts["ready"] / 1e9
        self._tmp = bench_tmpdir()
        self.urls = resolve_auto(bench, Path(self._tmp.name))
        # a CAN bus several drive processes share: each its own port, linked to each other
        self.can_urls: dict[str, str] = {}
        for bus in bench.can:
            names = [n for n, d in bench.drives.items() if d.can == bus]
            if not names:
                continue
            per_drive, self.urls[f"can:{bus}"] = bus_mesh(self.urls[f"can:{bus}"], len(names))
            self.can_urls.update(zip(names, per_drive, strict=True))
        self.procs: dict[str, subprocess.Popen] = {}
        self._ids = itertools.count(1)
        self._replies: dict[int, dict] = {}
        self._waiting: dict[int, threading.Event] = {}
        self._lock = threading.Lock()
        self._out: dict[str, list[str]] = {}
        try:
            for name, spec in bench.drives.items():
                cmd = [sys.executable, "-m", "hil.cli", "drive", "--bench", bench.path,
                       "--drive", name, "--name", name, "--control", "stdio"]
                if spec.can:
                    cmd += ["--can", self.can_urls[name], "--node-id", str(spec.node_id)]
                if spec.rs485:
                    cmd += ["--rs485", self.urls[f"rs485:{spec.rs485}"],
                            "--station", str(spec.station)]
                if spec.dio:
                    cmd += ["--dio", self.urls[f"dio:{name}"]]
                if spec.pulse:
                    cmd += ["--pulse", self.urls[f"pulse:{name}"]]
                # Its own session: a terminal's Ctrl-C reaches the runner only, which drives
                # the bench safe through this process before stopping it; if the runner dies,
                # EOF on the control channel stops it.
                p = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT, text=True, bufsize=1,
                                     start_new_session=True)
                self.procs[name] = p
                self._wait_ready(name, p, ready)
        except BaseException:
            self.close()
            raise

    def _wait_ready(self, name: str, p: subprocess.Popen, timeout_s: float) -> None:
        seen = self._out.setdefault(name, [])
        done = threading.Event()
        ready = threading.Event()

        def pump() -> None:
            assert p.stdout is not None
            for line in p.stdout:
                if line.startswith(CTL):
                    self._control_line(name, line[len(CTL):])
                    continue
                seen.append(line.rstrip())
                del seen[:-50]
                if "ready" in line:
                    ready.set()
                    done.set()
            done.set()  # its output ended: the process is ending

        threading.Thread(target=pump, name=f"hil-drive-{name}-out", daemon=True).start()
        done.wait(timeout_s)
        if not ready.is_set() or p.poll() is not None:
            with contextlib.suppress(subprocess.TimeoutExpired):
                p.wait(timeout=2)  # ended at start: its exit code and its own words
            end = (f"exited with code {p.returncode}" if p.returncode is not None
                   else f"not ready within {timeout_s:g} s")
            raise RuntimeError(f"virtual drive {name}: `hil drive` {end}; output: "
                               f"{' | '.join(seen[-5:]) or 'none'}")

    def _control_line(self, name: str, text: str) -> None:
        try:
            msg = json.loads(text)
        except ValueError:
            return
        if not isinstance(msg, dict):
            return  # not a record or a reply: dropped, the reader goes on
        if "truth" in msg:
            # the ground truth's own records only (`_LineRecorder`): a line cannot close the
            # recorder or call any other of its methods
            method = msg["truth"]
            ok = isinstance(method, str) and method in TRUTH_METHODS
            fn = getattr(self.rec, method, None) if ok else None
            if fn is not None:
                with contextlib.suppress(Exception):
                    fn(*msg.get("args", []), **msg.get("kw", {}))
            return
        rid = msg.get("reply")
        with self._lock:
            ev = self._waiting.pop(rid, None) if isinstance(rid, int) else None
            if ev is not None:
                self._replies[rid] = msg
        if ev is not None:
            ev.set()

    def _call(self, drive: str, op: str, **args: Any) -> Any:
        p = self.procs.get(drive)
        if p is None or p.poll() is not None or p.stdin is None:
            raise RuntimeError(f"virtual drive {drive}: its `hil drive` process is not running")
        rid = next(self._ids)
        ev = threading.Event()
        with self._lock:
            self._waiting[rid] = ev
        p.stdin.write(json.dumps({"id": rid, "op": op, **args}) + "\n")
        p.stdin.flush()
        if not ev.wait(self.reply_timeout_s + args.get("off_ns", 0) / 1e9):
            with self._lock:
                self._waiting.pop(rid, None)
            raise RuntimeError(f"virtual drive {drive}: no answer to {op} within "
                               f"{self.reply_timeout_s:g} s")
        with self._lock:
            reply = self._replies.pop(rid)
        if not reply.get("ok"):
            raise RuntimeError(f"virtual drive {drive}: {op}: {reply.get('error')}")
        return reply.get("result")

    def dead(self) -> dict[str, str]:
        """Drive processes that have exited: name -> what happened (empty while all live)."""
        out = {}
        for name, p in self.procs.items():
            code = p.poll()
            if code is not None:
                how = f"killed by signal {-code}" if code < 0 else f"exit code {code}"
                out[name] = f"virtual drive process {name!r} (hil drive, pid {p.pid}) died: {how}"
        return out

    def harness_urls(self) -> dict[str, str]:
        return {k: harness_side(u) for k, u in self.urls.items()}

    def power_cycle(self, drive: str, battery: bool = True, off_ns: int = 0) -> None:
        self._call(drive, "power_cycle", battery=battery, off_ns=off_ns)

    def inject(self, drive: str, options: dict | None = None, alarm: str | None = None) -> None:
        self._call(drive, "inject", options=options or {}, alarm=alarm)

    def snapshot(self, drive: str) -> dict:
        return dict(self._call(drive, "snapshot") or {})

    def close(self) -> None:
        for p in self.procs.values():
            if p.poll() is None:
                with contextlib.suppress(Exception):
                    assert p.stdin is not None
                    p.stdin.close()  # EOF on the control channel: the drive stops
                p.terminate()
            try:
                p.wait(5)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(5)
        self.procs.clear()
        with contextlib.suppress(Exception):
            self._tmp.cleanup()
