"""SCHED_FIFO for the real-time path's threads (hil.realtime), opt-in by HIL_RT_PRIORITY."""

from __future__ import annotations

import logging
import threading

import hil.transport.cyclic as cyclic
from hil import realtime


def test_set_fifo_asks_the_kernel_for_this_thread_or_says_why_not(monkeypatch, caplog):
    calls: list[tuple[int, int, int]] = []

    def grant(tid, policy, param):
        calls.append((tid, policy, param.sched_priority))

    monkeypatch.setattr(realtime.os, "sched_setscheduler", grant)
    assert realtime.set_fifo(None, "x") is False and calls == []
    assert realtime.set_fifo(12, "ticker") is True
    assert calls == [(threading.get_native_id(), realtime.os.SCHED_FIFO, 12)]

    def refuse(*_a):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(realtime.os, "sched_setscheduler", refuse)
    with caplog.at_level(logging.WARNING, logger="hil.realtime"):
        assert realtime.set_fifo(12, "ticker") is False
    assert "SCHED_FIFO priority 12 refused" in caplog.text and "ticker" in caplog.text


def test_a_cyclic_producers_thread_asks_for_hil_rt_priority(monkeypatch):
    asked: list[tuple[int | None, str, int]] = []
    done = threading.Event()

    def record(prio, who):
        asked.append((prio, who, threading.get_ident()))
        return False

    monkeypatch.setattr(cyclic, "set_fifo", record)
    monkeypatch.setenv("HIL_RT_PRIORITY", "20")
    c = cyclic.Cyclic(lambda: done.set() or False, 0.001, name="sync-producer")
    try:
        assert done.wait(5)
    finally:
        c.stop()
    assert len(asked) == 1
    prio, who, ident = asked[0]
    assert prio == 20 and who == "sync-producer" and ident != threading.get_ident()
