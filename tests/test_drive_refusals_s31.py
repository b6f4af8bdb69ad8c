"""`hil drive` reports what its pulse and DI/DO faces refused (session 31)."""

from __future__ import annotations

import io

from hil.transport.pulse import open_pulse
from hil.virtual.cli import report_refusals
from hil.virtual.stack import DriveSpec, VirtualDriveStack


def test_each_kind_is_reported_once_per_new_refusal() -> None:
    out, seen = io.StringIO(), {}
    report_refusals({"pulse thing(s)": (2, "bad freq")}, seen, out)
    report_refusals({"pulse thing(s)": (2, "bad freq")}, seen, out)  # nothing new: silent
    report_refusals({"pulse thing(s)": (5, "bad form"), "DI/DO level(s)": (1, "DI11")}, seen,
                    out)
    assert out.getvalue().splitlines() == [
        "hil drive: refused 2 pulse thing(s) (2 in all); last: bad freq",
        "hil drive: refused 3 pulse thing(s) (5 in all); last: bad form",
        "hil drive: refused 1 DI/DO level(s) (1 in all); last: DI11",
    ]


def test_a_stack_counts_the_segments_its_drive_refused() -> None:
    """A well-formed segment the model refuses (a pulse form it does not know) is counted
    by the face; a clean stack reports nothing."""
    stack = VirtualDriveStack(DriveSpec(name="d", pulse="virtual:refuse-s31")).start()
    plc = open_pulse("virtual:refuse-s31", role="master")
    try:
        assert stack.refusals() == {}
        stack.pulse_face._on_line("seg", {"freq": 1000.0, "direction": 1, "count": 5,
                                          "form": "morse", "logic": 0}, 0, None)
        (what, (n, last)), = stack.refusals().items()
        assert what == "pulse segment(s) the drive refused" and n == 1 and "morse" in last
    finally:
        plc.close()
        stack.stop()


def test_a_long_reason_is_clipped() -> None:
    """A reason quotes the peer's field: a 5 MB `freq` made a 5 MB stderr line, on the pipe
    a runner shares with the drive's control replies (helper-138)."""
    out = io.StringIO()
    report_refusals({"pulse thing(s)": (1, "freq " + "9" * 5_000_000)}, {}, out)
    line = out.getvalue()
    assert len(line) < 1000 and "more)" in line
