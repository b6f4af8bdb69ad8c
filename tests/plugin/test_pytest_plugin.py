"""The pytest plugin itself, exercised through pytester (a real inner pytest run)."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import pytest

pytest_plugins = ["pytester"]

INNER = '''
import pytest
from hil.pytest_plugin import TimingFailure

@pytest.mark.hil
def test_brake_release(hil_drive, hil_recorder, hil_check):
    hil_drive.write_param("P1.042", 80)
    hil_drive.set_function("SON", True)
    hil_drive.dio.wait_for("DO6", True, 2.0)      # BRKR on DO6 on the virtual bench
    verdicts = hil_check("servo_on_brake", params={"P1.042": 80})
    assert any(v.status == "pass" for v in verdicts)

@pytest.mark.hil
def test_deviation_reads_well(hil_drive, hil_check):
    hil_drive.write_param("P1.042", 80)
    hil_drive.set_function("SON", True)
    hil_drive.dio.wait_for("DO6", True, 2.0)
    with pytest.raises(TimingFailure, match=r"BRKR rises P1.042 after servo on: FAIL: .*allowed"):
        hil_check("servo_on_brake", params={"P1.042": 20})   # a wrong expectation fails
'''


def test_fixtures_recording_and_junit_property(pytester: pytest.Pytester, tmp_path) -> None:
    pytester.makepyfile(test_inner=INNER)
    junit = tmp_path / "junit.xml"
    result = pytester.runpytest_subprocess(
        "-m", "hil", "-p", "no:cacheprovider", f"--junitxml={junit}",
        f"--hil-out={tmp_path / 'out'}", "-q",
    )
    result.assert_outcomes(passed=2)
    props = [p.get("value") for p in ET.parse(junit).iter("property")
             if p.get("name") == "recording"]
    assert len(props) == 2
    for path in props:  # relative to the JUnit file, as `hil run` writes it
        assert path.endswith(".mcap") and path.startswith("out/")
    props = [str(tmp_path / p) for p in props]
    from hil.record.reader import Recording

    rec = Recording.open(props[0])
    topics = set(rec.topics())
    assert "/dio/drive1/DO6" in topics and "/drive/drive1/state" in topics
    assert "/safety" in topics  # the bench was driven to its safe state after the test


def test_marker_selects_and_option_is_known(pytester: pytest.Pytester) -> None:
    pytester.makepyfile(test_sel="""
import pytest
@pytest.mark.hil
def test_a(hil_bench):
    assert hil_bench.virtual
def test_b():
    pass
""")
    result = pytester.runpytest_subprocess("-m", "hil", "-q", "-p", "no:cacheprovider")
    result.assert_outcomes(passed=1, deselected=1)
    bad = pytester.runpytest_subprocess("--hil-bench", "/nonexistent.yaml", "-m", "hil", "-q",
                                        "-p", "no:cacheprovider")
    assert bad.ret != 0
    assert "nonexistent.yaml" in bad.stdout.str() + bad.stderr.str()
