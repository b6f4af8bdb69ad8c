"""How a PR program ends, written afresh from the A3 manual (session 28, helper-113): an
alarm that turns the servo off ends it unfinished (AL249 "觸發的 PR 路徑編號大於 99",
L20099-20101; AL809 "指令解碼異常", L20229-20232); P5.007 reads n while not finished and
n+20000 once "命令發送完畢，且馬達定位完成" (L11185-11189). Injected clock."""

from __future__ import annotations

import pytest

from hil.model.drive import Drive
from tests.model.test_pr import make, put, run


def cmd_ok(d: Drive) -> bool:
    return d.dio.do_function_state("Cmd_OK")


def test_a_jump_to_pr100_ends_the_program_unfinished():
    """It had raised AL249 and still turned Cmd_OK and MC_OK on, P5.007 20001."""
    d = make()
    d.params.write("P6.002", 0x00000007)  # PR#1: TYPE 7 jump (L4148)
    d.params.write("P6.003", 100)  # to PR#100 (L4527)
    d.params.write("P5.007", 1)
    run(d, 0.2)
    assert "AL249" in d.alarms.active and not d.servo_on
    assert not cmd_ok(d) and not d.dio.do_function_state("MC_OK")
    assert d.params.read("P5.007") == 1  # not finished


@pytest.mark.parametrize("type_", [4, 5, 6, 9, 0xC, 0xD, 0xE, 0xF])
def test_an_undefined_type_is_a_decode_error(type_: int):
    """Only TYPE 1, 2, 3, 7, 8, A and B exist (L4148-4155): another is AL809, the program
    unfinished (it had been skipped and reported positioned, n+20000)."""
    d = make()
    d.params.write("P6.002", type_)
    d.params.write("P5.007", 1)
    run(d, 0.2)
    assert d.alarms.active == ("AL809",) and not d.servo_on
    assert not cmd_ok(d) and d.params.read("P5.007") == 1


def test_pr99_continuing_to_pr100_moves_nothing():
    d = make()
    put(d, 99, type_="auto", data=50000, spd=4)
    start = d.feedback_counts()
    d.params.write("P5.007", 99)
    run(d, 0.5)
    assert "AL249" in d.alarms.active and d.feedback_counts() == start
    assert not any("motion" in what for _t, what in d.pr.trace)


def test_a_finished_program_keeps_its_readback_through_a_servo_off():
    """P5.007 = n means "PR#n running, not finished" (L11189): a servo off after it had
    finished had turned 20001 back into 1."""
    d = make()
    put(d, 1, type_="single", data=20000, spd=4)
    d.params.write("P5.007", 1)
    run(d, 0.5)
    assert d.params.read("P5.007") == 20001
    d.set_di(1, False)
    run(d, 0.2)
    assert not d.servo_on and d.params.read("P5.007") == 20001
    d.set_di(1, True)
    run(d, 0.5)
    assert d.params.read("P5.007") == 20001
