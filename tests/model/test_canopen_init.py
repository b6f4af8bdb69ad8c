"""P3.012.Z = 0: CANopen mode loads fixed values at power-up / communication reset.

Table "初始化時讀出的相關變數" (L10737-10745, repeated in §12.1 L16847-16855): P1.032 = 0x0010,
P2.035 = 50331648, P1.047 = 100, P1.049 = 0, P1.038 = 100, home offset = 0, P1.044 = 1,
P1.045 = 1; with Z = 1 the EEPROM values stay. CANopen mode is P1.001 = 0x0C (L16842).
"""

from __future__ import annotations

import pytest

from hil.model.drive import Drive
from hil.units import MS

TABLE = {
    "P1.032": 0x0010,
    "P2.035": 50331648,
    "P1.047": 100,
    "P1.049": 0,
    "P1.038": 100,
    "P1.044": 1,
    "P1.045": 1,
}
# EEPROM values a user configured (all different from the table)
CONFIGURED = {
    "P1.032": 0x0000,
    "P2.035": 1000000,
    "P1.047": 20,
    "P1.049": 5,
    "P1.038": 50,
    "P1.044": 128,
    "P1.045": 10,
}


def values(drive: Drive) -> dict[str, int]:
    return {name: drive.params.get(name) for name in TABLE}


def test_canopen_mode_z0_loads_the_table_at_power_up() -> None:
    """L10731, L10737-10745: Z = 0 -> the P parameters read the CANopen values."""
    drive = Drive(inputs={8: True}, params={"P1.001": 0x0C, "P3.012": 0x0000} | CONFIGURED)
    assert values(drive) == TABLE
    assert drive.read_object(0x212C) == 1  # 212Ch = P1.044, "預設值 1" (L18175-18184)
    assert drive.read_object(0x6093, 1) == 1 and drive.read_object(0x6093, 2) == 1
    assert drive.read_object(0x607C) == 0  # home offset (L10744)
    assert drive.axis.zero_speed_rpm == 10.0  # P1.038 = 100 -> 10.0 rpm
    assert drive.axis.stop_mode == 1  # P1.032.Y = 1: free run (L8323)


def test_canopen_mode_z1_keeps_eeprom_values() -> None:
    """L10733: Z = 1 -> the parameters keep their setting (the 0x0100 advice, L16847)."""
    drive = Drive(inputs={8: True}, params={"P1.001": 0x0C, "P3.012": 0x0100} | CONFIGURED)
    assert values(drive) == CONFIGURED


def test_other_control_modes_keep_eeprom_values() -> None:
    drive = Drive(inputs={8: True}, params={"P1.001": 0x00} | CONFIGURED)
    assert values(drive) == CONFIGURED
    assert drive.read_object(0x212C) == 128


@pytest.mark.parametrize("kind", ["reset communication", "reset node"])
def test_communication_reset_reloads(kind: str) -> None:
    """L10731: "在驅動器重新上下電或是進行通訊重置後" (power cycle or communication reset)."""
    drive = Drive(inputs={8: True}, params={"P1.001": 0x0C})
    drive.write_object(0x212C, 0, 128)
    drive.write_object(0x607C, 0, 5000)
    drive.params.write("P1.038", 30)
    drive.advance(5 * MS)
    drive.nmt_reset(kind)
    assert values(drive) == TABLE
    assert drive.read_object(0x607C) == 0
    assert drive.read_object(0x6093, 1) == 1


def test_power_cycle_reloads_after_a_sdo_write() -> None:
    drive = Drive(inputs={8: True}, params={"P1.001": 0x0C})
    drive.write_object(0x212D, 0, 7)  # P1.045
    assert drive.params.get("P1.045") == 7
    drive.power_cycle()
    assert drive.params.get("P1.045") == 1
