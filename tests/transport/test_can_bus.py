"""open_can: URL -> python-can bus, taps, and the socketcan path without the kernel module."""

from __future__ import annotations

import errno
import socket

import can
import pytest

from hil.transport import can_bus
from hil.transport.can_bus import TappedBus, open_can
from hil.transport.urls import TransportUrlError

pytestmark = pytest.mark.timeout(30)


def test_virtual_with_tap(tap):
    a = open_can("virtual:tb0", tap=tap, name="can0")
    b = open_can("virtual:tb0")
    try:
        assert isinstance(a, TappedBus)
        a.send(can.Message(arbitration_id=0x000, data=b"\x01\x05"))  # NMT start node 5
        assert b.recv(1).data == b"\x01\x05"
        b.send(can.Message(arbitration_id=0x705, data=b"\x05"))  # heartbeat, operational
        assert a.recv(1).arbitration_id == 0x705
    finally:
        a.shutdown()
        b.shutdown()
    assert [(f[0], f[1].arbitration_id, f[2]) for f in tap.can_frames] == [
        ("can0", 0x000, "tx"), ("can0", 0x705, "rx")]
    assert all(isinstance(f[3], int) and f[4] is None for f in tap.can_frames)


def test_filters_apply_after_the_tap(tap):
    a = open_can("virtual:tb1", tap=tap)
    b = open_can("virtual:tb1")
    try:
        a.set_filters([{"can_id": 0x185, "can_mask": 0x7FF}])
        b.send(can.Message(arbitration_id=0x285, data=b"\0"))
        b.send(can.Message(arbitration_id=0x185, data=b"\0"))
        assert a.recv(1).arbitration_id == 0x185
    finally:
        a.shutdown()
        b.shutdown()
    assert [f[1].arbitration_id for f in tap.can_frames] == [0x285, 0x185]  # all recorded


def test_zenoh_tap_has_sender_time(port, tap):
    ep = f"tcp/127.0.0.1:{port}"
    a = open_can(f"zenoh:tz/can0?listen={ep}", tap=tap)
    b = open_can(f"zenoh:tz/can0?connect={ep}")
    try:
        b.send(can.Message(arbitration_id=0x80, data=b""))  # SYNC
        msg = a.recv(2)
        assert msg is not None
    finally:
        a.shutdown()
        b.shutdown()
    ((bus, _frame, direction, t, source_t),) = tap.can_frames
    assert (bus, direction, source_t) == ("tz/can0", "rx", msg.sender_time_ns)
    assert source_t <= t


def test_url_params_pass_through(monkeypatch):
    seen = {}
    real_bus = can.Bus

    def fake_bus(**kwargs):
        seen.update(kwargs)
        return real_bus(interface="virtual", channel="fake")

    monkeypatch.setattr(can_bus.can, "Bus", fake_bus)
    open_can("socketcan:can0?bitrate=500000&receive_own_messages=true").shutdown()
    assert seen == {"interface": "socketcan", "channel": "can0", "bitrate": 500000,
                    "receive_own_messages": True, "ignore_config": True}
    seen.clear()
    open_can("pcan:PCAN_USBBUS1?bitrate=250000", fd=False).shutdown()
    assert seen["interface"] == "pcan" and seen["bitrate"] == 250000 and seen["fd"] is False
    seen.clear()
    open_can("zenoh:b/can1?connect=tcp/127.0.0.1:7447&mode=client").shutdown()
    assert seen == {"interface": "zenoh", "channel": "b/can1", "mode": "client", "listen": [],
                    "connect": ["tcp/127.0.0.1:7447"], "ignore_config": True}


def test_socketcan_missing_af_can_is_clear(monkeypatch):
    def no_af_can(**kwargs):
        raise OSError(errno.EAFNOSUPPORT, "Address family not supported by protocol")

    monkeypatch.setattr(can_bus.can, "Bus", no_af_can)
    with pytest.raises(TransportUrlError, match=r"'socketcan:can0'.*SocketCAN \(AF_CAN\)"):
        open_can("socketcan:can0")


def test_socketcan_no_such_interface_is_clear(monkeypatch):
    def no_dev(**kwargs):
        raise can.CanInitializationError("bind failed") from OSError(errno.ENODEV, "No dev")

    monkeypatch.setattr(can_bus.can, "Bus", no_dev)
    with pytest.raises(TransportUrlError, match=r"'socketcan:can9'.*no CAN interface 'can9'"):
        open_can("socketcan:can9")


def test_socketcan_real_call_on_this_machine():
    """The real python-can socketcan path: here (no CONFIG_CAN) it must fail clearly."""
    try:
        s = socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW)
    except (OSError, AttributeError):
        with pytest.raises(TransportUrlError, match=r"'socketcan:vcan0'.*AF_CAN"):
            open_can("socketcan:vcan0")
    else:
        s.close()
        pytest.skip("this machine has SocketCAN; covered by the monkeypatched tests")


def test_unknown_interface_error_names_url():
    with pytest.raises(TransportUrlError, match="'kvaser:0'"):
        open_can("kvaser:0")  # known to python-can, driver absent here
