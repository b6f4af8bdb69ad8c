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
    for _ in range(2):  # CAN, then DI/DO
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
