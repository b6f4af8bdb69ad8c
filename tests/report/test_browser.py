"""The HTML report of a real virtual-bench run: timing diagrams drawn from the recording, and
the page rendered by a real browser (headless Chromium screenshot, non-blank)."""

from __future__ import annotations

import io
import shutil
import struct
import subprocess
import zlib
from pathlib import Path

import pytest

from hil.bench.bench import load_bench
from hil.plan.plan import find_plans, load_plan
from hil.plan.runner import run_plans

pytestmark = pytest.mark.integration

CHROMIUM = next((shutil.which(n) for n in ("chromium", "chromium-browser", "google-chrome")
                 if shutil.which(n)), None)


@pytest.fixture(scope="module", params=["servo_on_off_brake", "homing_pr"])
def report(tmp_path_factory, request) -> Path:
    out = tmp_path_factory.mktemp("report")
    [r] = run_plans([load_plan(p) for p in find_plans([request.param])], load_bench(),
                    out, stream=io.StringIO(), allow_inconclusive=True)
    assert r.html, r.error
    return Path(r.html)


def test_report_draws_expected_vs_observed_diagrams(report: Path):
    html = report.read_text()
    assert "Timing diagrams: observed signals and expected windows" in html
    # hil.timing.render.svg: one diagram per checked spec, titled by the spec
    titles = {"servo_on_off_brake": ("servo_on_brake", "servo_off_brake"),
              "homing_pr": ("homing_pr",)}[report.stem]
    assert all(f"<title>{t}: " in html for t in titles), titles
    assert report.stat().st_size < 1_000_000  # under 1 MB, a homing report included
    assert "Diagram not drawn" not in html
    assert "<script src" not in html and "<link" not in html  # self-contained, offline


def _png_pixels(path: Path) -> tuple[int, int, bytes]:
    """(width, height, decompressed scanlines) of a PNG, standard library only."""
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n", "not a PNG"
    pos, idat, size = 8, b"", (0, 0)
    while pos < len(data):
        n, kind = struct.unpack(">I4s", data[pos:pos + 8])
        chunk = data[pos + 8:pos + 8 + n]
        if kind == b"IHDR":
            size = struct.unpack(">II", chunk[:8])
        elif kind == b"IDAT":
            idat += chunk
        pos += 12 + n
    return size[0], size[1], zlib.decompress(idat)


@pytest.mark.skipif(CHROMIUM is None, reason="no chromium on PATH (Debian: apt-get install "
                    "chromium; .ci/run installs it); see docs/plans.md for the manual check")
def test_report_renders_in_headless_chromium(report: Path, tmp_path: Path):
    shot = tmp_path / "report.png"
    cmd = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
           f"--user-data-dir={tmp_path / 'profile'}", f"--screenshot={shot}",
           "--window-size=1280,2000", report.resolve().as_uri()]
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert shot.exists(), f"no screenshot; chromium said: {p.stderr[-2000:]}"
    width, height, pixels = _png_pixels(shot)
    assert (width, height) == (1280, 2000)
    # non-blank: a white page decompresses to (almost) one byte value; a report has text,
    # tables and coloured diagrams
    assert len(set(pixels)) > 50, "screenshot is blank"
    nonwhite = sum(1 for b in pixels[::97] if b < 0xF0)
    assert nonwhite > len(pixels[::97]) // 100, "screenshot is (almost) blank"
