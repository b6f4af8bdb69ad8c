"""What a reviewer's tools say of a recording that contradicts itself, from an outside probe
of `hil report`, `hil check`, `hil diff`, `hil inspect` and `hil export` (wave 3, session 31,
helper-137)."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from rec_helpers import copy_mcap, plan_recording

from hil.cli import main as hil

pytestmark = pytest.mark.virtual_time


@pytest.fixture(scope="module")
def emgs(tmp_path_factory) -> Path:
    """A genuine passing recording with check steps and their verdicts."""
    return plan_recording(tmp_path_factory.mktemp("emgs"), "emgs")


def _first_changed(topic_wanted: str, change):
    done = []

    def message(topic: str, data: bytes, lt: int) -> tuple[bytes, int]:
        if topic == topic_wanted and not done:
            new = change(json.loads(data))
            if new is not None:
                done.append(1)
                return json.dumps(new).encode(), lt
        return data, lt
    return message


@pytest.mark.parametrize("status", ["FAIL", "failed", "maybe"])
def test_a_pass_result_over_a_verdict_status_no_check_gives_is_an_error(emgs, tmp_path,
                                                                          status):
    """The page said PASS over a verdict table counting "1 FAIL"; the JUnit said pass."""
    bad = copy_mcap(emgs, tmp_path / "v.mcap", _first_changed(
        "/timing/verdicts", lambda o: o | {"status": status} if o.get("status") == "pass"
        else None))
    out = tmp_path / "v.xml"
    assert hil(["report", str(bad), "-o", str(tmp_path / "v.html"), "--junit", str(out)]) == 0
    suite = ET.parse(out).getroot()
    assert suite.get("errors") == "1" and suite.get("failures") == "0"
    err = suite.find(".//testcase/error")
    assert err is not None and f"has the status {status!r}" in err.get("message")
    page = (tmp_path / "v.html").read_text(encoding="utf-8")
    assert "b-error" in page and "result says pass, but timing verdict emgs" in page
