"""Transport URL parsing (DESIGN.md "Transports are named by URL-like strings")."""

from __future__ import annotations

import pytest

from hil.transport.urls import SerialSettings, TransportUrlError, parse_url


def test_can_urls_from_design():
    u = parse_url("socketcan:vcan0", "can")
    assert (u.scheme, u.target, u.params) == ("socketcan", "vcan0", {})
    assert parse_url("virtual:bus0", "can").target == "bus0"
    u = parse_url("pcan:PCAN_USBBUS1?bitrate=500000", "can")
    assert (u.scheme, u.params) == ("pcan", {"bitrate": "500000"})


def test_zenoh_endpoints_several_and_mode():
    u = parse_url("zenoh:bench/can0?connect=tcp/127.0.0.1:7447,tcp/[::1]:7448&mode=client",
                  "can")
    ep = u.zenoh()
    assert u.target == "bench/can0"
    assert ep.mode == "client"
    assert ep.connect == ("tcp/127.0.0.1:7447", "tcp/[::1]:7448")
    assert ep.listen == ()
    # repeated keys join like commas
    ep = parse_url("zenoh:k?listen=tcp/127.0.0.1:1&listen=tcp/127.0.0.1:2", "dio").zenoh()
    assert ep.listen == ("tcp/127.0.0.1:1", "tcp/127.0.0.1:2")
    assert ep.mode == "peer"


def test_serial_urls():
    s = parse_url("serial:/dev/ttyUSB0?baud=115200&parity=E&bytesize=8&stopbits=1",
                  "serial").serial()
    assert s == SerialSettings(115200, "E", 8, 1.0)
    u = parse_url("pty:./ttyA?baud=9600", "serial")
    assert (u.scheme, u.target, u.serial().baud) == ("pty", "./ttyA", 9600)
    # A3 defaults: P3.001 X=3 -> 38400 (L10509-L10544), P3.002=6 -> 8,N,2 RTU (L10546-L10557)
    assert parse_url("pty:x", "serial").serial() == SerialSettings(38400, "N", 8, 2.0)
    u = parse_url("zenoh:bench/rs485?connect=tcp/127.0.0.1:7447&role=slave&baud=19200",
                  "serial")
    assert (u.params["role"], u.serial().baud) == ("slave", 19200)


def test_char_time_from_format():
    # 11-bit character for 8 data bits + parity or 2 stops (a3-comms §1.2, L15589-L15595)
    assert SerialSettings(38400, "N", 8, 2).bits_per_char == 11
    assert SerialSettings(38400, "E", 8, 1).bits_per_char == 11
    assert SerialSettings(9600, "N", 8, 1).char_time_s == pytest.approx(10 / 9600)
    assert SerialSettings(115200, "O", 7, 1).char_time_ns == round(10e9 / 115200)


def test_dio_urls():
    u = parse_url("modbus-tcp://127.0.0.1:5020?unit=3", "dio")
    assert (u.scheme, u.host, u.port, u.int_param("unit", 1, 0, 255)) == (
        "modbus-tcp", "127.0.0.1", 5020, 3)
    assert parse_url("virtual:drive1", "dio").target == "drive1"
    assert parse_url("zenoh:bench/dio?listen=tcp/127.0.0.1:7447", "dio").target == "bench/dio"


@pytest.mark.parametrize(("url", "kind", "words"), [
    ("", "can", "empty"),
    ("can0", "can", "<scheme>:<target>"),
    ("socketcan:", "can", "needs a target"),
    ("udp_multicast:239.0.0.1", "can", "forbidden"),
    ("nosuchbus:x", "can", "python-can interface"),
    ("pty:x", "can", "not a can transport"),
    ("socketcan:can0", "serial", "not a serial transport"),
    ("serial:/dev/ttyUSB0", "dio", "not a dio transport"),
    ("zenoh:bench/can0", "can", "at least one listen= or connect="),
    ("zenoh:bench/*?listen=tcp/127.0.0.1:1", "can", "must not contain"),
    ("zenoh:/bench?listen=tcp/127.0.0.1:1", "can", "empty chunk"),
    ("zenoh:k?listen=tcp/127.0.0.1:1&mode=router", "can", "mode='router'"),
    ("zenoh:k?listen=tcp/127.0.0.1:1&mode=client", "can", "needs a connect="),
    ("zenoh:k?listen=tcp/127.0.0.1:1&bitrate=1", "can", "unknown parameter(s) bitrate"),
    ("zenoh:k?listen=tcp/127.0.0.1:1&role=boss", "serial", "role='boss'"),
    ("serial:/dev/ttyUSB0?baud=fast", "serial", "baud='fast' is not an integer"),
    ("serial:/dev/ttyUSB0?baud=0", "serial", "outside 50..10000000"),
    ("serial:/dev/ttyUSB0?parity=X", "serial", "parity='X'"),
    ("serial:/dev/ttyUSB0?bytesize=9", "serial", "bytesize=9"),
    ("serial:/dev/ttyUSB0?stopbits=3", "serial", "stopbits"),
    ("serial:/dev/ttyUSB0?speed=9600", "serial", "unknown parameter(s) speed"),
    ("pty:x?baud", "serial", "not name=value"),
    ("modbus-tcp:127.0.0.1:502", "dio", "modbus-tcp://<host>:<port>"),
    ("modbus-tcp://127.0.0.1", "dio", "<host>:<port>"),
    ("modbus-tcp://127.0.0.1:99999", "dio", "outside 1..65535"),
    ("modbus-tcp://127.0.0.1:502?unit=300", "dio", "unit=300"),
    ("virtual:a?x=1", "dio", "unknown parameter(s) x"),
])
def test_errors_name_url_and_rule(url, kind, words):
    with pytest.raises(TransportUrlError) as e:
        parse_url(url, kind)
    assert repr(url) in str(e.value)
    assert words in str(e.value)


def test_unknown_kind():
    with pytest.raises(ValueError, match="kind 'bus'"):
        parse_url("virtual:x", "bus")
