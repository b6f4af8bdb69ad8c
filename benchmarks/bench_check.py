"""Time `hil check` (all shipped specs) on a large synthetic recording vs a bare mcap read.

    .venv/bin/python benchmarks/bench_check.py [--messages 500000] [--bus-fps 9000]

Writes a recording with the `mcap` package: drive state at 1 kHz, DI/DO/STO lines toggling
through servo-on/off, STO and EMGS cycles, CANopen control/status words. Prints messages/s
for a bare `mcap` reader pass (decode JSON too) and for `hil check` itself (all shipped specs, in
its own process: its time and peak RSS), then the same check on the whole file read as
messages, as `hil check` read it before (`--no-whole` skips it).
`--bus-fps N` adds N raw CAN frames a second on /can/can0/raw (9000: a saturated 1 Mbit/s
bus), which no shipped spec reads. Also prints the time one hour of the same mix would take at
the measured rate, and the peak RSS.
"""

from __future__ import annotations

import argparse
import json
import math
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from mcap.reader import make_reader
from mcap.writer import Writer

MS = 1_000_000


def write(path: Path, n: int, bus_fps: int = 0, moving: bool = False) -> int:
    """About `n` messages: a 1 ms state stream plus edges every cycle of 1 s. `moving`: the
    speed wobbles and a position changes at every sample (the worst case for columns)."""
    count = 0
    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        sid = w.register_schema("hil.Any", "jsonschema", b'{"type": "object"}')
        chans: dict[str, int] = {}

        def put(topic: str, t: int, payload: dict) -> None:
            nonlocal count
            if topic not in chans:
                chans[topic] = w.register_channel(topic, "json", sid, {})
            w.add_message(chans[topic], log_time=t, publish_time=t,
                          data=json.dumps(payload).encode())
            count += 1

        put("/drive/drive1/params", 0, {"snapshot": True, "values": {
            "P1.042": 150, "P1.043": 100, "P1.038": 100, "P2.009": 2}})
        for line, lvl in (("DI1", False), ("DI5", False), ("DI8", True), ("DO1", True),
                          ("DO6", False), ("STO_A", True), ("STO_B", True)):
            put(f"/dio/drive1/{line}", 0, {"level": lvl})
        t_ms = 0
        while count < n:
            cyc = t_ms // 1000
            phase = t_ms % 1000
            t = t_ms * MS
            on = 100 + 2 <= phase < 600 + 2
            put("/drive/drive1/state", t, {
                "state": "OPERATION ENABLED" if on else "SWITCH ON DISABLED",
                "servo_on": on, "torque_enabled": on, "brake_released": 252 <= phase < 602,
                "speed_rpm": (1000.0 if 300 <= phase < 580 else 0.0) + moving * (t_ms % 7) / 10,
                **({"position_puu": t_ms * 3} if moving else {}),
                "alarms": ["AL500"] if cyc % 4 == 3 and 710 <= phase < 902 else []})
            put("/canopen/can0", t, {"statusword": 0x0237 if on else 0x0250,
                                     "controlword": 0x0F if 100 <= phase < 600 else 0x06})
            for k in range(bus_fps * (t_ms + 1) // 1000 - bus_fps * t_ms // 1000):
                put("/can/can0/raw", t + k * 1000, {
                    "id": 0x181 + k % 4, "ext": False, "rtr": False, "err": False, "fd": False,
                    "brs": False, "esi": False, "dlc": 8,
                    "data": (t_ms * 8 + k).to_bytes(8, "little").hex(), "dir": "rx"})
            if phase == 100:
                put("/dio/drive1/DI1", t, {"level": True})
            if phase == 252:
                put("/dio/drive1/DO6", t, {"level": True})
            if phase == 600:
                put("/dio/drive1/DI1", t, {"level": False})
            if phase == 602:
                put("/dio/drive1/DO6", t, {"level": False})
            if cyc % 4 == 3 and phase in (700, 800):
                for ch in ("STO_A", "STO_B"):
                    put(f"/dio/drive1/{ch}", t, {"level": phase == 800})
            if cyc % 4 == 3 and phase in (900, 950):
                put("/dio/drive1/DI5", t, {"level": phase == 900})
            t_ms += 1
        w.finish()
    return count


def bare(path: Path) -> int:
    n = 0
    with open(path, "rb") as f:
        for _schema, _channel, message in make_reader(f).iter_messages():
            json.loads(message.data)
            n += 1
    return n


#: the check as `hil check` made it before session 7: the whole file read as messages
_WHOLE = """
import sys, time
from hil.timing.checker import check_all, summary
from hil.timing.source import RecordingSource
from hil.timing.spec import load_spec, shipped_specs
specs = [load_spec(p) for p in shipped_specs()]
t0 = time.perf_counter()
src = RecordingSource(sys.argv[1])
v = check_all(specs, src, binding={"drive": "drive1", "dio": "drive1", "bus": "can0"})
print(time.perf_counter() - t0, summary(v))
"""


def child(args: list[str]) -> tuple[float, int, str]:
    """Run a child process; (wall s, its peak RSS in MB, its stdout's last line)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    t0 = time.perf_counter()
    out = subprocess.run(args, capture_output=True, text=True, check=False)
    wall = time.perf_counter() - t0
    peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    if peak <= before:
        peak = -1024  # masked by an earlier, larger child: run it first to see it
    lines = (out.stdout.strip() or out.stderr.strip()).splitlines()
    return wall, peak // 1024, lines[-1] if lines else ""


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--messages", type=int, default=500_000)
    ap.add_argument("--bus-fps", type=int, default=0, help="raw CAN frames a second")
    ap.add_argument("--no-bare", action="store_true", help="skip the bare mcap read")
    ap.add_argument("--moving", action="store_true",
                    help="speed and position change at every state sample")
    ap.add_argument("--no-whole", action="store_true",
                    help="skip the baseline check on the whole file read as messages")
    args = ap.parse_args()

    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "bench.mcap"
        t0 = time.perf_counter()
        n = write(path, args.messages, args.bus_fps, args.moving)
        print(f"wrote {n} messages ({path.stat().st_size / 1e6:.1f} MB) "
              f"in {time.perf_counter() - t0:.1f} s")
        t0 = time.perf_counter()
        if not args.no_bare:
            bare(path)
        t_bare = time.perf_counter() - t0 if not args.no_bare else math.nan
        # the real command, in its own process (its peak RSS is its own)
        wall, rss, _last = child([sys.executable, "-m", "hil.cli", "check", str(path),
                                  "--json"])
        results = [("hil check (columns)", wall, rss)]
        if not args.no_whole:
            wall_w, rss_w, last = child([sys.executable, "-c", _WHOLE, str(path)])
            results.append(("whole file as messages", wall_w, rss_w))
            print(f"baseline verdicts: {last.partition(' ')[2]}")
    per_s = 2000 + args.bus_fps  # state + CANopen at 1 kHz each, plus the raw frames
    hour = 3600 * per_s
    print(f"bare mcap read+json : {n / t_bare:12,.0f} msg/s ({t_bare:.2f} s)")
    for name, wall, rss in results:
        print(f"{name:24s}: {n / wall:12,.0f} msg/s ({wall:.2f} s, process start included; "
              f"{wall / t_bare:.2f}x the bare read); peak RSS {rss} MB; one hour of this mix "
              f"({hour / 1e6:.1f} M messages): {hour / (n / wall) / 60:.1f} min")
    print(f"recording length: {n / per_s:.0f} s (goal: an hour in 2 min, 500 MB whatever the "
          "length)")


if __name__ == "__main__":
    main()
