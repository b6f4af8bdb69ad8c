"""Absolute encoder over the wire (issue 8): `hil drive` with DI/DO on zenoh, Modbus on a pty
and CANopen on zenoh; the harness reads the absolute position by the 80-bit DI/DO handshake
(AbsPositionReader on the real clock), by P0.049-P0.052 over Modbus and by SDO 2031h-2034h,
and they agree with each other and with 6064h after a move and across a restart (the
process keeps the battery-backed state in `--state DIR`, like a power cycle with battery).

Absolute bench (docs/absolute.md): P2.069 = 1 (absolute, a power-cycle parameter: `--params`
values are applied, then the drive powers up), ABSE = DI2 (0x011D), ABSC = DI3 (0x011F),
ABSW = DO4 (0x010D), DI4/DO2/DO3 idle (P2.013/P2.019/P2.020 = 0, L16504). DI2/DI3 rather
than DI9/DI10: on the virtual bench DI9 is wired to the home cam (ORGP) that the mechanics
drive, so a move across the cam would toggle ABSE.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import canopen
import pytest

from hil.drivers.abs_reader import AbsPositionReader
from hil.drivers.cia402 import Cia402Driver
from hil.drivers.delta_modbus import DeltaModbus
from hil.paths import fixture
from hil.record.recorder import Recorder
from hil.timing.checker import check
from hil.timing.source import RecordingSource
from hil.timing.spec import load_spec
from hil.transport.dio import open_dio
from hil.transport.serial_line import open_serial

pytestmark = pytest.mark.integration
EDS = str(Path(__file__).parents[2] / "fixtures" / "drive" / "a3.eds")
NODE, STATION = 5, 7
ABS_PARAMS = {
    "P2.069": 1,  # absolute system (L10034-10042, ● power cycle)
    "P2.011": 0x011D,  # DI2 = ABSE (L15137)
    "P2.012": 0x011F,  # DI3 = ABSC (L15141)
    "P2.021": 0x010D,  # DO4 = ABSW (L15294)
    "P2.013": 0,  # DI4 idle: ABSQ during the handshake (L16504)
    "P2.019": 0,  # DO2 idle: ABSR
    "P2.020": 0,  # DO3 idle: ABSD
}
BINDING = {"drive": "drive1", "dio": "drive1", "ABSE": "DI2", "ABSW": "DO4"}


class SwitchTap:
    """Forwards DI/DO taps to the recorder currently set (one recording per phase)."""

    def __init__(self) -> None:
        self.rec: Recorder | None = None

    def start(self, rec: Recorder, port) -> None:
        """Record into `rec`, starting with every line's current level (known initial state)."""
        t = time.time_ns()
        for line, level in port.levels().items():
            rec.dio(port.name, line, level, t, t)
        self.rec = rec

    def dio(self, *args, **kwargs) -> None:
        if self.rec is not None:
            self.rec.dio(*args, **kwargs)


class LateLines:
    """The harness answers bit `bit` of the first attempt `late_ms` late (ABSQ on)."""

    def __init__(self, inner, bit: int, late_ms: float) -> None:
        self.inner, self.bit, self.late_ms = inner, bit, late_ms
        self.acks, self.done = 0, False
        self.abse_on = False

    def set(self, line: str, level: bool) -> None:
        if line == "DI2":
            self.abse_on, self.acks = level, 0
        elif line == "DI4" and level and self.abse_on and self.inner.get("DO2"):
            if self.acks == self.bit and not self.done:
                self.done = True
                time.sleep(self.late_ms / 1000)
            self.acks += 1
        self.inner.set(line, level)

    def get(self, line: str) -> bool:
        return self.inner.get(line)

    def wait_for(self, line: str, level: bool, timeout_s: float):
        return self.inner.wait_for(line, level, timeout_s)


class Bench:
    """The harness side: DI/DO port, Modbus master, CANopen driver."""

    def __init__(self, tmp_path: Path, drive_process, ports, state: Path) -> None:
        self.tmp = tmp_path
        self.drive_process = drive_process
        self.can_port, self.dio_port_no = ports
        self.state = state
        self.link = tmp_path / "ttyA3"
        self.params = tmp_path / "params.json"
        self.params.write_text(json.dumps(ABS_PARAMS))
        self.tap = SwitchTap()
        self.proc = None
        self.dio = self.line = self.mb = self.net = self.cia = None

    def start(self) -> None:
        dio_key, can_key = f"t{self.dio_port_no}/dio", f"t{self.can_port}/can"
        self.proc = self.drive_process(
            "--dio", f"zenoh:{dio_key}?listen=tcp/127.0.0.1:{self.dio_port_no}",
            "--rs485", f"pty:{self.link}?baud=115200", "--station", str(STATION),
            "--can", f"zenoh:{can_key}?listen=tcp/127.0.0.1:{self.can_port}",
            "--node-id", str(NODE), "--params", str(self.params), "--state", str(self.state),
        )  # fmt: skip
        self.dio = open_dio(
            f"zenoh:{dio_key}?connect=tcp/127.0.0.1:{self.dio_port_no}",
            role="harness",
            name="drive1",
            tap=self.tap,
        )
        self.line = open_serial(f"serial:{self.link}?baud=115200&parity=N&stopbits=2")
        self.mb = DeltaModbus(self.line, station=STATION, baud=115200)
        canopen.Network.NOTIFIER_CYCLE = 0.05
        self.net = canopen.Network()
        self.net.connect(
            interface="zenoh", channel=can_key, connect=[f"tcp/127.0.0.1:{self.can_port}"]
        )
        self.cia = Cia402Driver(self.net, NODE, eds=EDS)
        self.dio.set("DI8", True)  # EMGS (b-contact) wired closed

    def stop(self) -> None:
        if self.net is not None:
            self.net.disconnect()
        for closer in (self.line, self.dio):
            if closer is not None:
                closer.close()
        self.net = self.line = self.dio = None
        if self.proc is not None:
            self.proc.stop()  # SIGINT: the drive saves DIR/absolute.json (Drive.close)
            self.proc = None

    def reader(self, lines=None, retries: int = 2) -> AbsPositionReader:
        return AbsPositionReader(lines or self.dio, abse="DI2", absc="DI3", absw="DO4",
                                 retries=retries)

    def by_modbus(self) -> tuple[int, int, int]:
        self.mb.write_param("P0.049", 1)  # latch P0.050-P0.052 (L7477-7491)
        _until_zero(lambda: self.mb.read_param("P0.049"))  # P0.049 = 0 once latched (L16529)
        return tuple(self.mb.read_param(f"P0.05{n}") for n in (0, 1, 2))  # type: ignore

    def by_sdo(self) -> tuple[int, int, int]:
        self.cia.write(0x2031, 0, 1)  # P0.049 as 2031h
        _until_zero(lambda: self.cia.read(0x2031))
        return tuple(self.cia.read(0x2032 + n) for n in range(3))  # type: ignore


def _until_zero(read, timeout_s: float = 5.0) -> None:
    """Poll a latch command register until the drive has cleared it (the latch is done)."""
    deadline = time.monotonic() + timeout_s
    while read() != 0:
        if time.monotonic() > deadline:
            raise AssertionError(f"P0.049 still not 0 after {timeout_s} s")
        time.sleep(0.01)


@pytest.fixture
def bench(tmp_path, drive_process, free_port_factory):
    b = Bench(tmp_path, drive_process, (free_port_factory(), free_port_factory()),
              tmp_path / "state")  # fmt: skip
    yield b
    b.stop()


def verdicts(path: Path, constants: dict | None = None) -> dict[str, set[str]]:
    spec = load_spec(fixture("timing", "abs_handshake.yaml"))
    out: dict[str, set[str]] = {}
    vs = check(spec, RecordingSource(path), params={"P2.009": 2}, binding=BINDING,
               constants=constants)  # fmt: skip
    for v in vs:
        out.setdefault(v.constraint, set()).add(v.status)
    return out


def test_absolute_position_agrees_over_dio_modbus_and_sdo(bench, tmp_path) -> None:
    bench.start()
    assert bench.dio.wait_for("DO4", True, 5.0)  # ABSW: AL06A, no origin yet (L16391)
    bench.reader().set_origin()  # ABSE, T_S, ABSC held P2.009 + 250 ms (L16436-16450)
    bench.dio.wait_for("DO4", False, 2.0)  # AL06A cleared by the origin
    origin = bench.reader().read()
    assert (origin.status, origin.turns, origin.position) == (0, 0, 0)  # PUU = P6.001
    bench.cia.move_to(1_234_567, 600_000, 200, 200)  # PP over CANopen
    time.sleep(0.3)  # settled: the frame is latched at ABSE + T_S
    # The recording is judged with the manual's windows; over the wire they include the
    # zenoh and scheduling latency of two processes, so a loaded machine may spoil one read:
    # up to three reads, one clean recording is required.
    for attempt in range(3):
        path = tmp_path / f"read{attempt}.mcap"
        with Recorder(path) as rec:
            bench.tap.start(rec, bench.dio)
            reading = bench.reader().read()
            bench.tap.rec = None
        got = verdicts(path)
        if reading.attempts == 1 and all(s <= {"pass", "skipped"} for s in got.values()):
            break
    assert reading.attempts == 1 and reading.status == 0, reading.errors
    for rule in ("T_Q", "T_N", "T_R"):
        (name,) = [n for n in got if n.startswith(rule)]
        assert got[name] == {"pass"}, got
    assert all(s <= {"pass", "skipped"} for s in got.values()), got
    puu = reading.position  # P2.070 bit0 = 0: PUU, turns field 0 (L16468)
    assert abs(puu - 1_234_567) < 100
    assert bench.by_modbus() == (0, 0, puu)  # P2.070 bit1 = 0: PUU (L7493-7516)
    assert bench.by_sdo() == (0, 0, puu)
    # 6064h rounds the motor counts, the absolute PUU truncates toward zero (L16408,
    # docs/manual-choices.md#absolute): they may differ by one PUU.
    assert abs(bench.cia.read(0x6064) - puu) <= 1

    # A host that answers too late gets ABSW (T_R, L16513); the retry succeeds.
    with Recorder(tmp_path / "late.mcap") as rec:
        bench.tap.start(rec, bench.dio)
        late = bench.reader(LateLines(bench.dio, bit=5, late_ms=260), retries=4).read()
        bench.tap.rec = None
    # the late answer costs exactly one attempt; a loaded machine may spoil the retry too
    # (a T_Q miss, as above), so a third attempt is allowed, but only for that reason
    assert late.attempts >= 2 and "bit 5: ABSW on" in late.errors[0]
    assert all("within T_Q" in e for e in late.errors[1:]), late.errors
    assert (late.status, late.position) == (0, puu)
    # abort_max (the drive's reaction to T_R / ABSE off) is a chosen bound, the manual gives
    # none (⚠); measured across two processes it includes the zenoh hop and the drive's 1 ms
    # tick, so the wire check allows 20 ms.
    got = verdicts(tmp_path / "late.mcap", {"abort_max": 20})
    assert "fail" in got["T_R - host raises ABSQ within 200 ms of ABSR on"]  # the host's fault
    assert got["ABSW when T_R passes without ABSQ on"] == {"pass"}
    assert got["ABSE off clears ABSW"] == {"pass"}


def test_absolute_position_survives_a_restart(bench) -> None:
    bench.start()
    bench.reader().set_origin()
    bench.cia.move_to(-3_456_789, 600_000, 200, 200)
    time.sleep(0.3)
    before = bench.reader().read()
    assert abs(before.position + 3_456_789) < 100
    bench.cia.shutdown()
    bench.stop()  # power off: the battery keeps the position (DIR/absolute.json)
    assert (bench.state / "absolute.json").exists()
    bench.start()  # power on
    after = bench.reader().read()
    assert (after.status, after.turns, after.position) == (0, 0, before.position)
    assert bench.by_modbus() == (0, 0, before.position)
    assert bench.by_sdo() == (0, 0, before.position)
