"""`SCHED_FIFO` for the real-time path's own threads, opt-in (docs/clock.md, "The real-time path").

`HIL_RT_PRIORITY=N` (1-99) asks for `SCHED_FIFO` at priority N for the threads that keep
time on the wall clock: the drive host's ticker (hil.virtual.host) and the cyclic producers
(hil.transport.cyclic: SYNC, the axis group's cycle, heartbeat, node guarding). At the
normal priority another process can hold a thread off its core for milliseconds: one axis at
a 2 ms SYNC then had its SYNC leave more than a millisecond late a few times a minute
(docs/performance.md, session 11). Neither thread spins, so a real-time priority never holds
a core. Where the host refuses (no CAP_SYS_NICE, no RLIMIT_RTPRIO), the thread runs at the
normal priority and the log says so.
"""

from __future__ import annotations

import logging
import os
import threading

log = logging.getLogger(__name__)


def env_priority() -> int | None:
    """`HIL_RT_PRIORITY` as a priority 1-99, or None (unset or invalid, with a warning)."""
    raw = os.environ.get("HIL_RT_PRIORITY", "").strip()
    if not raw:
        return None
    try:
        prio = int(raw)
    except ValueError:
        log.warning("HIL_RT_PRIORITY=%r is not an integer 1-99: ignored", raw)
        return None
    if not 1 <= prio <= 99:
        log.warning("HIL_RT_PRIORITY=%d is outside 1-99: ignored", prio)
        return None
    return prio


def set_fifo(prio: int | None, who: str) -> bool:
    """Put the calling thread at `SCHED_FIFO` priority `prio` (None: leave it). True if the
    host granted it; a refusal is logged and the thread keeps the normal priority."""
    if not prio:
        return False
    try:
        os.sched_setscheduler(threading.get_native_id(), os.SCHED_FIFO, os.sched_param(prio))
    except (OSError, AttributeError, ValueError) as exc:
        log.warning("%s: SCHED_FIFO priority %d refused (%s): running at the normal "
                    "priority", who, prio, exc)
        return False
    log.info("%s: thread at SCHED_FIFO priority %d", who, prio)
    return True
