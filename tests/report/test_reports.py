"""JUnit and HTML from a small recording made here (no bench)."""

from __future__ import annotations

import xml.etree.ElementTree as ET

from hil.record.recorder import Recorder
from hil.report.html import write_html
from hil.report.junit import junit_xml


def _recording(path):
    with Recorder(path, metadata={"plan": "demo", "bench": "virtual"}) as rec:
        rec.attach("bench.yaml", b"name: virtual\n", "application/yaml")
        rec.plan_step("di SON=on", "start", index=0, plan="demo", kind="di", line=4)
        rec.dio("drive1", "DI1", True, t=1_000_000_000)
        rec.plan_step("di SON=on", "end", index=0, plan="demo", status="pass",
                      duration_ns=200_000, line=4, file="plans/demo.yaml")
        rec.plan_step("expect BRKR on", "start", index=1, plan="demo")
        rec.plan_step("expect BRKR on", "end", index=1, plan="demo", status="fail",
                      message="expected DO BRKR on, saw BRKR off", line=5)
        for i in range(20):
            rec.drive_state("drive1", {"state": "OPERATION ENABLED", "position_counts": i * i,
                                       "speed_rpm": float(i), "torque_pct": 1.0})
        rec.verdict(spec="servo_on_brake", constraint="BRKR rises P1.042 after servo on",
                    status="fail", measured_ms=105.0, window_ms=[99.0, 101.0],
                    uncertainty_ms=[1.0, 0.0], message="4.0 ms late")
        rec.safety("DI SON off", "step 2 failed", drive="drive1", ok=True)
        rec.drive_params("drive1", {"P1.042": 100}, snapshot=True)


def test_junit_structure(tmp_path):
    p = tmp_path / "demo.mcap"
    _recording(p)
    root = ET.fromstring(junit_xml([p], tmp_path))
    assert root.tag == "testsuites" and root.get("tests") == "1"  # one testcase per plan
    [suite] = root.findall("testsuite")
    assert suite.get("name") == "hil" and suite.get("failures") == "1"
    [case] = suite.findall("testcase")
    assert case.get("name") == "demo" and case.get("classname") == "hil.plans"
    props = {x.get("name"): x.get("value") for x in case.iter("property")}
    assert props["recording"] == "demo.mcap" and props["bench"] == "virtual"  # relative
    assert [k for k in props if k.startswith(("step", "timing"))] == [
        "step 01 di SON=on", "step 02 expect BRKR on",
        "timing servo_on_brake: BRKR rises P1.042 after servo on"]
    fail = case.find("failure")
    assert "expected DO BRKR on, saw BRKR off" in fail.get("message")
    assert "4.0 ms late" in fail.text and "step 02 expect BRKR on" in case.find("system-out").text


def test_html_is_self_contained(tmp_path):
    p = tmp_path / "demo.mcap"
    _recording(p)
    out = write_html(p, tmp_path / "demo.html")
    html = out.read_text()
    assert "<svg" in html and "polyline" in html  # motion plot
    assert "expected window" in html  # timing diagram
    assert "expected DO BRKR on, saw BRKR off" in html
    assert "DI SON off" in html and "P1.042 = 100" in html and "name: virtual" in html
    assert "http://" not in html.replace("http://www.w3.org/2000/svg", "")
    # offline: inline script and style only, nothing fetched (no src=, no <link>)
    assert "<script src" not in html and "<link" not in html


def test_the_diagrams_of_one_spec_at_several_steps_share_one_context(tmp_path, monkeypatch):
    """A plan that checks one spec after each of several moves (homing_limits: six times)
    draws each check's diagram from traces built once per spec, binding and parameters; a
    check with other parameters gets its own. The pictures are those of a fresh context."""
    import hil.report.html as report_html
    from hil.report.data import load_run
    from hil.timing.checker import context
    from hil.timing.registry import load_specs
    from hil.timing.render import main_lanes, svg

    p = tmp_path / "steps.mcap"
    bind = {"drive": "drive1", "dio": "drive1"}
    with Recorder(p, metadata={"plan": "steps", "bench": "virtual"}) as rec:
        rec.drive_params("drive1", {"P1.042": 100}, snapshot=True)
        for i in range(30):
            rec.dio("drive1", "DI1", i % 10 >= 3, t=(i + 1) * 10_000_000)
            rec.dio("drive1", "DO6", i % 10 >= 5, t=(i + 1) * 10_000_000 + 1)
        for step, params in ((0, {}), (1, {}), (2, {"P1.042": 20})):
            rec.verdict(spec="servo_on_brake", constraint="BRKR rises P1.042 after servo on",
                        status="pass", step=step, occurrence=0, binding=bind,
                        check_params=params, from_ns=40_000_000 + step, to_ns=60_000_000,
                        window_ms=[19.0, 21.0], message=f"step {step}")
    built = []
    real = report_html.context
    monkeypatch.setattr(report_html, "context",
                        lambda *a, **k: built.append(a[2]) or real(*a, **k))
    run = load_run(p)
    pics = dict(report_html.timing_diagrams(run))
    assert built == [None, {"P1.042": 20}]  # two contexts for three checks
    spec = load_specs()["servo_on_brake"]
    verdicts = {int(v["step"]): v for v in run.verdicts}
    for step in (0, 1, 2):
        [pic] = [v for k, v in pics.items()
                 if k.startswith(f"servo_on_brake (step {step + 1})")]
        ctx = context(spec, report_html.RecordingSource(p),
                      verdicts[step]["check_params"] or None, bind)
        vd = report_html.Verdict(**{k: verdicts[step][k] for k in
                                    ("spec", "constraint", "status", "message", "occurrence",
                                     "from_ns", "to_ns")},
                                 window_ms=tuple(verdicts[step]["window_ms"]))
        main, _helpers = main_lanes(spec, [vd], ctx)
        fresh = svg(spec, ctx.source, [vd], occurrence=None, width=1100, t0=run.t0,
                    lanes=main, ctx=ctx)
        assert pic.startswith(fresh), step
