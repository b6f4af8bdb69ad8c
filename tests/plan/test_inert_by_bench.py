"""A DI function the virtual drive does not model is refused on a virtual bench only: a real
A3 has every function of table 8.1 (L15064-15191), so a real bench accepts the same plan."""

from __future__ import annotations

from dataclasses import replace

import pytest

from hil.bench.bench import load_bench
from hil.bench.yamlio import PlanFileError
from hil.model.dio import INERT_DI_FUNCTIONS
from hil.plan.plan import check_plan, loads_plan
from hil.plan.runner import timing_specs
from hil.profile.dio import DI_SYMBOLS

pytestmark = pytest.mark.skipif(not INERT_DI_FUNCTIONS, reason="every DI function is modelled")


def _inert() -> tuple[str, int]:
    func = sorted(INERT_DI_FUNCTIONS)[0]
    return func, 0x0100 | DI_SYMBOLS[func]  # a-contact


def _plans() -> tuple[str, str]:
    _, value = _inert()
    in_params = f"name: p\nparams:\n  P2.013: 0x{value:04X}\nsteps:\n  - wait: 1ms\n"
    in_write = f"name: p\nsteps:\n  - write: {{P2.013: 0x{value:04X}}}\n"
    return in_params, in_write


@pytest.mark.parametrize("which", [0, 1], ids=["plan params", "write step"])
def test_virtual_bench_refuses_an_inert_function_with_its_line(which):
    plan = loads_plan(_plans()[which], file="p.yaml")
    want = r"p\.yaml:(3|4): .*P2\.013: 0x01.. maps DI function \w+"
    with pytest.raises(PlanFileError, match=want):
        check_plan(plan, load_bench(), timing_specs())


@pytest.mark.parametrize("which", [0, 1], ids=["plan params", "write step"])
def test_real_bench_accepts_the_same_mapping(which):
    plan = loads_plan(_plans()[which], file="p.yaml")
    real = replace(load_bench(), virtual=False)
    check_plan(plan, real, timing_specs())


def test_expect_error_write_is_fine_on_a_virtual_bench():
    _, value = _inert()
    plan = loads_plan(f"name: p\nsteps:\n  - write: {{P2.013: 0x{value:04X}, via: sdo, "
                      "expect_error: 0x06090030}\n")
    check_plan(plan, load_bench(), timing_specs())


@pytest.mark.parametrize("func", ["PFQS", "JOGU", "JOGD", "TRQLM", "SPDLM", "ZCLAMP", "CCLR",
                                  "GAINUP"])
def test_virtual_bench_accepts_the_modelled_motion_functions(func):
    """Issue 13 item 6: these are modelled now (hil/model/di_functions.py; L15085-15121,
    L15209-15212, L15253), so a virtual bench takes them in params and write steps."""
    value = 0x0100 | DI_SYMBOLS[func]
    for text in (f"name: p\nparams:\n  P2.013: 0x{value:04X}\nsteps:\n  - wait: 1ms\n",
                 f"name: p\nsteps:\n  - write: {{P2.013: 0x{value:04X}}}\n"):
        check_plan(loads_plan(text, file="p.yaml"), load_bench(), timing_specs())
