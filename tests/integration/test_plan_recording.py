"""A plan run on the virtual bench yields one MCAP the official `mcap` reader opens, with
every channel of the recording contract populated (DESIGN.md, Recording)."""

from __future__ import annotations

import json
from collections import Counter

import pytest
from mcap.reader import make_reader

from hil.bench.bench import load_bench
from hil.plan.plan import find_plans, load_plan
from hil.plan.runner import run_plan

# the built-in virtual bench in virtual time: deterministic, never rerun (conftest.py)
pytestmark = [pytest.mark.integration, pytest.mark.virtual_time]


def test_one_recording_with_every_channel(tmp_path) -> None:
    plan = load_plan(find_plans(["servo_on_off_brake"])[0])
    result = run_plan(plan, load_bench(None), tmp_path)
    assert result.passed
    counts: Counter[str] = Counter()
    encodings = set()
    with open(result.recording, "rb") as f:
        reader = make_reader(f)
        for schema, channel, message in reader.iter_messages():
            counts[channel.topic] += 1
            encodings.add((channel.message_encoding, schema.encoding if schema else None))
            json.loads(message.data)  # every message is JSON
            assert message.log_time > 0 and message.publish_time > 0
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
        attachments = {a.name for a in reader.iter_attachments()}
    assert encodings == {("json", "jsonschema")}  # Foxglove opens it without plugins
    prefixes = ["/can/", "/canopen/", "/rs485/", "/modbus/", "/dio/drive1/DI1",
                "/dio/drive1/DO6", "/plan/steps", "/timing/verdicts", "/drive/drive1/state",
                "/drive/drive1/events", "/drive/drive1/params", "/log", "/safety"]
    for prefix in prefixes:
        assert any(t.startswith(prefix) and n > 0 for t, n in counts.items()), prefix
    assert any(t.endswith("/sdo") for t in counts)  # SDO transactions paired
    versions = metadata["hil.versions"]
    assert {"hil", "python-can", "canopen", "mcap"} <= set(versions)
    assert "git_revision" in versions
    assert {"hil.plan", "hil.bench", "hil.result"} <= set(metadata)
    assert {"bench.yaml", "plan.yaml"} <= attachments
