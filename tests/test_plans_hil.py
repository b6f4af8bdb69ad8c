"""`pytest -m hil`: every shipped plan as a test, on the bench given by `--hil-bench`.

On the built-in virtual bench this runs in virtual time (docs/clock.md), and each plan runs
twice: the two recordings must carry identical messages (topics, log times, payloads)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from mcap.reader import make_reader

from hil.cli import main as hil_main
from hil.plan.plan import find_plans, load_plan
from hil.plan.runner import run_plan
from hil.pytest_plugin import explain
from hil.record.schemas import message_problems
from hil.timing.checker import Context, check_all
from hil.timing.cli import read_plan, resolve_specs
from hil.timing.source import RecordingSource, infer_places, recorded_specs

PLANS = find_plans()


@pytest.mark.hil
@pytest.mark.virtual_time
@pytest.mark.parametrize("plan", PLANS, ids=[p.stem for p in PLANS])
def test_shipped_plan(plan, hil_run_plan, hil_bench, tmp_path, monkeypatch) -> None:
    result = hil_run_plan(plan)
    assert result.passed, explain(result)
    assert schema_problems(result.recording) == []
    if result.html:  # a reviewer's page stays small (issue: under 1 MB, homing included)
        assert Path(result.html).stat().st_size < 1_000_000, result.html
    if hil_bench.clock == "virtual":  # determinism: the same plan again, the same messages
        again = run_plan(load_plan(plan), hil_bench, tmp_path, reports=False)  # messages only
        first, second = messages(result.recording), messages(again.recording)
        assert len(first) == len(second)
        diff = next((i for i, (a, b) in enumerate(zip(first, second, strict=True)) if a != b),
                    None)
        assert diff is None, f"message {diff} differs: {first[diff]} vs {second[diff]}"
        whole, columns = judged_both_ways(result.recording, monkeypatch)
        assert whole == columns  # what `hil check` reads of a long recording judges the same
        # a reviewer's `hil check run.mcap` of a passing plan passes too (its default specs:
        # the ones the plan checked, else every shipped spec that applies to the drive)
        assert hil_main(["check", str(result.recording)]) == 0


def judged_both_ways(path: str, monkeypatch) -> tuple[list[dict], list[dict]]:
    """The recorded specs judged as `hil check` reads the recording (only the topics the
    specs read, the signal topics as columns, each run of equal values as its first and last
    sample), and on every message and every sample."""
    whole = RecordingSource(path)
    names, rec_bind = recorded_specs(whole.meta)
    specs = resolve_specs(names)
    bind = infer_places(whole.topics()) | rec_bind
    wanted, columns = read_plan(specs, [bind])
    cols = RecordingSource(path, topics=wanted, columns=columns)
    fast = [v.to_dict() for v in check_all(specs, cols, binding=bind)]
    with monkeypatch.context() as m:
        m.setattr(Context, "_runs_suffice", lambda self, s: False)
        return [v.to_dict() for v in check_all(specs, whole, binding=bind)], fast


def messages(path: str) -> list[tuple[str, int, bytes]]:
    """(topic, log time, payload) of every message, in file order."""
    with open(path, "rb") as f:
        return [(ch.topic, m.log_time, bytes(m.data))
                for _, ch, m in make_reader(f).iter_messages(log_time_order=False)]


def schema_problems(path: str) -> list[str]:
    """Every message of the recording against its channel's JSON Schema: no field the schema
    does not declare (Foxglove builds its field lists from them), no wrong type."""
    out: set[str] = set()
    with open(path, "rb") as f:
        for schema, channel, msg in make_reader(f).iter_messages():
            if schema is not None and schema.encoding == "jsonschema":
                out.update(f"{channel.topic}: {p}"
                           for p in message_problems(schema.name, json.loads(msg.data)))
    return sorted(out)
