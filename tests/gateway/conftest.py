"""Gateway test rigs: a virtual drive behind an in-process gateway, on loopback only."""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import can
import pytest

from hil.faces.stack import DriveSpec, VirtualDriveStack
from hil.gateway.gateway import Gateway, GatewayConfig
from hil.plan.bench import load_bench
from hil.transport import zenoh_net
from tests.conftest import free_port

HERE = Path(__file__).parent
SDO_UPLOAD_6041 = bytes([0x40, 0x41, 0x60, 0x00, 0, 0, 0, 0])  # CiA 301 initiate upload


def bench_yaml(name: str, can_url: str | None, dio_url: str | None,
               rs485_url: str | None = None) -> str:
    lines = [f"name: {name}", "virtual: false"]
    if can_url:
        lines += ["can:", f'  can0: "{can_url}"']
    if rs485_url:
        lines += ["rs485:", f'  rs485: "{rs485_url}"']
    lines += ["drives:", "  drive1:", "    profile: asda-a3"]
    if can_url:
        lines += ["    can: can0", "    node_id: 1"]
    if rs485_url:
        lines += ["    rs485: rs485", "    station: 1"]
    if dio_url:
        lines += [f'    dio: "{dio_url}"', "    wiring:", "      SON: DI1", "      SRDY: DO1"]
    lines += ["safe_state:", "  controlword: disable_voltage"]
    if dio_url:
        lines += ["  di: {SON: off}"]
    lines += ["  wait_brake: false", "  timeout: 1s"]
    return "\n".join(lines) + "\n"


@dataclass
class Rig:
    """One bench: a virtual drive and the gateway exporting its buses."""

    name: str
    port: int
    gateway: Gateway
    stack: VirtualDriveStack | None
    record: Path

    @property
    def endpoint(self) -> str:
        return f"tcp/127.0.0.1:{self.port}"

    def state(self) -> str:
        assert self.stack is not None
        with self.stack.host.lock:
            s = self.stack.drive.snapshot()["state"]
            return getattr(s, "name", str(s))


@pytest.fixture
def make_rig(tmp_path: Path):
    made: list[Rig] = []

    def make(name: str = "bench1", *, lab: str = "lab", drive: bool = True,
             can_factory: Callable | None = None, lease_timeout_s: float = 1.0,
             config: dict | None = None, listen: list[str] | None = None,
             rs485: tuple[str, str] | None = None) -> Rig:
        tag = uuid.uuid4().hex[:8]
        can_url, dio_url = f"virtual:gw-{tag}", f"virtual:gwdio-{tag}"
        path = tmp_path / f"{name}-{tag}.yaml"
        path.write_text(bench_yaml(name, can_url, dio_url, rs485[1] if rs485 else None))
        bench = load_bench(path)
        stack = None
        if drive:
            stack = VirtualDriveStack(DriveSpec(
                name="drive1", can=can_url, dio=dio_url, node_id=1, inputs={8: True},
                rs485=rs485[0] if rs485 else None)).start()
        port = free_port()
        record = tmp_path / f"gw-{name}-{tag}.mcap"
        cfg = GatewayConfig(lab=lab, listen=listen or [f"tcp/127.0.0.1:{port}"],
                            lease_timeout_s=lease_timeout_s, health_period_s=0.2,
                            record=record, backoff_s=(0.02, 0.2), **(config or {}))
        try:
            gw = Gateway(bench, cfg, can_factory=can_factory).start()
        except BaseException:
            if stack:
                stack.stop()
            raise
        rig = Rig(name, port, gw, stack, record)
        made.append(rig)
        assert gw.wait_ready(5), gw.health()
        return rig

    yield make
    for rig in made:
        rig.gateway.stop()
        if rig.stack is not None:
            rig.stack.stop()


@pytest.fixture(autouse=True)
def no_leaked_sessions():
    before = zenoh_net.open_sessions()
    yield
    leaked = zenoh_net.open_sessions() - before
    zenoh_net.close_all()
    for prefix in list(zenoh_net._lease_tokens):
        zenoh_net.set_lease_token(prefix, None)
    assert leaked <= 0, f"{leaked} zenoh session(s) left open"


def sdo_read_statusword(bus: can.BusABC, node: int = 1, timeout: float = 2.0) -> can.Message:
    """Upload 6041h:00 over `bus`; the answer frame (0x580 + node)."""
    bus.send(can.Message(arbitration_id=0x600 + node, data=SDO_UPLOAD_6041,
                         is_extended_id=False))
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        msg = bus.recv(0.05)
        if msg is not None and msg.arbitration_id == 0x580 + node and msg.data[1] == 0x41:
            return msg
    raise AssertionError(f"no SDO answer from node {node} within {timeout} s")


class Child:
    """A runner child process (tests/gateway/runner_child.py); killed at teardown."""

    def __init__(self, *args: str, timeout_s: float = 20.0):
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        self.proc = subprocess.Popen([sys.executable, str(HERE / "runner_child.py"), *args],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT, text=True, env=env,
                                     cwd=str(HERE.parent.parent))
        self.lines: list[str] = []
        self._ready = threading.Event()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()
        if not self._ready.wait(timeout_s):
            self.stop()
            raise RuntimeError(f"runner child {args} not ready: {self.lines[-10:]}")

    def _read(self) -> None:
        for line in self.proc.stdout:  # type: ignore[union-attr]
            self.lines.append(line.rstrip())
            if line.startswith(("ready", "refused", "error")):
                self._ready.set()

    def stop(self) -> None:
        if self.proc.poll() is None:
            with contextlib.suppress(OSError):
                self.proc.stdin.close()  # type: ignore[union-attr]
            try:
                self.proc.wait(5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        self._reader.join(2)
        with contextlib.suppress(OSError):
            self.proc.stdout.close()  # type: ignore[union-attr]


@pytest.fixture
def runner_child():
    children: list[Child] = []

    def start(*args: str) -> Child:
        c = Child(*args)
        children.append(c)
        return c

    yield start
    for c in children:
        c.stop()


class HilProcess:
    """`python -m hil.cli ARGS` as a child; ready once it prints a line with `ready`."""

    def __init__(self, args: list[str], timeout_s: float = 30.0) -> None:
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        self.proc = subprocess.Popen([sys.executable, "-m", "hil.cli", *args],
                                     stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                     text=True, env=env, cwd=str(HERE.parent.parent))
        self.lines: list[str] = []
        self._ready = threading.Event()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()
        if not self._ready.wait(timeout_s):
            self.stop()
            raise RuntimeError(f"hil {args[0]} never printed ready: {self.lines[-10:]}")

    def _read(self) -> None:
        for line in self.proc.stdout:  # type: ignore[union-attr]
            self.lines.append(line.rstrip())
            if "ready" in line:
                self._ready.set()
        self._ready.set()

    def stop(self) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(2)  # SIGINT
            try:
                self.proc.wait(15)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        self._reader.join(5)
        with contextlib.suppress(OSError):
            self.proc.stdout.close()  # type: ignore[union-attr]
        return self.proc.returncode


@pytest.fixture
def hil_process():
    procs: list[HilProcess] = []

    def start(*args: str) -> HilProcess:
        p = HilProcess(list(args))
        procs.append(p)
        return p

    yield start
    for p in reversed(procs):
        p.stop()
