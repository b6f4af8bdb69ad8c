"""Hostile plan and bench files are refused quickly, with `file:line`, never a traceback
(issue 12, "Input files"): alias bombs, huge files, NUL and random bytes, deep nesting."""

from __future__ import annotations

import random
import subprocess
import sys
import time
from pathlib import Path

import pytest

from hil.plan.bench import load_bench
from hil.plan.plan import load_plan
from hil.yamlio import FileError

HIL = str(Path(sys.executable).with_name("hil"))

BOMB = """\
name: bomb
a: &a ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]
b: &b [*a, *a, *a, *a, *a, *a, *a, *a, *a]
c: &c [*b, *b, *b, *b, *b, *b, *b, *b, *b]
d: &d [*c, *c, *c, *c, *c, *c, *c, *c, *c]
e: &e [*d, *d, *d, *d, *d, *d, *d, *d, *d]
f: &f [*e, *e, *e, *e, *e, *e, *e, *e, *e]
g: &g [*f, *f, *f, *f, *f, *f, *f, *f, *f]
h: &h [*g, *g, *g, *g, *g, *g, *g, *g, *g]
steps: *h
"""

# few aliases, each expanding a lot: stopped by the value budget, not the alias count
WIDE_BOMB = "name: wide\na: &a [" + ", ".join(["x"] * 5000) + "]\n" + \
    "steps: [" + ", ".join(["*a"] * 40) + "]\n"


def _refused(path: Path, loader=load_plan) -> FileError:
    t0 = time.monotonic()
    with pytest.raises(FileError) as ei:
        loader(path)
    assert time.monotonic() - t0 < 10
    assert str(ei.value).startswith(f"{path}:"), ei.value
    return ei.value


def test_alias_bomb_in_a_plan(tmp_path):
    p = tmp_path / "bomb.yaml"
    p.write_text(BOMB)
    e = _refused(p)
    assert "aliases" in e.problem and e.line >= 2, e


def test_wide_alias_expansion_is_bounded(tmp_path):
    p = tmp_path / "wide.yaml"
    p.write_text(WIDE_BOMB)
    e = _refused(p)
    assert "HIL_YAML_MAX_NODES" in e.problem, e


def test_alias_bomb_in_a_bench(tmp_path):
    p = tmp_path / "bench.yaml"
    p.write_text(BOMB)
    e = _refused(p, load_bench)
    assert "aliases" in e.problem


def test_huge_plan_is_refused_by_size(tmp_path):
    p = tmp_path / "huge.yaml"
    p.write_text("name: huge\nsteps:\n" + "  - wait: 1ms\n" * 200_000)  # 2.8 MB
    e = _refused(p)
    assert "HIL_YAML_MAX_BYTES" in e.problem and e.line == 1


def test_nul_bytes_name_their_line(tmp_path):
    p = tmp_path / "nul.yaml"
    p.write_bytes(b"name: x\nsteps:\n  - wait: 1\x00ms\n")
    e = _refused(p)
    assert e.line == 3 and "NUL" in e.problem


def test_random_bytes(tmp_path):
    rng = random.Random(12)
    for i in range(20):
        p = tmp_path / f"rand{i}.yaml"
        p.write_bytes(bytes(rng.randrange(256) for _ in range(400)))
        _refused(p)


def test_deep_nesting(tmp_path):
    p = tmp_path / "deep.yaml"
    p.write_text("name: deep\nsteps: " + "[" * 5000 + "]" * 5000 + "\n")
    e = _refused(p)
    assert "HIL_YAML_MAX_DEPTH" in e.problem and e.line == 2
    p.write_text("name: deep\nsteps:\n" + "".join("  " * i + f"k{i}:\n" for i in range(1, 200)))
    assert "HIL_YAML_MAX_DEPTH" in _refused(p).problem


def test_limits_can_be_raised(tmp_path, monkeypatch):
    p = tmp_path / "wide.yaml"
    p.write_text(WIDE_BOMB)
    monkeypatch.setenv("HIL_YAML_MAX_NODES", "1000000")
    with pytest.raises(FileError) as ei:  # parses now; refused later as a plan, not as YAML
        load_plan(p)
    assert "HIL_YAML" not in str(ei.value)


def test_hil_run_check_refuses_a_bomb_quickly(tmp_path):
    """The real entry point: exit 2 with `file:line`, bounded time and memory, no traceback."""
    p = tmp_path / "bomb.yaml"
    p.write_text(BOMB)
    t0 = time.monotonic()
    r = subprocess.run([HIL, "run", str(p), "--check"], capture_output=True, text=True,
                       timeout=60)
    assert time.monotonic() - t0 < 30
    assert r.returncode == 2, r.stdout + r.stderr
    assert f"{p}:" in r.stderr and "Traceback" not in r.stderr, r.stderr
