"""zenoh config, endpoint rules, session registry and the project router."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import pytest

from hil.transport import zenoh_net
from hil.transport.zenoh_net import ZenohConfigError, check_endpoint, make_config

pytestmark = pytest.mark.timeout(60)


def test_config_is_explicit_and_loopback(port):
    c = make_config("peer", connect=[f"tcp/127.0.0.1:{port}"])
    assert json.loads(c.get_json("mode")) == "peer"
    assert json.loads(c.get_json("scouting/multicast/enabled")) is False
    assert json.loads(c.get_json("scouting/gossip/enabled")) is False
    assert json.loads(c.get_json("scouting/delay")) == 0
    assert json.loads(c.get_json("listen/endpoints")) == []  # default would be tcp/[::]:0
    assert json.loads(c.get_json("connect/endpoints")) == [f"tcp/127.0.0.1:{port}"]


@pytest.mark.parametrize("ep", ["tcp/127.0.0.1:7447", "tcp/[::1]:7447", "tcp/localhost:1"])
def test_loopback_endpoints_accepted(ep):
    assert check_endpoint(ep) == ep


@pytest.mark.parametrize("ep", ["tcp/0.0.0.0:7447", "tcp/[::]:7447", "tcp/10.1.2.3:7447",
                                "udp/127.0.0.1:7447", "tcp/127.0.0.1", "tcp/127.0.0.1:99999"])
def test_other_endpoints_refused(ep):
    with pytest.raises(ZenohConfigError, match="allow_remote=True"):
        check_endpoint(ep)


def test_allow_remote_and_bad_modes():
    assert check_endpoint("tcp/10.1.2.3:7447", allow_remote=True)
    with pytest.raises(ZenohConfigError, match="mode 'hub'"):
        make_config("hub", listen=["tcp/127.0.0.1:1"])
    with pytest.raises(ZenohConfigError, match="at least one"):
        make_config("peer")
    with pytest.raises(ZenohConfigError, match="client"):
        make_config("client", listen=["tcp/127.0.0.1:1"])


def test_registry_closes_sessions(port):
    s = zenoh_net.open_session(make_config("peer", listen=[f"tcp/127.0.0.1:{port}"]))
    assert zenoh_net.open_sessions() >= 1
    zenoh_net.close_session(s)
    zenoh_net.close_session(s)  # idempotent
    assert s.is_closed()


def test_process_with_unclosed_callback_subscriber_exits(port):
    """feasibility §2.4 gotcha 1: without the registry this child hangs at exit."""
    code = textwrap.dedent(f"""
        from hil.transport import zenoh_net
        s = zenoh_net.open_session(zenoh_net.make_config(
            "peer", listen=["tcp/127.0.0.1:{port}"]))
        sub = s.declare_subscriber("k/x", lambda sample: None)
        print("opened", flush=True)
    """)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=20)
    assert r.returncode == 0, r.stderr
    assert "opened" in r.stdout


def test_router_starts_stops_and_refuses_remote(port):
    with pytest.raises(ZenohConfigError):
        zenoh_net.start_router(port, host="0.0.0.0")
    router = zenoh_net.start_router(port)
    try:
        assert router.endpoint == f"tcp/127.0.0.1:{port}"
        s = zenoh_net.open_session(make_config("client", connect=[router.endpoint]))
        assert s.info.routers_zid()
        zenoh_net.close_session(s)
    finally:
        router.stop()
    assert router.process.returncode is not None


def test_router_exits_when_parent_pipe_closes(port):
    router = zenoh_net.start_router(port)
    router.process.stdin.close()  # what happens when this process dies
    try:
        assert router.process.wait(10) == 0
    finally:
        router.stop()
