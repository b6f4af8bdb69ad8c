"""Output names keep the letters of every script: a Czech or Chinese plan name is not turned
into underscores (it was `zkou_ka_brzdy` for `zkouška brzdy`)."""

from __future__ import annotations

import unicodedata
from pathlib import Path

from hil.fileio import safe_stem
from hil.plan.plan import load_plan
from hil.plan.runner import output_stems
from hil.pytest_plugin import _safe_name


def _plan(path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(f"name: {path.stem}\nsteps:\n  - expect: {{do: {{SRDY: on}}}}\n",
                    encoding="utf-8")
    return path


def test_plan_output_names_keep_letters_of_every_script(tmp_path: Path) -> None:
    paths = [_plan(tmp_path / "zkouška brzdy.yaml"), _plan(tmp_path / "回原點.yaml"),
             _plan(tmp_path / "a#b?c.yaml")]
    assert output_stems([load_plan(p) for p in paths]) == ["zkouška_brzdy", "回原點", "a_b_c"]


def test_a_decomposed_spelling_is_the_same_name() -> None:
    """NFD (as some file systems hand names back) and NFC give one name."""
    nfd = unicodedata.normalize("NFD", "zkouška")
    assert nfd != "zkouška"
    assert safe_stem(nfd) == safe_stem("zkouška") == "zkouška"


def test_no_separator_or_anchor_survives() -> None:
    for bad in ("a/b", "a\\b", "a#b", "a?b", "a b", "a\x00b", "a:b"):
        out = safe_stem(bad)
        assert not set(out) & set("/\\#? \x00:"), out


def test_pytest_recording_names_keep_letters_too() -> None:
    assert _safe_name("tests/test_brzda.py::test_zkouška") == "tests_test_brzda.py_test_zkouška"
