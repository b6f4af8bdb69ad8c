"""A recording read as columns (`RecordingSource(columns=...)`, what `hil check` does) gives
the checker what a recording read as messages gives: the same samples, and, where the runs of
equal values are enough, their first and last samples; the same verdicts."""

from __future__ import annotations

import json
import random
import struct

import pytest
from mcap.writer import Writer

from hil.timing import source as source_mod
from hil.timing.checker import Context, check_all, spec_columns
from hil.timing.cli import read_plan
from hil.timing.source import (
    MISSING_FIELD,
    ColumnTable,
    MemorySource,
    RecordingSource,
    runs_of,
    samples,
)
from hil.timing.spec import load_spec, shipped_specs

MS = 1_000_000


def _runs_of(full: list[tuple[int, object]]) -> list[tuple[int, object]]:
    """Reference: of each run of equal values (same type), the first and the last sample."""
    out: list[tuple[int, object]] = []
    i = 0
    while i < len(full):
        j = i
        while (j + 1 < len(full) and type(full[j + 1][1]) is type(full[i][1])
               and full[j + 1][1] == full[i][1]):
            j += 1
        out.append(full[i])
        if j > i:
            out.append(full[j])
        i = j + 1
    return out


def _random_messages(rng: random.Random, n: int) -> list[tuple[int, dict]]:
    msgs = []
    t = 0
    for _ in range(n):
        t += rng.choice((0, 1, 1, 1, 2)) * MS  # equal times happen
        m: dict = {}
        if rng.random() < 0.9:
            m["a"] = rng.choice((0, 1, True, 1.0, "x", None, [1], [1, 2]))
        if rng.random() < 0.7:
            m["kind"] = rng.choice(("sdo_tx", "pdo", "sdo_tx"))
        if rng.random() < 0.5:
            m["n"] = {"b": rng.choice((1, 2)), "c": rng.random() < 0.5}
        if rng.random() < 0.97:  # a float that changes often, now and then another kind
            m["f"] = rng.choice((rng.random(), rng.random(), 0.0, -0.0, 2.0 ** 70,
                                 1 if rng.random() < 0.02 else 0.5))
        m["i"] = rng.choice((rng.randint(-5, 5), 2 ** 63 - 1, -(2 ** 63),
                             2 ** 64 if rng.random() < 0.01 else 7, True if rng.random() < 0.01
                             else 3))
        msgs.append((t, m))
    return msgs


@pytest.mark.parametrize("seed", range(40))
def test_column_samples_match_the_messages(seed: int, monkeypatch) -> None:
    rng = random.Random(seed)
    if seed % 2:  # typed arrays early, and their fall back to objects
        monkeypatch.setattr(source_mod, "_TYPED_AFTER", rng.randint(1, 5))
    msgs = _random_messages(rng, rng.randint(0, 300))
    if rng.random() < 0.3:  # file order is not always time order
        rng.shuffle(msgs)
    table = ColumnTable()
    for k, (t, m) in enumerate(msgs):
        if k and rng.random() < 0.5:
            m = dict(msgs[k - 1][1])  # a repeated message: its time alone is added
            msgs[k] = (t, m)
            table.add_again(t)
        else:
            table.add(t, m)
    table.finish()
    mem = MemorySource({"/x": msgs})
    assert list(table.times) == [t for t, _m in mem.messages("/x")]
    for field, where in (("f", None), ("i", None), ("f", {"i": 3}),
                         ("a", None), ("a", {"kind": "sdo_tx"}), ("n.b", None),
                         ("n.c", {"n.b": 2}), ("kind", {"a": 1}), ("missing", None)):
        full = samples(mem, "/x", field, where)
        assert table.samples(field, where, runs=False) == full, (field, where)
        assert table.samples(field, where, runs=True) == _runs_of(full), (field, where)
        assert samples(mem, "/x", field, where, runs=True) == _runs_of(full)
        assert runs_of(full) == _runs_of(full)


def test_a_value_run_keeps_true_apart_from_one() -> None:
    """`map: {1: on, True: yes}` must see True and 1 as they were recorded."""
    table = ColumnTable()
    for i, v in enumerate((1, True, True, 1.0, 1)):
        table.add(i * MS, {"a": v})
    table.finish()
    got = table.samples("a", None, runs=True)
    assert [type(v) for _t, v in got] == [int, bool, bool, float, int]


def test_cut_drops_the_unsure_tail() -> None:
    table = ColumnTable()
    for i in range(10):
        table.add(i * MS, {"a": i // 4, "b": "k"} if i % 3 else {"a": i // 4})
    table.finish()
    table.cut(6 * MS)
    assert list(table.times) == [i * MS for i in range(6)]
    assert [t for t, _v in table.samples("a", None, runs=False)] == list(table.times)
    assert table.samples("b", None, runs=False) == [(MS, "k"), (2 * MS, "k"), (4 * MS, "k"),
                                                   (5 * MS, "k")]
    assert MISSING_FIELD not in [v for _t, v in table.samples("b", None, runs=False)]


def _bench_like(path, seconds: int) -> None:
    """Drive state and CANopen at 1 kHz with servo-on/off, STO and alarm cycles, DI/DO edges
    (the mix of benchmarks/bench_check.py), and a raw bus no spec reads."""
    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        sid = w.register_schema("hil.Any", "jsonschema", b'{"type": "object"}')
        chans: dict[str, int] = {}

        def put(topic: str, t: int, payload: dict) -> None:
            if topic not in chans:
                chans[topic] = w.register_channel(topic, "json", sid, {})
            w.add_message(chans[topic], log_time=t, publish_time=t,
                          data=json.dumps(payload).encode())

        put("/drive/drive1/params", 0, {"snapshot": True, "values": {
            "P1.042": 150, "P1.043": 100, "P1.038": 100, "P2.009": 2}})
        for line, lvl in (("DI1", False), ("DI5", False), ("DI8", True), ("DO1", True),
                          ("DO6", False), ("STO_A", True), ("STO_B", True)):
            put(f"/dio/drive1/{line}", 0, {"level": lvl})
        for t_ms in range(seconds * 1000):
            cyc, phase, t = t_ms // 1000, t_ms % 1000, t_ms * MS
            on = 102 <= phase < 602
            put("/drive/drive1/state", t, {
                "state": "OPERATION ENABLED" if on else "SWITCH ON DISABLED",
                "servo_on": on, "torque_enabled": on, "brake_released": 252 <= phase < 602,
                "speed_rpm": 1000.0 * (phase - 300) / 280 if 300 <= phase < 580 else 0.0,
                "position": t_ms * 7, "periodic": phase % 3 == 0,
                "alarms": ["AL500"] if cyc % 4 == 3 and 710 <= phase < 902 else []})
            put("/canopen/can0", t, {"statusword": 0x0237 if on else 0x0250,
                                     "controlword": 0x0F if 100 <= phase < 600 else 0x06,
                                     "kind": "sdo_tx" if phase % 2 else "pdo"})
            put("/can/can0/raw", t, {"id": 0x181, "data": f"{t_ms:016x}", "dir": "rx"})
            for p, line, lvl in ((100, "DI1", True), (252, "DO6", True), (600, "DI1", False),
                                 (602, "DO6", False)):
                if phase == p:
                    put(f"/dio/drive1/{line}", t, {"level": lvl})
            if cyc % 4 == 3 and phase in (700, 800):
                for ch in ("STO_A", "STO_B"):
                    put(f"/dio/drive1/{ch}", t, {"level": phase == 800})
            if cyc % 4 == 3 and phase in (900, 950):
                put("/dio/drive1/DI5", t, {"level": phase == 900})
        w.finish()


def test_every_shipped_spec_judges_columns_as_messages(tmp_path, monkeypatch) -> None:
    path = tmp_path / "mix.mcap"
    _bench_like(path, 8)
    specs = [load_spec(p) for p in shipped_specs()]
    bind = {"drive": "drive1", "dio": "drive1", "bus": "can0"}
    wanted, columns = read_plan(specs, [bind])  # what `hil check` reads
    whole = RecordingSource(path)
    cols = RecordingSource(path, topics=wanted, columns=columns)
    assert "/can/can0/raw" in cols.topics()  # named, but no message kept
    assert cols.messages("/can/can0/raw") == []
    assert cols.columns("/drive/drive1/state") is not None
    a = [v.to_dict() for v in check_all(specs, whole, binding=bind)]
    b = [v.to_dict() for v in check_all(specs, cols, binding=bind)]
    assert any(v["status"] == "fail" for v in a) and any(v["status"] == "pass" for v in a)
    assert a == b
    # and as every sample, not only the first and last of each run
    monkeypatch.setattr(Context, "_runs_suffice", lambda self, s: False)
    assert [v.to_dict() for v in check_all(specs, RecordingSource(path), binding=bind)] == a
    assert cols.end_time() == whole.end_time() and cols.start_time() == whole.start_time()


def test_hil_check_json_is_written_verdict_by_verdict_and_reads_as_one_list(capsys) -> None:
    from hil.timing.checker import Verdict
    from hil.timing.cli import print_json

    vs = [Verdict("a", "b", "pass", "two\nlines", values={"P1.038": 1.5}),
          Verdict("c", "d", "fail", "é", window_ms=(None, 3.0))]
    for lst in (vs, vs[:1], []):
        print_json(lst)
        assert capsys.readouterr().out == json.dumps([v.to_dict() for v in lst], indent=2,
                                                     default=str) + "\n"


@pytest.mark.parametrize("damage", ["cut", "flip"])
def test_a_damaged_recording_judges_alike_as_columns(tmp_path, damage: str) -> None:
    """A killed run's cut tail, or a chunk damaged mid-file: columns and messages keep the
    same part (up to the cut) and judge it alike."""
    path = tmp_path / "mix.mcap"
    _bench_like(path, 4)
    data = bytearray(path.read_bytes())
    if damage == "cut":
        del data[len(data) * 2 // 3:]
    else:  # a byte of the middle chunk's compressed data
        chunks, off = [], 8
        while off + 9 <= len(data):
            op, ln = struct.unpack_from("<BQ", data, off)
            if op == 0x06:
                chunks.append((off, off + 9 + ln))
            off += 9 + ln
        _start, end = chunks[len(chunks) // 2]
        data[end - 20] ^= 0x40
    path.write_bytes(bytes(data))
    specs = [load_spec(p) for p in shipped_specs()]
    bind = {"drive": "drive1", "dio": "drive1", "bus": "can0"}
    wanted, columns = read_plan(specs, [bind])  # what `hil check` reads
    whole = RecordingSource(path)
    cols = RecordingSource(path, topics=wanted, columns=columns)
    assert whole.truncated and cols.truncated
    assert whole.corrupt == (damage == "flip")
    assert (whole.corrupt, whole.cut_ns, whole.error) == (cols.corrupt, cols.cut_ns, cols.error)
    assert whole.end_time() == cols.end_time()
    assert [v.to_dict() for v in check_all(specs, whole, binding=bind)] == [
        v.to_dict() for v in check_all(specs, cols, binding=bind)]


def test_reading_progress_shows_on_a_terminal_for_a_large_file_only(tmp_path) -> None:
    import io

    from hil.record import progress as cli

    path = tmp_path / "mix.mcap"
    _bench_like(path, 2)

    class Tty(io.StringIO):
        def isatty(self) -> bool:
            return True

    seen: list[tuple[int, int]] = []
    small = cli.ReadProgress(str(path), stream=Tty())
    assert not small.on  # a small file reads at once: no bar
    old = cli.PROGRESS_MIN_BYTES
    cli.PROGRESS_MIN_BYTES = 1
    try:
        tty, pipe = Tty(), io.StringIO()
        shown = cli.ReadProgress(str(path), "hil check: the topics the specs read", stream=tty)
        hidden = cli.ReadProgress(str(path), stream=pipe)
    finally:
        cli.PROGRESS_MIN_BYTES = old
    assert shown.on and not hidden.on  # a pipe or a CI log gets no bar

    def both(done: int, total: int) -> None:
        seen.append((done, total))
        shown(done, total)
        hidden(done, total)

    RecordingSource(path, progress=both)
    shown.close()
    size = path.stat().st_size
    assert seen and seen[-1][0] == size and all(t == size for _d, t in seen)
    assert [d for d, _t in seen] == sorted(d for d, _t in seen)
    assert "the topics the specs read" in tty.getvalue() and pipe.getvalue() == ""


def test_a_spec_reading_the_parameters_or_input_deliveries_reads_them_as_messages(tmp_path):
    """The parameters and the input deliveries stay messages (the checker reads them whole);
    a user's spec with a signal on them still judges from them."""
    from hil.timing.spec import loads_spec

    spec = loads_spec("""
id: user_params
title: a user's spec on the parameters
source: "test"
signals:
  p: {topic: "/drive/{drive}/params", field: snapshot}
  son: {topic: "/drive/{drive}/state", field: servo_on}
events:
  son_up: {rise: son}
  snap: {rise: p}
constraints:
  - {name: c, from: son_up, to: snap, window: {max: 1}}
""", "user.yaml")
    cols = spec_columns(spec, {"drive": "drive1"})
    assert "/drive/drive1/params" not in cols and "/drive/drive1/state" in cols


def test_a_field_that_changes_at_every_message_keeps_no_run_starts() -> None:
    """A speed that changes at every sample is one run a message: its run starts are the
    range 0..n-1, not an array of n numbers; a first run of two, a missing stretch and a cut
    give the samples the messages give."""
    msgs = [(i * MS, {"v": float(i)}) for i in range(2000)]
    table = ColumnTable()
    for t, m in msgs:
        table.add(t, m)
    assert type(table.cols["v"].starts) is range
    msgs += [(2000 * MS, {"v": 1999.0}), (2001 * MS, {"w": 1}), (2002 * MS, {"v": 5.0})]
    for t, m in msgs[2000:]:
        table.add(t, m)
    table.finish()
    assert type(table.cols["v"].starts) is not range
    mem = MemorySource({"/x": msgs})
    for runs in (False, True):
        full = samples(mem, "/x", "v")
        want = _runs_of(full) if runs else full
        assert table.samples("v", None, runs=runs) == want
    table.cut(1000 * MS)
    assert type(table.cols["v"].starts) is range or list(table.cols["v"].starts) == list(
        range(1000))
    assert table.samples("v", None, runs=False) == samples(
        MemorySource({"/x": msgs[:1000]}), "/x", "v")


def test_every_reading_command_can_show_the_bar(tmp_path, monkeypatch) -> None:
    """`hil report`, `diff`, `inspect` and `export` read through `Recording.stream`: once a
    command has turned the bar on, a large file shows it on a terminal (an outside audit
    found only `hil run` and `hil check` with progress)."""
    import io

    from hil.record import progress, reader
    from hil.record.reader import Recording

    class Tty(io.StringIO):
        def isatty(self) -> bool:
            return True

    path = tmp_path / "mix.mcap"
    _bench_like(path, 2)
    tty = Tty()
    monkeypatch.setattr("sys.stderr", tty)
    monkeypatch.setattr(progress, "PROGRESS_MIN_BYTES", 1)
    Recording.stream(path, None, lambda *_m: None)
    assert tty.getvalue() == ""  # off unless a command turns it on
    reader.progress_on_terminal("hil inspect: reading")
    try:
        Recording.stream(path, None, lambda *_m: None)
    finally:
        reader.progress_on_terminal(None)
    assert "hil inspect: reading" in tty.getvalue()
