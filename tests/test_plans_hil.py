"""`pytest -m hil`: every shipped plan as a test, on the bench given by `--hil-bench`."""

from __future__ import annotations

import pytest

from hil.plan.plan import find_plans
from hil.pytest_plugin import explain

PLANS = find_plans()


@pytest.mark.hil
@pytest.mark.integration
@pytest.mark.parametrize("plan", PLANS, ids=[p.stem for p in PLANS])
def test_shipped_plan(plan, hil_run_plan) -> None:
    result = hil_run_plan(plan)
    assert result.passed, explain(result)
