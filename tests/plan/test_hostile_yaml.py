"""Hostile plan and bench files are refused quickly, with `file:line`, never a traceback
(issue 12, "Input files"): alias bombs, huge files, NUL and random bytes, deep nesting."""

from __future__ import annotations

import random
import subprocess
import sys
import time
from pathlib import Path

import pytest

from hil.bench.bench import load_bench
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


@pytest.mark.parametrize("char", ["\u2028", "\u2029", "\x85"])
def test_a_break_only_yaml_sees_is_refused_on_its_own_line(tmp_path, char):
    """YAML breaks a line at U+2028, U+2029 and U+0085 and editors do not, so every later
    error named the line after the one it was on (an outside fuzz)."""
    p = tmp_path / "odd.yaml"
    p.write_text(f"name: x\ndescription: 'a{char}b'\nsteps:\n  - wait: 1 parsec\n",
                 encoding="utf-8")
    e = _refused(p)
    assert e.line == 2 and f"U+{ord(char):04X}" in e.problem, e


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


# ---------------------------------------------------------------- type confusion in steps

_WEIRD = [None, True, False, 0, -1, 1.5, float("nan"), 10**30, "", "x", "-5ms", "off",
          "P9.999", [], {}, ["CN2"], {"a": 1}]


def _paths(o, pre=()):
    if isinstance(o, dict):
        for k, x in o.items():
            yield (*pre, k)
            yield from _paths(x, (*pre, k))
    elif isinstance(o, list):
        for i, x in enumerate(o):
            yield (*pre, i)
            yield from _paths(x, (*pre, i))


def test_mutated_shipped_plans_are_refused_with_file_line_field():
    """Every shipped plan, one value inside its steps swapped for a value of the wrong
    type (a list for a name, a mapping for a command, a string for a flag...), or a key
    dropped: the loader and `check_plan` accept it or refuse it with file, line and field,
    never another exception. Found: `nmt: {..}`, `pr_wait.state: {..}`, `capture_arm.source:
    [..]`, `fault.match.function: {..}` (unhashable), `latch.window.min: x` (the error
    itself failed), `pr_table` fields `type: [..]`, `ins: "off"`, `dest: nan`."""
    import copy

    import yaml

    from hil.bench.yamlio import PlanFileError
    from hil.paths import fixture, plans_dir
    from hil.plan.plan import check_plan, loads_plan
    from hil.plan.runner import timing_specs

    bench, specs = load_bench(fixture("benches", "virtual.yaml")), timing_specs()
    rng = random.Random(77)
    plans = [yaml.safe_load(p.read_text()) for p in sorted(plans_dir().glob("*.yaml"))]
    assert len(plans) > 30
    refused = 0
    for i in range(120):  # ~20 ms each; the corpus in malformed/ pins what it found
        doc = copy.deepcopy(rng.choice(plans))
        path = rng.choice([p for p in _paths(doc) if p[0] == "steps" and len(p) > 2])
        parent = doc
        for k in path[:-1]:
            parent = parent[k]
        if isinstance(parent, dict) and rng.random() < 0.15:
            del parent[path[-1]]
        else:
            parent[path[-1]] = rng.choice(_WEIRD)
        text = yaml.safe_dump(doc, sort_keys=False)
        try:
            check_plan(loads_plan(text, f"m{i}.yaml"), bench, specs)
        except PlanFileError as e:
            assert e.line > 0 and e.field.startswith("steps["), (str(e), text)
            refused += 1
    assert refused > 60


def _shape(x):
    if isinstance(x, dict):
        return (x.line, x.key_lines, {k: _shape(v) for k, v in x.items()})
    if isinstance(x, list):
        return (x.line, x.item_lines, [_shape(v) for v in x])
    return (type(x).__name__, x)


def test_libyaml_and_the_python_loader_agree_on_every_shipped_file_and_error() -> None:
    # the fast path (libyaml) must give the same values and the same line numbers as the
    # pure-Python loader, and a broken file the Python loader's own error
    import yaml

    from hil.paths import fixture, plans_dir
    from hil.yamlio import FileError, _load, load_yaml_text

    if getattr(yaml, "CSafeLoader", None) is None:
        pytest.skip("PyYAML built without libyaml: only the Python loader runs")
    files = [*sorted(plans_dir().rglob("*.yaml")), *sorted(fixture("timing").glob("*.yaml")),
             *sorted(fixture("benches").glob("*.yaml"))]
    assert len(files) > 80
    for f in files:
        text = f.read_text()
        fast = _load(text, str(f), FileError, yaml.CSafeLoader)
        slow = _load(text, str(f), FileError, yaml.SafeLoader)
        assert _shape(fast) == _shape(slow), f
    # a file the project does not ship is read by the Python loader only: libyaml reads
    # some broken text differently (a tab after a value is an error only for PyYAML)
    with pytest.raises(FileError, match=r"user\.yaml:1"):
        load_yaml_text("timeout: 5s\t\n", "user.yaml")
    for bad in ("a: [1, 2\nb: 3\n", "a: 1\n  b: 2\n", "a: 1\na: 2\n", "- &x [*x]\n"):
        shipped = str(plans_dir() / "not_a_plan.yaml")  # the fast path, then the fallback
        with pytest.raises(FileError) as fast_err:
            load_yaml_text(bad, shipped)
        with pytest.raises(FileError) as slow_err:
            _load(bad, shipped, FileError, yaml.SafeLoader)
        assert str(fast_err.value) == str(slow_err.value)


def test_an_alias_chain_deeper_than_the_limit_is_an_error_not_a_crash() -> None:
    # each anchor 60 levels deep holding the previous alias: within the text's depth and
    # alias limits, 1500 levels once expanded
    from hil.yamlio import FileError, load_yaml_text

    lines = []
    for k in range(25):
        inner = f"*a{k - 1}" if k else "0"
        lines.append(f"a{k}: &a{k} " + "[" * 60 + inner + "]" * 60)
    with pytest.raises(FileError, match="nested deeper than 64 levels once aliases"):
        load_yaml_text("\n".join(lines) + "\n", "chain.yaml")


def test_a_long_list_is_refused_as_written_not_as_an_alias_bomb(tmp_path):
    """100 001 values with no alias: refused by the event scan before a node tree is built,
    and not called an alias bomb (helper-139: 33 s and 378 MB for a 520 000-value cam
    table, then "an alias bomb?")."""
    p = tmp_path / "long.yaml"
    p.write_text("name: long\nsteps:\n  - wait: 1ms\nx: [" + ",".join(["1"] * 100_001) + "]\n")
    e = _refused(p)
    assert "more than 100000 values (HIL_YAML_MAX_NODES)" in e.problem, e
    assert "alias" not in e.problem and e.line == 4
