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
