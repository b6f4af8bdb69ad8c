"""Rendering: WaveJSON structure and a well-formed, self-contained SVG."""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET

from hil.paths import fixture
from hil.timing.checker import check
from hil.timing.render import svg, wavejson
from hil.timing.spec import load_spec

from .test_timing_checker import servo_on

SPEC = load_spec(fixture("timing", "servo_on_brake.yaml"))


def test_svg_is_well_formed_and_marks_the_failure_red():
    src = servo_on([155])
    vs = check(SPEC, src)
    text = svg(SPEC, src, vs)
    root = ET.fromstring(text)
    assert root.tag == "{http://www.w3.org/2000/svg}svg"
    assert "http" not in text.replace("http://www.w3.org/2000/svg", "")  # no external refs
    assert "#c62828" in text and "4.0 ms late" in text  # failing band/legend in red
    names = [t.text for t in root.iter("{http://www.w3.org/2000/svg}text")]
    assert {"SON", "BRKR", "servo_on"} <= set(names)


def test_wavejson_structure():
    src = servo_on([150])
    vs = check(SPEC, src)
    wj = wavejson(SPEC, src, vs, cycles=80)
    assert set(wj) >= {"signal", "edge", "head", "foot"}
    lanes = {lane["name"]: lane for lane in wj["signal"]}
    assert set(SPEC.signals) <= set(lanes)
    for name in SPEC.signals:
        assert len(lanes[name]["wave"]) == 80 and set(lanes[name]["wave"]) <= set("01.x=")
    assert "1" in lanes["BRKR"]["wave"]
    nodes = lanes["events"]["node"]
    for edge in wj["edge"]:
        m = re.match(r"(\w)<->(\w) ", edge)
        assert m and m[1] in nodes and m[2] in nodes and " ms " in edge
    assert any("150.0 ms ✓" in e for e in wj["edge"])


def test_a_failing_constraint_does_not_cut_its_occurrences_trigger_out_of_the_diagram():
    """sto: the failing constraint is timed from 'both lost' (16 ms) while the occurrence
    began with STO_A falling at 8 ms; the diagram zoomed on 16-20 ms and hid the cause (an
    outside review)."""
    from hil.timing.checker import Verdict
    from hil.timing.render import _range

    ms = 1_000_000
    ok = Verdict("sto", "torque off", "pass", "", occurrence=1, t_ns=8 * ms, from_ns=8 * ms,
                 to_ns=12 * ms, window_ms=(0.0, 20.0))
    bad = Verdict("sto", "AL500", "fail", "", occurrence=1, t_ns=16 * ms, from_ns=16 * ms,
                  to_ns=20 * ms, window_ms=(10.0, 12.0))
    other = Verdict("sto", "AL500", "pass", "", occurrence=2, t_ns=900 * ms, from_ns=900 * ms)
    lo, hi = _range([ok, bad, other], None, None)  # type: ignore[arg-type]
    assert lo < 8 * ms < 28 * ms <= hi < 900 * ms
