"""A virtual drive's Modbus face choices from a bench file (`options.extra.modbus`): the
manual's 10 ms frame silence (L15703 "RTU 模式下的傳輸前與傳輸完成後，需有 10 ms 的靜止時段")
against the Modbus serial line's t3.5, chosen per bench; a bad choice names its file, line
and field (docs/manual-choices.md#modbus)."""

from __future__ import annotations

import dataclasses
import json

import pytest
from mcap.reader import make_reader

from hil.bench.bench import load_bench, loads_bench
from hil.bench.yamlio import PlanFileError
from hil.faces.modbus_slave import ModbusFaceOptions
from hil.plan.plan import loads_plan
from hil.plan.runner import run_plan
from hil.protocol import modbus as mb

BUILTIN = load_bench(None)
READS = """\
name: modbus_reads
steps:
  - read: {P1.042: 0, via: modbus}
  - read: {P1.043: 0, via: modbus}
"""


def _reply_gaps(tmp_path, extra: dict) -> list[int]:
    """ns from each request's first recorded byte (tx) to its reply's first (rx)."""
    d = BUILTIN.drives[BUILTIN.default_drive]
    drive = dataclasses.replace(d, options=dict(d.options) | {"extra": extra})
    bench = dataclasses.replace(BUILTIN, drives={**BUILTIN.drives, d.name: drive})
    res = run_plan(loads_plan(READS, str(tmp_path / "modbus_reads.yaml")), bench, tmp_path,
                   reports=False)
    assert res.status == "pass", [(s.index, s.status, s.message) for s in res.steps]
    with open(res.recording, "rb") as f:
        raw = [(json.loads(m.data)["dir"], m.log_time) for _, ch, m in make_reader(f)
               .iter_messages(log_time_order=True) if ch.topic.startswith("/rs485/")
               and ch.topic.endswith("/raw")]
    gaps, sent = [], None
    for direction, t in raw:
        if direction == "tx":
            sent = t
        elif sent is not None:
            gaps.append(t - sent)
            sent = None
    return gaps


@pytest.mark.virtual_time
def test_a_bench_chooses_the_manuals_10_ms_silence(tmp_path) -> None:
    """Every reply comes the manual's 10 ms after its request instead of t3.5 (1.75 ms above
    19200 baud): 8.25 ms later, to the ns, on the virtual clock."""
    t35 = _reply_gaps(tmp_path / "t35", {})
    manual = _reply_gaps(tmp_path / "manual", {"modbus": {"silence": "manual"}})
    assert len(t35) == len(manual) >= 3  # the session's own station read, then the two reads
    assert all(m - t == mb.MANUAL_SILENCE_NS - 1_750_000
               for m, t in zip(manual, t35, strict=True)), (t35, manual)


BAD = [
    ("{silence: 10ms}", "silence must be one of t3.5, manual"),
    ("{silense: manual}", "unknown silense"),
    ("{resync: 1}", "resync must be true or false"),
    ("{p3007_unit_ns: 0}", "p3007_unit_ns must be a whole number"),
    ("{max_read_words: 128}", "max_read_words must be a whole number 1-125"),  # a byte count
    ("{max_write_words: 124}", "max_write_words must be a whole number 1-123"),
    ("{comm_write_refused: [P9.999]}", "comm_write_refused"),
    ("{exception_codes: {}}", "unknown exception_codes"),
    ("[manual]", "modbus: a mapping"),
]


@pytest.mark.parametrize(("value", "said"), BAD)
def test_a_bad_modbus_choice_names_file_line_and_field(value: str, said: str) -> None:
    text = BUILTIN.text
    assert text.count("    options: {}\n") == 1
    bad = text.replace("    options: {}\n", f"    options: {{extra: {{modbus: {value}}}}}\n")
    line = text[:text.index("    options: {}\n")].count("\n") + 1
    with pytest.raises(PlanFileError) as e:
        loads_bench(bad, "bench.yaml")
    msg = str(e.value)
    assert msg.startswith(f"bench.yaml:{line}: drives.") and ".options" in msg, msg
    assert said in msg, msg


def test_good_choices_load_and_reach_the_face() -> None:
    text = BUILTIN.text.replace(
        "    options: {}\n", "    options: {extra: {modbus: {silence: manual, "
        "comm_write_refused: [P5-16], broadcast: ignore}}}\n")
    bench = loads_bench(text, "bench.yaml")
    extra = bench.drives[bench.default_drive].options["extra"]["modbus"]
    opts = ModbusFaceOptions.from_dict(dict(extra))
    assert opts.silence == "manual" and opts.broadcast == "ignore"
    assert opts.comm_write_refused == frozenset({"P5.016"})  # its canonical name
    assert ModbusFaceOptions.from_dict(None) == ModbusFaceOptions()


def test_the_model_alone_does_not_know_the_faces_room() -> None:
    """An `inject:` step sets model options on a running drive: its face is built already, so
    a modbus room there is unknown, not silently ignored."""
    from hil.model.options import ModelOptions

    with pytest.raises(ValueError, match="unknown room 'modbus'"):
        ModelOptions.from_dict({"extra": {"modbus": {"silence": "manual"}}})
