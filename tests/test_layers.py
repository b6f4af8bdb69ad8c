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
    assert "8 kept, 0 broken" in r.stdout


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


class _Packages:
    """The import graph of `hil.*` packages: `hil.plan.runner -> hil.virtual.truth` is an
    edge hil.plan -> hil.virtual (top-level modules such as hil.cli count as their own)."""

    def __init__(self, graph) -> None:
        def pkg(m: str) -> str:
            return ".".join(m.split(".")[:2])

        self.edges: dict[str, set[str]] = {}
        for m in graph.modules:
            if not m.startswith("hil"):
                continue
            out = self.edges.setdefault(pkg(m), set())
            out.update(pkg(w) for w in graph.find_modules_directly_imported_by(m)
                       if w.startswith("hil.") and pkg(w) != pkg(m))
        self.modules = frozenset(self.edges)

    def find_modules_directly_imported_by(self, m: str) -> set[str]:
        return self.edges.get(m, set())


def test_no_cycle_between_hil_packages():
    """One way between rooms: no package imports, however indirectly, one that imports it
    back (hil.plan <-> hil.virtual was one). The virtual world is loaded by name
    (hil.bench.virtual_module), which the graph rightly does not see."""
    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10000))
    graph = grimp.build_graph("hil", exclude_type_checking_imports=True, cache_dir=None)
    assert _cycles(_Packages(graph)) == []


def test_a_package_cycle_is_found(tmp_path):
    """The package check fails when the virtual world imports the plans again."""
    shutil.copytree(ROOT / "hil", tmp_path / "hil")
    world = tmp_path / "hil" / "virtual" / "world.py"
    world.write_text(world.read_text() + "\nimport hil.plan.runner  # noqa\n")
    plan = tmp_path / "hil" / "plan" / "runner.py"
    plan.write_text(plan.read_text() + "\nimport hil.virtual.world  # noqa\n")
    code = ("import grimp; "
            "from tests.test_layers import _Packages, _cycles; "
            "g = grimp.build_graph('hil', exclude_type_checking_imports=True, cache_dir=None); "
            "print(_cycles(_Packages(g)))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True,
                       text=True, timeout=120, cwd=tmp_path,
                       env={"PYTHONPATH": f"{tmp_path}:{ROOT}", "PATH": "/usr/bin:/bin"})
    assert "hil.plan" in r.stdout and "hil.virtual" in r.stdout, r.stdout + r.stderr


def test_a_real_bench_session_loads_no_model():
    """docs/architecture.md: importing the runner and its session for a real bench must not
    load the virtual drive (hil.model, hil.faces, hil.virtual)."""
    code = ("import sys, hil.plan.session, hil.plan.runner, hil.bench.bench; "
            "print(sorted(m for m in sys.modules if m.split('.')[:2] in "
            "(['hil', 'model'], ['hil', 'faces'], ['hil', 'virtual'])))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=120, cwd=ROOT)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "[]"


def test_the_cycle_finder_finds_a_cycle():
    class G:
        modules = frozenset({"a", "b", "c"})

        @staticmethod
        def find_modules_directly_imported_by(m):
            return {"a": {"b"}, "b": {"a"}, "c": set()}[m]

    assert _cycles(G()) == [["a", "b"]]


def test_every_package_is_installed():
    """pyproject's explicit package list names every hil package: a package missing there
    works in an editable checkout and is absent from `pip install .` (CI's fresh venv)."""
    import tomllib

    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
                 ["packages"])
    found = {".".join(p.parent.relative_to(ROOT).parts)
             for p in (ROOT / "hil").rglob("__init__.py")}
    assert found - listed == set()
