"""The layer rules of docs/architecture.md hold, and they can be broken (issue 17 item 8)."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import grimp  # import-linter's graph library (test extras)

ROOT = Path(__file__).resolve().parents[1]
LINT = Path(sys.executable).with_name("lint-imports")


def _lint(cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([str(LINT), "--no-cache"], cwd=cwd, capture_output=True, text=True,
                          timeout=120, env={"PYTHONPATH": str(cwd), "PATH": "/usr/bin:/bin"})


def test_contracts_kept_on_the_tree():
    r = _lint(ROOT)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "5 kept, 0 broken" in r.stdout


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


def test_drivers_importing_the_model_break_the_contract(tmp_path):
    """drivers/ never knows a drive is virtual (issue 17 item 2)."""
    shutil.copytree(ROOT / "hil", tmp_path / "hil")
    shutil.copy(ROOT / "pyproject.toml", tmp_path / "pyproject.toml")
    drv = tmp_path / "hil" / "drivers" / "cia402.py"
    drv.write_text(drv.read_text() + "\nimport hil.model.drive  # noqa\n")
    r = _lint(tmp_path)
    assert r.returncode != 0
    assert "drivers never know a drive is virtual BROKEN" in r.stdout


def _cycles(graph) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph.find_modules_directly_imported_by(v):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for m in sorted(graph.modules):
        if m not in index:
            visit(m)
    return out


def test_the_import_graph_has_no_cycles():
    """Issue 17: one-way flow; imports only for type checking do not count."""
    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10000))
    graph = grimp.build_graph("hil", exclude_type_checking_imports=True, cache_dir=None)
    assert _cycles(graph) == []


def test_the_cycle_finder_finds_a_cycle():
    class G:
        modules = frozenset({"a", "b", "c"})

        @staticmethod
        def find_modules_directly_imported_by(m):
            return {"a": {"b"}, "b": {"a"}, "c": set()}[m]

    assert _cycles(G()) == [["a", "b"]]
