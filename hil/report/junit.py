"""JUnit XML from recordings: one testsuite per plan run, one testcase per step and one per
timing verdict, the recording path as a suite property (read by CI test tabs)."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

from hil.fileio import write_text_atomic
from hil.report.data import RunData, load_run

NOT_PASSED = {"fail": "failure", "inconclusive": "failure", "error": "error",
              "aborted": "error"}


def _case(suite: ET.Element, classname: str, name: str, seconds: float, status: str,
          message: str, detail: str = "") -> None:
    tc = ET.SubElement(suite, "testcase", classname=classname, name=name, time=f"{seconds:.6f}")
    if status == "pass":
        return
    if status == "skipped":
        ET.SubElement(tc, "skipped", message=message or "not run")
        return
    tag = NOT_PASSED.get(status, "error")
    el = ET.SubElement(tc, tag, message=message or status, type=status)
    el.text = detail or message


def suite(run: RunData) -> ET.Element:
    cls = f"hil.{run.plan}"
    s = ET.Element("testsuite", name=run.plan)
    props = ET.SubElement(s, "properties")
    for k, v in (("recording", run.path), ("bench", run.bench), ("status", run.status),
                 ("truncated", str(run.truncated).lower())):
        ET.SubElement(props, "property", name=k, value=str(v))
    total = 0.0
    for st in run.steps:
        secs = st.duration_ns / 1e9
        total += secs
        where = f"{st.file}:{st.line}" if st.file else f"line {st.line}"
        name = f"{st.index + 1:02d} {st.label}" if st.index >= 0 else st.label
        _case(s, cls, name, secs, st.status, st.message, f"{where}: {st.message}")
    for v in run.verdicts:
        name = f"timing {v.get('spec', '?')}: {v.get('constraint', '?')}"
        if v.get("occurrence"):
            name += f" #{v['occurrence']}"
        detail = (f"measured {v.get('measured_ms')} ms, window {v.get('window_ms')}, "
                  f"margin {v.get('margin_ms')} ms; source {v.get('source', '')}")
        _case(s, cls + ".timing", name, 0.0, v.get("status", "error"), v.get("message", ""),
              detail)
    cases = s.findall("testcase")
    s.set("tests", str(len(cases)))
    s.set("failures", str(sum(1 for c in cases if c.find("failure") is not None)))
    s.set("errors", str(sum(1 for c in cases if c.find("error") is not None)))
    s.set("skipped", str(sum(1 for c in cases if c.find("skipped") is not None)))
    s.set("time", f"{total:.6f}")
    return s


def junit_xml(recordings: list[str | Path]) -> str:
    root = ET.Element("testsuites", name="hil")
    for p in recordings:
        root.append(suite(load_run(p)))
    for k in ("tests", "failures", "errors", "skipped"):
        root.set(k, str(sum(int(s.get(k, "0")) for s in root)))
    ET.indent(root)
    return ET.tostring(root, encoding="unicode", xml_declaration=True) + "\n"


def write_junit(recordings: list[str | Path], out: str | Path) -> Path:
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(out, junit_xml(recordings))
    return out
