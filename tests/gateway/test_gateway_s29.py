"""The gateway under an outside probe (helper-126): bad samples counted, a holder's RS-485
bytes gone with its lease, a safe state confirmed only by an answer, options checked, each
log line once, a bad lease request not shown as a held bench."""

from __future__ import annotations

import logging
import time
from pathlib import Path

import pytest

from hil.gateway.client import LeaseRefused, acquire
from hil.gateway.gateway import Gateway, GatewayConfig
from hil.transport.serial_line import open_serial
from hil.transport.zenoh_can import ERR, FD, HEADER, RTR
from hil.transport.zenoh_net import close_session, make_config, open_session, wait_connected


def _wait(pred, timeout_s: float = 5.0) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(0.01)
    return bool(pred())


def test_frames_no_controller_sends_are_counted_and_never_forwarded(make_rig) -> None:
    """docs/gateway.md: "dropped and counted". They were logged only; an error frame with
    DLC 255 and an FD remote frame went on to the bench's bus."""
    rig = make_rig("bench1")
    export = rig.gateway.can["can0"]
    samples = [
        HEADER.pack(0x800, 0, 2, 0) + b"\x01\x02",  # an 11-bit id above 7FFh
        HEADER.pack(0x601, 0, 2, 0) + b"\x01\x02\x03\x04\x05",  # data is not its DLC
        HEADER.pack(0x601, RTR, 2, 0) + b"\x01\x02",  # a remote frame with data
        HEADER.pack(0x20000004, ERR, 255, 0),  # an error frame, DLC 255
        HEADER.pack(0x601, FD | RTR, 0, 0),  # FD has no remote frames
        HEADER.pack(0x20000004, ERR, 8, 0) + bytes(8),  # a well-formed error frame: no
    ]  # controller sends one
    with acquire("lab", "bench1", holder="alice", connect=[rig.endpoint]) as lease:
        s = open_session(make_config("peer", connect=[rig.endpoint]))
        try:
            wait_connected(s, 5, what="holder")
            tx0 = export.health.tx
            for p in samples:
                s.put("lab/bench1/can/can0", p, attachment=lease.token)
            assert _wait(lambda: export.health.bad >= len(samples)), export.health.snapshot()
            time.sleep(0.1)
            assert export.health.tx == tx0  # none reached the bench's bus
            assert export.health.refused == 0  # the holder's: bad, not refused
        finally:
            close_session(s)


def test_a_holders_bytes_still_queued_do_not_outlive_its_lease(tmp_path: Path) -> None:
    """A line with line timing holding 2 s of bytes: dropped at once, and the next write
    starts now, not behind them (the gateway calls this as a lease ends)."""
    link = tmp_path / "tty"
    far = open_serial(f"pty:{link}?baud=9600")
    near = open_serial(f"serial:{link}?baud=9600")
    try:
        near.read(1, timeout=0.05)
        far.write(b"\x55" * 2000)  # about 2 s at 9600 8N1
        time.sleep(0.1)
        far.discard_output()
        t0 = time.monotonic()
        frame = far.write(b"\xAA")
        assert frame.times_ns[0] - time.monotonic_ns() < 50_000_000  # not 2 s from now
        got = b""
        while time.monotonic() - t0 < 1.0:
            got += near.read(4096, timeout=0.1)
            if got.endswith(b"\xAA"):
                break
        assert got.endswith(b"\xAA") and len(got) < 400, len(got)
    finally:
        near.close()
        far.close()


def test_the_safe_state_is_not_confirmed_without_an_sdo_answer(make_rig) -> None:
    """With no drive on the bus, the controlword was recorded ok: "sent; no SDO answer",
    and the safe state "done, ok: true"."""
    rig = make_rig("bench1", drive=False)
    rep = rig.gateway.go_safe("test", holder="t")
    cw = next(a for a in rep["actions"] if a["action"].startswith("controlword"))
    assert cw["ok"] is False and "no SDO answer" in cw["detail"], cw
    assert rep["ok"] is False


@pytest.mark.parametrize("period", [-1.0, 0.0, float("nan")])
def test_a_bad_health_period_is_refused(make_rig, period: float) -> None:
    rig = make_rig("bench1", drive=False)
    with pytest.raises(ValueError, match="health-period"):
        Gateway(rig.gateway.bench, GatewayConfig(listen=["tcp/127.0.0.1:1"],
                                                 health_period_s=period))


def test_each_log_line_once(make_rig, caplog) -> None:
    rig = make_rig("bench1", drive=False)
    with caplog.at_level(logging.INFO):
        rig.gateway._log("warning", "one line s29")
    assert [r.getMessage() for r in caplog.records].count("one line s29") == 1


def test_a_bad_lease_request_is_not_shown_as_a_held_bench(make_rig) -> None:
    rig = make_rig("bench1", drive=False)
    with pytest.raises(LeaseRefused) as e:
        acquire("lab", "bench1", holder="tab\there", connect=[rig.endpoint])
    assert "refused the lease request: bad request" in str(e.value)
    assert "leased by" not in str(e.value)



def test_an_unanswered_quick_stop_is_still_waited_for_before_disable_voltage() -> None:
    """helper-128: once a controlword without an SDO answer was not confirmed, a quick stop
    whose answer came late skipped its ramp and disable voltage cut the power stage mid-ramp.
    Unanswered is not confirmed, but the ramp wait (6041h/606Ch) still runs."""
    from types import SimpleNamespace

    from hil.safety import Unanswered, run_safe_state
    from hil.units import S

    log: list[str] = []

    class Late:
        name = "x"

        def gone(self) -> None:
            return None

        def has_controlword(self) -> bool:
            return True

        def write_controlword(self, cw: int) -> str:
            log.append(f"cw 0x{cw:02X}")
            raise Unanswered("sent; no SDO answer within 1 s")

        def quick_stop_done(self, timeout_ns: int) -> str:
            log.append("ramp")
            return "ramp ended"

        def di_wired(self, f: str) -> bool:
            return False

        def has_sto(self) -> bool:
            return False

        def has_brkr(self) -> bool:
            return False

    spec = SimpleNamespace(controlword="quick_stop", di={}, sto={}, wait_brake=False,
                           timeout_ns=2 * S)
    rep = run_safe_state([Late()], spec, "test")
    assert log == ["cw 0x02", "ramp", "cw 0x00"]
    assert rep.ok is False  # never confirmed by an answer
    assert rep.actions[0]["detail"].startswith("not confirmed")
