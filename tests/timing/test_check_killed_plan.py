"""`hil check` of a killed plan run (helper-84's review): the plan's checks each had their own
`since`, `bind` and `constants`, and what the run did after the cut was never recorded.

* Cut before its first check_timing step, the file holds none of the plan's checks: judging
  the specs with their defaults instead gave FAILs of scenarios the plan never checked that
  way (homing_pr with ref_dir +1 where the plan set -1). Exit 4, saying why, nothing judged.
* With `--whole` (asked for), an event not seen before the file's end is unknown, as after
  damage: inconclusive, not "it never did".
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import pytest

from hil.cli import main as hil
from hil.record.reader import Recording
from hil.timing.source import RecordingSource
from tests.record.rec_helpers import plan_recording
from tests.timing.test_check_incomplete import chunk_offsets


@pytest.fixture(scope="module")
def homing(tmp_path_factory) -> Path:
    return plan_recording(tmp_path_factory.mktemp("homing"), "homing_pr")


def _cuts_before_the_first_check(path: Path, most: int = 4) -> list[int]:
    """File offsets of whole chunks whose first message was logged before the plan's first
    check_timing record (cut there, the file holds none), `most` of them spread out."""
    data = path.read_bytes()
    first = min(lt for _topic, lt, _t, _m in Recording.open(path).messages("/timing/verdicts"))
    offs = [off for off in chunk_offsets(data)[1:]
            if struct.unpack_from("<Q", data, off + 9)[0] <= first]  # message_start_time
    step = max(1, len(offs) // most)
    return offs[::step][:most]


def test_a_run_killed_before_its_first_check_is_incomplete_not_judged(homing, tmp_path,
                                                                     capsys):
    data = homing.read_bytes()
    cuts = _cuts_before_the_first_check(homing)
    assert len(cuts) >= 3, cuts  # the run's first seconds span several chunks
    for off in cuts:
        cut = tmp_path / "cut.mcap"
        cut.write_bytes(data[:off])
        code = hil(["check", str(cut)])
        out, err = capsys.readouterr()
        assert code == 4, (off, out, err)
        assert "FAIL" not in out and "PASS" not in out, (off, out)
        assert "none of the plan's check_timing steps" in err and "homing_pr" in err, err
        assert "truncated (no footer" in err, err
        assert hil(["check", str(cut), "--json"]) == 4
        assert json.loads(capsys.readouterr().out) == []


def test_whole_on_a_killed_run_reads_a_missing_event_as_cut_not_absent(homing, tmp_path,
                                                                      capsys):
    data = homing.read_bytes()
    seen = 0
    for off in _cuts_before_the_first_check(homing):
        cut = tmp_path / "cut.mcap"
        cut.write_bytes(data[:off])
        hil(["check", str(cut), "--whole", "--json"])
        vs = json.loads(capsys.readouterr().out)
        assert not [v for v in vs if "it never did" in v["message"]], off
        missing = [v for v in vs if "not seen in the" in v["message"]]
        assert all(v["status"] in ("inconclusive", "skipped") and "no footer: the run was "
                   "killed" in v["message"] for v in missing), missing  # a window's: unknown
        seen += len(missing)
    assert seen  # some cut fell while the homing run was under way


def test_the_end_cut_is_only_for_a_file_at_rest(homing, tmp_path):
    """A plan's own check reads its recording while it is being written (no footer yet):
    that is no cut. `hil check` and `hil report` read a file at rest."""
    data = homing.read_bytes()
    off = chunk_offsets(data)[-1]
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[:off + 30])  # into the last chunk: its header is there
    live = RecordingSource(cut)
    rest = RecordingSource(cut, at_rest=True)
    assert live.truncated and live.cut_ns is None and live.cut_kind is None
    assert rest.cut_kind == "end" and rest.cut_ns is not None
    whole = RecordingSource(homing, at_rest=True)
    assert whole.cut_ns is None and whole.cut_kind is None


def test_damage_of_unknown_time_cuts_after_the_last_message_read(homing, tmp_path, capsys):
    """A record whose damage gives no time (an opcode zeroed mid-file, not a chunk whose
    header still reads) was judged as if the file were whole up to there: the events after
    it were "never" seen, FAIL. What followed could not be read: inconclusive."""
    data = bytearray(homing.read_bytes())
    off = _cuts_before_the_first_check(homing)[-1]
    data[off] = 0  # the chunk's opcode: no record 0x00, and non-zero bytes follow
    bad = tmp_path / "op0.mcap"
    bad.write_bytes(bytes(data))
    src = RecordingSource(bad)
    assert src.corrupt and src.cut_kind == "damage" and src.cut_ns is not None
    hil(["check", str(bad), "--whole", "--json"])  # (the specs' defaults: a FAIL may stand)
    vs = json.loads(capsys.readouterr().out)
    assert not [v for v in vs if "it never did" in v["message"]], vs
    cut = [v for v in vs if "before the recording's damage" in v["message"]]
    assert cut and all(v["status"] in ("inconclusive", "skipped") for v in cut)
