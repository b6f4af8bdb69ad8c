"""The plan runner on a bench behind `hil gateway`: it takes the lease, reaches the buses with
zenoh URLs, and a second runner is refused with who holds the bench."""

from __future__ import annotations

from pathlib import Path

import pytest

from hil.bench.bench import load_bench
from hil.plan.plan import loads_plan
from hil.plan.runner import run_plan
from hil.plan.session import BenchError, open_session
from hil.record.recorder import Recorder
from tests.gateway.test_gateway import wait

pytestmark = pytest.mark.integration

PLAN = """\
name: via_gateway
description: state machine and DI/DO through the gateway hop
steps:
  - expect: {do: {SRDY: on}}
  - state: OPERATION ENABLED
  - expect: {state: OPERATION ENABLED}
  - state: SWITCH ON DISABLED
  - di: {SON: on}
  - wait: 50ms
  - di: {SON: off}
"""


def runner_bench(tmp_path: Path, rig, holder: str) -> Path:
    path = tmp_path / f"remote-{holder}.yaml"
    path.write_text(f"""\
name: remote
virtual: false
gateway: {{lab: lab, bench: {rig.name}, connect: ["{rig.endpoint}"], holder: {holder}}}
can:
  can0: gateway
drives:
  drive1:
    profile: asda-a3
    can: can0
    node_id: 1
    param_via: sdo
    dio: gateway
    wiring: {{SON: DI1, SRDY: DO1}}
safe_state:
  controlword: disable_voltage
  di: {{SON: off}}
  wait_brake: false
  timeout: 1s
""")
    return path


def test_plan_runs_through_the_gateway_under_a_lease(tmp_path: Path, make_rig) -> None:
    rig = make_rig("bench7")
    bench = load_bench(runner_bench(tmp_path, rig, "runner-a"))
    result = run_plan(loads_plan(PLAN), bench, tmp_path / "out")
    assert result.passed, [(s.label, s.status, s.message) for s in result.steps]
    # the gateway drives its safe state on its own thread after the release: until it is
    # done it refuses any lease ("safing"), so wait for it before taking the lease again
    wait(lambda: rig.gateway.safe_reports and not rig.gateway.lease.safing
         and not rig.gateway.lease.status()["held"], what="gateway safe state after runner-a")
    # while one runner holds the lease, another one is refused, naming the holder
    rec = Recorder(tmp_path / "a.mcap")
    first = open_session(bench, rec)
    rec_b = Recorder(tmp_path / "b.mcap")
    try:
        other = load_bench(runner_bench(tmp_path, rig, "runner-b"))
        with pytest.raises(BenchError, match=r"leased by runner-a since"):
            open_session(other, rec_b)
    finally:
        first.close()
        rec.close()
        rec_b.close()


def test_gateway_transports_need_a_gateway_section(tmp_path: Path) -> None:
    from hil.bench.yamlio import PlanFileError

    path = tmp_path / "bad.yaml"
    path.write_text("name: b\ncan:\n  can0: gateway\ndrives:\n  d: {can: can0, node_id: 1}\n")
    with pytest.raises(PlanFileError, match=r"bad.yaml:3: can.can0: `gateway` needs"):
        load_bench(path)


def test_a_lost_lease_stops_the_session() -> None:
    import threading
    from types import SimpleNamespace

    from hil.plan.session import Session

    lost = threading.Event()
    s = Session(bench=None, recorder=None)  # type: ignore[arg-type]
    s.lease = SimpleNamespace(prefix="lab/bench1", lost=lost, lost_reason="")
    s.check_lease()  # held: nothing happens
    lost.set()
    s.lease.lost_reason = "the gateway ended the lease (now: free)"
    with pytest.raises(BenchError, match=r"lease of lab/bench1 lost \(the gateway ended"):
        s.check_lease()
