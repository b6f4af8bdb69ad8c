"""`check_timing` on a bench that records no drive parameters (a real bench: here `hil drive`
in its own process, reached over zenoh as `virtual: false`): the parameters a spec uses that
the plan did not write are read from the drive (SDO 2xxxh, L16860) and recorded with
`"source": "read"`, so the live verdict and `hil check` on the file agree."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from hil.bench.bench import load_bench
from hil.plan.plan import loads_plan
from hil.plan.runner import run_plan
from hil.record import topics
from hil.record.reader import Recording
from hil.timing.registry import load_specs

pytestmark = pytest.mark.integration

# Measured from the harness's SON stamp to the DO6 edge it saw: two zenoh hops late, never
# early. P1.042 = 150 is set in the drive only: with its default (0) the window is missed.
SPEC = """\
id: son_brkr_wire
title: BRKR rises P2.009 + P1.042 after SON, seen on the wires
source: "P2.009 L9229-9236; P1.042 L8492-8501"
for_each: son_in
constants: {slack: 100}
signals:
  SON: {function: SON}
  BRKR: {function: BRKR}
events:
  son_in: {rise: SON, label: SON closed}
  brkr_on: {rise: BRKR, after: son_in, within: 2000, label: BRKR rose}
constraints:
  - name: BRKR after the filter and P1.042
    from: son_in
    to: brkr_on
    window: {min: "P1.042", max: "P2.009 + P1.042 + slack"}
"""

UNREADABLE = """\
id: son_unreadable
title: a window on a parameter the drive does not have
source: "none"
signals:
  SON: {function: SON}
events:
  son_in: {rise: SON}
  son_out: {fall: SON, after: son_in}
constraints:
  - name: SON held at most P9.999
    from: son_in
    to: son_out
    window: {max: "P9.999"}
"""

SON_CYCLE = """\
  - wait_until: {do: {SRDY: on}, timeout: 2s}
  - di: {SON: on}
  - wait_until: {do: {BRKR: on}, timeout: 2s}
  - di: {SON: off}
  - wait_until: {do: {BRKR: off}, timeout: 2s}
  - check_timing: son_brkr_wire
"""

PLAN = """\
name: param_reads
description: SON on/off; the brake timing is judged with P2.009 and P1.042 read from the drive
steps:
""" + SON_CYCLE + """\
  - check_timing: son_brkr_wire
"""


def real_bench(tmp_path: Path, can_key: str, can_port: int, dio_key: str, dio_port: int) -> Path:
    path = tmp_path / "wire.yaml"
    path.write_text(f"""\
name: wire
virtual: false
can:
  can0: "zenoh:{can_key}?connect=tcp/127.0.0.1:{can_port}"
drives:
  drive1:
    profile: asda-a3
    can: can0
    node_id: 1
    param_via: sdo
    dio: "zenoh:{dio_key}?connect=tcp/127.0.0.1:{dio_port}"
    wiring: {{SON: DI1, SRDY: DO1, BRKR: DO6}}
safe_state:
  controlword: disable_voltage
  di: {{SON: off}}
  wait_brake: false
  timeout: 1s
""")
    return path


def wire_drive(drive_process, tmp_path: Path, free_port_factory) -> tuple[Path, Path]:
    """`hil drive` in its own process (P1.042 = 150, DO6 = BRKR) reached over zenoh as a
    real bench; (bench file, specs dir with SPEC and UNREADABLE)."""
    can_port, dio_port = free_port_factory(), free_port_factory()
    can_key, dio_key = f"t{can_port}/can", f"t{dio_port}/dio"
    params = tmp_path / "params.json"
    params.write_text('{"P2.041": 264, "P1.042": 150}')  # DO6 = BRKR (0x0108), MBT1 150 ms
    drive_process("--can", f"zenoh:{can_key}?listen=tcp/127.0.0.1:{can_port}",
                  "--node-id", "1", "--params", str(params),
                  "--dio", f"zenoh:{dio_key}?listen=tcp/127.0.0.1:{dio_port}", "--di", "8=1")
    specs_dir = tmp_path / "specs"
    specs_dir.mkdir()
    (specs_dir / "son_brkr_wire.yaml").write_text(SPEC)
    (specs_dir / "son_unreadable.yaml").write_text(UNREADABLE)
    return real_bench(tmp_path, can_key, can_port, dio_key, dio_port), specs_dir


def test_unrecorded_parameters_are_read_and_recorded(drive_process, tmp_path: Path,
                                                      free_port_factory) -> None:
    bench_file, specs_dir = wire_drive(drive_process, tmp_path, free_port_factory)
    bench = load_bench(bench_file)
    plan = loads_plan(PLAN, str(tmp_path / "param_reads.yaml"))
    res = run_plan(plan, bench, tmp_path / "out", specs=load_specs([specs_dir]), reports=False)
    st = {s.index: s for s in res.steps}
    assert [st[i].status for i in (5, 6)] == ["pass", "pass"], [st[i].message for i in (5, 6)]
    # a parameter no drive has is refused when the spec loads, naming the file and line
    # (session 28, helper-103: it had been judged inconclusive at the end of a run)
    reg = load_specs([specs_dir])
    assert "son_unreadable" not in reg
    assert re.search(r"son_unreadable\.yaml:\d+: .*unknown parameter 'P9\.999'",
                     reg.why_missing("son_unreadable")), reg.why_missing("son_unreadable")

    rec = Recording.open(res.recording)
    msgs = [m for _t, _l, _p, m in rec.messages([topics.drive_params("drive1")])]
    reads = [m for m in msgs if m.get("source") == "read"]
    # read once per plan (the second check finds them in the recording)
    assert reads == [{"snapshot": False, "source": "read",
                      "values": {"P1.042": 150, "P2.009": 2}}], msgs
    live = [(v["constraint"], v["status"], round(v["measured_ms"], 3))
            for _t, _l, _p, v in rec.messages([topics.TIMING_VERDICTS])
            if v["spec"] == "son_brkr_wire"]
    assert live and all(s == "pass" for _c, s, _m in live)

    out = subprocess.run([sys.executable, "-m", "hil.cli", "check", res.recording, "--spec",
                          str(specs_dir / "son_brkr_wire.yaml"), "--json"],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stdout + out.stderr
    offline = [(v["constraint"], v["status"], round(v["measured_ms"], 3))
               for v in json.loads(out.stdout)]
    assert offline == live[:1]
    assert json.loads(out.stdout)[0]["values"]["P1.042"] == 150


SDO_PLAN = """\
name: sdo_param
description: P1.042 written as a raw SDO 212Ah; the brake timing is judged with it
steps:
  - sdo: {"212A": 100}
""" + SON_CYCLE


def test_a_raw_sdo_write_to_a_parameter_object_is_recorded(drive_process, tmp_path: Path,
                                                           free_port_factory) -> None:
    """`sdo: {"212A": 100}` on a real bench is P1.042 = 100 (2aBCh <=> Pa-bc, L18154): it is
    recorded as a parameter change, so `check_timing` judges with 100, not with what it
    would otherwise read at the end, and `hil check` on the file agrees."""
    bench_file, specs_dir = wire_drive(drive_process, tmp_path, free_port_factory)
    bench = load_bench(bench_file)
    plan = loads_plan(SDO_PLAN, str(tmp_path / "sdo_param.yaml"))
    res = run_plan(plan, bench, tmp_path / "out", specs=load_specs([specs_dir]), reports=False)
    assert res.passed, [(s.label, s.status, s.message) for s in res.steps]
    rec = Recording.open(res.recording)
    msgs = [m for _t, _l, _p, m in rec.messages([topics.drive_params("drive1")])]
    assert {"snapshot": False, "values": {"P1.042": 100}} in msgs, msgs
    assert [m["values"] for m in msgs if m.get("source") == "read"] == [{"P2.009": 2}]
    (verdict,) = [v for _t, _l, _p, v in rec.messages([topics.TIMING_VERDICTS])]
    assert verdict["values"]["P1.042"] == 100 and verdict["status"] == "pass"
