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
