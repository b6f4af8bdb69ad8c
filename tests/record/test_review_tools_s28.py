"""What a reviewer's tools say of a recording that contradicts itself or holds unreadable
records, from an outside probe of `hil report`, `hil check` and `hil diff` (wave 3, session
28, helper-103): a result status no run gives, a result of pass over a failing step or
verdict, step and verdict records that are no JSON, and a plan's own deviation options."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from rec_helpers import copy_mcap, first_changed, plan_recording

from hil.bench.bench import load_bench
from hil.cli import main as hil
from hil.paths import plans_dir
from hil.plan.plan import load_plan
from hil.plan.runner import run_plan
from hil.record.reader import Recording

pytestmark = pytest.mark.virtual_time


@pytest.fixture(scope="module")
def emgs(tmp_path_factory) -> Path:
    """A genuine passing recording with check steps and their verdicts."""
    return plan_recording(tmp_path_factory.mktemp("emgs"), "emgs")


def _result(path: Path) -> dict[str, str]:
    return dict(Recording.head(path).metadata()["hil.result"])


def _junit(tmp_path: Path, rec: Path) -> ET.Element:
    out = tmp_path / f"{rec.stem}.xml"
    assert hil(["report", str(rec), "-o", str(tmp_path / f"{rec.stem}.html"),
                "--junit", str(out)]) == 0
    return ET.parse(out).getroot()


def test_a_result_status_no_run_gives_is_an_error_not_a_pass(emgs, tmp_path):
    bad = copy_mcap(emgs, tmp_path / "status.mcap",
                    metadata={"hil.result": _result(emgs) | {"status": "not-a-number"}})
    suite = _junit(tmp_path, bad)
    assert suite.get("errors") == "1" and suite.get("failures") == "0"
    err = suite.find(".//testcase/error")
    assert err is not None and "not-a-number" in err.get("message")
    page = (tmp_path / "status.html").read_text(encoding="utf-8")
    assert "b-error" in page and "is not a plan status" in page


def test_a_pass_result_over_a_failing_step_is_reported_failed(emgs, tmp_path):
    def fail(obj):
        return obj | {"status": "fail"} if obj.get("event") == "end" and obj.get(
            "index", -1) >= 0 else None

    bad = copy_mcap(emgs, tmp_path / "step.mcap", first_changed("/plan/steps", fail))
    assert _result(bad)["status"] == "pass"
    suite = _junit(tmp_path, bad)
    assert suite.get("failures") == "1"
    page = (tmp_path / "step.html").read_text(encoding="utf-8")
    assert "b-fail" in page and "result says pass, but step 1" in page


def test_a_pass_result_over_a_failing_verdict_is_reported_failed(emgs, tmp_path):
    bad = copy_mcap(emgs, tmp_path / "verdict.mcap", first_changed(
        "/timing/verdicts", lambda o: o | {"status": "fail"} if o.get("status") == "pass"
        else None))
    suite = _junit(tmp_path, bad)
    assert suite.get("failures") == "1"
    failure = suite.find(".//testcase/failure")
    assert failure is not None and "timing verdict emgs" in failure.get("message")


def _unreadable(topic_wanted: str):
    def message(topic: str, data: bytes, lt: int) -> tuple[bytes, int]:
        return (b"\xff{" if topic == topic_wanted else data), lt
    return message


def test_check_with_unreadable_verdict_records_is_incomplete(emgs, tmp_path, capsys, caplog):
    """The plan's own checks are re-made from its verdict records: none readable, `hil check`
    judged the specs over the whole file instead and exited 0."""
    assert hil(["check", str(emgs)]) == 0
    capsys.readouterr()
    bad = copy_mcap(emgs, tmp_path / "v.mcap", _unreadable("/timing/verdicts"))
    assert hil(["check", str(bad)]) == 4
    err = capsys.readouterr().err
    assert "wrong shape skipped" in caplog.text
    assert "incomplete" in err and "/timing/verdicts message(s) of a wrong shape" in err


def test_report_says_it_skipped_unreadable_step_records(emgs, tmp_path, caplog):
    bad = copy_mcap(emgs, tmp_path / "s.mcap", _unreadable("/plan/steps"))
    assert hil(["report", str(bad), "-o", str(tmp_path / "s.html")]) == 0
    assert "the first: /plan/steps" in caplog.text  # one warning names the first
    page = (tmp_path / "s.html").read_text(encoding="utf-8")
    assert "record(s) of a wrong shape skipped" in page
    assert "SKIPPED</span></td><td>–" not in page  # no junk step row


def test_diff_with_unreadable_step_records_is_incomplete(emgs, tmp_path, capsys, caplog):
    """B's steps unreadable: its edges were placed from the epoch (deltas of 30 years) and
    the diff exited 0 without a word."""
    bad = copy_mcap(emgs, tmp_path / "b.mcap", _unreadable("/plan/steps"))
    code = hil(["diff", str(emgs), str(bad), "-o", str(tmp_path / "d.html")])
    err = capsys.readouterr().err
    assert code == 4
    assert "no step start could be read" in err and "wrong shape" in err
    assert "the first: /plan/steps" in caplog.text
    assert json.loads((tmp_path / "d.json").read_text())["incomplete"]


def test_diff_lists_a_deviation_option_the_plan_set(tmp_path, capsys):
    text = (plans_dir() / "servo_on_off_brake.yaml").read_text(encoding="utf-8")
    dev = tmp_path / "brake_dev.yaml"
    dev.write_text(text.replace("\nsteps:", "\noptions:\n  dev_brake_on_delay_ms: 30\nsteps:", 1),
                   encoding="utf-8")
    bench = load_bench(None)
    a = run_plan(load_plan(plans_dir() / "servo_on_off_brake.yaml"), bench, tmp_path / "a",
                 reports=False)
    b = run_plan(load_plan(dev), bench, tmp_path / "b", reports=False)
    assert hil(["diff", a.recording, b.recording, "-o", str(tmp_path / "d.html")]) == 0
    d = json.loads((tmp_path / "d.json").read_text())
    assert d["options"] == {"dev_brake_on_delay_ms": [None, 30]}


def test_the_index_names_the_first_failing_step_not_end_of_plan(emgs, tmp_path):
    """A plan that ran to its end and failed had "end of plan" as its reason on the index."""
    def fail(obj):
        return obj | {"status": "fail", "message": "made to fail"} if obj.get(
            "event") == "end" and obj.get("index") == 2 else None

    bad = copy_mcap(emgs, tmp_path / "idx.mcap", first_changed("/plan/steps", fail),
                    metadata={"hil.result": _result(emgs) | {"status": "fail"}})
    assert _result(bad)["reason"] == "end of plan"
    index = tmp_path / "index.html"
    assert hil(["report", str(bad), "-o", str(tmp_path / "idx.html"), "--index",
                str(index)]) == 0
    page = index.read_text(encoding="utf-8")
    assert "step 3 " in page and "made to fail" in page and "end of plan" not in page


def test_check_counts_occurrences_from_one_as_the_report(emgs, capsys):
    assert hil(["check", str(emgs)]) == 0
    rows = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("PASS")]
    assert rows and all(ln.split()[2] != "0" for ln in rows)
    assert any(ln.split()[2] == "1" for ln in rows)


def test_a_cut_virtual_recording_is_not_called_a_real_bench(emgs, tmp_path):
    data = emgs.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[:1500])
    assert hil(["report", str(cut), "-o", str(tmp_path / "cut.html")]) == 0
    page = (tmp_path / "cut.html").read_text(encoding="utf-8")
    if "No ground truth" in page:  # the cut fell before the first state sample
        assert "real bench" not in page and "virtual bench" in page


def test_a_passing_run_whose_file_lost_its_tail_stays_incomplete():
    """The reader marks the step a cut file holds starting and not ending "cut short"
    (error): that is the file's loss, not a failure the result contradicts. The recorder's
    `hil.result` can land before its last chunk, so such a file exists (helper-108 cut one
    at 21542 bytes: the page said FAIL, "the result says incomplete")."""
    from hil.report.data import RunData, StepData, _reconcile_status

    def run(message: str) -> RunData:
        r = RunData("x.mcap", "emgs", "virtual", "incomplete", truncated=True,
                    metadata={"hil.result": {"status": "pass"}})
        r.steps = [StepData(0, "wait", status="pass"),
                   StepData(1, "check_timing emgs", status="error", message=message)]
        return r

    cut = run("cut short: the recording's tail is lost (the run ended; how this step did "
              "was not kept)")
    _reconcile_status(cut)
    assert cut.status == "incomplete" and not cut.status_note
    failed = run("a real error")
    _reconcile_status(failed)
    assert failed.status == "fail"
    assert failed.status_note == ("the recording's result says pass, but step 2 "
                                  "check_timing emgs error")
