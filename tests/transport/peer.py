"""Child process for the transport tests: `python peer.py MODE ARGS...`.

Prints `ready` once set up, and exits when its stdin closes (the test ended or died).

    can-echo <key> <mode> <endpoint> <listen|connect> <offset>
        answer every frame with id < 0x400 by id+offset and inverted data
    canopen-slave <key> <endpoint>
        a canopen.LocalNode (node 5) listening on the endpoint
"""

from __future__ import annotations

import sys
import threading


def _wait_stdin_eof() -> None:
    sys.stdin.read()


def can_echo(key: str, mode: str, endpoint: str, how: str, offset: str) -> None:
    import can

    kwargs = {how: [endpoint]}
    bus = can.Bus(interface="zenoh", channel=key, mode=mode, match_timeout=0, **kwargs)
    stop = threading.Event()

    def loop() -> None:
        while not stop.is_set():
            msg = bus.recv(0.05)
            if msg is None or msg.arbitration_id >= 0x400:
                continue
            bus.send(can.Message(arbitration_id=msg.arbitration_id + int(offset, 0),
                                 data=bytes(b ^ 0xFF for b in msg.data),
                                 is_extended_id=msg.is_extended_id))

    t = threading.Thread(target=loop)
    t.start()
    print("ready", flush=True)
    _wait_stdin_eof()
    stop.set()
    t.join(2)
    bus.shutdown()


def make_od():
    import canopen
    from canopen.objectdictionary import ODVariable, datatypes

    od = canopen.ObjectDictionary()
    dev_type = ODVariable("Device type", 0x1000)
    dev_type.data_type = datatypes.UNSIGNED32
    dev_type.default = 0x00020192  # CiA 402 servo drive
    name = ODVariable("Manufacturer device name", 0x1008)
    name.data_type = datatypes.VISIBLE_STRING
    name.default = "hil virtual ASDA-A3 over zenoh 0123"  # 35 B: segmented SDO
    for var in (dev_type, name):
        var.access_type = "ro"
        od.add_object(var)
    return od


def canopen_slave(key: str, endpoint: str) -> None:
    import canopen

    net = canopen.Network()
    net.NOTIFIER_CYCLE = 0.05
    net.connect(interface="zenoh", channel=key, listen=[endpoint])
    net.create_node(5, make_od())
    print("ready", flush=True)
    _wait_stdin_eof()
    net.disconnect()


if __name__ == "__main__":
    mode, *args = sys.argv[1:]
    {"can-echo": can_echo, "canopen-slave": canopen_slave}[mode](*args)
