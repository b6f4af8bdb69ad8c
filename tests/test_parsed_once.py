"""`fileio.parsed_once`: the tables, EDS and specs a run reads for every plan are parsed once
per file version, and again as soon as the file changes."""

from __future__ import annotations

import os

from hil.fileio import parsed_once
from hil.profile.alarms import AlarmTable
from hil.profile.params import ParamTable


def test_parsed_once_per_file_version_and_kind(tmp_path):
    f = tmp_path / "table.csv"
    f.write_text("a\n")
    calls: list[str] = []

    def parse() -> str:
        calls.append(f.read_text())
        return f.read_text()

    assert parsed_once("t", f, parse) == "a\n"
    assert parsed_once("t", str(f), parse) == "a\n"  # the same file, named as a str
    assert calls == ["a\n"]
    assert parsed_once("other kind", f, parse) == "a\n"  # another kind parses for itself
    assert parsed_once("t", f, parse, 5) == "a\n"  # and so does another key (a node id)
    assert len(calls) == 3
    f.write_text("bb\n")  # a new version (its size differs, whatever the mtime's tick)
    assert parsed_once("t", f, parse) == "bb\n"
    st = f.stat()
    f.write_text("cc\n")  # same size: the mtime tells it
    os.utime(f, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000_000))
    assert parsed_once("t", f, parse) == "cc\n"
    assert calls[-2:] == ["bb\n", "cc\n"]


def test_a_file_that_cannot_be_stated_is_parsed_every_time(tmp_path):
    calls = []
    missing = tmp_path / "gone.csv"
    for _ in range(2):
        parsed_once("t", missing, lambda: calls.append(1))
    assert calls == [1, 1]


def test_an_edited_parameter_table_is_read_again(tmp_path):
    """A table copied and then edited gives the edited rows, not the first read's."""
    src = ParamTable.load()
    path = tmp_path / "p.csv"
    from hil.paths import fixture
    text = fixture("drive", "a3_parameters.csv").read_text(encoding="utf-8")
    path.write_text(text, encoding="utf-8")
    first = ParamTable.load(path)
    assert len(first) == len(src)
    assert ParamTable.load(path) is first  # parsed once
    lines = text.splitlines(keepends=True)
    path.write_text("".join(lines[:-1]), encoding="utf-8")  # the last row gone
    assert len(ParamTable.load(path)) == len(src) - 1
    assert AlarmTable.load() is AlarmTable.load()
