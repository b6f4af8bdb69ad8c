"""RS-485 byte streams with line timing: `open_serial(url)` -> `SerialLine`.

    serial:/dev/ttyUSB0?baud=115200&parity=E   a real port (pyserial); the wire does timing
    pty:<link-path>?baud=38400                 a pseudo-terminal: <link-path> -> far end
                                               (mbpoll, pymodbus open it); we own the near end
    zenoh:<key>?connect=...&role=master|slave  bytes over zenoh, line timing kept

Line timing. Times are `time.monotonic_ns()`; each received byte carries the time its
character *ends* on the line. A pty has no baud rate, so `PtyLine` emulates it both ways:
written bytes are released to the far end no earlier than the end of their character
(one `char_time_ns` each, back to back), and bytes from the far end are stamped as if they
had crossed a line at `baud` and are handed to `read*` only once their character has ended.
`read_frame()` returns after `silence_s` (default t3.5) of idle line, so a slave that answers
after it can never answer faster than a real line allows. zenoh carries each chunk's
per-character end times, so gaps survive the hop (see `pack_chunk`).

Taps: `tap.serial(port, data, "tx"|"rx", t, source_t, gaps_us)` per chunk written / read;
`t` = wall ns at the start of the chunk's first character, `gaps_us[i]` = idle line time in
µs between characters i and i+1 (len(data)-1 entries), `source_t` = the zenoh sender's
time of that first character (None elsewhere).
"""

from __future__ import annotations

import contextlib
import errno
import functools
import os
import select
import struct
import termios
import threading
import time
import tty
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import serial
import zenoh

from hil import clock
from hil.record.tap import Tap
from hil.transport.urls import SerialSettings, TransportUrl, TransportUrlError, parse_url
from hil.transport.zenoh_net import (
    close_session,
    config_from,
    lease_token,
    open_session,
    undeclare,
    wait_connected,
    wait_matching,
)
from hil.units import S


def t35_s(settings: SerialSettings) -> float:
    """Modbus RTU t3.5: 3.5 character times, fixed 1.75 ms above 19200 bps (Modbus over
    Serial Line V1.02 §2.5.1.1). The A3 manual asks for >10 ms (L15703)."""
    return 0.00175 if settings.baud > 19200 else 3.5 * settings.char_time_s


@dataclass(frozen=True)
class SerialFrame:
    """Bytes with the monotonic ns at which each character ends on the line."""

    data: bytes
    times_ns: tuple[int, ...]
    char_time_ns: int
    source_t: int | None = None

    @property
    def t_start_ns(self) -> int:
        return self.times_ns[0] - self.char_time_ns

    @property
    def t_end_ns(self) -> int:
        return self.times_ns[-1]

    @property
    def gaps_us(self) -> list[int]:
        """Idle time between consecutive characters, µs (len(data)-1 entries)."""
        c = self.char_time_ns
        return [max(0, (b - a - c)) // 1000 for a, b in zip(self.times_ns, self.times_ns[1:],
                                                            strict=False)]


class SerialLine:
    """A byte stream with line timing. Subclasses move the bytes (see module docstring)."""

    emulate_rx = True  # stamp received bytes as if they crossed a line at `baud`

    def __init__(self, url: str, settings: SerialSettings, *, tap: Tap | None, name: str):
        self.url = url
        self.name = name
        self.settings = settings
        self.tap = tap
        self._rx: deque[tuple[int, int, int | None]] = deque()  # byte, t_end, source_t
        self._cond = threading.Condition()
        self._rx_free = 0  # monotonic ns when the emulated rx line is idle again
        self._tx_free = 0
        self._closed = False
        self._wall_offset = time.time_ns() - self._now()

    # -- time (a SimLine runs these on the virtual clock) -------------------------------
    def _now(self) -> int:
        return time.monotonic_ns()

    def _block(self, until: int | None, now: int) -> None:
        """Wait on `_cond` (held) until `until` (monotonic ns, None: a notify)."""
        self._cond.wait(None if until is None else max(0, until - now) / S)

    # -- properties ------------------------------------------------------------------
    @property
    def baudrate(self) -> int:
        return self.settings.baud

    @property
    def char_time_s(self) -> float:
        """start + data + parity + stop bits, over the baud rate."""
        return self.settings.char_time_s

    @property
    def char_time_ns(self) -> int:
        return self.settings.char_time_ns

    @property
    def t35_s(self) -> float:
        return t35_s(self.settings)

    @property
    def closed(self) -> bool:
        return self._closed

    def wall_ns(self, mono_ns: int) -> int:
        """A monotonic ns time of this line as wall-clock ns (for the recorder)."""
        return mono_ns + self._wall_offset

    # -- writing ---------------------------------------------------------------------
    def write(self, data: bytes, *, not_before_ns: int | None = None) -> SerialFrame:
        """Queue `data` for the line; returns its schedule (character end times).

        Characters go back to back at `baud`, starting no earlier than now, the end of the
        previous write, and `not_before_ns` (monotonic), e.g. `frame.t_end_ns + t3.5`.
        """
        self._check_open()
        data = bytes(data)
        if not data:
            return SerialFrame(b"", (), self.char_time_ns)
        c = self.char_time_ns
        with self._cond:
            start = max(self._now(), self._tx_free, not_before_ns or 0)
            ends = tuple(start + (i + 1) * c for i in range(len(data)))
            self._tx_free = ends[-1]
        frame = SerialFrame(data, ends, c)
        self._transmit(data, ends)
        if self.tap is not None:
            self.tap.serial(self.name, data, "tx", self.wall_ns(start), None, frame.gaps_us)
        return frame

    def flush(self, timeout: float | None = None) -> bool:
        """Wait until every written byte has left (True) or `timeout` s passed (False)."""
        return True

    def discard_output(self) -> None:
        """Drop what was written but has not left yet (a lease ended: its holder's bytes
        must not reach the bench after it, docs/gateway.md). The next write starts now."""
        with self._cond:
            self._tx_free = 0

    # -- reading ---------------------------------------------------------------------
    def read(self, n: int = 1, timeout: float | None = None) -> bytes:
        """Up to `n` bytes, waiting at most `timeout` s (None: until `n` arrive or close)."""
        frame = self._take(n, timeout)
        return frame.data if frame else b""

    def read_timed(self, n: int = 1, timeout: float | None = None) -> SerialFrame | None:
        """Like `read` but with each byte's character end time; None if nothing came."""
        return self._take(n, timeout)

    def read_frame(self, silence_s: float | None = None,
                   timeout: float | None = None) -> SerialFrame | None:
        """The next run of bytes ended by `silence_s` of idle line (default t3.5).

        Waits up to `timeout` s for the first byte (None: forever); returns None if none.
        Returns only once the silence has elapsed on the (emulated) line.
        """
        silence = round((self.t35_s if silence_s is None else silence_s) * S)
        c = self.char_time_ns
        first_deadline = None if timeout is None else self._now() + round(timeout * S)
        out: list[tuple[int, int, int | None]] = []
        with self._cond:
            while True:
                now = self._now()
                if out:
                    last = out[-1][1]
                    if self._rx:
                        nxt = self._rx[0][1]
                        if nxt - c - last >= silence:
                            break
                        if nxt <= now:
                            out.append(self._rx.popleft())
                            continue
                        until = nxt
                    else:
                        if now >= last + silence or self._closed:
                            break
                        until = last + silence
                else:
                    if self._rx and self._rx[0][1] <= now:
                        out.append(self._rx.popleft())
                        continue
                    if self._closed or (first_deadline is not None and now >= first_deadline):
                        return None
                    candidates = [t for t in (self._rx[0][1] if self._rx else None,
                                              first_deadline) if t is not None]
                    until = min(candidates) if candidates else None
                self._block(until, now)
        return self._deliver(out)

    def reset_input_buffer(self) -> None:
        """Drop every received byte not read yet."""
        with self._cond:
            self._rx.clear()

    def _take(self, n: int, timeout: float | None) -> SerialFrame | None:
        deadline = None if timeout is None else self._now() + round(timeout * S)
        out: list[tuple[int, int, int | None]] = []
        with self._cond:
            while len(out) < n:
                now = self._now()
                if self._rx and self._rx[0][1] <= now:
                    out.append(self._rx.popleft())
                    continue
                if self._closed or (deadline is not None and now >= deadline):
                    break
                candidates = [t for t in (self._rx[0][1] if self._rx else None, deadline)
                              if t is not None]
                until = min(candidates) if candidates else None
                self._block(until, now)
        return self._deliver(out) if out else None

    def _deliver(self, out: list[tuple[int, int, int | None]]) -> SerialFrame:
        frame = SerialFrame(bytes(b for b, _, _ in out), tuple(t for _, t, _ in out),
                            self.char_time_ns, out[0][2])
        if self.tap is not None:
            self.tap.serial(self.name, frame.data, "rx", self.wall_ns(frame.t_start_ns),
                            frame.source_t, frame.gaps_us)
        return frame

    # -- for backends ----------------------------------------------------------------
    def _received(self, data: bytes, t_ns: int, *, rel_ends_ns: list[int] | None = None,
                  source_t: int | None = None, gap_ns: int = 0,
                  continues: bool = False) -> None:
        """Stamp bytes that arrived at `t_ns` (monotonic) and queue them for reading.

        Emulated: the chunk starts at max(t_ns, end of the previous character) and its
        characters end at `rel_ends_ns` (from the sender) or back to back, never closer
        than one character time; `gap_ns` is idle line time the sender left before it.
        `continues`: the sender's own times say the chunk follows the previous one `gap_ns`
        later; while bytes of that previous chunk are still unread, it starts there however
        late it arrived (a chunk held up on a loaded host does not open a silence the wire
        never had, which would split a Modbus frame). Once the reader has taken them, it
        starts no earlier than its arrival (a reader already waiting is never handed bytes
        stamped in its past).
        Real line: the last byte ended at `t_ns`.
        """
        if not data:
            return
        c = self.char_time_ns
        n = len(data)
        with self._cond:
            if self.emulate_rx:
                start = self._rx_free + gap_ns
                if not (continues and self._rx):
                    start = max(t_ns, start)
                prev = start
                for i, b in enumerate(data):
                    rel = rel_ends_ns[i] if rel_ends_ns else (i + 1) * c
                    prev = max(start + rel, prev + c)
                    self._rx.append((b, prev, source_t))
            else:
                prev = self._rx_free
                for i, b in enumerate(data):
                    prev = max(t_ns - (n - 1 - i) * c, prev + c)
                    self._rx.append((b, prev, source_t))
            self._rx_free = prev
            self._cond.notify_all()

    def _transmit(self, data: bytes, ends_ns: tuple[int, ...]) -> None:
        raise NotImplementedError

    def _close_backend(self) -> None:
        pass

    def _check_open(self) -> None:
        if self._closed:
            raise OSError(errno.EBADF, f"serial line {self.name!r} ({self.url}) is closed")

    def close(self) -> None:
        """Stop threads, release the port (idempotent)."""
        with self._cond:
            if self._closed:
                return
            self._closed = True
            self._cond.notify_all()
        self._close_backend()

    def __enter__(self) -> SerialLine:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.name} {self.url}>"


# -- pty ---------------------------------------------------------------------------------


class PtyLine(SerialLine):
    """A pseudo-terminal pair; `link` is a symlink to the far end (removed on close)."""

    def __init__(self, url: str, settings: SerialSettings, link: str | os.PathLike, *,
                 tap: Tap | None, name: str):
        super().__init__(url, settings, tap=tap, name=name)
        self.link = Path(link)
        if self.link.exists() and not self.link.is_symlink():
            raise TransportUrlError(url, f"{self.link} exists and is not a symlink; "
                                         "pty: will not replace it")
        if not self.link.parent.is_dir():
            raise TransportUrlError(url, f"directory {self.link.parent} does not exist")
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)  # far end raw, no echo; we keep it open (no EIO on master)
        self.device = os.ttyname(self._slave)
        if self.link.is_symlink():
            self.link.unlink()  # stale link from an earlier run
        os.symlink(self.device, self.link)
        self._wake_r, self._wake_w = os.pipe()
        self._tx: deque[tuple[int, int]] = deque()  # byte, release time
        self._tx_cond = threading.Condition()
        self._reader = threading.Thread(target=self._read_loop, daemon=True,
                                        name=f"pty-rx {self.link}")
        self._writer = threading.Thread(target=self._write_loop, daemon=True,
                                        name=f"pty-tx {self.link}")
        self._reader.start()
        self._writer.start()

    def _read_loop(self) -> None:
        while not self._closed:
            try:
                ready, _, _ = select.select([self._master, self._wake_r], [], [])
            except (OSError, ValueError):
                return
            if self._wake_r in ready:
                return
            t = time.monotonic_ns()
            try:
                data = os.read(self._master, 4096)
            except OSError:
                return
            self._received(data, t)

    def _transmit(self, data: bytes, ends_ns: tuple[int, ...]) -> None:
        with self._tx_cond:
            self._tx.extend(zip(data, ends_ns, strict=True))
            self._tx_cond.notify_all()

    def _write_loop(self) -> None:
        """Release each byte to the far end once its character has ended."""
        while True:
            with self._tx_cond:
                while not self._tx and not self._closed:
                    self._tx_cond.wait()
                if self._closed:
                    return
                now = time.monotonic_ns()
                due = bytearray()
                while self._tx and self._tx[0][1] <= now:
                    due.append(self._tx.popleft()[0])
                wait_ns = self._tx[0][1] - now if (self._tx and not due) else 0
                if not due:
                    self._tx_cond.wait(wait_ns / S)
                    continue
            try:
                os.write(self._master, bytes(due))
            except OSError:
                return
            with self._tx_cond:
                self._tx_cond.notify_all()

    def discard_output(self) -> None:
        with self._tx_cond:
            self._tx.clear()
            self._tx_cond.notify_all()
        super().discard_output()

    def flush(self, timeout: float | None = None) -> bool:
        deadline = None if timeout is None else time.monotonic() + timeout
        with self._tx_cond:
            while self._tx and not self._closed:
                left = None if deadline is None else deadline - time.monotonic()
                if left is not None and left <= 0:
                    return False
                self._tx_cond.wait(0.01 if left is None else min(left, 0.01))
        return True

    def _close_backend(self) -> None:
        with self._tx_cond:
            self._tx_cond.notify_all()
        with contextlib.suppress(OSError):
            os.write(self._wake_w, b"x")
        self._reader.join(2)
        self._writer.join(2)
        for fd in (self._master, self._slave, self._wake_r, self._wake_w):
            with contextlib.suppress(OSError):
                os.close(fd)
        with contextlib.suppress(OSError):
            if self.link.is_symlink() and os.readlink(self.link) == self.device:
                self.link.unlink()


# -- pyserial ----------------------------------------------------------------------------


class PySerialLine(SerialLine):
    """A real serial port through pyserial; the hardware does the line timing."""

    emulate_rx = False

    def __init__(self, url: str, settings: SerialSettings, port: str, *, tap: Tap | None,
                 name: str):
        super().__init__(url, settings, tap=tap, name=name)
        try:
            self.port = serial.Serial(
                port=port, baudrate=settings.baud, parity=settings.parity,
                bytesize=settings.bytesize, stopbits=settings.stopbits, timeout=0.05)
        except (serial.SerialException, ValueError, OSError) as e:
            raise TransportUrlError(url, f"cannot open serial port {port}: {e}") from None
        self._reader = threading.Thread(target=self._read_loop, daemon=True,
                                        name=f"serial-rx {port}")
        self._reader.start()

    def _read_loop(self) -> None:
        while not self._closed:
            try:
                data = self.port.read(max(1, self.port.in_waiting or 0))
            except (serial.SerialException, OSError, TypeError):
                if self._closed:
                    return
                time.sleep(0.01)
                continue
            if data:
                self._received(data, time.monotonic_ns())

    def _transmit(self, data: bytes, ends_ns: tuple[int, ...]) -> None:
        try:
            self.port.write(data)
        except serial.SerialException as e:
            raise OSError(errno.EIO, f"serial line {self.name!r}: write failed: {e}") from None

    def flush(self, timeout: float | None = None) -> bool:
        self.port.flush()
        return True

    def discard_output(self) -> None:
        with contextlib.suppress(serial.SerialException, OSError, termios.error):
            self.port.reset_output_buffer()  # the driver's and the UART's queue (TCOFLUSH)
        super().discard_output()

    def _close_backend(self) -> None:
        self._reader.join(1)
        with contextlib.suppress(Exception):
            self.port.close()


# -- zenoh -------------------------------------------------------------------------------

# version, sender wall ns at the first character's start, sender wall ns at publishing, n
CHUNK = struct.Struct("<BqqH")
CHUNK_VERSION = 1
MAX_GAP_NS = S  # longer sender pauses are not reproduced (clock steps, idle lines)


def pack_chunk(data: bytes, t0_wall_ns: int, rel_ends_ns: list[int] | tuple[int, ...],
               pub_wall_ns: int | None = None) -> bytes:
    """zenoh serial payload: header, data, then u32 ns end time of each character after
    the start of the first one (so gaps and baud survive the hop). `t0_wall_ns` may lie
    after `pub_wall_ns` (bytes scheduled ahead); the receiver keeps that lead."""
    rel = [min(max(0, r), 0xFFFFFFFF) for r in rel_ends_ns]
    pub = time.time_ns() if pub_wall_ns is None else pub_wall_ns
    return CHUNK.pack(CHUNK_VERSION, t0_wall_ns, pub, len(data)) + data + struct.pack(
        f"<{len(rel)}I", *rel)


def unpack_chunk(payload: bytes) -> tuple[bytes, int, int, list[int]]:
    """-> data, t0_wall_ns, pub_wall_ns, rel_ends_ns."""
    version, t0, pub, n = CHUNK.unpack_from(payload)
    if version != CHUNK_VERSION or len(payload) != CHUNK.size + 5 * n:
        raise ValueError(f"zenoh serial chunk: bad version {version} or length {len(payload)}")
    data = payload[CHUNK.size:CHUNK.size + n]
    rel = list(struct.unpack_from(f"<{n}I", payload, CHUNK.size + n))
    return data, t0, pub, rel


class ZenohLine(SerialLine):
    """Serial bytes over zenoh. role=master publishes `<key>/m2s` and reads `<key>/s2m`;
    role=slave the reverse (master = the Modbus master / harness side)."""

    def __init__(self, url: str, settings: SerialSettings, u: TransportUrl, *,
                 tap: Tap | None, name: str, connect_timeout: float = 5.0,
                 match_timeout: float = 0.5, allow_remote: bool = False):
        super().__init__(url, settings, tap=tap, name=name)
        self.role = u.params.get("role", "master")
        self._prev_end_wall: int | None = None  # sender's end of its previous chunk
        out, inp = ("m2s", "s2m") if self.role == "master" else ("s2m", "m2s")
        self._out_key = f"{u.target}/{out}"
        ep = u.zenoh()
        try:
            config = config_from(ep, allow_remote=allow_remote)
        except ValueError as e:
            raise TransportUrlError(url, str(e)) from None
        try:
            self.session = open_session(config, what=f"zenoh serial {u.target!r}")
        except ConnectionError as e:
            raise TransportUrlError(url, str(e)) from None
        self._pub = self._sub = None
        try:
            if ep.connect:
                wait_connected(self.session, connect_timeout, what=url, endpoints=ep.connect)
            self._pub = self.session.declare_publisher(
                f"{u.target}/{out}", express=True,
                congestion_control=zenoh.CongestionControl.BLOCK,
                allowed_destination=zenoh.Locality.REMOTE)
            self._sub = self.session.declare_subscriber(
                f"{u.target}/{inp}", self._on_sample, allowed_origin=zenoh.Locality.REMOTE)
            if ep.connect and match_timeout > 0:
                wait_matching(self._pub, match_timeout)
        except (ConnectionError, zenoh.ZError) as e:
            self._close_backend()
            raise TransportUrlError(url, str(e)) from None

    def _on_sample(self, sample: zenoh.Sample) -> None:
        t = time.monotonic_ns()
        try:
            data, t0, pub, rel = unpack_chunk(sample.payload.to_bytes())
        except (ValueError, struct.error):
            return
        gap = None if self._prev_end_wall is None else t0 - self._prev_end_wall
        self._prev_end_wall = t0 + (rel[-1] if rel else 0)
        if gap is not None and 0 <= gap <= MAX_GAP_NS:  # follows the previous chunk: keep gap
            self._received(data, t, rel_ends_ns=rel, source_t=t0, gap_ns=gap, continues=True)
        else:  # after idle: keep how far ahead the sender scheduled it
            lead = min(max(0, t0 - pub), MAX_GAP_NS)
            self._received(data, t + lead, rel_ends_ns=rel, source_t=t0)

    def _transmit(self, data: bytes, ends_ns: tuple[int, ...]) -> None:
        start = ends_ns[0] - self.char_time_ns
        payload = pack_chunk(data, self.wall_ns(start), [e - start for e in ends_ns])
        if self._pub is None:
            raise OSError(errno.EBADF, f"serial line {self.name!r} is closed")
        self._pub.put(payload, attachment=lease_token(self._out_key))

    def _close_backend(self) -> None:
        undeclare(self._sub, self._pub)
        self._sub = self._pub = None
        close_session(self.session)


# -- virtual time ------------------------------------------------------------------------

class SimLine(SerialLine):
    """One end of an in-process RS-485 line on the virtual clock (`pty:` / `serial:` under a
    virtual clock: the drive opens `pty:<path>`, the harness `serial:<path>`)."""

    def __init__(self, url: str, settings: SerialSettings, u: TransportUrl, *,
                 tap: Any, name: str) -> None:
        clk = clock.current()
        if not isinstance(clk, clock.VirtualClock):
            raise TransportUrlError(url, "a virtual-time line needs a virtual clock")
        self.clock = clk
        super().__init__(url, settings, tap=tap, name=name)
        self._wall_offset = 0  # the virtual clock is the recording's clock
        key = f"rs485:{u.target}"
        ends = clk.media.setdefault(key, [])
        if len(ends) >= 2:
            raise TransportUrlError(url, "this virtual-time line already has both ends open")
        self._ends: list[SimLine] = ends
        ends.append(self)
        self.on_rx: Callable[[], None] | None = None
        self._count = 0  # chunks received (a wait ends when it changes)

    def _now(self) -> int:
        return self.clock.time_ns()

    def _block(self, until: int | None, now: int) -> None:
        n0 = self._count
        end = until if until is not None else now + 3600 * S
        # the line's lock is released while the clock runs, as a condition's wait releases
        # it: another thread's close (a watchdog's) or write is not held up for the whole wait
        saved = self._cond._release_save()  # type: ignore[attr-defined]
        try:
            self.clock.run_until(end, lambda: self._count != n0 or self._closed)
        finally:
            self._cond._acquire_restore(saved)  # type: ignore[attr-defined]

    def _peer(self) -> SimLine | None:
        return next((e for e in self._ends if e is not self and not e._closed), None)

    def _transmit(self, data: bytes, ends_ns: tuple[int, ...]) -> None:
        # the far UART hands each character over at its own end: a chunk handed over whole
        # at its last character let the far end's t3.5 pass inside a frame written in two
        # back-to-back chunks (1 + 7 bytes at 38400 baud), which the drive then dropped
        c = self.char_time_ns
        for i, end in enumerate(ends_ns):
            self.clock.at(end, functools.partial(self._hand_over, data[i:i + 1], end - c))

    def _hand_over(self, char: bytes, start: int) -> None:
        peer = self._peer()
        if peer is not None:
            peer._arrive(char, start, [self.char_time_ns])

    def _arrive(self, data: bytes, start: int, rel: list[int]) -> None:
        self._received(data, start, rel_ends_ns=rel)
        self._count += 1
        if self.on_rx is not None:
            self.on_rx()

    def flush(self, timeout: float | None = None) -> bool:
        return self.clock.wait_for(lambda: self._tx_free <= self.clock.time_ns(), timeout)

    def _close_backend(self) -> None:
        if self in self._ends:
            self._ends.remove(self)


def open_serial(url: str, *, tap: Tap | None = None, name: str | None = None,
                **options) -> SerialLine:
    """Open an RS-485 line from its URL. `name` names the port in recordings (default:
    the URL target). `options` go to the backend (zenoh: connect_timeout, match_timeout,
    allow_remote)."""
    u = parse_url(url, "serial")
    settings = u.serial()
    label = name or u.target
    if clock.is_virtual() and u.scheme in ("pty", "serial"):  # the virtual bench's line
        return SimLine(url, settings, u, tap=tap, name=label)
    if u.scheme == "pty":
        return PtyLine(url, settings, u.target, tap=tap, name=label)
    if u.scheme == "serial":
        return PySerialLine(url, settings, u.target, tap=tap, name=label)
    return ZenohLine(url, settings, u, tap=tap, name=label, **options)
