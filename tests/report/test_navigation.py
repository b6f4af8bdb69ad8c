"""What a reviewer navigates (issue 28 item 4): plan pages link back to the index and to
their recording, bus lines wrap instead of being cut, the index has statistics by tag and,
over several runs, each plan's history."""

from __future__ import annotations

import can

from hil.record.recorder import Recorder
from hil.report.html import write_html
from hil.report.index import write_index


def _run(path, plan: str, status: str, tags: list[str]):
    path.parent.mkdir(parents=True, exist_ok=True)
    with Recorder(path, metadata={"plan": plan, "bench": "virtual"}) as rec:
        import json

        rec.add_metadata("hil.plan", {"name": plan, "tags": json.dumps(tags)})
        rec.add_metadata("hil.result", {"status": status})
        rec.can("can0", can.Message(arbitration_id=0x601, data=bytes(8)), "tx", 10**9, None)
    return path


def test_plan_page_links_back_to_index_and_recording(tmp_path):
    rec = _run(tmp_path / "run1" / "a.mcap", "a", "pass", ["brake"])
    write_index([rec], tmp_path / "run1" / "index.html")
    page = write_html(rec, tmp_path / "run1" / "a.html").read_text()
    assert "href='index.html'" in page and "href='a.mcap'" in page
    assert "pre.bus{white-space:pre-wrap" in page


def test_index_statistics_by_tag_and_history(tmp_path):
    recs = [_run(tmp_path / "run1" / "a.mcap", "a", "pass", ["brake", "quick"]),
            _run(tmp_path / "run1" / "b.mcap", "b", "fail", ["brake"]),
            _run(tmp_path / "run2" / "a.mcap", "a", "fail", ["brake", "quick"]),
            _run(tmp_path / "run2" / "b.mcap", "b", "pass", ["brake"])]
    one = write_index(recs[:2], tmp_path / "run1" / "index.html").read_text()
    assert "Statistics by tag" in one and "History across runs" not in one
    assert "<td>brake</td><td class='num'>2</td><td class='num pass'>1</td>" in one
    both = write_index(recs, tmp_path / "index.html").read_text()
    hist = both.split("History across runs", 1)[1]
    assert "<th>run1</th><th>run2</th>" in hist
    row_a = hist.split("<td>a</td>", 1)[1].split("</tr>", 1)[0]
    assert row_a.index("PASS") < row_a.index("FAIL")
