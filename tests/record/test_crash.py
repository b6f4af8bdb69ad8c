"""Truncated files: cut at random offsets, and a real `kill -9` of a recording process."""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import textwrap
import time

import pytest
from mcap.reader import make_reader
from test_recorder import record_mix

from hil.record.cli import repair
from hil.record.reader import Recording, RecordingError


def test_cut_at_random_offsets_reads_a_prefix_and_repairs(tmp_path):
    p = tmp_path / "full.mcap"
    record_mix(p)
    full = Recording.open(p)
    ref = list(full.raw_messages())
    data = p.read_bytes()
    rng = random.Random(20241122)
    offsets = sorted({rng.randrange(8, len(data)) for _ in range(25)} | {8, 9, len(data) - 1})
    for off in offsets:
        cut = tmp_path / f"cut{off}.mcap"
        cut.write_bytes(data[:off])
        r = Recording.open(cut)
        assert r.truncated
        got = list(r.raw_messages())
        assert got == ref[: len(got)], off
        out = tmp_path / f"rep{off}.mcap"
        n = repair(r, out)
        assert n == len(got)
        with open(out, "rb") as f:
            reader = make_reader(f)
            assert reader.get_summary().statistics.message_count == n
            assert sum(1 for _ in reader.iter_messages()) == n
        assert not Recording.open(out).truncated
    with pytest.raises(RecordingError, match=r"cut_magic\.mcap: not an MCAP file"):
        (tmp_path / "cut_magic.mcap").write_bytes(data[:5])
        Recording.open(tmp_path / "cut_magic.mcap")


CHILD = textwrap.dedent(
    """
    import sys, time, can
    from hil.record.recorder import Recorder
    rec = Recorder(sys.argv[1])
    period = 1 / float(sys.argv[2])
    print("ready", flush=True)
    i, nxt = 0, time.monotonic()
    while True:
        msg = can.Message(arbitration_id=0x181, data=i.to_bytes(4, "little"),
                          is_extended_id=False)
        rec.can("can0", msg, "rx", time.time_ns(), None)
        i += 1
        nxt += period
        d = nxt - time.monotonic()
        if d > 0:
            time.sleep(d)
    """
)


@pytest.mark.integration
def test_kill_minus_9_keeps_everything_older_than_100_ms(tmp_path):
    p = tmp_path / "killed.mcap"
    script = tmp_path / "child.py"
    script.write_text(CHILD)
    rate = 2000  # frames/s, steady
    proc = subprocess.Popen(
        [sys.executable, str(script), str(p), str(rate)], stdout=subprocess.PIPE, text=True
    )
    try:
        assert proc.stdout.readline().strip() == "ready"
        time.sleep(1.0)  # let it record ~2000 frames
        t_kill = time.time_ns()
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=10)
        proc.stdout.close()
    assert proc.returncode == -signal.SIGKILL
    r = Recording.open(p)
    assert r.truncated
    got = [
        (lt, int.from_bytes(bytes.fromhex(o["data"]), "little"))
        for _t, lt, _p, o in r.messages("/can/can0/raw")
    ]
    seqs = [s for _lt, s in got]
    assert seqs == list(range(len(seqs))), "readable frames must be a gap-free prefix"
    last = max(lt for lt, _s in got)
    tail_loss_ms = (t_kill - last) / 1e6
    print(f"\nkill -9: {len(got)} frames readable, tail loss {tail_loss_ms:.1f} ms")
    # every frame logged more than 100 ms before the kill is in the file
    assert tail_loss_ms < 100.0
    assert len(got) > rate // 2
