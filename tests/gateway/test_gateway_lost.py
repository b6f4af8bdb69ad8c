"""A lost gateway (issue 16, docs/faults.md "Lost link or gateway"): real processes on own
loopback ports - `hil drive` (CAN over zenoh), `hil gateway` in front of it, the plan
runner in this process holding the lease. While the runner produces the master heartbeat
that the drive consumes (1016h, L17097-17115), the gateway is killed or paused:

* the drive reacts on its own: no heartbeat -> AL180 after the consumer time, EMCY 8130h
  (L20021-20025, L17061-17069), seen by an observer connected to the drive directly;
* the runner reports it: the lease keep-alive gets no answer for the lease timeout, the
  next step check ends the plan with ERROR naming the lost gateway, nothing hangs;
* the lost link is a fault on the /faults channel of the runner's recording: `link_lost`
  from the first unanswered renewal, ended when the lease is released.
"""

from __future__ import annotations

import io
import json
import os
import signal
import sys
import time

import pytest

from hil.bench.bench import load_bench
from hil.plan.listeners import StepLines
from hil.plan.plan import loads_plan
from hil.plan.runner import run_plan
from hil.record import topics as T
from hil.record.reader import Recording
from hil.virtual.world import CTL
from tests.children import ChildProcess, children
from tests.gateway.conftest import bench_yaml

pytestmark = pytest.mark.integration

PLAN = """\
name: gateway_lost
description: the master heartbeat goes through the gateway; the gateway is lost mid-plan
steps:
  - nmt: start
  - sdo: {"1016:1": 0x007F0064}                   # consume node 127's heartbeat, 100 ms
  - produce: {heartbeat: 20ms, node: 127}
  - wait: 300ms
  - expect: {alarm: none}
  - wait: 4s                                      # the gateway is lost here
  - expect: {alarm: none}
"""


class _KillAfter(io.StringIO):
    """The runner's progress stream: runs `action` once step `n` has been reported."""

    def __init__(self, n: int, action) -> None:
        super().__init__()
        self.tag, self.action, self.done_at = f"[{n:>2}/", action, None
        self.lost_ns = 0

    def write(self, s: str) -> int:
        if self.done_at is None and self.tag in s:
            self.done_at = time.monotonic()
            self.lost_ns = time.time_ns()
            self.action()
        return super().write(s)


@pytest.fixture
def drive_child():
    """`hil drive ARGS --control stdio` as a child, stopped by closing its stdin."""
    yield from children(lambda *args: ChildProcess(
        [sys.executable, "-m", "hil.cli", "drive", *args], how="stdin", what="hil drive"))


@pytest.mark.parametrize("how", ["kill", "pause"])
def test_lost_gateway_drive_raises_al180_and_runner_reports(tmp_path, free_port_factory,
                                                            hil_process, drive_child, how):
    drive_ep = f"tcp/127.0.0.1:{free_port_factory()}"
    gw_ep = f"tcp/127.0.0.1:{free_port_factory()}"
    key = f"hw/lost-{how}/can0"
    # the drive streams its ground truth (alarms) on stdout: the observer of its reaction
    drive = drive_child("--name", "drive1", "--node-id", "1", "--can",
                        f"zenoh:{key}?listen={drive_ep}", "--control", "stdio")
    hw = tmp_path / "hw.yaml"
    hw.write_text(bench_yaml("lostbench", f"zenoh:{key}?connect={drive_ep}", None))
    gw = hil_process("gateway", "--bench", str(hw), "--lab", "lab", "--listen", gw_ep,
                     "--lease-timeout", "1", "--no-record")
    runner = tmp_path / "runner.yaml"
    runner.write_text(f"""\
name: remote
virtual: false
gateway: {{lab: lab, bench: lostbench, connect: ["{gw_ep}"], holder: runner-{how}}}
can:
  can0: gateway
drives:
  drive1:
    profile: asda-a3
    can: can0
    node_id: 1
    param_via: sdo
safe_state:
  controlword: disable_voltage
  wait_brake: false
  timeout: 1s
""")
    sig = signal.SIGKILL if how == "kill" else signal.SIGSTOP
    stream = _KillAfter(5, lambda: os.kill(gw.proc.pid, sig))
    t0 = time.monotonic()
    try:
        result = run_plan(loads_plan(PLAN), load_bench(runner), tmp_path / "out",
                          listeners=[StepLines(stream)])
    finally:
        if how == "pause":
            os.kill(gw.proc.pid, signal.SIGCONT)
    assert stream.done_at is not None, stream.getvalue()
    # the runner reports the lost gateway on the long wait and stops there, without hanging
    bad = [s for s in result.steps if s.status != "pass"]
    assert result.status == "error" and bad[0].label.startswith("wait"), stream.getvalue()
    assert "no answer from the gateway" in bad[0].message, bad[0].message
    assert time.monotonic() - t0 < 30
    # the drive reacted on its own, after the gateway was lost: AL180 (its EMCY 8130h went
    # out on its wire; nobody was left to see it)
    states = _alarms(drive.lines)
    raised = [t for t, alarms in states if "AL180" in alarms]
    assert raised, states[-3:]
    assert raised[0] > stream.lost_ns  # not before: the heartbeat came while the gateway ran
    assert not any("AL180" in alarms for t, alarms in states if t < stream.lost_ns)
    # the lost link is on /faults: one start, one end, both after the gateway was lost (the
    # start is the first renewal without an answer: at most a renewal period, 0.25 s, and
    # its query before the loss was seen)
    faults = _faults(result.recording)
    assert [(f["fault"], f["active"]) for _, f in faults] == [("link_lost", True),
                                                             ("link_lost", False)], faults
    (t_start, start), (t_end, end) = faults
    assert start["transport"] == "zenoh:lab/lostbench" and start["id"] == end["id"]
    assert start["detail"]["target"] == gw_ep
    assert "no answer from the gateway" in start["detail"]["reason"]
    assert end["detail"]["reason"] == "lease released"
    assert stream.lost_ns - 300_000_000 < t_start < t_end


def _faults(path) -> list[tuple[int, dict]]:
    rec = Recording.open(path)
    return [(pt, msg) for _topic, _lt, pt, msg in rec.messages(T.FAULTS)]


def _alarms(lines: list[str]) -> list[tuple[int, tuple[str, ...]]]:
    """(wall ns, active alarms) of every ground-truth state of a `hil drive --control stdio`."""
    out = []
    for line in lines:
        if not line.startswith(CTL) or '"drive_state"' not in line:
            continue
        msg = json.loads(line[len(CTL):])
        out.append((int(msg["kw"]["source_t"]), tuple(msg["args"][1].get("alarms", ()))))
    return out
