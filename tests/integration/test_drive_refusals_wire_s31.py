"""`hil drive` says what its pulse face refused (session 31: a PLC whose messages a `hil
drive` dropped saw nothing on its output; the CANopen and Modbus faces answer on the wire,
the pulse line has no answer). Real time, loopback only."""

from __future__ import annotations

import time

import pytest

from hil.transport.zenoh_net import close_session, make_config, open_session, wait_connected

pytestmark = [pytest.mark.integration, pytest.mark.timeout(90)]


def _wait_line(proc, text: str, timeout_s: float = 10.0) -> str:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        for line in proc.lines:
            if text in line:
                return line
        time.sleep(0.05)
    raise AssertionError(f"no line with {text!r} in {proc.lines[-10:]}")


def test_hil_drive_prints_the_pulse_messages_it_refused(drive_process,
                                                        free_port_factory) -> None:
    pp = free_port_factory()
    key = f"t{pp}/pulse"
    proc = drive_process("--pulse", f"zenoh:{key}?listen=tcp/127.0.0.1:{pp}")
    s = open_session(make_config("peer", connect=[f"tcp/127.0.0.1:{pp}"]))
    try:
        wait_connected(s, 5, what="a PLC")
        pub = s.declare_publisher(f"{key}/seg")
        time.sleep(0.5)  # the drive's subscriber routed
        pub.put(b"not json")
        line = _wait_line(proc, "malformed message(s) on the pulse line")
        assert "refused 1 " in line and "(1 in all)" in line and "not JSON" in line
        for _ in range(3):  # JSON, but no segment: the field is named
            pub.put(b'{"freq": "fast", "direction": 1, "count": 5}')
        line = _wait_line(proc, "(4 in all)")
        assert "freq" in line
    finally:
        close_session(s)
    assert proc.stop() == 0
