"""The suite's rerun policy (tests/conftest.py), through pytester: a test marked
`integration` (real time on a shared host) is rerun once; a unit test never; nothing is
rerun in virtual time or when a bench file is given (a plan is never repeated on hardware
by itself)."""

from __future__ import annotations

from pathlib import Path

import pytest

pytest_plugins = ["pytester"]

PROBE = """
import pytest
N = {"n": 0}

@pytest.mark.integration
def test_fails_once():
    N["n"] += 1
    assert N["n"] > 1

@pytest.mark.integration
def test_fails_always():
    assert False

def test_unit_fails():
    assert False

@pytest.mark.integration
@pytest.mark.virtual_time
def test_virtual_time_fails():
    assert False

@pytest.mark.integration
def test_unmarked_virtual_run_fails():  # a plan on the built-in bench, not marked
    from hil import clock
    with clock.use(clock.VirtualClock()):
        pass
    assert False

@pytest.mark.integration
def test_virtual_and_real_run_fails():  # a test that compares both clocks
    from hil import clock
    with clock.use(clock.VirtualClock()):
        pass
    with clock.use(clock.REAL):
        pass
    assert False
"""


@pytest.fixture
def probe(pytester: pytest.Pytester) -> pytest.Pytester:
    pytester.makeconftest((Path(__file__).parents[1] / "conftest.py").read_text())
    pytester.makeini("[pytest]\nmarkers =\n    integration: real time\n"
                     "    virtual_time: virtual clock\n")
    pytester.makepyfile(test_probe=PROBE)
    return pytester


def test_integration_tests_are_rerun_once_and_unit_tests_never(probe, monkeypatch):
    monkeypatch.delenv("HIL_BENCH", raising=False)
    res = probe.runpytest("-p", "no:cacheprovider", "-ra")
    # once each; never a virtual-time test, even one marked integration (docs/clock.md), nor
    # one that ran only in virtual time unmarked; one that also ran on the wall clock is
    assert res.parseoutcomes() == {"passed": 1, "failed": 5, "rerun": 3}
    res.stdout.fnmatch_lines(["*FAILED*test_fails_always*", "*FAILED*test_unit_fails*"])
    res.stdout.fnmatch_lines(["*FAILED*test_virtual_time_fails*"])
    reruns = [ln for ln in res.stdout.lines if ln.startswith("RERUN")]
    assert not [ln for ln in reruns if "virtual_time_fails" in ln or "unmarked_virtual" in ln]
    assert [ln for ln in reruns if "test_virtual_and_real_run_fails" in ln]
    # why each rerun happened is in the log: the first attempt's traceback
    res.stdout.fnmatch_lines(["*rerun test summary info*", "RERUN *test_fails_once",
                              "*assert 1 > 1*", "PASSED *test_fails_once"])


def test_virtual_time_tests_are_not_rerun_even_with_reruns_on_the_command_line(probe,
                                                                               monkeypatch):
    """An outside audit: `pytest --reruns 2` reran a virtual-time test."""
    monkeypatch.delenv("HIL_BENCH", raising=False)
    res = probe.runpytest("-p", "no:cacheprovider", "-ra", "--reruns", "2",
                          "-k", "virtual_time")
    assert res.parseoutcomes() == {"failed": 1, "deselected": 5}


def test_nothing_is_rerun_against_a_bench_file(probe, monkeypatch):
    monkeypatch.setenv("HIL_BENCH", "my-bench.yaml")
    res = probe.runpytest("-p", "no:cacheprovider")
    assert res.parseoutcomes() == {"failed": 6}
