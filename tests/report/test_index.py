"""Issue 18, review: one index.html per run (rendered by headless Chromium), and every plan
report names the run, labels verdicts with their step, reads time in ms from the plan start
and shows the bus frames around a failing check.

Two real plan runs on the virtual bench: servo_on_off_brake on a bench whose drive is 30 ms
late with BRKR (`dev_brake_on_delay_ms`, so `servo_on_brake` fails: P1.042, L8492-8501),
and pv_move as it is (passes)."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest
import yaml

from hil.record.recorder import versions
from hil.report.index import write_index

pytestmark = [pytest.mark.integration,  # `hil run` in virtual time (a copy of the built-in
              pytest.mark.virtual_time]  # bench): never rerun (tests/conftest.py)

CHROMIUM = next((shutil.which(n) for n in ("chromium", "chromium-browser", "google-chrome")
                 if shutil.which(n)), None)
ROOT = Path(__file__).resolve().parents[2]


def _late_bench(tmp: Path) -> Path:
    data = yaml.safe_load((ROOT / "fixtures/benches/virtual.yaml").read_text())
    data["name"] = "late"
    data["drives"]["drive1"]["options"] = {"dev_brake_on_delay_ms": 30}
    p = tmp / "late.yaml"
    p.write_text(yaml.safe_dump(data, sort_keys=False))
    return p


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    """`hil run` itself (its main), as a user runs it: two plans, one failing."""
    from hil.cli import main

    tmp = tmp_path_factory.mktemp("index")
    out = tmp / "out"
    rc = main(["run", "servo_on_off_brake", "pv_move", "--bench", str(_late_bench(tmp)),
               "--out", str(out), "-q", "--plans", str(ROOT / "plans")])
    assert rc == 1  # one plan failed
    return out


def _text(html: str) -> str:
    return re.sub(r"\s+", " ", re.sub(r"<[^>]+>", " ", html))


def test_run_writes_index_with_every_plan(run_dir: Path):
    html = (run_dir / "index.html").read_text()
    text = _text(html)
    assert "1/2 PASSED" in text
    v = versions()
    for item in (v["hil"], v["git_revision"], "late", "UTC"):
        assert item in text, item
    rows = re.findall(r"<tr class='plan'>(.*?)</tr>", html, re.S)
    assert len(rows) == 2
    brake, pv = rows
    assert "servo_on_off_brake" in brake and ">FAIL<" in brake
    # 4 verdicts: 3 pass, servo_on_brake's "BRKR rises P1.042 after servo on" fails
    assert "3 / 1 / 0" in brake and "9/9" not in brake
    assert "pv_move" in pv and ">PASS<" in pv
    for stem in ("servo_on_off_brake", "pv_move"):
        for suffix in (".html", ".mcap", ".junit.xml"):
            assert f"href='{stem}{suffix}'" in html, (stem, suffix)
    assert re.search(r"\d+\.\d\d s", brake)


def test_plan_report_names_run_steps_and_plan_time(run_dir: Path):
    html = (run_dir / "servo_on_off_brake.html").read_text()
    text = _text(html)
    v = versions()
    for item in ("date", "UTC", v["hil"], "host", "late", v["git_revision"]):
        assert item in text, item
    # each verdict row names its step: both checks are steps 8 and 9 of the plan
    rows = re.findall(r"<tr class='v' data-status='\w+'><td><a href='#step-(\d)'>\d</a>: "
                      r"([^<]*)</td><td>([^<]*)</td>", html)
    assert {(n, label, spec) for n, label, spec in rows} == {
        ("8", "check_timing servo_on_brake", "servo_on_brake"),
        ("9", "check_timing servo_off_brake", "servo_off_brake")}
    # time axes: ms from the plan start, never epoch (a 1.7e12 ms axis label)
    assert "ms from the plan start" in html
    assert not re.search(r"ms from t = \d{9,}", html)
    starts = [float(x) for x in re.findall(r"<td>(-?\d+\.\d) ms</td><td>\d+\.\d ms</td>", html)]
    assert len(starts) >= 9 and all(0 <= s < 5000 for s in starts)


def test_bus_log_shows_frames_around_the_failing_check(run_dir: Path):
    html = (run_dir / "servo_on_off_brake.html").read_text()
    part = html[html.index("Bus log around failing checks"):]
    part = part[:part.index("</pre>")]
    assert "BRKR rises P1.042 after servo on" in part
    lines = re.findall(r"^(<b>)?\s*(-?\d+\.\d+) ms\s+(\S+)\s+level=(\w+)", part, re.M)
    edges = [(bool(b), topic, lvl) for b, _t, topic, lvl in lines]
    # the judged interval: servo on (SON closed + P2.009) .. BRKR (DO6) 100 + 30 ms later;
    # the SON edge itself (DI1) just before it, the servo off after it
    k = edges.index((True, "/dio/drive1/DO6", "True"))
    assert edges[k - 1] == (False, "/dio/drive1/DI1", "True")
    assert (False, "/dio/drive1/DI1", "False") in edges[k + 1:]
    assert [e for e in edges if e[0]] == [(True, "/dio/drive1/DO6", "True")]
    delta = float(lines[k][1]) - float(lines[k - 1][1])
    assert 125 < delta < 150
    times = [float(t) for t in re.findall(r"^\s*(-?\d+\.\d+) ms", part, re.M)]
    assert times == sorted(times) and len(times) > 2  # frames before and after too


def test_index_of_an_unreadable_recording_says_so(tmp_path: Path):
    bad = tmp_path / "broken.mcap"
    bad.write_bytes(b"not an mcap")
    html = write_index([bad], tmp_path / "index.html").read_text()
    assert ">UNREADABLE<" in html and "0/1 PASSED" in html


@pytest.mark.skipif(CHROMIUM is None, reason="no chromium on PATH")
def test_index_renders_in_headless_chromium(run_dir: Path, tmp_path: Path):
    """Chromium parses the page: its DOM has the plan table with both rows and their links,
    and every link resolves to a file of the run directory."""
    index = run_dir / "index.html"
    cmd = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu",
           "--disable-background-networking", "--disable-dev-shm-usage",
           f"--user-data-dir={tmp_path / 'profile'}", "--dump-dom", index.resolve().as_uri()]
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    dom = p.stdout
    assert "<table id=\"plans\">" in dom, p.stderr[-2000:]
    assert len(re.findall(r"<tr class=\"plan\">", dom)) == 2
    hrefs = re.findall(r"href=\"([^\"]+)\"", dom)
    assert len(hrefs) >= 8
    for h in hrefs:
        assert (run_dir / h).is_file(), h
    shot = tmp_path / "index.png"
    cmd = [*cmd[:-2], f"--screenshot={shot}", "--window-size=1200,600", index.resolve().as_uri()]
    subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert shot.exists() and shot.stat().st_size > 5000
