"""A plan's or step's name reaches the terminal without its escape sequences (helper-139:
`name: "ok\\e]0;pwned\\a\\e[2J"` retitled and cleared the terminal from the progress line,
the -v step lines, the summary table and --list)."""

from __future__ import annotations

import subprocess
import sys

import pytest

pytestmark = pytest.mark.virtual_time

PLAN = """name: "ok\\e]0;pwned\\a\\e[2J"
steps:
  - name: "w\\e[31mRED"
    wait: 1ms
"""


@pytest.mark.parametrize("flags", [["-v"], ["--list"], ["--check"], ["-q"]])
def test_names_are_escaped_on_the_terminal(tmp_path, flags) -> None:
    plan = tmp_path / "esc.yaml"
    plan.write_text(PLAN, encoding="utf-8")
    out = subprocess.run([sys.executable, "-m", "hil.cli", "run", str(plan), "--out",
                          str(tmp_path / "out"), *flags], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr
    both = out.stdout + out.stderr
    assert "\x1b" not in both and "\x07" not in both
    if "--check" not in flags:
        assert "ok\\x1b]0;pwned\\x07\\x1b[2J" in both


def test_names_are_escaped_on_the_pages_too(tmp_path) -> None:
    """helper-139: index.html kept the raw ESC and BEL (HTML-escaped, but still control
    characters, which HTML does not allow); the plan's page and `hil diff` likewise."""
    plan = tmp_path / "esc.yaml"
    plan.write_text(PLAN, encoding="utf-8")
    out = tmp_path / "out"
    run = subprocess.run([sys.executable, "-m", "hil.cli", "run", str(plan), "--out", str(out),
                          "-q"], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    rec = next(out.glob("*.mcap"))
    diff = subprocess.run([sys.executable, "-m", "hil.cli", "diff", str(rec), str(rec),
                           "-o", str(tmp_path / "d.html")], capture_output=True, text=True,
                          timeout=120)
    assert diff.returncode in (0, 1), diff.stderr
    pages = [out / "index.html", out / "esc.html", tmp_path / "d.html"]
    assert len(pages) == 3 and all(p.exists() for p in pages), pages
    for page in pages:
        text = page.read_text(encoding="utf-8")
        assert "\x1b" not in text and "\x07" not in text, page.name
    assert "ok\\x1b]0;pwned\\x07\\x1b[2J" in (out / "index.html").read_text(encoding="utf-8")
