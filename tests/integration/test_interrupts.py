"""`hil run` as a stranger stops it: Ctrl-C twice, a step timeout, a dead drive process.

Each test runs the real `hil run` entry point as a child process on a virtual bench and then
reads the recording with the official mcap reader (issue 12, "Runner and recordings").
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from mcap.reader import make_reader

from hil.paths import fixture

pytestmark = pytest.mark.integration

LONG_MOVE = """\
name: long_move
bench_requires: [motion, can]
steps:
  - state: OPERATION ENABLED
  - move: {mode: PP, target: 50000000, velocity: 20000, accel: 200, decel: 200}
"""

TIMED_MOVE = LONG_MOVE.replace("name: long_move", "name: timed_move") + "    timeout: 1s\n"

SON_HOLD = """\
name: son_hold
steps:
  - di: {SON: on}
  - wait: 4s
  - di: {SON: off}
"""


def _start(tmp_path: Path, plan_text: str, *extra: str) -> tuple[subprocess.Popen, Path]:
    plan = tmp_path / "plan.yaml"
    plan.write_text(plan_text)
    out = tmp_path / "out"
    hil = str(Path(sys.executable).with_name("hil"))
    p = subprocess.Popen([hil, "run", "-v", str(plan), "--out", str(out), *extra],  # -v: step lines
                         stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                         env=dict(os.environ, PYTHONUNBUFFERED="1"))
    return p, out / f"{plan.stem}.mcap"


def _wait_line(p: subprocess.Popen, needle: str, timeout_s: float = 60.0) -> list[str]:
    lines: list[str] = []
    end = time.monotonic() + timeout_s
    assert p.stdout is not None
    while time.monotonic() < end:
        line = p.stdout.readline()
        if not line:
            break
        lines.append(line)
        if needle in line:
            return lines
    raise AssertionError(f"{needle!r} not seen; output: {''.join(lines)[-2000:]}")


def _read(path: Path) -> tuple[object, dict[str, dict], list[dict]]:
    with path.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        meta = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        f.seek(0)
        safety = [json.loads(m.data) for _, ch, m in make_reader(f).iter_messages(
            topics=["/safety"])]
    return summary, meta, safety


@pytest.mark.parametrize("gap_s", [0.002, 0.020])
def test_second_ctrl_c_does_not_cut_the_safe_state_or_the_recording(tmp_path, gap_s):
    p, mcap = _start(tmp_path, LONG_MOVE)
    try:
        _wait_line(p, " 1/2]")  # enabled; the move has started
        time.sleep(0.3)
        p.send_signal(signal.SIGINT)
        time.sleep(gap_s)
        p.send_signal(signal.SIGINT)
        out, _ = p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 130, out
    assert "Traceback" not in out, out
    summary, meta, safety = _read(mcap)
    assert summary is not None  # summary section and footer written
    assert meta["hil.result"]["status"] == "aborted", meta.get("hil.result")
    assert meta["hil.result"]["safe_state_ok"] == "true", meta["hil.result"]
    # the record names the signal that stopped the run
    assert meta["hil.result"]["reason"] == "interrupted (SIGINT (Ctrl-C))", meta["hil.result"]
    actions = [s["action"] for s in safety]
    assert actions[-1] == "safe_state_reached", actions
    assert any(a.startswith("controlword") for a in actions), actions


@pytest.mark.parametrize("clock", ["real", "virtual"])
def test_step_timeout_ends_the_step_at_its_timeout(tmp_path, clock):
    """`timeout: 1s` on a move that takes minutes: the step ends at 1 s, not 2 s (a
    real-time regression: the wall clock is where it happened; virtual time, 1 s exactly)."""
    p, mcap = _start(tmp_path, TIMED_MOVE, "--clock", clock)
    out, _ = p.communicate(timeout=60)
    assert p.returncode == 1, out
    _, _, safety = _read(mcap)
    assert safety[-1]["action"] == "safe_state_reached"
    with mcap.open("rb") as f:
        ends = [json.loads(m.data) for _, _, m in make_reader(f).iter_messages(
            topics=["/plan/steps"])]
    move = [e for e in ends if e.get("event") == "end" and e.get("kind") == "move"]
    assert move and move[0]["status"] == "error", move
    assert 1.0e9 <= move[0]["duration_ns"] < 1.3e9, move[0]  # was 2.0 s
    if clock == "virtual":
        assert move[0]["duration_ns"] == 1_000_000_000, move[0]


def _children(pid: int) -> list[tuple[int, str]]:
    out = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
            ppid = int(stat.rsplit(")", 1)[1].split()[1])
            cmd = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode()
        except (OSError, ValueError, IndexError):
            continue
        if ppid == pid:
            out.append((int(d.name), cmd))
    return out


def test_dead_drive_process_is_reported_not_passed(tmp_path):
    """`hil drive` killed mid-plan: the run fails naming the dead process, and the safe
    state does not claim `DI SON off` on a drive that is gone."""
    bench = str(fixture("benches", "virtual-zenoh.yaml"))
    p, mcap = _start(tmp_path, SON_HOLD, "--bench", bench)
    try:
        _wait_line(p, " 1/3]")
        drives = [pid for pid, cmd in _children(p.pid) if " drive" in cmd]
        assert drives, _children(p.pid)
        os.kill(drives[0], signal.SIGKILL)
        out, _ = p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 1, out
    assert "virtual drive process 'drive1'" in out and "killed by signal 9" in out, out
    _, meta, safety = _read(mcap)
    assert meta["hil.result"]["safe_state_ok"] == "false", meta["hil.result"]
    gone = [s for s in safety if s["action"] == "drive process alive"]
    assert gone and gone[0]["ok"] is False and "died" in gone[0]["detail"], safety
    assert not any(s["action"].startswith("DI SON") and s.get("ok") for s in safety), safety

