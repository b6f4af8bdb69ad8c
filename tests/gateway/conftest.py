"""Gateway test rigs: a virtual drive behind an in-process gateway, on loopback only."""

from __future__ import annotations

import sys
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import can
import pytest

from hil.bench.bench import load_bench
from hil.gateway.gateway import Gateway, GatewayConfig
from hil.transport import zenoh_net
from hil.virtual.stack import DriveSpec, VirtualDriveStack
from tests.children import ChildProcess, children, hil
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


@pytest.fixture
def runner_child():
    """tests/gateway/runner_child.py as a child; stopped by closing its stdin."""
    yield from children(lambda *args: ChildProcess(
        [sys.executable, str(HERE / "runner_child.py"), *args], how="stdin", timeout_s=20.0,
        ready=lambda line: line.startswith(("ready", "refused", "error")), what="runner child"))


@pytest.fixture
def hil_process():
    """`python -m hil.cli ARGS` as a child, ready once it prints `ready`."""
    yield from children(hil)
