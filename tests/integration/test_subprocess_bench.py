"""Plans on `process: subprocess` virtual benches: the drive is a `hil drive` process reached
over zenoh (CAN, DI/DO/STO) and a pty (RS-485); power_cycle, inject and the ground truth go
through its control channel (`--control stdio`)."""

from __future__ import annotations

import io
import subprocess
import sys

import pytest

from hil.bench.bench import load_bench, loads_bench
from hil.paths import fixture
from hil.plan.plan import find_plans, load_plan, loads_plan
from hil.plan.runner import run_plans
from hil.record import topics as T
from hil.record.reader import Recording

pytestmark = pytest.mark.integration


def test_sto_single_channel_on_the_zenoh_bench(tmp_path):
    """AL501/AL502 after 1 s, ARST does not clear them, power_cycle (control channel) does;
    the timing specs are judged on the ground truth the drive process streams."""
    bench = load_bench(fixture("benches", "virtual-zenoh.yaml"))
    assert bench.process == "subprocess"
    [r] = run_plans([load_plan(p) for p in find_plans(["sto_single_channel"])], bench,
                    tmp_path, stream=io.StringIO())
    assert r.passed, [(s.label, s.status, s.message) for s in r.steps if s.status != "pass"]
    assert r.safe is not None and r.safe.ok
    rec = Recording.open(r.recording)
    counts = rec.counts()
    assert counts.get(T.drive_state("drive1"), 0) > 50  # streamed ground truth
    assert any(t.startswith("/dio/drive1/") for t in counts)


def test_explicit_ports_inject_and_power_cycle(tmp_path, free_port_factory):
    """A bench with explicit loopback ports (from the test's free ports); `inject` reaches
    the drive process: an injected AL009 is what P0.001 shows over Modbus."""
    text = fixture("benches", "virtual-zenoh.yaml").read_text()
    for _ in range(3):  # CAN, DI/DO, the pulse line
        text = text.replace("tcp/127.0.0.1:auto", f"tcp/127.0.0.1:{free_port_factory()}", 1)
    assert "127.0.0.1:auto" not in text
    bench_file = tmp_path / "bench.yaml"
    bench_file.write_text(text)
    bench = load_bench(bench_file)
    plan = loads_plan("name: inject_demo\nsteps:\n  - expect: {alarm: none}\n"
                      "  - inject: {alarm: AL009}\n  - wait_until: {alarm: AL009, timeout: 1s}\n"
                      "  - power_cycle: {battery: true}\n"
                      "  - wait_until: {alarm: none, timeout: 2s}\n",
                      str(tmp_path / "inject_demo.yaml"))
    [r] = run_plans([plan], bench, tmp_path, stream=io.StringIO())
    assert r.passed, [(s.label, s.status, s.message) for s in r.steps if s.status != "pass"]


def test_subprocess_bench_rejects_in_process_buses():
    with pytest.raises(ValueError, match="in-process only"):
        loads_bench("name: b\nvirtual: true\nprocess: subprocess\ncan: {c: 'virtual:auto'}\n"
                    "drives: {d: {can: c, node_id: 1}}\n")


def test_hil_drive_names_an_unknown_bench_drive():
    p = subprocess.run([sys.executable, "-m", "hil.cli", "drive", "--bench",
                        str(fixture("benches", "virtual-zenoh.yaml")), "--drive", "axis9",
                        "--dio", "zenoh:t/dio?listen=tcp/127.0.0.1:1"],
                       capture_output=True, text=True, timeout=60)
    assert p.returncode == 2
    assert "--drive axis9: bench 'virtual-zenoh' has no such drive (drives: drive1)" in p.stderr


def test_pr_soft_limit_judges_its_parameters_from_the_streamed_snapshot(tmp_path):
    """P5.008 (written by the plan) and P2.009 (not written) without `params:` on the step:
    the drive process's snapshot comes after its first change events and still covers them;
    nothing needs a read (docs/timing.md, Parameters)."""
    bench = load_bench(fixture("benches", "virtual-zenoh.yaml"))
    [r] = run_plans([load_plan(p) for p in find_plans(["pr_soft_limit"])], bench, tmp_path,
                    stream=io.StringIO())
    assert r.passed, [(s.label, s.status, s.message) for s in r.steps if s.status != "pass"]
    rec = Recording.open(r.recording)
    params = [m for _t, _l, _p, m in rec.messages([T.drive_params("drive1")])]
    assert any(m.get("snapshot") for m in params)
    assert not any(m.get("source") == "read" for m in params)


TWO_ON_ONE_BUS = """\
name: two_on_one_bus
virtual: true
process: subprocess
can:
  can0: "zenoh:auto?listen=tcp/127.0.0.1:auto"
drives:
  axis1: {profile: asda-a3, can: can0, node_id: 1, param_via: sdo,
          dio: "zenoh:auto?listen=tcp/127.0.0.1:auto", wiring: {SON: DI1, EMGS: "DI8:b"}}
  axis2: {profile: asda-a3, can: can0, node_id: 2, param_via: sdo,
          dio: "zenoh:auto?listen=tcp/127.0.0.1:auto", wiring: {SON: DI1, EMGS: "DI8:b"}}
safe_state: {controlword: disable_voltage, wait_brake: false, timeout: 3s}
"""

HEARD = """\
name: heard
steps:
  - {drive: axis1, state: OPERATION ENABLED}
  - {drive: axis2, state: OPERATION ENABLED}
  - {drive: axis1, sdo: {"1017": 50}}              # node 1: a heartbeat every 50 ms
  - {drive: axis2, sdo: {"1016:1": 0x000101F4}}    # node 2 consumes node 1's: 500 ms
  - wait: 1s
  - {drive: axis2, expect: {alarm: none}}          # node 1's heartbeats reach node 2
  - {drive: axis1, sdo: {"1017": 0}}               # node 1 falls silent
  # AL180 only if node 2 heard node 1 (a consumer arms on the first heartbeat, CiA 301)
  - {drive: axis2, wait_until: {alarm: AL180, timeout: 3s}}
"""


def test_several_drive_processes_share_one_zenoh_bus(tmp_path):
    """Two `hil drive` processes on one zenoh CAN bus: each listens on a port of its own and
    links to the other (one port takes one listener; zenoh peers do not route for each
    other), the harness reaches both, and one drive hears the other's heartbeat directly."""
    path = tmp_path / "two.yaml"
    path.write_text(TWO_ON_ONE_BUS)
    bench = load_bench(path)
    [r] = run_plans([loads_plan(HEARD, str(tmp_path / "heard.yaml"))], bench, tmp_path,
                    stream=io.StringIO())
    assert r.passed, [(s.label, s.status, s.message) for s in r.steps if s.status != "pass"]


def test_bus_mesh_gives_each_drive_its_own_port_linked_to_the_earlier_ones():
    from hil.virtual.world import bus_mesh, harness_side

    url = "zenoh:hil/1-1/can?listen=tcp/127.0.0.1:7001&mode=peer"
    drives, harness = bus_mesh(url, 3)
    ports = [d.split("listen=")[1].split("&")[0] for d in drives]
    assert ports[0] == "tcp/127.0.0.1:7001" and len(set(ports)) == 3
    assert "connect=" not in drives[0]
    assert f"connect={ports[0]}&" in drives[1]
    assert f"connect={ports[0]},{ports[1]}&" in drives[2]
    assert all(d.startswith("zenoh:hil/1-1/can?") and d.endswith("&mode=peer") for d in drives)
    assert harness_side(harness) == f"zenoh:hil/1-1/can?connect={','.join(ports)}&mode=peer"
    assert bus_mesh(url, 1) == ([url], url)  # one drive: the bus as it is


def test_a_plc_plan_on_the_zenoh_bench(tmp_path):
    """The pulse line over zenoh to the `hil drive` process: a PLC DRVZ MD1 homing with its
    DOG/limit inputs and CLR output crossing the same hop, on the wall clock."""
    bench = load_bench(fixture("benches", "virtual-zenoh.yaml"))
    [r] = run_plans([load_plan(p) for p in find_plans(["plc_home_md1"])], bench,
                    tmp_path, stream=io.StringIO())
    assert r.passed, [(s.label, s.status, s.message) for s in r.steps if s.status != "pass"]
    counts = Recording.open(r.recording).counts()
    assert counts.get("/pulse/drive1/seg", 0) > 5
