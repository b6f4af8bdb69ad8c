"""Homing over the wire: `hil drive` on a zenoh CAN bus, homed by canopen's BaseNode402 and by
our own Cia402Driver (issue 7: "canopen's BaseNode402.homing() works against the virtual drive
over the zenoh bus").

Default bench mechanics: home cam ORGP on [-0.5, +0.5] rev (physically on DI9), Z at every
whole revolution, the axis starts at 0 (on the cam). P2.036 = 0x0124 maps DI9 to ORGP
(a-contact, L15194); NL/PL are the factory DI6/DI7.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import canopen
import pytest

from hil.drivers.cia402 import Cia402Driver

pytestmark = pytest.mark.integration
EDS = str(Path(__file__).parents[2] / "fixtures" / "drive" / "a3.eds")
NODE = 5


@pytest.fixture
def network():
    canopen.Network.NOTIFIER_CYCLE = 0.05
    net = canopen.Network()
    yield net
    net.disconnect()


def start_drive(drive_process, tmp_path: Path, port: int) -> str:
    params = tmp_path / "params.json"
    params.write_text(json.dumps({"P2.036": 0x0124}))  # DI9 = ORGP, a-contact (L15194)
    key = f"t{port}/can"
    drive_process(
        "--can",
        f"zenoh:{key}?listen=tcp/127.0.0.1:{port}",
        "--node-id",
        str(NODE),
        "--params",
        str(params),
    )
    return key


def test_basenode402_homing_over_zenoh(drive_process, network, tmp_path, free_port_factory):
    port = free_port_factory()
    key = start_drive(drive_process, tmp_path, port)
    network.connect(interface="zenoh", channel=key, connect=[f"tcp/127.0.0.1:{port}"])
    node = canopen.BaseNode402(NODE, EDS)
    network.add_node(node)
    node.nmt.state = "PRE-OPERATIONAL"
    node.setup_402_state_machine()
    node.nmt.state = "OPERATIONAL"
    # Method 3 (CiA 402: positive home switch, index on its - side), started on the cam:
    # - at 6099h sub2 until ORGP off (-0.5 rev), on to the next Z (-1 rev), back there.
    node.sdo[0x6098].raw = 3
    node.sdo[0x6099][1].raw = 1200  # 120 rpm (0.1 rpm, L18998)
    node.sdo[0x6099][2].raw = 500  # 50 rpm, the maximum (L19007)
    node.sdo[0x609A].raw = 100  # ms per 3000 rpm (L19021)
    node.sdo[0x607C].raw = 5000
    t0 = time.monotonic()
    assert node.homing(timeout=15) is True
    assert time.monotonic() - t0 > 0.5  # it moved (1 rev at 50 rpm), no fixed delay
    sw = node.sdo[0x6041].raw
    assert sw & 0x1000 and not sw & 0x2000  # bit 12 attained, bit 13 clear (L18337-18338)
    assert node.sdo[0x6064].raw == node.sdo[0x607C].raw == 5000  # 6064h = 607Ch
    node.state = "SWITCH ON DISABLED"


def test_cia402_driver_home_over_zenoh(drive_process, network, tmp_path, free_port_factory):
    port = free_port_factory()
    key = start_drive(drive_process, tmp_path, port)
    network.connect(interface="zenoh", channel=key, connect=[f"tcp/127.0.0.1:{port}"])
    driver = Cia402Driver(network, NODE, eds=EDS)
    driver.node.nmt.state = "OPERATIONAL"
    # Method 34: the next index pulse moving + (L18968): from 0 rev, Z at +1 rev.
    sw = driver.home(34, speeds=(1200, 500), accel=100, offset=-700, timeout=15)
    assert sw & 0x1000 and not sw & 0x2000
    assert driver.read(0x6064) == -700
    # Method 21 (negative home switch, no Z): the cam's upper edge crossed +.
    sw = driver.home(21, speeds=(1200, 500), accel=100, offset=250, timeout=15)
    assert sw & 0x1000 and not sw & 0x2000
    assert driver.read(0x6064) == 250
    driver.shutdown()
