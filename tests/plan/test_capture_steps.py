"""CAPTURE / COMPARE plan steps and the `latch` assertion (docs/capture.md)."""

from __future__ import annotations

import io
import math

import pytest

from hil.bench.bench import load_bench
from hil.bench.yamlio import Checker, PlanFileError, load_yaml_text
from hil.plan.plan import find_plans, load_plan, loads_plan
from hil.plan.runner import run_plans
from hil.plan.steps import parse_steps
from hil.report.html import write_html
from hil.timing.latch import Edge, Reference, judge

# a reference moving 1000 counts per ms, sampled every 1 ms (t in ns)
REF = Reference([(k * 1_000_000, 1000.0 * k) for k in range(100)])


def pulses(*spans: tuple[float, float]) -> list[Edge]:
    """Closing at a, opening at b (ms) for each span."""
    out = []
    for a, b in spans:
        out += [Edge(round(a * 1e6), True), Edge(round(b * 1e6), False)]
    return out


def test_error_and_uncertainty_from_the_sampling() -> None:
    """An edge between samples: interpolated truth, uncertainty = the distance to the
    farther of the two samples plus half a count; on a sample: half a count."""
    [r] = judge(pulses((10.25, 12)), REF, [10260], tolerance=20)
    assert r.true_counts == pytest.approx(10250) and r.error_counts == pytest.approx(10)
    assert r.uncertainty_counts == pytest.approx(750.5)
    assert r.status == "inconclusive"  # 10 ± 750.5 straddles ±20
    [r] = judge(pulses((10, 12)), REF, [10005], tolerance=20)
    assert (r.status, r.uncertainty_counts) == ("pass", 0.5)
    [r] = judge(pulses((10, 12)), REF, [10100], tolerance=20)
    assert r.status == "fail" and "beyond" in r.reason


def test_window_width_and_first_edge() -> None:
    """B&R LATCH semantics (003:454-489): window on the true position, width between the
    edges in counts, `first` judges only the first accepted edge."""
    edges = pulses((5, 6), (20, 20.1), (30, 35), (40, 42))
    caps = [5000, 20000, 30000, 40999]
    rs = judge(edges, REF, caps, tolerance=5, window=(10000, 50000), width=(500, 3000))
    assert [r.status for r in rs] == ["rejected", "rejected", "rejected", "fail"]
    assert "window" in rs[0].reason and "width 100" in rs[1].reason
    assert "width 5000" in rs[2].reason
    rs = judge(edges, REF, caps, tolerance=5, every=False)
    assert [r.status for r in rs] == ["pass", "skipped", "skipped", "skipped"]
    rs = judge(edges, REF, caps, tolerance=5, trigger_level=False)  # NC: the opening edges
    assert [round(r.true_counts) for r in rs] == [6000, 20100, 35000, 42000]


def test_missing_capture_and_missing_reference() -> None:
    rs = judge(pulses((10, 11), (500, 501)), REF, [10000], tolerance=5)
    assert rs[0].status == "pass" and rs[1].status == "inconclusive"
    assert math.isnan(rs[1].true_counts)
    [r] = judge(pulses((10, 11)), REF, [], tolerance=5)
    assert r.status == "fail" and "no value" in r.reason


@pytest.mark.parametrize(("text", "line", "what"), [
    ("  - capture_arm: {start: 790, count: 20}\n", 2, "exceeds the 800-entry"),
    ("  - capture_arm: {source: off}\n", 2, "one of CN5, CN1, CN2"),
    ("  - capture_arm: {trigger: no}\n", 2, "one of closing, opening"),
    ("  - capture_arm: {min_interval: 20ms}\n", 2, "0..15"),
    ("  - compare_table: {positions: [1, x]}\n", 2, "positions[1]"),
    ("  - compare_table:\n      positions: [1]\n      width: 1.5ms\n", 4, "whole ms"),
    ("  - latch: {tolerance: 5, edges: last}\n", 2, "first or every"),
    ("  - latch: {tolerance: 5, window: {min: 9, max: 1}}\n", 2, "min 9 > max 1"),
    ("  - latch: {window: {min: 1}}\n", 2, "tolerance"),
    ("  - mark: {line: DO4}\n", 2, "a DI line"),
])
def test_malformed_steps_name_file_line_field(text: str, line: int, what: str) -> None:
    doc = load_yaml_text("steps:\n" + text, "p.yaml")
    with pytest.raises(PlanFileError) as e:
        parse_steps(Checker("p.yaml"), doc["steps"], 1)
    assert f"p.yaml:{line}:" in str(e.value) and what in str(e.value)


@pytest.mark.integration
def test_latch_fails_on_a_late_capture(tmp_path) -> None:
    """The shipped plan with the deviation `dev_capture_delay_us: 100` (50 counts late at
    500 000 PUU/s): the latch step fails and names the error."""
    [path] = find_plans(["capture_di7_pv"])
    text = path.read_text().replace(
        "steps:\n", "options:\n  extra: {capture: {dev_capture_delay_us: 100}}\nsteps:\n", 1)
    plan = loads_plan(text, str(tmp_path / "late.yaml"))
    [r] = run_plans([plan], load_bench(), tmp_path, stream=io.StringIO())
    latch = next(s for s in r.steps if s.label.startswith("latch"))
    assert latch.status == "fail" and "beyond ±10" in latch.message, latch.message
    [r] = run_plans([load_plan(path)], load_bench(), tmp_path, stream=io.StringIO())
    assert r.passed


@pytest.mark.integration
@pytest.mark.parametrize("name", ["capture_di7_pv", "capture_z", "compare_table",
                                  "capture_pr50"])
def test_capture_plans_pass(tmp_path, name) -> None:
    [r] = run_plans([load_plan(p) for p in find_plans([name])], load_bench(), tmp_path,
                    stream=io.StringIO())
    assert r.passed, [(s.label, s.status, s.message) for s in r.steps if s.status != "pass"]
    if name.startswith("capture"):  # the error figures in the HTML report
        page = write_html(r.recording, tmp_path / "r.html").read_text()
        section = page.split("Capture / latch: captured position vs ground truth")[1]
        rows = section.split("</table>")[0].count("<tr>") - 1
        assert rows == (1 if name == "capture_pr50" else 3)
        assert "error [counts]" in section and "± uncertainty" in section
        assert "No timing spec latch" not in page


@pytest.mark.integration
def test_compare_table_plan_fails_on_a_long_pulse(tmp_path) -> None:
    """compare_pulse judges each of the 10 pulses: 2 ms too long fails the check."""
    [path] = find_plans(["compare_table"])
    text = path.read_text().replace(
        "steps:\n", "options:\n  extra: {capture: {dev_compare_width_extra_ms: 2}}\nsteps:\n", 1)
    [r] = run_plans([loads_plan(text, str(tmp_path / "long.yaml"))], load_bench(), tmp_path,
                    stream=io.StringIO())
    step = next(s for s in r.steps if s.label.startswith("check_timing"))
    assert step.status == "fail" and "10 fail" in step.message, step.message


def test_real_bench_sources() -> None:
    """Without model events the edges come from the harness's DI7 line, and a named
    reference channel gives the true position (a real bench's reference encoder)."""
    from hil.timing.latch import edges_from
    from hil.timing.source import MemorySource

    src = MemorySource({
        "/dio/drive1/DI7": [(0, {"level": True}), (5_000_000, {"level": False}),
                            (8_000_000, {"level": True})],
        "/enc/ref": [(k * 1_000_000, {"counts": 10.0 * k}) for k in range(20)],
    })
    edges = edges_from(src, "drive1")
    assert [(e.t, e.level) for e in edges] == [(5_000_000, False), (8_000_000, True)]
    ref = Reference.from_source(src, "/enc/ref", "counts")
    [r] = judge(edges, ref, [52], trigger_level=False, tolerance=3)
    assert (r.true_counts, r.error_counts, r.status) == (50.0, 2.0, "pass")


@pytest.mark.integration
def test_a_check_that_judges_nothing_does_not_pass(tmp_path) -> None:
    """check_timing of a spec whose scenario never happened (servo_on_brake with no servo
    on: every constraint skipped, "not applicable") fails the step: nothing judged is not
    a pass, as for `hil check` (exit 4)."""
    text = ("name: judged_nothing\nsteps:\n  - wait: 20ms\n"
            "  - check_timing: servo_on_brake\n")
    [r] = run_plans([loads_plan(text, str(tmp_path / "n.yaml"))], load_bench(), tmp_path,
                    stream=io.StringIO())
    step = r.steps[-1]
    assert step.status == "fail", (step.status, step.message)
    assert "nothing judged" in step.message and "not applicable" in step.message


def test_a_capture_past_the_32_bit_wrap_is_judged_on_the_32_bit_axis():
    """The drive's capture is a 32-bit register (P5.037, L11482): past +2^31 - 1 it reads
    -2^31 on, where the ground truth counts on. The error is the distance on that axis, not
    2^32 (helper-99)."""
    truth = 2**31 + 100.0
    ref = Reference([(0, truth - 10), (2_000_000, truth + 10)], resolution=0.5)
    [r] = judge([Edge(1_000_000, True)], ref, [-(2**31) + 100], tolerance=20)
    assert r.status == "pass" and abs(r.error_counts) < 1, r
