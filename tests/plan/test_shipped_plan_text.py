"""Shipped plans say what their file says: a description with ` #` in it is quoted, or YAML
cuts it there as a comment (the index showed "PR#1 -> JUMP (DLY")."""

from __future__ import annotations

from pathlib import Path

import pytest

from hil.paths import plans_dir
from hil.plan.plan import load_plan

PLANS = sorted(Path(plans_dir()).glob("*.yaml"))


def _description_block(text: str) -> str:
    lines = text.splitlines()
    i = next(k for k, ln in enumerate(lines) if ln.startswith("description:"))
    block = [lines[i].split(":", 1)[1].strip()]
    for ln in lines[i + 1:]:
        if not ln.startswith((" ", "\t")):
            break
        block.append(ln.strip())
    return " ".join(block)


@pytest.mark.parametrize("path", PLANS, ids=[p.stem for p in PLANS])
def test_no_description_is_cut_by_a_comment(path: Path) -> None:
    raw = _description_block(path.read_text(encoding="utf-8"))
    if raw[:1] not in "\"'>|":
        assert " #" not in raw, f"{path.name}: quote the description, ' #' starts a comment"
    assert load_plan(path).description.split()[-1] == raw.strip("\"'").split()[-1]


def test_the_check_sees_a_cut_description(tmp_path: Path) -> None:
    p = tmp_path / "p.yaml"
    p.write_text("name: p\ndescription: PR#1 -> JUMP (DLY #1) -> PR#4\nsteps:\n  - wait: 1ms\n")
    assert load_plan(p).description == "PR#1 -> JUMP (DLY"  # what YAML makes of it
    assert " #" in _description_block(p.read_text())
