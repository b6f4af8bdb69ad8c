"""The drive's CANopen communication supervision: what it alarms on, fed by the CANopen face.

The face (hil/faces/canopen_slave.py) says what arrived and when; this decides what the A3
does about it (docs/faults.md; thresholds and deviation knobs: `ModelOptions`):

* AL111 SDO Rx buffer overflow: a second SDO request within 1 ms, sent before the answer to
  the previous one left (L19933-19937);
* AL112 PDO Rx buffer overflow: two PDOs with one COB-ID within 1 ms, the second sent before
  the first was processed (L19941-19945);
* AL185 bus error: error frames raise the receive error counter past 128 (L20029);
* AL180 heartbeat consumer / life guarding timeout (L17806-L17838), and what 1029h makes of
  it (`error_behaviour`);
* in IP mode with 1006h > 0: AL3E2 early SYNC (L20159-20163), AL301 cycle off 1006h
  (L20123-20127, P3.009 E, L10629-10645), AL3E3 SYNC timeout (L20165-20169); with 1006h = 0,
  AL305 at a SYNC (L20135-20139).

Times are ns: `sent` is the sender's stamp of a frame, `now` the model time it acts.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable

from hil.model.options import ModelOptions
from hil.units import MS, US

ERROR_PASSIVE = 128  # AL185: "Rx/Tx error counter > 128" (L20029)


class CommSupervision:
    """One drive's supervision of its CANopen traffic."""

    def __init__(self, options: ModelOptions, raise_alarm: Callable[[str], None],
                 p3009: Callable[[], int]) -> None:
        self.options = options
        self._raise = raise_alarm
        # where a failing alarm path is reported (the CANopen face sets its last resort);
        # without one the exception propagates to the caller
        self.on_error: Callable[[str, Exception], None] | None = None
        self._p3009 = p3009
        self.rx_error_counter = 0  # receive error counter (AL185)
        self._bus_error_raised = False
        self._sdo_answered = 0
        self._pdo_prev: dict[int, tuple[int, int]] = {}  # RPDO COB-ID -> (sent, processed)
        self.reset()

    def _alarm(self, code: str) -> None:
        """Raise `code`; a failing alarm path is reported to `on_error` (counted and logged
        by the face), so the supervision and the rest of the face's work go on."""
        try:
            self._raise(code)
        except Exception as exc:
            if self.on_error is None:
                raise
            self.on_error(code, exc)

    def reset(self) -> None:
        """NMT reset / power-on: monitoring starts anew (the error counter is the
        controller's and survives)."""
        self._sdo_prev_sent: int | None = None
        self._pdo_prev = {}
        self.consumer_deadline: int | None = None
        self.life_deadline: int | None = None
        self.sync_reset()

    # ---------------------------------------------------------------- buffers
    def sdo_request(self, sent: int) -> None:
        """AL111: an SDO request arrived (call before serving it)."""
        prev, self._sdo_prev_sent = self._sdo_prev_sent, sent
        opts = self.options
        if prev is None or opts.dev_ignore_sdo_flood:
            return
        if sent - prev < opts.sdo_flood_window_us * US and sent < self._sdo_answered:
            self._alarm("AL111")

    def sdo_answered(self, t: int) -> None:
        """The answer left (or the request needed none) at wall time `t`: the buffer is free."""
        self._sdo_answered = t

    def rpdo(self, cob: int, sent: int) -> None:
        """AL112: an RPDO arrived (call before applying it)."""
        prev = self._pdo_prev.get(cob)
        opts = self.options
        if prev is None or opts.dev_ignore_pdo_overflow:
            return
        if 0 <= sent - prev[0] < opts.pdo_overflow_window_us * US and sent < prev[1]:
            self._alarm("AL112")

    def rpdo_processed(self, cob: int, sent: int, t: int) -> None:
        self._pdo_prev[cob] = (sent, t)

    # ---------------------------------------------------------------- bus errors
    def error_frame(self) -> None:
        """AL185: an error frame raises the receive error counter (L20029)."""
        opts = self.options
        self.rx_error_counter = min(255, self.rx_error_counter + opts.can_error_frame_weight)
        limit = opts.dev_bus_error_limit or ERROR_PASSIVE
        if self.rx_error_counter > limit and not self._bus_error_raised:
            self._bus_error_raised = True
            self._alarm("AL185")

    def valid_frame(self) -> None:
        """A valid frame lowers the counter (ISO 11898-1 fault confinement: by 1, and from
        above 127 to 127, within the standard's 119..127)."""
        c = self.rx_error_counter
        if c:
            self.rx_error_counter = 127 if c > 127 else c - 1
            limit = self.options.dev_bus_error_limit or ERROR_PASSIVE
            if self.rx_error_counter <= limit:
                self._bus_error_raised = False

    def bus_error_cleared(self) -> None:
        """AL185 was cleared (NMT reset, 6040h, L20031): the next error frame that finds the
        counter above 128 raises it again."""
        self._bus_error_raised = False

    # ---------------------------------------------------------------- error control
    def _late(self) -> int:
        return round(self.options.dev_heartbeat_extra_ms * MS)  # deviation knob

    def heartbeat(self, now: int, consumer_ms: int, bootup: bool) -> None:
        """The watched node's heartbeat: a boot-up stops monitoring until the next one."""
        self.consumer_deadline = None if bootup else now + consumer_ms * MS + self._late()

    def guarded(self, now: int, guard_ms: int, factor: int) -> None:
        """A node-guarding RTR arrived: the life time is 100Ch x 100Dh."""
        self.life_deadline = now + guard_ms * factor * MS + self._late() \
            if guard_ms and factor else None

    def error_behaviour(self, value_1029: int) -> int:
        """What 1029h sub 1 makes of a communication error (0 PRE-OP, 1 none, 2 STOPPED)."""
        dev = self.options.dev_1029h_behaviour  # deviation knob: 1029h not honoured
        return value_1029 if dev is None else dev

    def timed_out(self, now: int) -> bool:
        """AL180 when the consumer or the life time ran out; True: apply 1029h."""
        out = False
        if self.consumer_deadline is not None and now > self.consumer_deadline:
            self.consumer_deadline = None
            out = True
        if self.life_deadline is not None and now > self.life_deadline:
            self.life_deadline = None
            out = True
        if out:
            self._alarm("AL180")
        return out

    # ---------------------------------------------------------------- SYNC (IP mode)
    def sync_reset(self) -> None:
        self._sync_prev_sent: int | None = None
        self.sync_deadline: int | None = None
        self._sync_intervals: deque[int] = deque()

    def _p3009_e(self) -> int:
        """P3.009 digit E, the sync error range in 10 us (lowest digit, 1-9; L10629-10645)."""
        return min(max(self._p3009() & 0xF, 1), 9)

    def sync(self, sent: int, now: int, period_ns: int, monitored: bool) -> None:
        """A SYNC arrived; `monitored`: IP mode with 1006h = `period_ns` > 0."""
        if not monitored:
            self.sync_reset()
            return
        opts = self.options
        prev, self._sync_prev_sent = self._sync_prev_sent, sent
        late = round(opts.dev_sync_timeout_extra_ms * MS)
        self.sync_deadline = now + round(opts.sync_timeout_cycles * period_ns) + late
        if prev is None:
            return
        dt = sent - prev
        early_limit = opts.sync_early_ratio * period_ns
        fail_tol = opts.sync_fail_tolerance * period_ns
        if opts.sync_tolerance == "p3009":  # P3.009 E x 10 us (L10629-10645)
            e_ns = self._p3009_e() * 10 * US
            early_limit, fail_tol = period_ns - e_ns, e_ns
        if dt < early_limit and not opts.dev_ignore_early_sync:
            self._alarm("AL3E2")  # SYNC too early (L20159-20163)
            return
        window = max(1, int(opts.sync_fail_window))
        self._sync_intervals.append(dt)
        while len(self._sync_intervals) > window:
            self._sync_intervals.popleft()
        if len(self._sync_intervals) == window:
            mean = sum(self._sync_intervals) / window
            if abs(mean - period_ns) > fail_tol and not opts.dev_ignore_sync_cycle:
                self._alarm("AL301")  # synchronisation failure (L20123-20127)
                self._sync_intervals.clear()

    def sync_period_error(self) -> None:
        """A SYNC for IP mode while 1006h is 0: AL305 "SYNC period error", 1006h <= 0
        (L20135-20139). 0 also means "SYNC not used" (L17630), and the manual names no moment
        for the check: it is made when a SYNC arrives in IP mode (docs/manual-choices.md)."""
        self._alarm("AL305")

    def sync_timed_out(self, now: int, monitored: Callable[[], bool]) -> None:
        """AL3E3 when no SYNC came in time and `monitored()` (IP mode, asked only then); a
        resumed SYNC starts anew."""
        if self.sync_deadline is None or now <= self.sync_deadline:
            return
        self.sync_deadline = None  # re-armed by the next SYNC
        if monitored():
            self._alarm("AL3E3")  # SYNC timeout in IP mode (L20165-20169)
            self._sync_prev_sent = None
            self._sync_intervals.clear()


__all__ = ["ERROR_PASSIVE", "CommSupervision"]
