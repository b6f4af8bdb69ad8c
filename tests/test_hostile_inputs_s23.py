"""Bad input found in wave 3, session 23: a name with a trailing newline, and a PLC speed
that is not a whole number. Python's `$` matches before a final newline, so `"AL014\\n"`
passed every `^...$` check: a `wait_until` then waited for an alarm no drive raises, and a
tag `"brake\\n"` was never selected by `-m brake`."""

from __future__ import annotations

import pytest

from hil.bench.bench import load_bench, loads_bench
from hil.bench.yamlio import PlanFileError
from hil.gateway.keys import KeyError_, check_chunk
from hil.gateway.tls import is_loopback
from hil.plan.plan import loads_plan
from hil.plan.runner import check_plan, timing_specs
from hil.transport.urls import check_endpoint


def _refused(text: str, said: str) -> str:
    bench = load_bench()  # the built-in virtual bench
    with pytest.raises(PlanFileError) as e:
        check_plan(loads_plan(text, "p.yaml"), bench, timing_specs())
    msg = str(e.value)
    assert said in msg and "\n" not in msg, msg  # one line, naming the field
    return msg


BENCH = load_bench().text

# each: a step whose value ends in a newline; what the message names
STEPS = [
    ('wait_until: {alarm: "AL014\\n", timeout: 10ms}', "p.yaml:3: steps[0].wait_until.alarm"),
    ('write: {"P1.044\\n": 16777216}', "p.yaml:3: steps[0].write.'P1.044\\n'"),
    ('expect: {alarm: "AL014\\n"}', "p.yaml:3: steps[0].expect.alarm"),
    ('di: {"SON\\n": on}', "p.yaml:3: steps[0].di.'SON\\n'"),
    ('sdo: {"1016h:1\\n": 0x000A0064}', "p.yaml:3: steps[0].sdo"),
]


@pytest.mark.parametrize(("step", "said"), STEPS)
def test_a_name_with_a_trailing_newline_is_refused_with_file_line_field(step: str,
                                                                       said: str) -> None:
    good = step.replace("\\n", "")
    loads_plan(f"name: t\nsteps:\n  - {good}\n", "p.yaml")  # the same without: accepted
    _refused(f"name: t\nsteps:\n  - {step}\n", said)


def test_a_tag_with_a_trailing_newline_is_refused() -> None:
    with pytest.raises(PlanFileError, match=r"p.yaml:2: tags\[0\]: 'brake\\n'"):
        loads_plan('name: t\ntags: ["brake\\n"]\nsteps:\n  - wait: 1ms\n', "p.yaml")


def test_a_bench_drive_name_with_a_trailing_newline_is_refused() -> None:
    """(A wiring value is read with its blanks stripped: `"DI6:b\\n"` is DI6:b.)"""
    assert "  drive1:\n" in BENCH
    loads_bench(BENCH)
    with pytest.raises(PlanFileError, match=r"drive1\\n"):
        loads_bench(BENCH.replace("  drive1:\n", '  "drive1\\n":\n'))


def test_network_names_with_a_trailing_newline_are_refused() -> None:
    """A zenoh endpoint or key chunk must be exactly what the check saw."""
    assert is_loopback("tcp/127.0.0.1:7447")
    assert not is_loopback("tcp/127.0.0.1:7447\n")
    assert check_endpoint("tcp/127.0.0.1:7447") == "tcp/127.0.0.1:7447"
    with pytest.raises(ValueError):
        check_endpoint("tcp/127.0.0.1:7447\n")
    assert check_chunk("lab", "lab1") == "lab1"
    with pytest.raises(KeyError_):
        check_chunk("lab", "lab1\n")


PLC = """name: t
bench_requires: [virtual, motion, pulse, dio]
steps:
  - plc_program:
      axis: {{max_speed: 100000}}
      program:
        - {{SPD: {spd}, DRV: "ADR,+,100,Ps"}}
        - MD
"""


@pytest.mark.parametrize("spd", ["1000", "1000.0"])
def test_a_whole_plc_speed_is_taken(spd: str) -> None:
    check_plan(loads_plan(PLC.format(spd=spd), "p.yaml"), load_bench(), timing_specs())


@pytest.mark.parametrize("spd", ["1000.7", "0.5"])
def test_a_plc_speed_that_is_not_a_whole_number_is_refused(spd: str) -> None:
    """SPD is a constant or a register pair, a 32-bit number (001:38): 1000.7 Ps/s had been
    taken as is."""
    msg = _refused(PLC.format(spd=spd), "p.yaml:7: steps[0].plc_program.program[0].SPD")
    assert "a whole number" in msg
