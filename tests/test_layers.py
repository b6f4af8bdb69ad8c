"""The layer rules of docs/architecture.md hold, and they can be broken (issue 17 item 8)."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LINT = Path(sys.executable).with_name("lint-imports")


def _lint(cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([str(LINT), "--no-cache"], cwd=cwd, capture_output=True, text=True,
                          timeout=120, env={"PYTHONPATH": str(cwd), "PATH": "/usr/bin:/bin"})


def test_contracts_kept_on_the_tree():
    r = _lint(ROOT)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "3 kept, 0 broken" in r.stdout


def test_a_model_importing_a_bus_library_breaks_the_contract(tmp_path):
    """A copy of the package whose model imports python-can and a face: two contracts break."""
    shutil.copytree(ROOT / "hil", tmp_path / "hil")
    shutil.copy(ROOT / "pyproject.toml", tmp_path / "pyproject.toml")
    timebase = tmp_path / "hil" / "model" / "timebase.py"
    extra = "\nimport can  # noqa\nimport hil.faces.dio_face  # noqa\n"
    timebase.write_text(timebase.read_text() + extra)
    r = _lint(tmp_path)
    assert r.returncode != 0
    assert "the model imports no bus or recording library BROKEN" in r.stdout
    assert "the virtual world sits on the faces, the faces on the model BROKEN" in r.stdout
