"""A raw SDO write to a 2xxxh object is the parameter it sets (Pa-bc <=> 2aBCh, L18154-18156),
read with the parameter's own size and sign; any other object is no parameter."""

from __future__ import annotations

import pytest

from hil.bench.param_rules import sdo_parameter


@pytest.mark.parametrize(("index", "sub", "value", "want"), [
    (0x212A, 0, 100, ("P1.042", 100)),               # P1.042 MBT1 (L18156 example form)
    (0x2300, 0, 0x7F, ("P3.000", 0x7F)),             # P3.000 node address
    (0x2109, 0, 0xFFFFFFFF, ("P1.009", -1)),         # signed 32-bit: two's complement
    (0x210C, 0, 0xFFFFFF9C, ("P1.012", -100)),       # signed 16-bit: the low word's sign
    (0x210C, 0, -100, ("P1.012", -100)),
    (0x6040, 0, 0x0F, None),                         # a CiA 402 object
    (0x212A, 1, 100, None),                          # a parameter is sub 0 only
    (0x2FFF, 0, 1, None),                            # no such parameter
])
def test_sdo_parameter(index, sub, value, want):
    assert sdo_parameter(index, sub, value) == want
