"""The RS-485 line on the virtual clock as a stranger uses it (an outside probe, docs/clock.md):
a request written in back-to-back chunks is one frame (no silence between its characters),
and a Modbus master whose line is closed under it stops waiting."""

from __future__ import annotations

import time

import pytest

from hil import clock
from hil.clock import VirtualClock
from hil.drivers.delta_modbus import DeltaModbus, ModbusError
from hil.protocol import modbus as mb
from hil.transport.serial_line import open_serial
from hil.virtual.stack import DriveSpec, VirtualDriveStack

pytestmark = pytest.mark.virtual_time


@pytest.fixture
def bench(tmp_path):
    """A virtual drive (station 1) on a virtual-time line at `baud`; the harness's end."""
    def make(baud: int):
        stack = VirtualDriveStack(DriveSpec(rs485=f"pty:{tmp_path}/l{baud}?baud={baud}",
                                            station=1, modbus_baud=baud)).start()
        line = open_serial(f"serial:{tmp_path}/l{baud}?baud={baud}")
        made.append((stack, line))
        return line
    made: list = []
    clk = VirtualClock()
    with clock.use(clk):
        yield make
        for stack, line in made:
            line.close()
            stack.stop()


@pytest.mark.parametrize("baud", [4800, 9600, 19200, 38400])
@pytest.mark.parametrize("cut", [1, 2, 4, 6])
def test_a_request_written_in_two_back_to_back_chunks_is_one_frame(bench, baud, cut) -> None:
    """Modbus RTU: a frame ends only at t3.5 of idle line (L15703). Written as `cut` bytes and
    then the rest at once, the characters follow each other with no gap; the drive answers.
    Each chunk used to reach the drive whole at its last character, so t3.5 passed inside the
    frame when the second chunk took longer than t3.5 (1+7 bytes at 38400 baud: no reply)."""
    line = bench(baud)
    req = mb.encode_adu(1, mb.read_request(0x0154, 1), "rtu")
    clock.sleep(0.05)
    first = line.write(req[:cut])
    second = line.write(req[cut:])
    assert second.t_start_ns == first.t_end_ns  # back to back on the wire
    reply = line.read_frame(timeout=0.3)
    assert reply is not None and reply.data[:3] == b"\x01\x03\x02", reply


@pytest.mark.parametrize("baud", [9600, 38400])
def test_characters_a_gap_of_t35_apart_are_two_frames(bench, baud) -> None:
    """The other side of the rule: the same request with t3.5 of silence inside it is two
    frames, neither a valid request, and the drive answers nothing."""
    line = bench(baud)
    req = mb.encode_adu(1, mb.read_request(0x0154, 1), "rtu")
    clock.sleep(0.05)
    first = line.write(req[:4])
    line.write(req[4:], not_before_ns=first.t_end_ns + round(line.t35_s * 1e9) + 1000)
    assert line.read_frame(timeout=0.3) is None


def test_a_master_whose_line_closes_under_it_stops_waiting(bench) -> None:
    """The line closed 100 ms into a transaction with an absent station: the master read an
    empty line at once and looped without waiting, so bench time never reached its deadline
    (100 % CPU for ever, no step timeout either). It now says the line closed."""
    line = bench(38400)
    master = DeltaModbus(line, station=9, timeout_s=0.5)
    clock.call_later(0.1, line.close)
    t0, w0 = clock.monotonic(), time.monotonic()
    with pytest.raises(ModbusError, match="closed"):
        master.read_registers(0x0154, 1)
    assert clock.monotonic() - t0 < 0.2
    assert time.monotonic() - w0 < 5


def test_the_reply_timeout_counts_from_the_end_of_the_request(tmp_path) -> None:
    """Modbus over serial line: the response timeout runs once the request is sent. A write
    of 8 registers in ASCII at 4800 baud 7E1 is 51 characters, 106 ms on the wire; with a
    100 ms timeout the master gave up before its own request had left."""
    url = f"pty:{tmp_path}/a?baud=4800&parity=E&bytesize=7&stopbits=1"
    with clock.use(VirtualClock()):
        stack = VirtualDriveStack(DriveSpec(rs485=url, station=1, modbus_mode="ascii",
                                            modbus_baud=4800)).start()
        line = open_serial(url.replace("pty:", "serial:"))
        try:
            master = DeltaModbus(line, station=1, mode="ascii", timeout_s=0.1, baud=4800,
                                 char_format=mb.CharFormat(7, "E", 1))
            t0 = clock.monotonic()
            try:
                master.write_registers(0x0154, [0] * 8)  # P1.042.. (any reply will do)
            except ModbusError as exc:
                assert not isinstance(exc, TimeoutError), exc  # an exception reply answers
            assert clock.monotonic() - t0 > 0.106  # the request alone took this long
        finally:
            line.close()
            stack.stop()


def test_another_thread_closes_the_line_during_a_long_read(bench) -> None:
    """A watchdog thread that closes the line ends a pending read (as on the wall clock). The
    read held the line's lock while the clock ran, so the close waited for the whole read:
    60 s of bench time, or about 23 s of wall time for an hour's read (an outside probe)."""
    import threading

    line = bench(38400)
    closer = threading.Timer(0.05, line.close)
    t0, w0 = clock.monotonic(), time.monotonic()
    closer.start()
    assert line.read(1, timeout=3600.0) == b""
    closer.join(5)
    assert line.closed
    assert time.monotonic() - w0 < 5
    assert clock.monotonic() - t0 < 3000


@pytest.mark.parametrize("url, mode, p3001, p3002", [
    ("pty:auto?baud=38400", None, 0x0203, 6),  # the A3's defaults (L10510, L10557)
    ("pty:auto?baud=115200", None, 0x0205, 6),  # X = 5 (L10527)
    ("pty:auto?baud=4800&parity=E&bytesize=7&stopbits=1", "ascii", 0x0200, 1),  # 7,E,1 ASCII
    ("pty:auto?baud=9600&parity=O&stopbits=1", "rtu", 0x0201, 8),  # 8,O,1 RTU
    ("pty:auto?baud=19200&stopbits=1", None, 0x0202, 6),  # 8N1 is not offered: 8N2 reads it
])
def test_the_drive_is_set_for_the_line_its_bench_declares(url, mode, p3001, p3002) -> None:
    """P3.001 X and P3.002 (L10509-L10557) follow the bench's line URL where the bench sets
    neither; a parameter the bench sets wins."""
    from hil.virtual.stack import line_params

    assert line_params({}, url, mode) == {"P3.001": p3001, "P3.002": p3002}
    assert line_params({"P3.001": 0x0201, "P3.002": 7}, url, mode) == {"P3.001": 0x0201,
                                                                       "P3.002": 7}


def test_a_line_the_a3_cannot_run_is_said_and_left_to_garble(caplog) -> None:
    """230400 baud is no P3.001 X, 7 data bits no RTU format: a warning names the line, and
    the parameters stay at their defaults (the drive then reads garbage, as a real one)."""
    from hil.virtual.stack import line_params

    with caplog.at_level("WARNING"):
        assert line_params({}, "pty:auto?baud=230400", None) == {"P3.002": 6}
        assert line_params({}, "pty:auto?baud=9600&bytesize=7", "rtu") == {"P3.001": 0x0201}
    assert "230400" in caplog.text and "P3.001 X" in caplog.text
    assert "no P3.002 protocol is RTU 7N" in caplog.text


def test_a_plan_that_moves_the_drive_off_its_line_loses_it(tmp_path) -> None:
    """A Modbus write of P3.001 X = 1 (9600) is answered at 38400; the next request on the
    bench's 38400 line gets no reply (L16035), as a real bench's would. The virtual drive used
    to answer on at 38400, whatever P3.001 said."""
    from hil.bench.bench import load_bench
    from hil.plan.plan import loads_plan
    from hil.plan.runner import run_plan

    plan = loads_plan("name: baud\nsteps:\n  - write: {P3.001: 0x0201, via: modbus}\n"
                      "  - read: {P1.042: null, via: modbus, expect_error: timeout}\n",
                      str(tmp_path / "baud.yaml"))
    res = run_plan(plan, load_bench(None), tmp_path)
    assert res.status == "pass", [(s.status, s.message) for s in res.steps]


def test_p3002_written_over_sdo_moves_the_uart_from_the_next_frame(tmp_path) -> None:
    """P3.002 has no power-cycle mark (L10546-L10557), and a new protocol is used from the next
    frame (L16037), whichever way it was written: an SDO write of 8E1 RTU loses a 8N2 line, and
    one of 8N2 brings it back. Only a power cycle took an SDO's P3.002 before (helper-78)."""
    from hil.bench.bench import load_bench
    from hil.plan.plan import loads_plan
    from hil.plan.runner import run_plan

    plan = loads_plan(
        "name: sdo_line\nsteps:\n"
        "  - write: {P3.002: 7, via: modbus}\n"
        "  - read: {P1.042: null, via: modbus, expect_error: timeout}\n"
        "  - write: {P3.002: 6, via: sdo}\n"
        "  - read: {P1.042: null, via: modbus}\n"
        "  - write: {P3.002: 7, via: sdo}\n"
        "  - read: {P1.042: null, via: modbus, expect_error: timeout}\n",
        str(tmp_path / "sdo_line.yaml"))
    res = run_plan(plan, load_bench(None), tmp_path)
    assert res.status == "pass", [(s.status, s.message) for s in res.steps]


def _bench_text(**swap: str) -> str:
    from pathlib import Path

    from hil.paths import fixture

    text = Path(fixture("benches", "virtual.yaml")).read_text()
    for old, new in swap.values():
        assert old in text, old
        text = text.replace(old, new)
    return text


@pytest.mark.parametrize("swap, said", [
    ({}, None),
    ({"u": ('"pty:auto?baud=38400"', '"pty:auto?baud=115200&parity=E&stopbits=1"')}, None),
    ({"u": ('"pty:auto?baud=38400"', '"pty:auto?baud=230400"')},
     "the line runs 230400 baud 8N2, the drive's UART 38400 baud 8N2"),
    ({"p": ("      P3.000: 1 ", "      P3.002: 7\n      P3.000: 1 ")},
     "the line runs 38400 baud 8N2, the drive's UART 38400 baud 8E1"),
    ({"m": ("    param_via: modbus\n", "    param_via: modbus\n    modbus_mode: ascii\n"),
      "p": ("      P3.000: 1 ", "      P3.002: 6\n      P3.000: 1 ")},
     "the harness speaks ASCII, P3.002 = 6 is RTU"),
])
def test_a_bench_whose_drive_cannot_read_its_line_is_warned_of(swap, said, tmp_path) -> None:
    """The line's URL and `modbus_mode` against the drive's P3.001 X / P3.002 (L10509-L10557),
    said by `hil run` and on the recording's /log with the bench file and the drive's line (the
    plan then only said "received nothing"; helper-78)."""
    from hil.bench.bench import line_warnings, loads_bench

    got = line_warnings(loads_bench(_bench_text(**swap), str(tmp_path / "b.yaml")))
    if said is None:
        assert got == []
    else:
        assert len(got) == 1 and said in got[0], got
        assert got[0].startswith(f"{tmp_path / 'b.yaml'}:18: drives.drive1: ")


def test_a_real_bench_is_judged_by_the_params_it_sets(tmp_path) -> None:
    """A real drive's settings are unknown unless the bench's params set them: nothing is said
    then; P3.001 = 9600 on a 38400 line is."""
    from pathlib import Path

    from hil.bench.bench import line_warnings, loads_bench
    from hil.paths import fixture

    text = Path(fixture("benches", "example-asda-a3-socketcan.yaml")).read_text()
    bench = loads_bench(text, "real.yaml")
    assert bench.rs485 and line_warnings(bench) == []
    d = next(iter(bench.drives.values()))
    d.params["P3.001"] = 0x0201
    assert "drive's UART 9600 baud" in " ".join(line_warnings(bench))


def test_the_line_leaves_a_retained_or_otherwise_spelt_setting_alone(tmp_path) -> None:
    """A P3.001 / P3.002 the drive retained (`state_path`) or one its params spell another way
    (`P3-2`, as `hil drive --params` keeps them) is the drive's own: the line does not overwrite
    it (it reset the retained P3.001 to its default, CAN digit Z with it; helper-77)."""
    import json

    from hil.virtual.stack import line_params

    (tmp_path / "params.json").write_text(json.dumps({"parameters": {"P3.001": 0x0401,
                                                                     "P3.002": 7}}))
    assert line_params({}, "pty:auto?baud=38400", None, tmp_path) == {}
    assert line_params({"P3-1": 0x0201, "p3.2": 7}, "pty:auto?baud=38400", None) == {
        "P3-1": 0x0201, "p3.2": 7}
    with VirtualDriveStack(DriveSpec(rs485=f"pty:{tmp_path}/l?baud=38400",
                                     state_path=tmp_path)) as stack:
        assert stack.drive.params.get("P3.001") == 0x0401
        assert stack.drive.params.get("P3.002") == 7
    assert json.loads((tmp_path / "params.json").read_text())["parameters"]["P3.001"] == 0x0401


def test_a_subprocess_bench_refuses_a_virtual_bus_in_any_case(tmp_path) -> None:
    """`VIRTUAL:x` is the in-process bus too: refused on a `process: subprocess` bench as
    `virtual:x` is (its drives could never reach the harness)."""
    from hil.bench.bench import loads_bench
    from hil.bench.yamlio import PlanFileError

    text = _bench_text(p=("process: inproc", "process: subprocess"),
                       c=('can0: "virtual:auto"', 'can0: "VIRTUAL:auto"'))
    with pytest.raises(PlanFileError, match=r"drives\.drive1\.can: a virtual: bus is in-process"):
        loads_bench(text, "b.yaml")


def test_the_warning_is_on_the_recording_of_a_plan_and_of_a_pytest_test(tmp_path) -> None:
    """`record_bench` (a plan's recording, and `hil_session`'s) logs each line warning on /log,
    where a reviewer of the recording finds why Modbus went unanswered."""
    from hil import clock as hclock
    from hil.bench.bench import loads_bench
    from hil.plan.runner import record_bench

    class Rec:
        def __init__(self) -> None:
            self.logs: list[tuple] = []

        def add_metadata(self, *_a) -> None:
            pass

        def log(self, level, text, name=None, **_kw) -> None:
            self.logs.append((level, text, name))

    bench = loads_bench(_bench_text(p=("      P3.000: 1 ", "      P3.002: 7\n      P3.000: 1 ")),
                        str(tmp_path / "b.yaml"))
    rec = Rec()
    with hclock.use(hclock.VirtualClock()):
        record_bench(rec, bench)
    assert [(lv, name) for lv, _t, name in rec.logs] == [("warning", "hil.bench")]
    assert "the drive's UART 38400 baud 8E1" in rec.logs[0][1]
