"""The reports say which clock the bench ran on (helper-86 #5: a virtual-time PASS and a
`--clock real` PASS showed the same page, index and JUnit; only the MCAP's `hil.clock`
metadata told them apart)."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import replace
from pathlib import Path

import pytest

from hil.bench.bench import load_bench
from hil.plan.plan import find_plans, load_plan
from hil.report.index import render_index

pytestmark = pytest.mark.virtual_time


def _clock_cell(html: str) -> str:
    head, _, rest = html.partition("<small>clock</small><br><b>")
    assert head != html, "no clock in the run's table"
    return rest.partition("</b>")[0]


@pytest.mark.parametrize("clock", ["virtual", "real"])
def test_the_page_index_and_junit_name_the_clock(tmp_path, clock) -> None:
    from hil.plan.runner import run_plan

    plan = load_plan(find_plans(["sto_both"])[0])
    res = run_plan(plan, replace(load_bench(None), clock=clock), tmp_path)
    assert res.html and res.junit  # (whatever the verdicts: a wall clock may be late)
    assert _clock_cell(Path(res.html).read_text(encoding="utf-8")) == clock
    assert _clock_cell(render_index([res.recording], tmp_path / "index.html")) == clock
    props = {p.get("name"): p.get("value")
             for p in ET.parse(res.junit).getroot().iter("property")}
    assert props["clock"] == clock
