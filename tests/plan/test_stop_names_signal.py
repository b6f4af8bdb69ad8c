"""A `-j` worker's plan stopped before it began names the signal that stopped it, as a plan
stopped while running does (helper-86 #6: it recorded "interrupted (Ctrl-C / SIGTERM)"
where docs/plans.md says the record names the signal)."""

from __future__ import annotations

import pytest

from hil.bench.bench import load_bench
from hil.plan.plan import find_plans, load_plan
from hil.plan.runner import run_plan
from hil.record.reader import Recording

pytestmark = pytest.mark.virtual_time


@pytest.mark.parametrize("why, reason", [("SIGTERM", "interrupted (SIGTERM)"),
                                         ("SIGINT (Ctrl-C)", "interrupted (SIGINT (Ctrl-C))"),
                                         (True, "interrupted (Ctrl-C / SIGTERM)")])
def test_a_plan_stopped_before_it_began_names_the_signal(tmp_path, why, reason) -> None:
    plan = load_plan(find_plans(["sto_both"])[0])
    with pytest.raises(KeyboardInterrupt) as ei:
        run_plan(plan, load_bench(None), tmp_path, stop=lambda: why, reports=False)
    res = ei.value.plan_result
    assert res.status == "aborted"
    result = Recording.open(res.recording).metadata()["hil.result"]
    assert result["reason"] == reason
