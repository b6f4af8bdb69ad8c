"""Outputs never destroy inputs; devices and endless files; `hil diff`'s reader checks;
selection and output names (issue 23, items 3-6).

Seeded, generated corpora: every spelling of an input path (relative, absolute, `./`, `..`,
a symbolic link, a hard link) against every output flag of every command; every kind of
non-regular file against every file-reading flag. Each must be refused with exit 2 and the
input must keep its bytes.
"""

from __future__ import annotations

import hashlib
import os
import random
import shutil
from pathlib import Path

import can
import pytest

from hil.cli import main as hil
from hil.fileio import FileProblem, atomic_path, read_limited, write_text_atomic
from hil.plan.plan import load_plan
from hil.plan.runner import output_stems
from hil.plan.select import ExprError, select
from hil.record.recorder import Recorder
from tests.timing.test_check_incomplete import corrupt


def _rc(argv: list[str]) -> int:
    try:
        return hil(argv)
    except SystemExit as e:  # argparse
        return e.code if isinstance(e.code, int) else 1


def _digest(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


def _recording(path: Path, n: int = 20) -> Path:
    with Recorder(path, metadata={"plan": path.stem, "bench": "virtual"}) as rec:
        for i in range(n):
            rec.can("can0", can.Message(arbitration_id=0x181, data=bytes([i])), "rx",
                    10**9 + i * 10**6, None)
    return path


@pytest.fixture
def recs(tmp_path: Path, monkeypatch) -> dict[str, Path]:
    monkeypatch.chdir(tmp_path)
    a = _recording(tmp_path / "a.mcap")
    b = _recording(tmp_path / "b.mcap", 25)
    (tmp_path / "sub").mkdir()
    os.symlink(a, tmp_path / "sub" / "link.mcap")
    os.link(b, tmp_path / "sub" / "hard.mcap")
    return {"a": a, "b": b, "dir": tmp_path}


def _spellings(p: Path, root: Path) -> list[str]:
    """Other names of the file `p` (in `root`)."""
    rel = os.path.relpath(p, root)
    return [str(p), rel, f"./{rel}", f"sub/../{rel}", str(root / "sub" / ".." / rel)]


def test_no_output_may_be_an_input(recs) -> None:
    """hil diff -o/--json, hil report -o/--index/--junit, hil export -o onto an input, in
    any spelling, exit 2 and leave every input as it was."""
    a, b, root = recs["a"], recs["b"], recs["dir"]
    link, hard = root / "sub" / "link.mcap", root / "sub" / "hard.mcap"
    before = {p: _digest(p) for p in (a, b)}
    rng = random.Random(23)
    cases = []
    for victim in (a, b):
        names = _spellings(victim, root) + ([str(link)] if victim == a else [str(hard)])
        for name in names:
            cases += [
                ["diff", str(a), str(b), "-o", name],
                ["diff", str(a), str(b), "-o", str(root / "d.html"), "--json", name],
                ["report", str(victim), "-o", name],
                ["report", str(a), str(b), "--index", name],
                ["report", str(victim), "--junit", name],
                ["export", str(victim), "-o", name,
                 "-f", "csv"],
            ]
    rng.shuffle(cases)
    for argv in cases:
        assert _rc(argv) == 2, argv
        assert {p: _digest(p) for p in (a, b)} == before, argv


def test_two_outputs_of_one_call_may_not_be_one_file(recs) -> None:
    a, root = recs["a"], recs["dir"]
    page = str(root / "page.html")
    assert _rc(["report", str(a), "-o", page, "--index", page]) == 2
    assert _rc(["report", str(a), "--junit", page, "--index", f"./{Path(page).name}"]) == 2
    assert _rc(["diff", str(a), str(recs["b"]), "-o", page, "--json", page]) == 2


def test_atomic_write_keeps_the_old_file_on_failure(tmp_path: Path) -> None:
    out = tmp_path / "report.html"
    out.write_text("old")
    with pytest.raises(RuntimeError), atomic_path(out) as tmp:
        tmp.write_text("half a new")
        raise RuntimeError("renderer failed")
    assert out.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report.html"]  # no temp left
    write_text_atomic(out, "new")
    assert out.read_text() == "new"


def test_outputs_onto_a_directory_are_refused(recs) -> None:
    a, root = recs["a"], recs["dir"]
    for argv in (["report", str(a), "-o", str(root / "sub")],
                 ["diff", str(a), str(recs["b"]), "-o", str(root / "sub")],
                 ["export", str(a), "-o", str(root / "sub"), "-f", "csv"]):
        assert _rc(argv) == 2, argv


# -- devices and endless files ----------------------------------------------------------------


def _specials(root: Path) -> list[str]:
    fifo = root / "fifo.yaml"
    os.mkfifo(fifo)
    return ["/dev/zero", "/dev/urandom", str(fifo), str(root)]


@pytest.mark.timeout(60)  # a hung read fails this test, not the suite
def test_no_command_reads_an_endless_or_special_file(recs) -> None:
    a, root = recs["a"], recs["dir"]
    for special in _specials(root):
        for argv in (["check", special], ["check", str(a), "--spec", special],
                     ["report", special], ["diff", str(a), special], ["diff", special, str(a)],
                     ["inspect", special], ["export", special, "-o", str(root / "x.csv")],
                     ["run", "--check", "--bench", special],
                     ["run", "--check", special]):
            assert _rc(argv) == 2, argv


def test_read_limited_caps_what_is_read(tmp_path: Path) -> None:
    p = tmp_path / "big.yaml"
    p.write_bytes(b"a" * 2000)
    assert read_limited(p, 2000) == b"a" * 2000
    with pytest.raises(FileProblem, match="more than 1999 bytes"):
        read_limited(p, 1999)
    with pytest.raises(FileProblem, match="a device"):
        read_limited("/dev/zero", 10)


# -- hil diff uses hil check's reader checks -----------------------------------------------------


def test_diff_refuses_what_is_no_hil_recording(recs) -> None:
    root, a = recs["dir"], recs["a"]
    magic = root / "magic.mcap"
    magic.write_bytes(b"\x89MCAP0\r\n")
    from mcap.writer import Writer
    foreign = root / "foreign.mcap"
    with open(foreign, "wb") as f:
        w = Writer(f)
        w.start()
        sid = w.register_schema("x.Y", "jsonschema", b"{}")
        cid = w.register_channel("/x", "json", sid)
        w.add_message(cid, log_time=1, publish_time=1, data=b"{}")
        w.finish()
    for other in (magic, foreign):
        assert _rc(["diff", str(a), str(other), "-o", str(root / "d.html")]) == 2
        assert _rc(["diff", str(other), str(a), "-o", str(root / "d.html")]) == 2
        # `hil report` too (it drew an ABORTED page for either, exit 0)
        assert _rc(["report", str(other), "-o", str(root / "r.html")]) == 2
        assert not (root / "r.html").exists()


def test_report_refuses_an_output_that_is_a_directory_before_writing_any(recs) -> None:
    """`hil report a.mcap --junit DIR`: refused up front; a.html was written, then exit 2."""
    root, a = recs["dir"], recs["a"]
    (root / "out.xml").mkdir()
    page = root / "page.html"
    assert _rc(["report", str(a), "-o", str(page), "--junit", str(root / "out.xml")]) == 2
    assert not page.exists()


@pytest.mark.parametrize("cut", ["truncated", "damaged"])
def test_diff_says_when_a_recording_is_cut_or_damaged(recs, capsys, cut: str) -> None:
    """As `hil check`: the comparison is written, exit 4 names what is incomplete."""
    root, a = recs["dir"], recs["a"]
    bad = root / f"{cut}.mcap"
    if cut == "truncated":
        data = recs["b"].read_bytes()
        bad.write_bytes(data[: len(data) * 2 // 3])
    else:
        corrupt(recs["b"], bad, 0)  # bytes inverted inside the first chunk
    code = _rc(["diff", str(a), str(bad), "-o", str(root / "d.html")])
    err = capsys.readouterr().err
    assert code == 4, err
    assert "incomplete" in err and str(bad) in err
    assert (cut == "damaged") == ("damaged" in err)
    assert (root / "d.html").is_file()


# -- selection and output names ---------------------------------------------------------------


def test_an_empty_selection_expression_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ExprError, match="empty"):
        select([], keyword="")
    with pytest.raises(ExprError, match="empty"):
        select([], marker="  ")
    assert _rc(["run", "--list", "-k", ""]) == 2
    assert _rc(["run", "--list", "-m", ""]) == 2


def _plan_file(path: Path, name: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(f"name: {name}\nsteps:\n  - expect: {{do: {{SRDY: on}}}}\n")
    return path


def test_output_names_are_unique_within_a_run(tmp_path: Path) -> None:
    """Same file name in different folders: each gets its own recording name."""
    rng = random.Random(5)
    for _ in range(20):
        paths = []
        for k in range(rng.randint(2, 6)):
            folder = tmp_path / f"r{rng.randint(0, 9999)}" / rng.choice(["a", "b", "c"])
            name = rng.choice(["x", "y"])
            paths.append(_plan_file(folder / f"{name}.yaml", f"p{k}"))
        plans = [load_plan(p) for p in paths]
        stems = output_stems(plans)
        assert len(set(stems)) == len(stems), stems
        for p, s in zip(paths, stems, strict=True):
            assert s.endswith(p.stem)
        shutil.rmtree(tmp_path)
        tmp_path.mkdir()


def test_unique_names_stay_inside_the_output_folder_and_never_collide(tmp_path: Path) -> None:
    """Folders up to the root, a renamed name that equals another plan's, case: all unique,
    all plain file names (no separator, no anchor)."""
    paths = [_plan_file(tmp_path / "a" / "x.yaml", "p1"),
             _plan_file(tmp_path / "b" / "a" / "x.yaml", "p2"),
             _plan_file(tmp_path / "c" / "a-x.yaml", "p3"),
             _plan_file(tmp_path / "d" / "A-X.yaml", "p4"),
             _plan_file(tmp_path / "e" / "x-2.yaml", "p5")]
    stems = output_stems([load_plan(p) for p in paths])
    assert len({s.casefold() for s in stems}) == len(stems), stems
    assert all("/" not in s and s and not s.startswith("-") for s in stems), stems


def test_unique_names_keep_single_plans_as_they_were(tmp_path: Path) -> None:
    plans = [load_plan(_plan_file(tmp_path / "a" / "x.yaml", "x")),
             load_plan(_plan_file(tmp_path / "b" / "y.yaml", "y"))]
    assert output_stems(plans) == ["x", "y"]


@pytest.mark.parametrize("jobs", ["1", "2"])
def test_same_named_plans_of_two_folders_both_keep_their_recording(tmp_path, jobs) -> None:
    a = _plan_file(tmp_path / "a" / "same.yaml", "same_a")
    b = _plan_file(tmp_path / "b" / "same.yaml", "same_b")
    out = tmp_path / "out"
    assert _rc(["run", "-q", "-j", jobs, str(a), str(b), "--out", str(out)]) == 0
    recordings = sorted(p.name for p in out.glob("*.mcap"))
    assert recordings == ["a-same.mcap", "b-same.mcap"]


def test_outputs_onto_devices_and_links_keep_them(tmp_path: Path) -> None:
    """Writing a report to /dev/null leaves the device a device; a link is written through."""
    before = os.stat("/dev/null")
    write_text_atomic("/dev/null", "report")
    after = os.stat("/dev/null")
    assert (after.st_mode, after.st_rdev) == (before.st_mode, before.st_rdev)
    target = tmp_path / "real.html"
    target.write_text("old")
    link = tmp_path / "link.html"
    os.symlink(target, link)
    write_text_atomic(link, "new")
    assert link.is_symlink() and target.read_text() == "new"
