"""The spec loader fuzzed as a stranger would write specs (an outside fuzz found type errors
escaping as tracebacks): every shipped spec with each value in turn replaced by a list, a
mapping, a number, null or text. Each gives a SpecError naming its file and line, or a spec;
nothing else escapes."""

from __future__ import annotations

import random

import pytest
import yaml

from hil.paths import fixture
from hil.timing.spec import SpecError, parse_spec
from hil.yamlio import load_yaml_text

SPECS = sorted(fixture("timing").glob("*.yaml"))
REPLACEMENTS = [["x"], {"a": 1}, 7, None, "zz", -1, 1e308, True, [["start"]], ""]


def _paths(node, path=()):
    if isinstance(node, dict):
        for k, v in node.items():
            yield from _paths(v, (*path, k))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from _paths(v, (*path, i))
    yield path


def _replaced(doc, path, value):
    if not path:
        return value
    out = doc.copy() if isinstance(doc, dict) else list(doc)
    out[path[0]] = _replaced(doc[path[0]], path[1:], value)
    return out


@pytest.mark.parametrize("path", SPECS, ids=[p.stem for p in SPECS])
def test_every_value_replaced_gives_a_spec_error_or_a_spec(path):
    doc = yaml.safe_load(path.read_text(encoding="utf-8"))
    rng = random.Random(path.stem)
    paths = [p for p in _paths(doc) if p]
    for p in rng.sample(paths, min(len(paths), 12)):
        for value in rng.sample(REPLACEMENTS, 3):
            text = yaml.safe_dump(_replaced(doc, p, value), allow_unicode=True)
            try:
                parse_spec(load_yaml_text(text, "mutant.yaml", SpecError), "mutant.yaml")
            except SpecError as e:
                assert str(e).startswith("mutant.yaml:"), (p, value, str(e))
