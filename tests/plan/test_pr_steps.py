"""PR plan steps and the DeltaPr driver (docs/pr.md)."""

from __future__ import annotations

import pytest

from hil.bench.yamlio import Checker, PlanFileError, load_yaml_text
from hil.drivers.delta_pr import DeltaPr, PrTableError
from hil.model.drive import Drive
from hil.plan.steps import parse_steps
from hil.units import MS

TEXT = """steps:
  - pr_table:
      1: {type: single, data: 1000}
      2: {type: jump, data: 120}
"""


def test_check_rejects_a_table_the_drive_refuses() -> None:
    """A jump to PR#120 raises AL249 on the drive (L20099): refused at load, with the line."""
    doc = load_yaml_text(TEXT, "p.yaml")
    with pytest.raises(PlanFileError) as e:
        parse_steps(Checker("p.yaml"), doc["steps"], 1)
    assert ":4:" in str(e.value) and "AL249" in str(e.value)


def test_driver_writes_reads_back_triggers_and_waits() -> None:
    """DeltaPr over the drive's parameters: table, P5.007 trigger, n+20000 read-back (L11185)."""
    d = Drive(inputs={8: True}, params={"P2.010": 0x0101, "P1.001": 0x0001}, sensors={})
    d.set_di(1, True)
    d.advance(400 * MS)
    class Access:  # the model's parameters, as a bus would reach them
        read_param = staticmethod(d.params.read)
        write_param = staticmethod(d.params.write)

    pr = DeltaPr(Access(), sleep=lambda s: d.advance(int(s * 1e9)), clock=lambda: d.now / 1e9)
    pr.write_table({4: {"type": "single", "data": 30000, "spd": 4}})
    assert pr.read_path(4).data == 30000
    pr.trigger(4)
    assert pr.wait(4, "in_position", timeout_s=2) > 0
    assert pr.status() == (4, "in_position")
    with pytest.raises(PrTableError, match="L4451"):
        pr.write_table({1: {"type": "speed", "data": 70000}})


@pytest.mark.parametrize("data", [1.5, 100000.0, True])
def test_a_pr_data_word_that_is_not_an_integer_is_refused(data):
    """A PR's data is one 32-bit word (L4440): 1.5 had been written to P6.003 as it was
    (helper-101); only whole numbers are words."""
    from hil.drivers.delta_pr import PrTableError, table_words

    with pytest.raises(PrTableError, match="an integer"):
        table_words({1: {"type": "auto", "data": data, "spd": 4, "dly": 1}})
    assert table_words({1: {"type": "auto", "data": 100000, "spd": 4, "dly": 1}})


def test_pr_wait_takes_its_last_look_at_its_timeout():
    """A review (helper-133), the rule wait_until keeps: `pr_wait` polled P5.007 every 10 ms
    and slept past its timeout, so a PR in position up to a poll late still passed."""
    from hil.drivers.delta_pr import DeltaPr

    now = [0.0]

    class Access:  # PR#1 in position (20000 + 1, L11185) from 25 ms on
        def read_param(self, name):
            return 20001 if now[0] >= 0.025 else 1

    def sleep(s):
        now[0] += s

    pr = DeltaPr(Access(), poll_s=0.01, sleep=sleep, clock=lambda: now[0])
    with pytest.raises(TimeoutError, match=r"PR#1 not in_position after 0\.022 s"):
        pr.wait(1, "in_position", timeout_s=0.022)
    assert now[0] == pytest.approx(0.022)  # looked at the timeout, not at 30 ms
    now[0] = 0.0
    assert pr.wait(1, "in_position", timeout_s=0.025) == pytest.approx(0.025)
