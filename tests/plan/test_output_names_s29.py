"""Output names keep the letters of every script: a Czech or Chinese plan name is not turned
into underscores (it was `zkou_ka_brzdy` for `zkouška brzdy`)."""

from __future__ import annotations

import unicodedata
from pathlib import Path

from hil.fileio import fit_bytes, safe_stem
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


def test_marks_of_every_script_are_kept_and_format_characters_are_not() -> None:
    """`\\w` dropped combining and spacing marks without a precomposed form (helper-123):
    `हिन्दी परीक्षण` became `ह_न_द__पर_क_षण`. A bidi override is no name character."""
    assert safe_stem("हिन्दी परीक्षण") == "हिन्दी_परीक्षण"
    assert safe_stem("مُحَرِّك") == "مُحَرِّك"
    assert safe_stem("q\u0307") == "q\u0307"
    assert safe_stem("a\u202eb") == "a_b"
    assert safe_stem("a  b", collapse=True) == "a_b"


def test_a_long_name_fits_a_file_name_in_bytes(tmp_path: Path) -> None:
    """150 characters of CJK are 450 bytes: past the 255 a file name holds (helper-123:
    "File name too long" for a test named in Chinese)."""
    long = "test_" + "制动器释放时间" * 13
    name = _safe_name(f"tests/test_x.py::{long}")
    assert len(name.encode("utf-8")) <= 150
    (tmp_path / f"{name}.junit.xml").write_text("x", encoding="utf-8")  # it can be made
    assert fit_bytes("制动器", 4) == "制"  # never half a character
    [stem] = output_stems([load_plan(_plan(tmp_path / ("制" * 80 + ".yaml")))])
    assert len(stem.encode("utf-8")) <= 200


def test_index_links_to_names_with_anchors_are_encoded(tmp_path: Path) -> None:
    """A `#` in a file name started a fragment in the index's link."""
    from hil.report.index import _link

    target = tmp_path / "a #1 %.html"
    target.write_text("x", encoding="utf-8")
    assert "href='a%20%231%20%25.html'" in _link(target, tmp_path, "x")


def test_a_cut_name_is_the_same_whatever_is_selected(tmp_path: Path) -> None:
    """Two plans whose names differ only past the cut were both cut to one stem, and the
    second got `-2`, which depended on the selection: `--lf` then ran one plan under the
    other's name and overwrote its recording (helper-125)."""
    a = _plan(tmp_path / ("制" * 80 + "甲.yaml"))
    b = _plan(tmp_path / ("制" * 80 + "乙.yaml"))
    both = output_stems([load_plan(a), load_plan(b)])
    assert len(set(both)) == 2
    assert output_stems([load_plan(b)]) == [both[1]]  # alone, the same name as in the pair
    assert output_stems([load_plan(a)]) == [both[0]]
    assert all(len(s.encode("utf-8")) <= 200 for s in both)
