"""`hil gateway` processes on a project router: several benches, several runners."""

from __future__ import annotations

import pytest

from hil.gateway.client import LeaseRefused, acquire
from hil.record.reader import Recording
from hil.transport.can_bus import open_can
from hil.transport.zenoh_net import start_router
from tests.gateway.conftest import bench_yaml, sdo_read_statusword


@pytest.mark.integration
def test_gateways_and_runners_through_a_router(tmp_path, free_port_factory, hil_process):
    router_port = free_port_factory()
    router = f"tcp/127.0.0.1:{router_port}"
    with start_router(router_port):
        gateways = []
        for name in ("bench1", "bench2"):
            drive_ep = f"tcp/127.0.0.1:{free_port_factory()}"
            hil_process("drive", "--name", "drive1", "--node-id", "1",
                        "--can", f"zenoh:hw/{name}/can0?listen={drive_ep}")
            bench = tmp_path / f"{name}.yaml"
            bench.write_text(bench_yaml(name, f"zenoh:hw/{name}/can0?connect={drive_ep}", None))
            record = tmp_path / f"{name}.mcap"
            gw = hil_process("gateway", "--bench", str(bench), "--lab", "lab1",
                             "--connect", router, "--record", str(record),
                             "--lease-timeout", "1")
            assert "ready: lab1/" + name in gw.lines[-1] and "still down" not in gw.lines[-1]
            gateways.append((gw, record))
        with acquire("lab1", "bench1", holder="runner-a", connect=[router], mode="client") as a, \
                acquire("lab1", "bench2", holder="runner-b", connect=[router],
                        mode="client") as b:
            with pytest.raises(LeaseRefused, match="leased by runner-a"):
                acquire("lab1", "bench1", holder="runner-b", connect=[router], mode="client")
            buses = [open_can(a.can_url("can0")), open_can(b.can_url("can0"))]
            try:
                for bus in buses:
                    ans = sdo_read_statusword(bus)
                    assert ans.data[0] == 0x4B and ans.sender_time_ns > 0
            finally:
                for bus in buses:
                    bus.shutdown()
        for gw, record in gateways:
            assert gw.stop() == 0 and gw.lines[-1] == "hil gateway: stopped"
            safety = [m for _t, _l, _p, m in Recording.open(record).messages("/safety")]
            assert safety[-1]["action"] == "safe state done"
