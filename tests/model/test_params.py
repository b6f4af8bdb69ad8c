"""Parameter table and store, checked against the manual's own numbers."""

from __future__ import annotations

import pytest

from hil.model.errors import (
    OutOfRange,
    ProtectedParameter,
    ReadOnly,
    ServoOnLocked,
    UnknownParameter,
)
from hil.model.params import ParameterStore
from hil.profile.params import ParamTable, parse_name

_NAMES = (
    "P0.001 P0.002 P0.046 P0.049 P0.050 P0.051 P0.052 P1.001 P1.032 P1.034 P1.035 P1.038 P1.039 "
    "P1.042 P1.043 P1.044 P1.045 P1.054 P1.055 P1.087 P1.088 P2.008 P2.009 P2.030 P2.035 P2.065 "
    "P2.066 P2.068 P2.069 P2.070 P2.071 P4.006 P4.007 P4.024 P5.003 P5.004 P5.005 P5.006 P5.007 "
    "P5.008 P5.009 P6.000 P6.001"
)
REQUIRED = _NAMES.split(" ")
REQUIRED += [f"P2.{n:03d}" for n in (*range(10, 23), *range(36, 42))]
REQUIRED += [f"P3.{n:03d}" for n in (0, 1, 2, 3, 4, 6, 7, 9, 10, 11, 12)]
REQUIRED += [f"P4.{n:03d}" for n in range(5)] + [f"P5.{n:03d}" for n in range(20, 36)]


@pytest.fixture(scope="module")
def table() -> ParamTable:
    return ParamTable.load()


@pytest.fixture
def store(table: ParamTable) -> ParameterStore:
    return ParameterStore(table)


def test_required_parameters_present(table: ParamTable) -> None:
    missing = [p for p in REQUIRED if p not in table]
    assert not missing
    assert len(table) > 500  # all of chapter 8.3 incl. PR#1-99 (P6.002-P7.099)


def test_parse_name() -> None:
    assert parse_name("P1.042") == (1, 42)
    assert parse_name("P1-42") == (1, 42)
    with pytest.raises(UnknownParameter, match=r"P9\.001"):
        parse_name("P9.001")
    with pytest.raises(UnknownParameter, match="expected P<group"):
        parse_name("brake delay")


def test_addresses(table: ParamTable) -> None:
    assert table.spec("P1.042").modbus_address == 0x0154  # L8492
    assert table.spec("P0.049").modbus_address == 0x0062  # L7477
    assert table.spec("P2.070").modbus_address == 0x028C  # L10044
    assert table.spec("P1.044").od_index == 0x212C  # L18154-18156
    assert table.spec("P3.000").od_index == 0x2300
    assert table.by_modbus_address(0x0155).param == "P1.042"  # high word
    assert table.by_od_index(0x212C).param == "P1.044"
    with pytest.raises(UnknownParameter, match="0x0008"):  # P0.004 is reserved (L7126)
        table.by_modbus_address(0x0008)


def test_resolved_defaults(store: ParameterStore) -> None:
    assert store.read("P2.017") == 0x0021  # EMGS b-contact, L6981 / L1877 / L2882
    assert store.read("P5.003") == 0xEEEFEEFF  # L11085
    assert store.read("P5.009") == -2147483648  # L6906
    assert store.read("P1.038") == 100  # 10.0 rpm in comm units, L8407-8412
    assert store.read("P1.054") == 167772  # L8685
    assert store.read("P2.009") == 2  # L9229


def test_ranges(store: ParameterStore) -> None:
    store.write("P1.042", 1000)  # 0 ~ 1000 (L8492)
    with pytest.raises(OutOfRange, match=r"P1\.042.*1000"):
        store.write("P1.042", 1001)
    store.write("P1.043", -1000)  # -1000 ~ 1000 (L8503)
    with pytest.raises(OutOfRange, match=r"P1\.043"):
        store.write("P1.043", -1001)
    with pytest.raises(UnknownParameter):
        store.write("P0.004", 0)


def test_read_only_and_servo_on_lock(store: ParameterStore) -> None:
    with pytest.raises(ReadOnly, match=r"P0\.046"):
        store.write("P0.046", 1)  # ★ (L7460)
    store.servo_on = lambda: True
    with pytest.raises(ServoOnLocked, match=r"P1\.044"):
        store.write("P1.044", 1)  # ▲ (L8518)
    store.write("P1.042", 5)  # no ▲
    store.servo_on = lambda: False
    store.write("P1.044", 1)
    assert store.get("P1.044") == 1


def test_p2071_needs_p2008_key(store: ParameterStore) -> None:
    with pytest.raises(ProtectedParameter, match=r"P2\.008 = 271"):
        store.write("P2.071", 1)  # L10081, L16454
    store.write("P2.008", 271)
    store.write("P2.071", 1)


def test_p0001_only_zero_writable(store: ParameterStore) -> None:
    store.write("P0.001", 0)  # alarm reset (L7079-7083)
    with pytest.raises(OutOfRange, match="only 0"):
        store.write("P0.001", 0x500)


def test_power_cycle_parameter(store: ParameterStore) -> None:
    store.write("P3.000", 0x05)  # ● (L7014)
    assert store.read("P3.000") == 0x05
    assert store.get("P3.000") == 0x7F
    assert store.pending() == {"P3.000": 0x05}
    store.power_cycle()
    assert store.get("P3.000") == 0x05


def test_not_retained_reverts(store: ParameterStore) -> None:
    store.write("P4.006", 0x3)  # ■ (L7042)
    store.write("P1.042", 100)
    store.power_cycle()
    assert store.read("P4.006") == 0
    assert store.read("P1.042") == 100


def test_retained_survives_processes(table: ParamTable, tmp_path) -> None:
    path = tmp_path / "params.json"
    a = ParameterStore(table, retained_path=path)
    a.write("P1.042", 250)
    a.write("P3.006", 0x1)  # ■: not saved
    a.set_internal("P4.000", 0x13)  # drive-side values are saved by save() / power_cycle()
    a.save()
    b = ParameterStore(table, retained_path=path)
    assert b.read("P1.042") == 250
    assert b.read("P3.006") == 0
    assert b.read("P4.000") == 0x13


def test_modbus_words(store: ParameterStore) -> None:
    # P1.009 = 3000 is written as 0112H = 0x0BB8, 0113H = 0 (low word first, L7931-7934)
    store.modbus_write(0x0112, [0x0BB8, 0x0000])
    assert store.read("P1.009") == 3000
    assert store.modbus_read(0x0112, 2) == [0x0BB8, 0x0000]
    store.write("P1.045", 0x12345)  # 32-bit
    assert store.modbus_read(0x015A, 2) == [0x2345, 0x0001]
    store.modbus_write(0x015B, [0x0002])  # high half only: combined with the current low
    assert store.read("P1.045") == 0x22345
    store.write("P1.043", -1000)  # 16-bit signed: high word reads as sign extension
    assert store.modbus_read(0x0156, 2) == [0xFC18, 0xFFFF]
    store.modbus_write(0x0156, [0x0064])
    assert store.read("P1.043") == 100
    store.modbus_write(0x0157, [0x1234])  # high word of a 16-bit parameter: ignored
    assert store.read("P1.043") == 100
    with pytest.raises(UnknownParameter, match="0x0008"):
        store.modbus_read(0x0006, 4)


def test_modbus_write_is_all_or_nothing(store: ParameterStore) -> None:
    with pytest.raises(OutOfRange, match=r"P1\.043"):
        store.modbus_write(0x0154, [10, 0, 2000, 0])  # P1.042 ok, P1.043 out of range
    assert store.read("P1.042") == 0


def test_hooks(store: ParameterStore) -> None:
    seen = []
    store.on_write("P1.042", lambda n, old, new: seen.append((n, old, new)))
    store.write("P1.042", 7)
    store.on_read("P0.009", lambda: 1234)
    assert seen == [("P1.042", 0, 7)]
    assert store.read("P0.009") == 1234
    assert store.modbus_read(0x0012, 2) == [1234, 0]
    store.reset_defaults()
    assert store.read("P1.042") == 0


def test_p2030_returns_to_0_at_power_up_and_p1053_stops_at_6000() -> None:
    """P2.030 = 1 forces a software servo on; "its value goes back to 0 when the power comes
    back" (L9505). P1.053's range is 0 ~ 6000 W (L8667)."""
    from hil.model.errors import OutOfRange
    from hil.model.params import ParameterStore

    s = ParameterStore(autosave=False)
    s.write("P2.030", 1)
    s.power_cycle()
    assert s.read("P2.030") == 0 and s.get("P2.030") == 0
    s.write("P1.053", 6000)
    with pytest.raises(OutOfRange):
        s.write("P1.053", 6001)
