"""`hil diff` as a stranger reads it (found by an outside probe, helper-129): explanations
from the options the recordings carry, options on stdout, a cut file said in the page and
the JSON, verdicts of one run only counted."""

from __future__ import annotations

import io
import json
from pathlib import Path

import pytest

from hil.bench.bench import load_bench
from hil.cli import main as hil
from hil.paths import plans_dir
from hil.plan.plan import loads_plan
from hil.plan.runner import run_plans


def _run(tmp: Path, name: str, options: dict | None) -> str:
    text = (plans_dir() / "servo_on_off_brake.yaml").read_text(encoding="utf-8")
    text = text.replace("name: servo_on_off_brake", f"name: {name}", 1)
    if options:
        text += "options: " + json.dumps(options) + "\n"
    plan = loads_plan(text, str(tmp / f"{name}.yaml"))
    [res] = run_plans([plan], load_bench(None), tmp / name, stream=io.StringIO(), quiet=True)
    return res.recording


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[str, str]:
    tmp = tmp_path_factory.mktemp("diff")
    return {"base": _run(tmp, "base", None),
            "on30": _run(tmp, "on30", {"dev_brake_on_delay_ms": 30}),
            "on6": _run(tmp, "on6", {"dev_brake_on_delay_ms": 6}),
            "isr": _run(tmp, "isr", {"dev_ignore_speed_rule": True})}


def _rewrite(src: Path, dst: Path, message) -> Path:
    """`src` rewritten to `dst` by the `mcap` library's writer, each message's data through
    `message(topic, data, log_time)` (None: left out)."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    with open(src, "rb") as f, open(dst, "wb") as out:
        reader = make_reader(f)
        w = Writer(out)
        w.start(profile="", library="test")
        ids: dict[int, int] = {}
        schemas: dict[int, int] = {}
        summary = reader.get_summary()
        for sid, sch in summary.schemas.items():
            schemas[sid] = w.register_schema(sch.name, sch.encoding, sch.data)
        for cid, ch in summary.channels.items():
            ids[cid] = w.register_channel(ch.topic, ch.message_encoding,
                                          schemas.get(ch.schema_id, 0), dict(ch.metadata))
        for m in reader.iter_metadata():
            w.add_metadata(m.name, dict(m.metadata))
        for a in reader.iter_attachments():
            w.add_attachment(a.log_time, a.create_time, a.name, a.media_type, a.data)
        for _s, ch, m in reader.iter_messages(log_time_order=False):
            data = message(ch.topic, m.data, m.log_time)
            if data is not None:
                w.add_message(ids[ch.id], m.log_time, data, m.publish_time)
        w.finish()
    return dst


def _diff(a: str, b: str, out: Path) -> tuple[int, dict]:
    rc = hil(["diff", a, b, "-o", str(out / "d.html"), "--json", str(out / "d.json")])
    return rc, json.loads((out / "d.json").read_text(encoding="utf-8"))


def test_an_explanation_uses_the_option_values_on_record(runs, tmp_path, capsys) -> None:
    """The page showed 30 in A and 6 in B and explained "~ -24 ms, with the option at 0
    in A"; stdout never listed the options."""
    rc, d = _diff(runs["on30"], runs["on6"], tmp_path)
    assert rc == 0
    [e] = [e for e in d["explanations"] if e["signature"] == "brake_on"]
    assert e["option"] == "dev_brake_on_delay_ms" and e["estimate"] == 6
    assert "30 in A, 6 in B" in e["basis"]
    assert "option dev_brake_on_delay_ms: A 30, B 6" in capsys.readouterr().out


def test_an_option_of_another_interval_is_not_blamed(runs, tmp_path) -> None:
    """Only dev_ignore_speed_rule differed, and the page named dev_brake_off_delay_ms
    ~ 50 ms."""
    _rc, d = _diff(runs["base"], runs["isr"], tmp_path)
    named = [e["option"] for e in d["explanations"]]
    assert "dev_brake_off_delay_ms" not in named
    assert all("dev_ignore_speed_rule" in e["basis"] for e in d["explanations"]), named


def test_a_cut_recording_is_said_in_the_page_and_the_json(runs, tmp_path) -> None:
    cut = tmp_path / "cut.mcap"
    data = Path(runs["base"]).read_bytes()
    cut.write_bytes(data[: len(data) * 2 // 3])
    rc, d = _diff(runs["base"], str(cut), tmp_path)
    assert rc == 4
    assert any("truncated" in w for w in d["incomplete"]), d["incomplete"]
    assert "Incomplete:" in (tmp_path / "d.html").read_text(encoding="utf-8")


def test_verdicts_of_one_run_only_are_counted(runs, tmp_path, capsys) -> None:
    """A verdict in one run only was "0 verdict(s) measured differently"; its cell read
    "– None"."""
    # B without A's last verdict (the file cut at half its bytes had kept every verdict in a
    # CI run: where a chunk ends follows the writer's wall-clock flushes)
    from mcap.reader import make_reader

    src = Path(runs["base"])
    with open(src, "rb") as f:
        last = max(m.log_time for _s, ch, m in make_reader(f).iter_messages(log_time_order=False)
                   if ch.topic == "/timing/verdicts")
    cut = _rewrite(src, tmp_path / "cut.mcap", lambda topic, data, lt: None if (
        topic == "/timing/verdicts" and lt == last) else data)
    capsys.readouterr()
    _rc, d = _diff(runs["base"], str(cut), tmp_path)
    one = sum((v["a_status"] is None) != (v["b_status"] is None) for v in d["verdicts"])
    assert one > 0
    assert f"{one} in one run only" in capsys.readouterr().out
    assert "None" not in (tmp_path / "d.html").read_text(encoding="utf-8").split("<table")[-1]


def test_a_level_record_of_a_wrong_shape_is_counted_and_params_of_one_run_not_listed(
        runs, tmp_path, capsys) -> None:
    """A DI/DO record with level "false" read as a True edge (or `{}` vanished), exit 0;
    a recording cut before its parameter snapshot listed 554 "parameter P0.000: A 100, B
    None" lines."""

    src = Path(runs["base"])
    changed = []

    def spoil(topic: str, data: bytes, lt: int) -> bytes:
        if topic.endswith("/DO6") and not changed:
            changed.append(lt)
            return b'{"level":"false"}'
        return data

    bad = _rewrite(src, tmp_path / "bad.mcap", spoil)
    assert changed
    capsys.readouterr()
    rc, d = _diff(runs["base"], str(bad), tmp_path)
    assert rc == 4 and any("wrong shape" in w for w in d["incomplete"])
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(src.read_bytes()[:600])
    capsys.readouterr()
    rc, d = _diff(runs["base"], str(cut), tmp_path)
    assert rc == 4 and d["params"] == {}
    assert "parameter P0.000" not in capsys.readouterr().out


def test_the_page_names_each_runs_clock_and_says_which_of_plan_or_steps_differs(
        runs, tmp_path) -> None:
    """A virtual run against a real-time one showed "bench virtual" for both; a plan whose
    steps differed was called "not of the same plan" while the JSON said it was."""
    _rc, d = _diff(runs["base"], runs["on30"], tmp_path)
    page = (tmp_path / "d.html").read_text(encoding="utf-8")
    assert d["a"]["clock"] == "virtual" and "bench virtual, clock virtual" in page
    assert not d["same_plan"] and "not of the same plan" in page  # names differ: base/on30


def test_statuswords_read_in_hex(runs) -> None:
    """The state sequences showed statuswords as 535, 1559, 4663."""
    from hil.report.diff import load_side

    states = load_side(runs["base"]).states
    words = states["drive1 statusword"]
    assert words, states
    assert all(w.startswith("0x") and len(w) == 6 for w in words), words
