"""JUnit XML from recordings, the one shape both entry points write (`hil run`, `hil report
--junit` and the pytest plugin): one testcase per plan run, its steps and timing verdicts as
properties and in system-out, the recording path relative to the JUnit file."""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from pathlib import Path

from hil.fileio import write_text_atomic
from hil.report.data import RunData, load_run
from hil.terminal import xml_text

NOT_PASSED = {"fail": "failure", "inconclusive": "failure", "error": "error",
              "aborted": "error", "incomplete": "error"}
CLASSNAME = "hil.plans"


def recording_ref(path: str | Path, junit_dir: str | Path | None) -> str:
    """The recording's path as the JUnit file names it: relative to the JUnit file's folder
    (the pair survives being archived together), absolute when there is no JUnit file."""
    if junit_dir is None:
        return str(Path(path).resolve())
    return os.path.relpath(Path(path).resolve(), Path(junit_dir).resolve())


def _lines(run: RunData) -> list[tuple[str, str, str]]:
    """(name, status, text) of every step and timing verdict of a plan run."""
    out = []
    for st in run.steps:
        name = f"step {st.index + 1:02d} {st.label}" if st.index >= 0 else f"step {st.label}"
        where = f"{st.file}:{st.line}" if st.file else f"line {st.line}"
        text = f"{st.status} {st.duration_ns / 1e6:.1f} ms ({where})"
        out.append((name, st.status, text + (f": {st.message}" if st.message else "")))
    for v in run.verdicts:
        name = f"timing {v.get('spec', '?')}: {v.get('constraint', '?')}"
        occ = v.get("occurrence")
        if type(occ) is int and occ > 0:  # the second and later, counted from 1 as the
            name += f" #{occ + 1}"  # report's diagrams and `hil check` count them
        status = v.get("status", "error")
        out.append((name, status, f"{status}: {v.get('message', '')}"))
    return out


def failure_text(run: RunData) -> tuple[str, str]:
    """(first, all) of what did not pass in a plan run, as the JUnit failure gives it (and
    pytest's report of a collected plan): `step 03 wait_until ...: fail 300.0 ms
    (plans/x.yaml:13): message`, a line per step or verdict."""
    bad = [(n, t) for n, s, t in _lines(run) if s not in ("pass", "skipped")]
    # no step or verdict to name (a pytest test's recording): the result's own reason
    why = str(run.metadata.get("hil.result", {}).get("reason") or "")
    first = f"{bad[0][0]}: {bad[0][1]}" if bad else (why or run.status or "not passed")
    return first, "\n".join(f"{n}: {t}" for n, t in bad) or first


def case_properties(run: RunData, junit_dir: str | Path | None) -> list[tuple[str, str]]:
    """The properties of a plan's testcase, the same from `hil run` and from pytest: the
    recording (relative to the JUnit file), bench, the bench's clock, status, and one per
    step and verdict."""
    props = [("recording", recording_ref(run.path, junit_dir)), ("bench", run.bench),
             ("clock", run.info()["clock"]),
             ("status", run.status), ("truncated", str(run.truncated).lower())]
    return props + [(name, text) for name, _status, text in _lines(run)]


def plan_case(run: RunData, junit_dir: str | Path | None) -> ET.Element:
    """One testcase per plan run (pytest's shape): its steps and verdicts as properties and in
    system-out, a failure naming what failed first."""
    try:  # the plan's wall time, as the summary table and the index give it (and pytest);
        # its steps' durations, on the run's clock, are in the properties
        secs = float(run.metadata["hil.result"]["duration_ms"]) / 1e3
    except (KeyError, TypeError, ValueError):  # a killed run: the steps it recorded
        secs = sum(st.duration_ns for st in run.steps) / 1e9
    tc = ET.Element("testcase", classname=CLASSNAME, name=run.plan, time=f"{secs:.6f}")
    props = ET.SubElement(tc, "properties")
    for k, v in case_properties(run, junit_dir):
        ET.SubElement(props, "property", name=k, value=v)
    lines = _lines(run)
    status = run.status  # the plan's own verdict (an allowed inconclusive still passes)
    if status == "skipped":
        ET.SubElement(tc, "skipped", message="not run")
    elif status != "pass":  # anything else never passes (an "unknown" run included)
        tag = NOT_PASSED.get(status, "error")
        first, text = failure_text(run)
        if run.status_note:
            first, text = run.status_note, f"{run.status_note}\n{text}"
        el = ET.SubElement(tc, tag, message=first, type=status)
        el.text = text
    out = ET.SubElement(tc, "system-out")
    out.text = "\n".join(f"{n}: {t}" for n, _s, t in lines)
    return tc


def junit_xml(recordings: list[str | Path], junit_dir: str | Path | None = None) -> str:
    """One testsuite `hil`, one testcase per recording (plan run)."""
    root = ET.Element("testsuites", name="hil")
    suite = ET.SubElement(root, "testsuite", name="hil")
    total = 0.0
    for p in recordings:
        tc = plan_case(load_run(p, truth=False), junit_dir)
        total += float(tc.get("time", "0"))
        suite.append(tc)
    cases = suite.findall("testcase")
    for el in (suite, root):
        el.set("tests", str(len(cases)))
        el.set("failures", str(sum(c.find("failure") is not None for c in cases)))
        el.set("errors", str(sum(c.find("error") is not None for c in cases)))
        el.set("skipped", str(sum(c.find("skipped") is not None for c in cases)))
        el.set("time", f"{total:.6f}")
    for el in root.iter():  # text from the recording: only what XML 1.0 can carry
        if el.text:
            el.text = xml_text(el.text)
        for k, v in el.attrib.items():
            el.set(k, xml_text(v))
    ET.indent(root)
    return ET.tostring(root, encoding="unicode", xml_declaration=True) + "\n"


def write_junit(recordings: list[str | Path], out: str | Path) -> Path:
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(out, junit_xml(recordings, out.parent))
    return out
