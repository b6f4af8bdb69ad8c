"""`pytest -m hil`: every shipped plan as a test, on the bench given by `--hil-bench`."""

from __future__ import annotations

import json

import pytest
from mcap.reader import make_reader

from hil.plan.plan import find_plans
from hil.pytest_plugin import explain
from hil.record.schemas import message_problems

PLANS = find_plans()


@pytest.mark.hil
@pytest.mark.integration
@pytest.mark.parametrize("plan", PLANS, ids=[p.stem for p in PLANS])
def test_shipped_plan(plan, hil_run_plan) -> None:
    result = hil_run_plan(plan)
    assert result.passed, explain(result)
    assert schema_problems(result.recording) == []


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
