"""Readable diagrams and reports: round ticks, numbers drawn as plots (no value boxes piled
into black bars), labels only where they fit, the manual's signals first with helpers folded,
passing verdicts folded and counted, pages that stay small."""

from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from hil.report.html import _verdict_rows
from hil.timing.checker import Trace
from hil.timing.render import _boxes, _plot_lane, main_lanes, nice_ticks
from hil.timing.spec import loads_spec

SVG = "{http://www.w3.org/2000/svg}"


def test_ticks_are_round_and_cover_the_range() -> None:
    for a, b in [(-657.9, 1234.5), (0, 1), (3.3, 3.7), (-0.02, 0.05), (100, 40100)]:
        ticks = nice_ticks(a, b)
        assert 3 <= len(ticks) <= 16
        step = ticks[1] - ticks[0]
        mant = step / 10 ** math.floor(math.log10(step))
        assert any(math.isclose(mant, m, rel_tol=1e-9) for m in (1, 2, 5, 10)), step
        assert all(math.isclose(t / step, round(t / step), abs_tol=1e-6) for t in ticks)
        assert ticks[0] >= a - 1e-9 and ticks[-1] <= b + 1e-9
        assert ticks[0] - a < step and b - ticks[-1] < step


def _x(lo: int, hi: int, width: float = 800):
    return lambda t: 100 + (min(max(t, lo), hi) - lo) / (hi - lo) * width


def test_a_number_lane_is_a_bounded_plot_not_boxes() -> None:
    times = list(range(0, 20_000_000_000, 1_000_000))  # 20 000 samples at 1 kHz
    values = [1000 * math.sin(t / 1e9) for t in times]
    tr = Trace("speed", times, values, 0)
    drawn, scale = _plot_lane(tr, _x(0, times[-1]), 0, times[-1], 10, 40)
    assert drawn.startswith("<polyline") and "<rect" not in drawn and "<text" not in drawn
    points = re.search(r'points="([^"]*)"', drawn).group(1).split()
    assert len(points) <= 4 * 801 + 1  # at most four per pixel column
    assert "…" in scale  # its range is printed under the lane's name
    lo, hi = (float(x) for x in scale.split(" … "))
    assert math.isclose(lo, min(values), rel_tol=1e-5)  # printed to 6 digits
    assert math.isclose(hi, max(values), rel_tol=1e-5)
    ys = [float(p.split(",")[1]) for p in points]
    assert min(ys) >= 10 - 1e-6 and max(ys) <= 40 + 1e-6  # inside its lane


def test_box_labels_only_where_they_fit() -> None:
    times = [0, 1_000_000, 2_000_000, 500_000_000]
    tr = Trace("phase", times, ["search", "index", "stop", "done"], 0)
    drawn = _boxes(tr, _x(0, 1_000_000_000), 0, 1_000_000_000, 10, 40)
    texts = re.findall(r"<text[^>]*>([^<]*)</text>", drawn)
    assert texts == ["stop", "done"]  # search, index: under a pixel wide, a tooltip only
    assert drawn.count("<title>") == 4


SPEC = loads_spec("""
id: demo
title: demo
source: test
signals:
  speed: {topic: "/drive/{drive}/state", field: speed_rpm}
  BRKR: {function: BRKR}
  fast: {signal: speed, above: 100}
  moving: {signal: speed, abs: true, above: 1}
events:
  brkr_on: {rise: BRKR}
  fast_on: {rise: fast, after: brkr_on, within: 1000}
constraints:
  - name: fast soon
    from: brkr_on
    to: fast_on
    window: {min: 0, max: 500}
""")


def test_recorded_signals_and_constrained_lanes_lead_helpers_fold() -> None:
    main, helpers = main_lanes(SPEC, [])
    assert main == ["speed", "BRKR"] and helpers == ["fast", "moving"]


def _v(step: int, constraint: str, status: str, margin: float, measured: float) -> dict:
    return {"step": step, "spec": "s", "constraint": constraint, "status": status,
            "margin_ms": margin, "measured_ms": measured, "message": f"m{margin}"}


def test_passing_occurrences_share_a_row_failures_keep_theirs() -> None:
    vs = [_v(3, "a", "pass", 5, 1), _v(3, "a", "pass", 2, 4), _v(3, "a", "fail", -1, 9),
          _v(3, "b", "pass", 1, 2), _v(4, "a", "pass", 7, 1)]
    rows = _verdict_rows(vs)
    assert [len(r) for r in rows] == [2, 1, 1, 1]
    assert rows[0][0]["margin_ms"] == 2  # led by the one closest to its limit
    assert rows[1][0]["status"] == "fail"


def test_report_page_folds_an_all_pass_table_and_parses(tmp_path) -> None:
    from test_reports import _recording  # a recorded plan with a failing check

    from hil.report.html import write_html

    p = tmp_path / "demo.mcap"
    _recording(p)
    html = write_html(p, tmp_path / "demo.html").read_text()
    assert "<details class='verdicts' open>" in html  # it has a failure: open
    assert "onchange='hilFilter(this)'" in html  # filter by status
    assert "oninput='hilFind(this)'" in html and "<tr class='s' id='step-1'>" in html  # find
    assert "classList.toggle('zoom')" in html  # click a diagram to zoom it
    for m in re.finditer(r"<svg.*?</svg>", html, re.S):
        ET.fromstring(m.group(0))  # every diagram is well-formed XML


def test_the_report_keeps_only_the_ground_truth_it_draws(tmp_path) -> None:
    """A report keeps of each state sample the plot's fields and what the recording's specs
    read (issue 28: a homing report under 100 MB), and still draws their diagrams; with specs
    it does not know it keeps every field."""
    from hil.bench.bench import load_bench
    from hil.plan.plan import find_plans, load_plan
    from hil.plan.runner import run_plan
    from hil.report import data as report_data
    from hil.report.html import write_html

    res = run_plan(load_plan(find_plans(["plc_drv_gear"])[0]), load_bench(None), tmp_path)
    assert res.passed
    report_data._RUNS.clear()
    run = report_data.load_run(res.recording)
    kept = run.truth_fields
    assert kept is not None and {"pt_error", "speed_rpm", "position_counts"} <= kept
    assert "di" not in kept and "abs_turns" not in kept  # nothing plc_tpos reads
    sample = run.truth["drive1"][-1][1]
    assert set(sample) <= kept and "pt_error" in sample
    page = write_html(res.recording, tmp_path / "r.html").read_text()
    assert "plc_tpos" in page and "<svg" in page
    # a recording whose specs are unknown keeps every field
    assert report_data.truth_fields(["no_such_spec"]) is None
    assert report_data.truth_fields(None) is None


def test_a_runs_junit_and_index_read_no_recording_again(tmp_path, monkeypatch) -> None:
    """The run's JUnit and index need each plan's steps and verdicts, not its ground truth: they
    use the summaries kept when each plan's own reports read its recording (a 55-plan run
    re-read every recording twice at its end), and a summary read from a file skips the
    ground truth. Either way they say what a whole read says."""
    from hil.bench.bench import load_bench
    from hil.plan.plan import find_plans, load_plan
    from hil.plan.runner import run_plan
    from hil.report import data as report_data
    from hil.report.index import write_index
    from hil.report.junit import junit_xml, write_junit

    bench = load_bench(None)
    recs = [run_plan(load_plan(find_plans([n])[0]), bench, tmp_path).recording
            for n in ("emgs", "param_access", "plc_drv_gear")]
    reads: list[tuple[str, bool]] = []
    real = report_data._load_run
    monkeypatch.setattr(report_data, "_load_run",
                        lambda p, *, truth=True, **kw: (reads.append((str(p), truth)),
                                                        real(p, truth=truth, **kw))[1])
    write_junit(recs, tmp_path / "junit.xml")
    write_index(recs, tmp_path / "index.html")
    assert reads == []
    # a new process (a `-j` parent): each recording read once, without its ground truth
    report_data._RUNS.clear()
    report_data._SUMMARIES.clear()
    from_files = junit_xml(recs, tmp_path)
    assert reads == [(str(r), False) for r in recs]
    assert (tmp_path / "junit.xml").read_text() == from_files  # the same from either
    summary = report_data.load_run(recs[2], truth=False)
    assert summary.truth == {} and len(reads) == 3  # kept: not read again
    whole = report_data.load_run(recs[2])
    assert whole.truth["drive1"] and reads[-1] == (str(recs[2]), True)
    assert (summary.steps, summary.verdicts, summary.status, summary.t0) == (
        whole.steps, whole.verdicts, whole.status, whole.t0)
    report_data._RUNS.clear()
    report_data._SUMMARIES.clear()
    assert junit_xml(recs, tmp_path) == from_files


def test_a_recording_written_again_is_read_again(tmp_path, monkeypatch) -> None:
    """A plan run again into the same file could leave it with the old size and, on a coarse
    file system, the old mtime: the runner drops what the report kept of that file."""
    from hil.bench.bench import load_bench
    from hil.plan import runner
    from hil.plan.plan import find_plans, load_plan
    from hil.report import data as report_data

    plan = load_plan(find_plans(["emgs"])[0])
    first = runner.run_plan(plan, load_bench(None), tmp_path)
    name = str(Path(first.recording).resolve())
    report_data.load_run(first.recording, truth=False)
    assert any(k[0] == name for k in report_data._SUMMARIES)
    forgotten: list[tuple[str, bool]] = []
    real = runner.forget_report

    def forget(p):
        real(p)
        kept = any(k[0] == name for c in (report_data._RUNS, report_data._SUMMARIES) for k in c)
        forgotten.append((p, kept))

    monkeypatch.setattr(runner, "forget_report", forget)
    second = runner.run_plan(plan, load_bench(None), tmp_path)
    assert forgotten == [(second.recording, False)] and second.recording == first.recording


def test_report_and_diff_read_a_recording_a_message_at_a_time(tmp_path, monkeypatch) -> None:
    """`hil report` and `hil diff` never hold a recording whole (a long run would not fit in
    memory): they read its metadata outside the chunks, then each message as it comes. What
    they find is what a whole read finds: every step, verdict, ground-truth sample, bus
    message, the metadata and attachments; and a cut recording is still reported cut."""
    import json as json_mod

    from hil.bench.bench import load_bench
    from hil.plan.plan import find_plans, load_plan
    from hil.plan.runner import run_plan
    from hil.record import topics as T
    from hil.record.reader import Recording
    from hil.report import data as report_data
    from hil.report.diff import load_side

    res = run_plan(load_plan(find_plans(["servo_on_off_brake"])[0]), load_bench(None), tmp_path)
    whole = Recording.open(res.recording)  # the reference: one whole read, before the ban
    msgs = list(whole.messages())
    state = [m for topic, _lt, _pt, m in msgs if topic == T.drive_state("drive1")]
    verdicts = [m for topic, _lt, _pt, m in msgs if topic == T.TIMING_VERDICTS]
    starts = {m["index"] for topic, _lt, _pt, m in msgs
              if topic == T.PLAN_STEPS and m.get("event") == "start"}
    bus = [m for topic, _lt, _pt, m in msgs
           if topic.startswith(("/canopen/", "/modbus/", "/dio/"))]
    meta, names = whole.metadata(), sorted(a.name for a in whole.attachments())

    def banned(*_a, **_k):
        raise AssertionError("read whole")

    monkeypatch.setattr(Recording, "open", classmethod(banned))
    report_data._RUNS.clear()
    report_data._SUMMARIES.clear()
    run = report_data.load_run(res.recording)
    assert len(run.truth["drive1"]) == len(state) > 10
    assert [{k: v for k, v in m.items() if k != "_t"} for m in run.verdicts] == verdicts
    assert {s.index for s in run.steps} == starts and run.status == "pass"
    assert run.metadata == meta and sorted(run.attachments) == names
    assert not run.truncated and run.plan == "servo_on_off_brake"
    got_bus = [json_mod.loads(raw) if isinstance(raw, bytes) else raw
               for _t, _topic, raw in report_data.bus_of(run)]
    assert len(got_bus) == len(bus) > 0

    def key(m):
        return json_mod.dumps(m, sort_keys=True)

    assert sorted(got_bus, key=key) == sorted(bus, key=key)
    side = load_side(res.recording)
    assert side.plan == "servo_on_off_brake" and set(side.starts) == starts
    assert len(side.verdicts) == len(verdicts)
    # cut in the middle of its data: reported cut, with what could be read
    data = Path(res.recording).read_bytes()
    partial = []
    for i, frac in enumerate((0.3, 0.5, 0.7, 0.9)):
        cut = tmp_path / f"cut{i}.mcap"
        cut.write_bytes(data[: int(len(data) * frac)])
        run = report_data.load_run(cut)
        assert run.truncated
        partial.append(0 < len(run.truth.get("drive1", [])) < len(state))
    assert any(partial)


@pytest.mark.parametrize("plan_name", ["servo_on_off_brake", "emgs", "homing_pr"])
def test_the_runs_page_from_the_recorders_messages_is_the_page_from_the_file(
        tmp_path, plan_name) -> None:
    """In virtual time the runner's report takes the messages its recorder wrote (its
    mirror) instead of reading the file again: the page must be the one `hil report` writes
    from the file, byte for byte (plans with and without checks)."""
    from hil.bench.bench import load_bench
    from hil.plan.plan import find_plans, load_plan
    from hil.plan.runner import run_plan
    from hil.report import data as report_data
    from hil.report.html import write_html

    res = run_plan(load_plan(find_plans([plan_name])[0]), load_bench(None), tmp_path)
    assert res.html
    live = Path(res.html).read_text()
    report_data.forget(res.recording)
    from_file = write_html(res.recording, tmp_path / "again.html", index=True).read_text()
    assert live == from_file


def test_the_bus_log_around_a_failing_check_shows_the_checkers_times(tmp_path) -> None:
    """The highlighted DO edge in 'Bus log around failing checks' was printed at its log
    time (138.983 ms) while the verdict and its diagram give the source's stamp (138.697
    ms): a reviewer subtracting lines got 105.29 ms for a 105.0 ms verdict (helper-52)."""
    from hil.bench.bench import load_bench
    from hil.plan.plan import find_plans, loads_plan
    from hil.plan.runner import run_plan
    from hil.report import data as report_data
    from hil.report.data import bus_around, load_run

    text = (find_plans(["servo_on_off_brake"])[0].read_text()
            .replace("steps:\n", "options: {dev_brake_on_delay_ms: 5}\nsteps:\n", 1))
    res = run_plan(loads_plan(text, str(tmp_path / "b.yaml")), load_bench(None), tmp_path)
    report_data.forget(res.recording)
    run = load_run(res.recording)
    bad = next(v for v in run.verdicts if v.get("status") == "fail")
    rows = bus_around(run, bad)
    edge = [t for t, topic, _text, inside in rows if inside and topic.endswith("/DO6")]
    assert edge and edge[-1] == bad["to_ns"], (edge, bad)  # the verdict's observed instant
    assert [r[0] for r in rows] == sorted(r[0] for r in rows)


def test_a_failing_page_says_its_first_failure_and_the_deviation_knobs_first(tmp_path) -> None:
    """The first screen of a failing plan's page: which step failed, at which line of which
    file, and why; and a drive made wrong on purpose (`dev_*` options) says so next to the
    bench's name (an outside review: both were below the fold or only in bench.yaml)."""
    from hil.bench.bench import load_bench
    from hil.plan.plan import find_plans, loads_plan
    from hil.plan.runner import run_plan

    text = (find_plans(["servo_on_off_brake"])[0].read_text()
            .replace("steps:\n", "options: {dev_brake_on_delay_ms: 5}\nsteps:\n", 1))
    res = run_plan(loads_plan(text, str(tmp_path / "b.yaml")), load_bench(None), tmp_path)
    page = Path(res.html).read_text()
    head = page[:page.index("<h2>")]  # before the first section
    assert "First failure" in head and "step 8</a>" in head and "(b.yaml:19)" in head
    assert "5.0 ms late" in head or "4.0 ms late" in head
    assert "drive1.dev_brake_on_delay_ms=5" in head
    ok = run_plan(loads_plan(find_plans(["servo_on_off_brake"])[0].read_text(),
                             str(tmp_path / "ok.yaml")), load_bench(None), tmp_path / "ok")
    ok_head = Path(ok.html).read_text().split("<h2>")[0]
    assert "First failure" not in ok_head and "deviation" not in ok_head


def test_a_killed_runs_page_says_where_it_was_cut_and_that_no_safe_state_was_seen(
        tmp_path) -> None:
    """A run killed by SIGKILL leaves a file that just ends: the step that was running is
    'cut short', not SKIPPED; the steps never reached are listed; the safe-state section says
    none was confirmed; the JUnit error names the cut step (an outside review)."""
    import xml.etree.ElementTree as ET

    from hil.bench.bench import load_bench
    from hil.plan.plan import find_plans, load_plan
    from hil.plan.runner import run_plan
    from hil.report import data as report_data
    from hil.report.html import write_html
    from hil.report.junit import junit_xml

    res = run_plan(load_plan(find_plans(["homing_pr"])[0]), load_bench(None), tmp_path)
    data = Path(res.recording).read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    report_data.forget(cut)
    run = report_data.load_run(cut)
    assert run.truncated and not run.metadata.get("hil.result")
    total = int(run.metadata["hil.plan"]["steps"])
    assert len([s for s in run.steps if s.index >= 0]) == total  # (the `params` step is -1)
    cut_steps = [s for s in run.steps if s.message.startswith("cut short")]
    assert len(cut_steps) == 1 and cut_steps[0].status == "error", [
        (s.index, s.status, s.message) for s in run.steps]
    assert run.steps[-1].message.startswith("not reached")
    page = write_html(cut, tmp_path / "cut.html").read_text()
    assert "Safe state not confirmed: the recording ends" in page
    case = ET.fromstring(junit_xml([cut])).find(".//testcase")
    err = case.find("error")
    assert err is not None and "cut short" in err.get("message"), ET.tostring(case)[:400]


def test_a_damaged_runs_page_says_damaged_not_killed(tmp_path) -> None:
    """A file damaged mid-file (a chunk that cannot be read) is not a killed run: the page,
    the cut step and the safe-state section say the recording is damaged and name the
    unreadable record (helper-84 #5: it said "truncated (killed run)")."""
    from hil.bench.bench import load_bench
    from hil.plan.plan import find_plans, load_plan
    from hil.plan.runner import run_plan
    from hil.report import data as report_data
    from hil.report.html import write_html
    from tests.timing.test_check_incomplete import corrupt

    # homing_pr: 0.6 MB, ten 64 KiB chunks however the host's clock flushed them
    res = run_plan(load_plan(find_plans(["homing_pr"])[0]), load_bench(None), tmp_path,
                   reports=False)
    bad = tmp_path / "bad.mcap"
    off = corrupt(Path(res.recording), bad, 3)
    report_data.forget(bad)
    run = report_data.load_run(bad)
    assert run.damage and f"chunk at offset {off} unreadable" in run.damage
    cut_steps = [s for s in run.steps if s.message.startswith("cut short")]
    assert [s.message for s in cut_steps] == ["cut short: the recording is damaged while it "
                                               "ran (what followed could not be read)"]
    page = write_html(bad, tmp_path / "bad.html").read_text()
    assert f"recording damaged (chunk at offset {off} unreadable" in page
    assert "killed run" not in page and "the run was killed" not in page
    assert "Safe state not seen: the recording is damaged before it" in page


def test_the_ground_truth_is_held_as_columns_and_reads_back_as_recorded(tmp_path) -> None:
    """helper-84 #3: the report kept a dict a state sample (some 640 bytes each; 655 MB for a
    23 MB recording). It holds them as columns now (TruthSamples): what it gives back, by
    index and in order, is each recorded state with the kept fields, at its publish time."""
    import json

    from mcap.reader import make_reader

    from hil.bench.bench import load_bench
    from hil.plan.plan import find_plans, load_plan
    from hil.plan.runner import run_plan
    from hil.report import data as report_data

    res = run_plan(load_plan(find_plans(["homing_pr"])[0]), load_bench(None), tmp_path,
                   reports=False)
    report_data.forget(res.recording)
    run = report_data.load_run(res.recording)
    samples = run.truth["drive1"]
    assert isinstance(samples, report_data.TruthSamples)
    kept = run.truth_fields
    with open(res.recording, "rb") as f:
        want = sorted(((m.publish_time, {k: v for k, v in json.loads(m.data).items()
                                         if kept is None or k in kept})
                       for _, _, m in make_reader(f).iter_messages(
                           topics=["/drive/drive1/state"])), key=lambda r: r[0])
    assert len(want) > 1000 and len(samples) == len(want)
    assert list(samples) == want
    assert samples[-1] == want[-1] and samples[0] == want[0] and samples[500] == want[500]
    assert samples[10:13] == want[10:13]
    with pytest.raises(IndexError):
        samples[len(want)]
