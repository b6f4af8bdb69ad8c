"""The drive's CANopen supervision on its own, without a face or a bus (comm_supervision.py).

Each rule from the manual's alarm table; the face's end-to-end tests are
tests/faces/test_comm_faults.py.
"""

from __future__ import annotations

from hil.model.comm_supervision import CommSupervision
from hil.model.options import ModelOptions
from hil.units import MS, US


def make(**opts) -> tuple[CommSupervision, list[str]]:
    raised: list[str] = []
    return CommSupervision(ModelOptions(**opts), raised.append, lambda: 0x5055), raised


def test_al185_past_128_and_valid_frames_count_down() -> None:
    """L20029: "Rx/Tx error counter > 128": 16 error frames of 8 make 128, not enough."""
    sup, raised = make()
    for _ in range(16):
        sup.error_frame()
    assert sup.rx_error_counter == 128 and raised == []
    sup.valid_frame()
    sup.error_frame()  # 127 + 8 = 135
    assert raised == ["AL185"]
    sup.error_frame()
    assert raised == ["AL185"]  # once, until the counter is back at 0


def test_al111_a_second_sdo_request_before_the_answer_within_1ms() -> None:
    """L19933-19937: the one-deep SDO Rx buffer overflows."""
    sup, raised = make()
    sup.sdo_request(0)
    sup.sdo_answered(800 * US)  # the answer left at 0.8 ms
    sup.sdo_request(900 * US)  # sent after it: the buffer was free
    assert raised == []
    sup.sdo_answered(1200 * US)
    sup.sdo_request(1100 * US)  # sent 0.2 ms after the last, before its answer left
    assert raised == ["AL111"]
    sup.sdo_answered(5 * MS)
    sup.sdo_request(3 * MS)  # before the answer, but more than 1 ms after the last request
    assert raised == ["AL111"]


def test_al112_the_same_rpdo_again_before_it_was_processed() -> None:
    """L19941-19945: two PDOs with one COB-ID within 1 ms, the first not yet processed."""
    sup, raised = make()
    sup.rpdo(0x205, 0)
    sup.rpdo_processed(0x205, 0, 800 * US)
    sup.rpdo(0x205, 900 * US)  # processed before this was sent
    sup.rpdo_processed(0x205, 900 * US, 1900 * US)
    assert raised == []
    sup.rpdo(0x205, 1500 * US)  # sent while the previous one was still in the buffer
    assert raised == ["AL112"]


def test_al180_heartbeat_consumer_and_1029h() -> None:
    """L17806-L17838: the consumer time runs out; 1029h sub 1 decides the NMT state."""
    sup, raised = make()
    sup.heartbeat(0, 100, bootup=False)
    assert not sup.timed_out(100 * MS)
    assert sup.timed_out(100 * MS + 1) and raised == ["AL180"]
    assert not sup.timed_out(300 * MS)  # once per loss
    sup.heartbeat(400 * MS, 100, bootup=True)  # a boot-up: no monitoring until the next one
    assert not sup.timed_out(900 * MS)
    assert sup.error_behaviour(2) == 2
    dev, _ = make(dev_1029h_behaviour=1)
    assert dev.error_behaviour(0) == 1  # a drive that ignores 1029h (deviation knob)


def test_sync_rules_in_ip_mode() -> None:
    """AL3E2 early SYNC (L20159-20163), AL3E3 none for 3 cycles (L20165-20169); outside IP
    mode (not monitored) nothing is judged."""
    sup, raised = make()
    period = 2 * MS
    sup.sync(0, 0, period, monitored=True)
    sup.sync(period, period, period, monitored=True)
    sup.sync(period + 500 * US, period + 500 * US, period, monitored=True)  # 0.5 ms: early
    assert raised == ["AL3E2"]
    sup.sync_timed_out(period + 500 * US + 3 * period, monitored=lambda: True)
    assert raised == ["AL3E2"]
    sup.sync_timed_out(period + 500 * US + 3 * period + 1, monitored=lambda: True)
    assert raised == ["AL3E2", "AL3E3"]
    idle, quiet = make()
    for k in range(5):
        idle.sync(k * 100 * US, k * 100 * US, period, monitored=False)
    idle.sync_timed_out(10 * period, monitored=lambda: False)
    assert quiet == []


def test_a_failing_alarm_path_is_reported_and_the_supervision_goes_on() -> None:
    def broken(code: str) -> None:
        raise RuntimeError(f"cannot raise {code}")

    sup = CommSupervision(ModelOptions(), broken, lambda: 0x5055)
    sup.heartbeat(0, 100, bootup=False)
    try:
        sup.timed_out(101 * MS)
    except RuntimeError:
        pass
    else:
        raise AssertionError("without an error sink the failure must propagate")
    seen: list[tuple[str, str]] = []
    sup.on_error = lambda code, exc: seen.append((code, str(exc)))
    for _ in range(17):
        sup.error_frame()
    assert seen == [("AL185", "cannot raise AL185")]
    assert sup.rx_error_counter == 136  # counting went on
