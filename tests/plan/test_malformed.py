"""Every file in tests/plan/malformed/ is rejected with its precise `file:line: field: problem`.

Each file says what it expects in its header: `# expect: LINE: FIELD: PROBLEM-PREFIX`, and
for plans checked against a shipped bench `# bench: NAME` (else the plan is checked alone).
Files named bench_* are bench files.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from hil.bench.bench import load_bench
from hil.bench.yamlio import PlanFileError
from hil.paths import fixture
from hil.plan.plan import check_plan, load_plan
from hil.plan.runner import timing_specs

CORPUS = sorted((Path(__file__).parent / "malformed").glob("*.yaml"))


def _header(path: Path) -> tuple[str, str | None]:
    text = path.read_text()
    expect = re.search(r"^# expect: (.*)$", text, re.M)
    bench = re.search(r"^# bench: (\S+)$", text, re.M)
    assert expect, f"{path.name}: no '# expect:' header"
    return expect.group(1).strip(), bench.group(1) if bench else None


def test_corpus_is_large_enough():
    assert len(CORPUS) >= 20


@pytest.mark.parametrize("path", CORPUS, ids=[p.stem for p in CORPUS])
def test_malformed_file_gets_its_precise_error(path: Path):
    expect, bench = _header(path)
    with pytest.raises(PlanFileError) as ei:
        if path.name.startswith("bench_"):
            load_bench(path)
        else:
            plan = load_plan(path)
            if bench:
                check_plan(plan, load_bench(fixture("benches", f"{bench}.yaml")),
                           timing_specs())
    e = ei.value
    assert e.file == str(path)
    assert str(e).startswith(f"{path}:{e.line}: {e.field}: "), str(e)
    got = f"{e.line}: {e.field}: {e.problem}"
    assert got.startswith(expect), f"\n got: {got}\nwant: {expect}"
