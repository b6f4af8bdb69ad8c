"""Host side of the ASDA-A3 absolute-position DI/DO handshake (§10.3.5.1, L16460-16521).

The reader works on *electrical levels* of named lines (docs/transports.md: `1` = input contact
closed / output transistor conducting). With the drive's default a-contact mapping of ABSE (0x1D)
and ABSW (0x0D), and the fixed ABSQ = DI4, ABSR = DO2, ABSD = DO3, "function on" = level True.
For a b-contact mapping pass the `*_active` level arguments.

Frame (L16464-16486): status(15-0) | turns or 0(31-16) | position(63-32) | checksum(79-64).
Host sequence: ABSQ high (idle), ABSE on, wait T_S max, then 80 times
{ABSQ low -> wait ABSR high -> sample ABSD -> ABSQ high -> wait ABSR low}; ABSW (or no ABSR
answer) -> ABSE off, wait T_B, restart (L16513-16517). After 80 bits the host drops ABSE.

The reader takes any line set with `set`/`get`/`wait_for` and a clock; a model on an injected
clock plugs in through `hil.virtual.model_lines.ModelLines`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

from hil import clock
from hil.units import MS

FRAME_BITS = 80
_CS_K = (0xA700, 0x605A, 0x30A5, 0x5A06)


class DioLines(Protocol):
    """A set of named DI/DO lines (electrical levels); hil.transport.dio.DioPort fits."""

    def set(self, line: str, level: bool) -> None: ...
    def get(self, line: str) -> bool: ...
    def wait_for(self, line: str, level: bool, timeout_s: float) -> int | None:
        """Block until `line` has `level`; return the time (ns) it was seen. On timeout
        return None or raise TimeoutError (both accepted)."""
        ...


class Clock(Protocol):
    def now_ns(self) -> int: ...
    def sleep(self, seconds: float) -> None: ...


class SystemClock:
    """Clock for a real bench: time.time_ns, the clock DioPort.wait_for stamps changes with."""

    def now_ns(self) -> int:
        return clock.time_ns()

    def sleep(self, seconds: float) -> None:
        clock.sleep(seconds)


class AbsReadError(Exception):
    """The absolute position could not be read (names the step and the rule)."""


class AbsChecksumError(AbsReadError):
    def __init__(self, expected: int, received: int, frame: int) -> None:
        super().__init__(
            f"absolute frame checksum mismatch: expected 0x{expected:04X} (computed from bits"
            f" 0-63 by the L16476-16486 formula), received 0x{received:04X} in bits 64-79"
            f" (frame 0x{frame:020X})"
        )
        self.expected = expected
        self.received = received
        self.frame = frame


class AbsTimingError(AbsReadError):
    def __init__(self, violations: list[str]) -> None:
        super().__init__(
            "absolute handshake timing out of the manual's window: " + "; ".join(violations)
        )
        self.violations = violations


def checksum(w0: int, w1: int, w2: int, w3: int) -> int:
    """((((((W0 + 0xA700) ^ W1) + 0x605A) ^ W2) + 0x30A5) ^ W3) + 0x5A06, 16-bit (L16476)."""
    cs = (w0 + _CS_K[0]) & 0xFFFF
    cs = ((cs ^ w1) + _CS_K[1]) & 0xFFFF
    cs = ((cs ^ w2) + _CS_K[2]) & 0xFFFF
    return ((cs ^ w3) + _CS_K[3]) & 0xFFFF


def _signed(value: int, width: int) -> int:
    return value - (1 << width) if value & (1 << (width - 1)) else value


@dataclass(frozen=True)
class BitTiming:
    """One bit's handshake, host clock ns: request (ABSQ low), ready (ABSR high seen),
    ack (ABSQ high), release (ABSR low seen)."""

    index: int
    value: int
    t_request: int
    t_ready: int
    t_ack: int
    t_release: int

    @property
    def t_q_ns(self) -> int:  # drive: request -> data ready
        return self.t_ready - self.t_request

    @property
    def host_ns(self) -> int:  # host: ABSR on -> ABSQ on, must be <= T_R (L19789)
        return self.t_ack - self.t_ready

    @property
    def t_n_ns(self) -> int:  # drive: ack -> ABSR off
        return self.t_release - self.t_ack


@dataclass(frozen=True)
class AbsReading:
    """A verified frame. position = PUU (turns 0) or single-turn pulses, per P2.070 bit0."""

    status: int
    turns: int
    position: int
    checksum: int
    frame: int
    bits: tuple[int, ...]
    timings: tuple[BitTiming, ...]
    attempts: int
    t_abse: int  # ABSE on of the successful attempt (ns)
    violations: tuple[str, ...] = field(default=())
    errors: tuple[str, ...] = field(default=())  # why earlier attempts were retried

    @property
    def lost(self) -> bool:
        return bool(self.status & 0x01)

    @property
    def battery_low(self) -> bool:
        return bool(self.status & 0x02)

    @property
    def overflow(self) -> bool:
        return bool(self.status & 0x0C)

    @property
    def not_established(self) -> bool:
        return bool(self.status & 0x10)


class _Retry(Exception):
    pass


class AbsPositionReader:
    """Reads the 80-bit absolute frame over DI/DO with retries after ABSW (L16460-16521)."""

    def __init__(
        self,
        lines: DioLines,
        *,
        abse: str = "DI9",
        absq: str = "DI4",
        absr: str = "DO2",
        absd: str = "DO3",
        absw: str | None = None,
        p2009_ms: float = 2.0,
        t_r_ms: float = 200.0,
        t_b_ms: float | None = None,
        io_slack_ms: float = 20.0,
        tolerance_ms: float = 1.0,
        absc: str | None = None,
        absc_active: bool = True,
        retries: int = 2,
        bit_order: str = "lsb_first",
        abse_active: bool = True,
        absq_active: bool = True,
        absr_active: bool = True,
        absd_one: bool = True,
        absw_active: bool = True,
        strict_timing: bool = False,
        clock: Clock | None = None,
    ) -> None:
        if bit_order not in ("lsb_first", "msb_first"):
            raise ValueError(f"bit_order: 'lsb_first' or 'msb_first', got {bit_order!r}")
        if not 0 <= p2009_ms <= 20:
            raise ValueError(f"p2009_ms: P2.009 is 0 ~ 20 ms (L9229), got {p2009_ms}")
        if retries < 0:
            raise ValueError(f"retries must be >= 0, got {retries}")
        self.lines = lines
        self.abse, self.absq, self.absr, self.absd, self.absw = abse, absq, absr, absd, absw
        self.p2009_ms = p2009_ms
        self.t_max_ms = p2009_ms + 10  # T_S/T_Q/T_N/T_B max (L16495-16499)
        self.t_min_ms = p2009_ms + 2
        self.t_r_ms = t_r_ms
        self.t_b_ms = self.t_max_ms if t_b_ms is None else t_b_ms
        self.io_slack_ms = io_slack_ms
        self.tolerance_ms = tolerance_ms
        self.absc, self.absc_active = absc, absc_active
        self.retries = retries
        self.bit_order = bit_order
        self.abse_active, self.absq_active, self.absr_active = abse_active, absq_active, absr_active
        self.absd_one, self.absw_active = absd_one, absw_active
        self.strict_timing = strict_timing
        self.clock = clock or SystemClock()

    # -- public ----------------------------------------------------------------------------

    def read(self) -> AbsReading:
        """Full read with retries; raises AbsChecksumError / AbsTimingError / AbsReadError."""
        errors: list[str] = []
        for attempt in range(1, self.retries + 2):
            try:
                return self._attempt(attempt, tuple(errors))
            except _Retry as exc:
                errors.append(f"attempt {attempt}: {exc}")
                self._recover()
        raise AbsReadError(
            f"absolute DI/DO read failed after {self.retries + 1} attempts: " + "; ".join(errors)
        )

    def set_origin(self, hold_ms: float | None = None) -> int:
        """Origin by DI/DO (L16436-16450): ABSE on, wait T_S, ABSC on held T_Q, both off.

        Holds ABSC P2.009 + 250 ms by default (the table's max, the latest the drive may
        need). Returns the time ABSC went on (ns).
        """
        if self.absc is None:
            raise ValueError("set_origin needs the ABSC line (absc='DI?')")
        hold = self.p2009_ms + 250 if hold_ms is None else hold_ms
        self._set(self.absq, True, self.absq_active)  # keep ABSQ idle: no read request
        self._set(self.abse, True, self.abse_active)
        self.clock.sleep(self.t_max_ms / 1000.0)  # T_S max
        self._set(self.absc, True, self.absc_active)
        t_absc = self.clock.now_ns()
        self.clock.sleep(hold / 1000.0)
        self._set(self.absc, False, self.absc_active)
        self._set(self.abse, False, self.abse_active)
        self.clock.sleep(self.t_b_ms / 1000.0)
        return t_absc

    # -- steps -----------------------------------------------------------------------------

    def _set(self, line: str, function_on: bool, active_level: bool) -> None:
        self.lines.set(line, function_on == active_level)

    def _wait(self, line: str, function_on: bool, active_level: bool, timeout_ms: float) -> int:
        level = function_on == active_level
        try:
            t = self.lines.wait_for(line, level, timeout_ms / 1000.0)
        except TimeoutError:
            t = None
        if t is None:
            raise TimeoutError(line)
        return int(t)

    def _absw_on(self) -> bool:
        return self.absw is not None and self.lines.get(self.absw) == self.absw_active

    def _recover(self) -> None:
        """ABSE off; the drive drops ABSW (L16514-16515); wait T_B before again (L16516)."""
        self._set(self.abse, False, self.abse_active)
        if self.absw is not None:
            try:
                self._wait(self.absw, False, self.absw_active, self.t_max_ms + self.io_slack_ms)
            except TimeoutError:
                pass  # another warning keeps ABSW on (L16521); the next attempt will say so
        self.clock.sleep(self.t_b_ms / 1000.0)

    def _attempt(self, attempt: int, errors: tuple[str, ...]) -> AbsReading:
        slack = self.io_slack_ms
        self._set(self.absq, True, self.absq_active)  # idle high: "low" is the request (L16505)
        self._set(self.abse, True, self.abse_active)
        t_abse = self.clock.now_ns()
        self.clock.sleep(self.t_max_ms / 1000.0)  # T_S max: pins switched (L16504)
        if self._absw_on():
            raise _Retry("ABSW on after T_S: a warning blocks the handshake (L16521)")
        bits: list[int] = []
        timings: list[BitTiming] = []
        for i in range(FRAME_BITS):
            self._set(self.absq, False, self.absq_active)
            t_req = self.clock.now_ns()
            try:
                t_ready = self._wait(self.absr, True, self.absr_active, self.t_max_ms + slack)
            except TimeoutError:
                why = "ABSW on" if self._absw_on() else "no ABSR rise within T_Q max (L16506)"
                raise _Retry(f"bit {i}: {why}")
            bit = int(self.lines.get(self.absd) == self.absd_one)
            self._set(self.absq, True, self.absq_active)
            t_ack = self.clock.now_ns()
            try:
                t_rel = self._wait(self.absr, False, self.absr_active, self.t_max_ms + slack)
            except TimeoutError:
                raise _Retry(f"bit {i}: ABSR stayed on after ABSQ on (T_N max, L16508)")
            if self._absw_on():
                late = (t_ack - t_ready) / MS
                raise _Retry(
                    f"bit {i}: ABSW on (host answered after {late:.1f} ms, T_R"
                    f" {self.t_r_ms:g} ms, L16513)"
                )
            bits.append(bit)
            timings.append(BitTiming(i, bit, t_req, t_ready, t_ack, t_rel))
        self._set(self.abse, False, self.abse_active)  # choice: drop ABSE after a good frame
        order = bits if self.bit_order == "lsb_first" else bits[::-1]
        frame = sum(b << n for n, b in enumerate(order))
        w = [(frame >> (16 * k)) & 0xFFFF for k in range(5)]
        expected = checksum(w[0], w[1], w[2], w[3])
        if expected != w[4]:
            raise AbsChecksumError(expected, w[4], frame)
        violations = self._check_timing(timings)
        if violations and self.strict_timing:
            raise AbsTimingError(violations)
        return AbsReading(
            status=w[0],
            turns=_signed(w[1], 16),
            position=_signed(w[2] | (w[3] << 16), 32),
            checksum=w[4],
            frame=frame,
            bits=tuple(bits),
            timings=tuple(timings),
            attempts=attempt,
            t_abse=t_abse,
            violations=tuple(violations),
            errors=errors,
        )

    def _check_timing(self, timings: list[BitTiming]) -> list[str]:
        """Drive-side windows (L16495-16499) and T_R enforcement (L19789)."""
        out: list[str] = []
        hi = (self.t_max_ms + self.tolerance_ms) * MS
        for t in timings:
            if t.t_q_ns > hi:
                out.append(f"bit {t.index}: T_Q {t.t_q_ns / MS:.3f} ms > max {self.t_max_ms:g} ms")
            if t.t_n_ns > hi:
                out.append(f"bit {t.index}: T_N {t.t_n_ns / MS:.3f} ms > max {self.t_max_ms:g} ms")
            if t.host_ns > (self.t_r_ms + self.tolerance_ms) * MS:
                out.append(
                    f"bit {t.index}: host answered {t.host_ns / MS:.3f} ms after ABSR on, over"
                    f" T_R {self.t_r_ms:g} ms, and the drive did not raise ABSW (L16513)"
                )
        return out
