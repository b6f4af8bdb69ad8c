"""P3.000 written over Modbus on a virtual drive whose bench gave it a station (found by an
outside probe, helper-124). P3.000 is the drive's station on the line (L10495-L10507) and
takes effect after a power cycle (●, L7014)."""

from __future__ import annotations

from pathlib import Path

from hil import clock
from hil.clock import VirtualClock
from hil.protocol import modbus as mb
from hil.transport.serial_line import open_serial
from hil.virtual.stack import DriveSpec, VirtualDriveStack


def test_a_station_written_over_modbus_is_the_station_after_a_power_cycle(tmp_path: Path) -> None:
    """The bench's `station: 5` won for ever: after P3.000 = 9 and a power cycle the drive
    still answered at 5 (and read back P3.000 = 9)."""
    clk = VirtualClock()
    with clock.use(clk):
        url = f"pty:{tmp_path}/l?baud=38400"
        stack = VirtualDriveStack(DriveSpec(rs485=url, station=5)).start()
        line = open_serial(f"serial:{tmp_path}/l?baud=38400")
        try:
            def ask(station: int, pdu: bytes) -> bytes | None:
                clock.sleep(0.05)
                line.write(mb.encode_adu(station, pdu, "rtu"))
                rep = line.read_frame(timeout=0.3)
                return None if rep is None else bytes(rep.data)

            read = mb.read_request(0x0300, 1)  # P3.000 at 0300H (L6697)
            assert ask(5, read) is not None
            assert ask(5, bytes([6, 3, 0, 0, 9])) is not None  # 06h: P3.000 = 9, echoed
            assert ask(9, read) is None  # ●: not before the power cycle
            stack.host.call(stack.drive.power_cycle)
            stack.modbus.power_cycle()
            clock.sleep(0.5)
            reply = ask(9, read)
            assert reply is not None and reply[0] == 9 and reply[-4:-2] == b"\x00\x09"
            assert ask(5, read) is None
        finally:
            line.close()
            stack.stop()


def test_a_station_written_by_sdo_moves_too_and_a_rewrite_of_the_same_value_does_not(
        tmp_path: Path) -> None:
    """helper-128: an SDO write of 2300h (P3.000, the node ID and the station) left the
    bench's station; a Modbus write of the value P3.000 already held handed the station to
    it (node ID 3, station 5: the drive moved to 3)."""
    clk = VirtualClock()
    with clock.use(clk):
        url = f"pty:{tmp_path}/l?baud=38400"
        stack = VirtualDriveStack(DriveSpec(rs485=url, station=5, node_id=3)).start()
        line = open_serial(f"serial:{tmp_path}/l?baud=38400")
        try:
            def ask(station: int) -> bool:
                clock.sleep(0.05)
                line.write(mb.encode_adu(station, mb.read_request(0x0300, 1), "rtu"))
                return line.read_frame(timeout=0.3) is not None

            def power_cycle() -> None:
                stack.host.call(stack.drive.power_cycle)
                stack.modbus.power_cycle()
                clock.sleep(0.5)

            assert ask(5) and stack.drive.params.get("P3.000") == 3
            line.write(mb.encode_adu(5, bytes([6, 3, 0, 0, 3]), "rtu"))  # P3.000 = 3 again
            assert line.read_frame(timeout=0.3) is not None
            power_cycle()
            assert ask(5) and not ask(3)
            stack.host.call(stack.drive.write_object, 0x2300, 0, 9)  # SDO 2300h: P3.000 = 9
            power_cycle()
            assert ask(9) and not ask(5)
        finally:
            line.close()
            stack.stop()
