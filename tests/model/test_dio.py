"""DI/DO: contacts, P2.009 filter, software DI, DO mapping, P0.046, overlay."""

from __future__ import annotations

import pytest

from hil.model.dio import DigitalIO
from hil.model.errors import UnknownFunction
from hil.model.events import DoChanged
from hil.model.params import ParameterStore
from hil.model.timebase import Scheduler
from hil.profile.params import ParamTable
from hil.units import MS


@pytest.fixture(scope="module")
def ptable() -> ParamTable:
    return ParamTable.load()


class Rig:
    def __init__(self, ptable: ParamTable, mapping_on_write: bool = True) -> None:
        self.params = ParameterStore(ptable)
        self.sched = Scheduler()
        self.events: list[DoChanged] = []
        self.dio = DigitalIO(self.params, self.sched, self.events.append,
                             mapping_on_write=mapping_on_write)

    def advance(self, dt: int) -> None:
        self.sched.now += dt
        self.sched.run_due()


@pytest.fixture
def rig(ptable) -> Rig:
    return Rig(ptable)


def test_default_mapping(rig: Rig) -> None:
    d = rig.dio
    assert [d.di_function(n) for n in range(1, 9)] == [
        "SON", "CCLR", "TCM0", "TCM1", "ARST", "NL", "PL", "EMGS",
    ]  # fmt: skip  # L9238-9314, P2.017 = 0x0021
    assert [d.do_function(n) for n in range(1, 6)] == ["SRDY", "ZSPD", "HOME", "TPOS", "ALRM"]


def test_filter_stable_for_p2009(rig: Rig) -> None:
    # P2.009 = 2 ms (L9229): a 1 ms glitch is not accepted, a level held 2 ms is, at +2 ms.
    d = rig.dio
    d.set_input(1, True)
    rig.advance(1 * MS)
    d.set_input(1, False)
    rig.advance(5 * MS)
    assert not d.function_active("SON")
    d.set_input(1, True)
    rig.advance(2 * MS - 1)
    assert not d.function_active("SON")
    rig.advance(1)
    assert d.function_active("SON")


def test_filter_accepts_level_due_at_the_same_instant(rig: Rig) -> None:
    d = rig.dio
    d.set_input(1, True)
    rig.sched.now += 2 * MS  # timers not run yet
    d.set_input(1, False)  # the 2 ms level is accepted first
    assert d.function_active("SON")
    rig.advance(2 * MS)
    assert not d.function_active("SON")


def test_b_contact_emgs_on_di8(rig: Rig) -> None:
    d = rig.dio
    rig.params.write("P2.009", 0)
    seen = []
    d.on_function("EMGS", seen.append)
    assert d.function_active("EMGS")  # open b-contact = emergency stop active (L2882)
    d.set_input(8, True)
    assert not d.function_active(0x21)
    d.set_input(8, False)
    assert d.function_active("EMGS")
    assert seen == [False, True]


def test_software_di(ptable) -> None:
    rig = Rig(ptable, mapping_on_write=False)  # option mapping_effect: power_cycle
    d, p = rig.dio, rig.params
    p.write("P4.007", 0x0001)  # SDI1 on
    assert not d.function_active("SON")  # P3.006 bit0 = 0: terminal is the source
    p.write("P3.006", 0x0001)  # L10585-10606
    assert d.function_active("SON")
    assert p.read("P4.007") & 0x1  # read shows the mixed DI state (L10901)
    p.write("P2.038", 0x0102)  # VDI11 = ARST (a); needs a power cycle
    p.write("P3.006", 0x0401)
    p.write("P4.007", 0x0401)
    assert not d.function_active("ARST")
    p.power_cycle()  # ■ P3.006 / P4.007 revert
    d.power_cycle()
    assert d.di_function(11) == "ARST"
    p.write("P3.006", 0x0400)
    p.write("P4.007", 0x0400)
    assert d.function_active("ARST")


def test_unknown_di_code_names_parameter(rig: Rig) -> None:
    with pytest.raises(UnknownFunction, match=r"0x07.*P2\.012"):
        rig.params.write("P2.012", 0x0107)  # no DI code 0x07 in table 8.1
    with pytest.raises(UnknownFunction, match=r"P2\.041"):
        rig.params.write("P2.041", 0x010A)  # no DO code 0x0A in table 8.2


def test_do5_alrm_b_contact_and_p0046(rig: Rig) -> None:
    d = rig.dio
    assert d.do_level(5)  # b-contact ALRM conducts while no alarm (P2.022 = 0x0007)
    d.set_do_function("ALRM", True)
    assert not d.do_level(5)
    assert rig.events[-1] == DoChanged(0, 5, False, "ALRM")
    d.set_do_function("SRDY", True)
    d.set_do_function("BRKR", True)
    assert d.do_level(1)
    assert rig.params.read("P0.046") == (1 << 0) | (1 << 6) | (1 << 7)  # L7460-7475


@pytest.mark.parametrize("on_write", [True, False])
def test_a_mapping_write_takes_effect_as_the_option_says(ptable, on_write: bool) -> None:
    # the parameter table marks no P2.010-P2.022 / P2.036-P2.041 "power cycle" and L2981
    # clears an unmapped EMGS's alarm with ARST: at once (default); L9339 advises a restart
    # after a change: option mapping_effect = power_cycle reads the mapping at power-up only
    rig = Rig(ptable, mapping_on_write=on_write)
    d, p = rig.dio, rig.params
    p.write("P2.041", 0x0108)  # DO6 = BRKR (a)
    d.set_do_function("BRKR", True)
    assert d.do_level(6) is on_write
    d.power_cycle()
    assert d.do_level(6)


def test_spo_follows_p4006(rig: Rig) -> None:
    p, d = rig.params, rig.dio
    p.write("P2.041", 0x0130)  # DO6 = SPO_0
    d.power_cycle()
    p.write("P4.006", 0x0001)
    assert d.do_level(6)


def test_abs_overlay(rig: Rig) -> None:
    d, p = rig.dio, rig.params
    p.write("P2.009", 0)
    p.write("P2.013", 0x0112)  # DI4 = POS1 (a)
    d.power_cycle()
    d.set_input(4, True)
    assert d.function_active("POS1")
    d.overlay()
    d.set_input(4, False)
    assert not d.function_active("ABSQ")
    assert d.function_active("POS1")  # held at the level it had (L15137)
    d.set_do_function("ABSR", True)
    assert d.do_level(2) and d.do_function(2) == "ABSR"
    assert not d.do_level(3)
    d.clear_overlay()
    assert not d.function_active("POS1")
    assert d.do_function(2) == "ZSPD"
