"""A PLC on one side of a zenoh pulse line, the virtual drive in a `hil drive` process on the
other (issue 26: tested from outside). Real time, loopback only."""

from __future__ import annotations

import json
import time

import pytest

from hil.drivers.plc_pulse import AxisParams, Drv, Program, PulseMaster, Step
from hil.transport.dio import open_dio
from hil.transport.pulse import open_pulse

pytestmark = [pytest.mark.integration, pytest.mark.timeout(90)]

PER_REV = 10000  # P1.044 / P1.045 = 16777216 / 10000; OA/OB: 4 x P1.046 = 10000 per rev


def test_plc_drives_hil_drive_over_a_zenoh_pulse_line(drive_process, free_port_factory,
                                                       tmp_path) -> None:
    pp, dp = free_port_factory(), free_port_factory()
    params = tmp_path / "params.json"
    params.write_text(json.dumps({"P1.045": 10000, "P1.044": 16777216, "P2.041": 0x0108}))
    pulse_key, dio_key = f"t{pp}/pulse", f"t{dp}/dio"
    proc = drive_process(
        "--pulse", f"zenoh:{pulse_key}?listen=tcp/127.0.0.1:{pp}",
        "--dio", f"zenoh:{dio_key}?listen=tcp/127.0.0.1:{dp}",
        "--params", str(params))
    assert "pulse line on zenoh" in proc.lines[-1]
    dio = open_dio(f"zenoh:{dio_key}?connect=tcp/127.0.0.1:{dp}", role="harness")
    line = open_pulse(f"zenoh:{pulse_key}?connect=tcp/127.0.0.1:{pp}", role="master")
    try:
        dio.set("DI8", True)  # EMGS released (b contact)
        dio.set("DI1", True)  # SON
        assert dio.wait_for("DO6", True, 5.0)  # BRKR: the servo is on
        assert line.get("X0") is True  # the axis stands on the home cam (-0.5 ~ 0.5 rev)
        plc = PulseMaster(line, AxisParams(max_speed=100_000, start_speed=500, accel_ms=100,
                                           creep_speed=2000, dog="X0", clr="Y8",
                                           origin=100))
        st = plc.run(Program([Step(spd=50_000, drive=Drv("ABS", "", 30_000), wait_time=0.3)]))
        assert st.position == 30_000
        # the PLC's high-speed counter on the drive's OA/OB sees the motor arrive (once the
        # encoder output stops coming: a loaded host may deliver its last window late)
        assert _settled(lambda: st.feedback) == pytest.approx(30_000, abs=4)
        assert not line.get("X0")  # and the cam is behind it
        st = plc.run(Program([Step(spd=20_000, drive="MD1", wait_time=0.3)]), timeout_s=30)
        assert st.homed and st.position == 100
        # MD1's zero is DOG's OFF edge moving back at creep speed: +0.5 rev (001:112); a
        # real-time line reacts a few ms late at 2000 Ps/s: a few pulses past it
        assert _settled(lambda: st.feedback) == pytest.approx(PER_REV // 2, abs=40)
    finally:
        line.close()
        dio.close()


def _settled(read, quiet_s: float = 0.2, timeout_s: float = 5.0):
    """`read()` once it has not changed for `quiet_s` (or at `timeout_s`, whatever it is)."""
    deadline = time.monotonic() + timeout_s
    last, since = read(), time.monotonic()
    while time.monotonic() < deadline:
        time.sleep(0.02)
        now = read()
        if now != last:
            last, since = now, time.monotonic()
        elif time.monotonic() - since >= quiet_s:
            break
    return last
