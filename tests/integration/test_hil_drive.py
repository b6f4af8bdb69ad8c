"""`hil drive` as its own process, driven over zenoh CAN, a pty and zenoh DI/DO.

canopen's BaseNode402 is a real third-party master; mbpoll a real third-party Modbus master.
"""

from __future__ import annotations

import shutil
import subprocess
import time
from pathlib import Path

import canopen
import pytest

from hil.drivers.delta_modbus import DeltaModbus
from hil.transport.dio import open_dio
from hil.transport.serial_line import open_serial

pytestmark = pytest.mark.integration
EDS = str(Path(__file__).parents[2] / "fixtures" / "drive" / "a3.eds")


@pytest.fixture
def network():
    canopen.Network.NOTIFIER_CYCLE = 0.05
    net = canopen.Network()
    yield net
    net.disconnect()


def test_basenode402_over_zenoh(drive_process, network, free_port_factory) -> None:
    port = free_port_factory()
    key = f"t{port}/can"
    drive = drive_process("--can", f"zenoh:{key}?listen=tcp/127.0.0.1:{port}", "--node-id", "5")
    assert "CANopen node 5" in drive.lines[-1]
    network.connect(interface="zenoh", channel=key, connect=[f"tcp/127.0.0.1:{port}"])
    node = canopen.BaseNode402(5, EDS)
    network.add_node(node)
    assert node.sdo[0x1018][1].raw == 0x1DD  # Delta vendor id (L17778-17784)
    assert node.sdo[0x6502].raw == 0x6D  # PP, PV, PT, HM, IP (L19250-19278)
    node.nmt.state = "PRE-OPERATIONAL"
    node.setup_402_state_machine()
    node.nmt.state = "OPERATIONAL"
    node.state = "OPERATION ENABLED"
    assert node.state == "OPERATION ENABLED"
    node.op_mode = "PROFILED VELOCITY"
    assert node.op_mode == "PROFILED VELOCITY"
    node.op_mode = "PROFILED POSITION"
    assert node.op_mode == "PROFILED POSITION"
    node.state = "SWITCH ON DISABLED"
    assert node.state == "SWITCH ON DISABLED"
    # A mode the A3 lacks (CSP) is refused by the drive itself (6060h range).
    with pytest.raises(canopen.SdoAbortedError) as info:
        node.sdo[0x6060].raw = 8
    assert info.value.code == 0x06090030


def test_pdos_configured_by_sdo_arrive_on_sync_and_on_events(
    drive_process, network, free_port_factory
) -> None:
    port = free_port_factory()
    key = f"t{port}/can"
    drive_process("--can", f"zenoh:{key}?listen=tcp/127.0.0.1:{port}", "--node-id", "3")
    network.connect(interface="zenoh", channel=key, connect=[f"tcp/127.0.0.1:{port}"])
    node = network.add_node(3, EDS)
    node.nmt.state = "PRE-OPERATIONAL"
    node.tpdo.read()
    # TPDO2: 6064h actual position, synchronous every SYNC (transmission type 1).
    t2 = node.tpdo[2]
    t2.clear()
    t2.add_variable(0x6064)
    t2.trans_type = 1
    t2.enabled = True
    # TPDO3: 6041h statusword, event driven (255), no event timer.
    t3 = node.tpdo[3]
    t3.clear()
    t3.add_variable(0x6041)
    t3.trans_type = 255
    t3.event_timer = 0
    t3.enabled = True
    node.tpdo.save()
    node.nmt.state = "OPERATIONAL"
    time.sleep(0.1)
    received: list[float] = []
    t2.add_callback(lambda _map: received.append(time.monotonic()))
    for _ in range(100):  # a SYNC every 10 ms, counted (a loaded host may send them late)
        network.sync.transmit()
        time.sleep(0.01)
    deadline = time.monotonic() + 5
    while len(received) < 100 and time.monotonic() < deadline:
        time.sleep(0.01)
    time.sleep(0.1)  # and no more than one each
    assert len(received) == 100  # one TPDO2 per SYNC
    events: list[int] = []
    t3.add_callback(lambda m: events.append(m[0x6041].raw))
    node.sdo[0x6040].raw = 0x06  # Shutdown -> READY TO SWITCH ON: the statusword changes
    deadline = time.monotonic() + 2
    while not events and time.monotonic() < deadline:
        time.sleep(0.01)
    assert events and events[-1] & 0x6F == 0x21


def test_modbus_over_pty_and_dio_over_zenoh(
    drive_process, tmp_path: Path, free_port_factory
) -> None:
    link = tmp_path / "ttyA3"
    port = free_port_factory()
    dio_key = f"t{port}/dio"
    params = tmp_path / "params.json"
    params.write_text('{"P2.041": 264, "P1.042": 150}')  # DO6 = BRKR (0x0108), MBT1 150 ms
    drive_process(
        "--rs485",
        f"pty:{link}?baud=115200",
        "--station",
        "7",
        "--params",
        str(params),
        "--dio",
        f"zenoh:{dio_key}?listen=tcp/127.0.0.1:{port}",
        "--di",
        "8=1",
    )
    line = open_serial(f"serial:{link}?baud=115200&parity=N&stopbits=2")
    try:
        mb = DeltaModbus(line, station=7, baud=115200)
        assert mb.read_param("P1.042") == 150
        assert mb.read_param("P1.044") == 16777216  # 32-bit, low word first (L7156)
        mb.write_param("P1.043", -20)
        assert mb.read_param("P1.043") == -20  # signed 16-bit
    finally:
        line.close()
    dio = open_dio(f"zenoh:{dio_key}?connect=tcp/127.0.0.1:{port}", role="harness", name="b")
    try:
        dio.wait_for("DO1", True, 5.0)  # SRDY (a-contact, DO1 default)
        assert not dio.get("DO6")
        t_son = time.time_ns()
        dio.set("DI1", True)  # SON (DI1 default)
        t_brkr = dio.wait_for("DO6", True, 2.0)
        # P2.009 filter (2 ms) + P1.042 (150 ms), plus loopback latency of two zenoh hops.
        assert 150e6 <= t_brkr - t_son <= 400e6
        dio.set("DI1", False)
        dio.wait_for("DO6", False, 2.0)  # at rest: BRKR drops at once (L1362)
    finally:
        dio.close()


@pytest.mark.skipif(shutil.which("mbpoll") is None, reason="mbpoll (Debian package) not installed")
def test_mbpoll_reads_and_writes_parameters(drive_process, tmp_path: Path) -> None:
    link = tmp_path / "ttyMB"
    drive_process("--rs485", f"pty:{link}?baud=115200", "--station", "5")
    base = [
        "mbpoll",
        "-m",
        "rtu",
        "-a",
        "5",
        "-b",
        "115200",
        "-P",
        "none",
        "-s",
        "2",
        "-0",
        "-1",
        "-o",
        "2",
        "-t",
        "4",
        "-r",
        "0x0154",
    ]  # P1.042 (L8492)
    wrote = subprocess.run([*base, str(link), "150"], capture_output=True, text=True, timeout=20)
    assert wrote.returncode == 0, wrote.stdout + wrote.stderr
    read = subprocess.run([*base, "-c", "1", str(link)], capture_output=True, text=True, timeout=20)
    assert read.returncode == 0, read.stdout + read.stderr
    assert "[340]: \t150" in read.stdout or "150" in read.stdout.split("[340]:")[-1]
    bad = subprocess.run([*base, str(link), "5000"], capture_output=True, text=True, timeout=20)
    assert bad.returncode != 0  # out of range -> exception 03 (illegal data value)


def test_the_control_channel_answers_every_bad_line_and_keeps_serving(tmp_path) -> None:
    """`hil drive --control stdio`: an invalid UTF-8 line killed the channel under a strict
    locale; a huge off_ns blocked it for an hour; inject set any attribute with any value
    (an unknown option, a text where a time belongs) and the drive failed later; an
    unparseable line after a good one carried that one's id (an outside fuzz)."""
    import json
    import os
    import subprocess
    import sys

    env = dict(os.environ, PYTHONIOENCODING="utf-8:strict")
    p = subprocess.Popen([sys.executable, "-m", "hil.cli", "drive", "--dio",
                          f"virtual:ctl-{os.getpid()}", "--control", "stdio"],
                         stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=env)
    assert p.stdin is not None and p.stdout is not None

    def ask(raw: bytes) -> dict:
        p.stdin.write(raw + b"\n")
        p.stdin.flush()
        while True:
            line = p.stdout.readline().decode()
            assert line, "the drive stopped answering"
            if line.startswith("hil-ctl ") and '"reply"' in line:
                return json.loads(line[len("hil-ctl "):])

    try:
        for line in iter(p.stdout.readline, b""):
            if b"ready" in line:
                break
        assert ask(b"\xff\xfe not utf-8")["ok"] is False
        assert ask(b'{"id": 1, "op": "snapshot"}')["ok"] is True
        bad = ask(b"{not json")
        assert bad["ok"] is False and bad["reply"] is None  # not the previous command's id
        r = ask(b'{"id": 2, "op": "power_cycle", "off_ns": 3600000000000}')
        assert r["ok"] is False and "off_ns" in r["error"]
        r = ask(b'{"id": 3, "op": "inject", "options": {"nonexistent_opt": 5}}')
        assert r["ok"] is False and "unknown model option" in r["error"]
        r = ask(b'{"id": 4, "op": "inject", "options": {"sto_torque_cut_ms": "abc"}}')
        assert r["ok"] is False
        assert ask(b'{"id": 5, "op": "inject", "options": {"sto_torque_cut_ms": 2}}')["ok"]
        assert ask(b'{"id": 6, "op": "snapshot"}')["reply"] == 6
        p.stdin.close()
        assert p.wait(timeout=20) == 0  # closing stdin still stops it
    finally:
        if p.poll() is None:
            p.kill()
            p.wait(10)
