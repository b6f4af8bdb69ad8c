"""DI/DO/STO lines: `open_dio(url, role=...)` -> `DioPort`.

Lines carry *electrical* levels (docs/transports.md): inputs `DI<n>`, `STO_A`, `STO_B` (True =
contact closed / 24 V present), outputs `DO<n>`, `FDBK` (True = transistor conducting / closed).
Two roles share the classes:

- role="harness": `set()` inputs, `subscribe()` / `wait_for()` outputs;
- role="drive":   `set()` outputs, `subscribe()` / `wait_for()` inputs.

Backends:
- `virtual:<name>`: in-process board shared by every port of that name (thread-safe).
- `zenoh:<key>?...`: `<key>/<line>` with payload b"1" / b"0" (the source's wall ns as an
  8-byte little-endian attachment, then a gateway lease token where one is held); a side
  publishes its lines on every change, and a queryable on `<key>/**` answers each of its
  lines' current level (`query_levels()`).
- `modbus-tcp://host:port?unit=1&poll_ms=5`: a remote I/O module (harness only); `mapping`
  gives each line its coil (inputs of the drive) or discrete input (outputs of the drive):
  `{"DI1": 0, "STO_A": "coil:8", "DO1": "di:0"}` (a bare int takes the line's natural kind).

Taps: `tap.dio(name, line, level, t, source_t)` for every level set or seen changing.
"""

from __future__ import annotations

import contextlib
import re
import struct
import threading
import time
from collections.abc import Callable, Mapping
from typing import Literal

import zenoh
from pymodbus.client import ModbusTcpClient

from hil import clock
from hil.record.tap import Tap
from hil.transport.urls import TransportUrl, TransportUrlError, parse_url
from hil.transport.zenoh_net import (
    ASK_TIMEOUT_S,
    AskAgain,
    close_session,
    config_from,
    lease_token,
    open_session,
    undeclare,
    wait_connected,
)

Role = Literal["harness", "drive"]
ROLES = ("harness", "drive")
Listener = Callable[[str, bool, int], None]

_INPUT = re.compile(r"^(DI[1-9][0-9]*|STO_A|STO_B)\Z")
_OUTPUT = re.compile(r"^(DO[1-9][0-9]*|FDBK)\Z")
_T = struct.Struct("<q")


def is_input(line: str) -> bool:
    """True for a drive input (DI<n>, STO_A, STO_B), False for an output (DO<n>, FDBK)."""
    if _INPUT.match(line):
        return True
    if _OUTPUT.match(line):
        return False
    raise ValueError(f"DI/DO line {line!r}: must be DI<n>, STO_A, STO_B (inputs) or "
                     "DO<n>, FDBK (outputs)")


class DioPort:
    """One side of a set of DI/DO lines (see module docstring)."""

    def __init__(self, url: str, role: Role, *, tap: Tap | None, name: str):
        if role not in ROLES:
            raise ValueError(f"DI/DO role {role!r}: must be 'harness' or 'drive'")
        self.url = url
        self.role = role
        self.name = name
        self.tap = tap
        self._levels: dict[str, tuple[bool, int]] = {}  # line -> (level, t_ns of change)
        self._listeners: list[tuple[Callable[..., None], bool]] = []
        # the run's thread waits on the virtual clock with the lock released (another
        # thread's `get` is not held up), any other thread in wall time (docs/clock.md)
        self._cond = clock.ClockCondition()
        self._closed = False

    def owns(self, line: str) -> bool:
        """Whether this side drives `line` (harness: inputs; drive: outputs)."""
        return is_input(line) == (self.role == "harness")

    def set(self, line: str, level: bool, source_t: int | None = None) -> None:
        """Drive one of our lines; published if it changed (or was never set).

        `source_t` is when the source itself changed the level (wall ns; e.g. the model's
        event time on a virtual drive); it travels with the level as its publish time."""
        self._check_open()
        if not self.owns(line):
            other = "harness" if self.role == "drive" else "drive"
            raise ValueError(f"DI/DO {self.name}: line {line} is driven by the {other} side, "
                             f"not by role {self.role!r}")
        level = bool(level)
        t = clock.time_ns()
        with self._cond:
            old = self._levels.get(line)
            if old is not None and old[0] == level:
                return
            self._levels[line] = (level, t)
            self._cond.notify_all()
        self._publish(line, level, t if source_t is None else source_t)
        if self.tap is not None:
            self.tap.dio(self.name, line, level, t, source_t)

    def get(self, line: str) -> bool:
        """Last known level of any line (False = open / not conducting if never seen).
        Raises ValueError on a closed port: its levels are no longer known."""
        is_input(line)
        self._check_open()
        with self._cond:
            entry = self._levels.get(line)
        if entry is None and not self.owns(line):
            self._ask_levels()
        return entry[0] if entry else False

    def _ask_levels(self) -> None:
        """Ask the other side again, in the background, for the levels of lines never heard
        of (a backend that can): a level set before this side was there to hear it is not
        published again while the line does not change. Never blocks the caller."""

    def levels(self) -> dict[str, bool]:
        """Every line seen or set so far, with its level."""
        with self._cond:
            return {line: lv for line, (lv, _) in sorted(self._levels.items())}

    def subscribe(self, fn: Listener, *, source: bool = False) -> Callable[[], None]:
        """Call fn(line, level, t_ns) on every change of the other side's lines (with
        `source`, fn(line, level, t_ns, source_t): the other side's own stamp of the change,
        None when it sent none). Returns a function that unsubscribes."""
        entry = (fn, source)
        with self._cond:
            self._listeners.append(entry)

        def unsubscribe() -> None:
            with self._cond, contextlib.suppress(ValueError):
                self._listeners.remove(entry)

        return unsubscribe

    def wait_for(self, line: str, level: bool, timeout_s: float) -> int:
        """Wait until `line` is at `level`; returns the wall ns of the change to it.

        Raises TimeoutError naming the line, the expected and the last seen level."""
        is_input(line)
        clock.refuse_in_event("DioPort.wait_for")
        # bench time in the run's thread on a virtual clock (the events deliver levels to it),
        # wall time in any other thread and on the wall clock
        # in whole ns: a float of seconds since 2000 (virtual time) resolves only ~119 ns, and
        # a deadline rounded early missed an edge at 2 ms of a 2.00003 ms wait (helper-131)
        now_ns = clock.monotonic_ns if clock.waits_on_clock() else time.monotonic_ns
        deadline_ns = now_ns() + round(timeout_s * 1e9)
        if line not in self._levels and not self.owns(line):
            self._ask_levels()
        with self._cond:
            while True:
                entry = self._levels.get(line)
                if entry is not None and entry[0] == bool(level):
                    return entry[1]
                left = (deadline_ns - now_ns()) / 1e9
                if left <= 0 or self._closed:
                    seen = "never seen" if entry is None else f"last seen {int(entry[0])}"
                    raise TimeoutError(f"DI/DO {self.name}: {line} did not become "
                                       f"{int(bool(level))} within {timeout_s:g} s ({seen})")
                self._cond.wait_for(lambda e=entry: self._levels.get(line) != e or self._closed,
                                    left)

    def _changed(self, line: str, level: bool, t: int | None = None,
                 source_t: int | None = None, *, if_unknown: bool = False) -> None:
        """Backends report the other side's line levels here (`if_unknown`: only for a line
        never heard of; a query's answer must not undo a change seen since it was asked)."""
        t = clock.time_ns() if t is None else t
        with self._cond:
            old = self._levels.get(line)
            if old is not None and (if_unknown or old[0] == level):
                return
            self._levels[line] = (level, t)
            listeners = list(self._listeners)
            self._cond.notify_all()
        if self.tap is not None:
            self.tap.dio(self.name, line, level, t, source_t)
        for fn, with_source in listeners:
            if with_source:
                fn(line, level, t, source_t)
            else:
                fn(line, level, t)

    def _publish(self, line: str, level: bool, t: int) -> None:
        raise NotImplementedError

    def _check_open(self) -> None:
        if self._closed:
            raise ValueError(f"DI/DO {self.name} ({self.url}) is closed")

    def _close_backend(self) -> None:
        pass

    def close(self) -> None:
        with self._cond:
            if self._closed:
                return
            self._closed = True
            self._cond.notify_all()
        self._close_backend()

    def __enter__(self) -> DioPort:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.name} role={self.role} {self.url}>"


# -- virtual -----------------------------------------------------------------------------


class _Board:
    def __init__(self) -> None:
        self.levels: dict[str, tuple[bool, int]] = {}
        self.ports: list[VirtualDio] = []


_boards: dict[str, _Board] = {}
_boards_lock = threading.Lock()


class VirtualDio(DioPort):
    """In-process lines shared by every VirtualDio of the same name."""

    def __init__(self, url: str, board: str, role: Role, *, tap: Tap | None, name: str):
        super().__init__(url, role, tap=tap, name=name)
        self.board = board
        with _boards_lock:
            b = _boards.setdefault(board, _Board())
            b.ports.append(self)
            self._levels.update(b.levels)

    def _publish(self, line: str, level: bool, t: int) -> None:
        with _boards_lock:
            b = _boards[self.board]
            b.levels[line] = (level, t)
            others = [p for p in b.ports if p is not self and p.role != self.role]
        seen = clock.time_ns()
        for p in others:
            p._changed(line, level, seen, t)  # t: the publisher's (source) time

    def _close_backend(self) -> None:
        with _boards_lock:
            b = _boards.get(self.board)
            if b is not None:
                b.ports.remove(self)
                if not b.ports:
                    del _boards[self.board]


# -- zenoh -------------------------------------------------------------------------------


class ZenohDio(DioPort):
    """DI/DO over zenoh, layout `<key>/<line>` (docs/transports.md) = b"1" / b"0"."""

    def __init__(self, url: str, u: TransportUrl, role: Role, *, tap: Tap | None, name: str,
                 connect_timeout: float = 5.0, query_timeout: float = 1.0,
                 allow_remote: bool = False):
        super().__init__(url, role, tap=tap, name=name)
        self.key = u.target
        ep = u.zenoh()
        try:
            config = config_from(ep, allow_remote=allow_remote)
        except ValueError as e:
            raise TransportUrlError(url, str(e)) from None
        try:
            self.session = open_session(config, what=f"zenoh DI/DO {self.key!r}")
        except ConnectionError as e:
            raise TransportUrlError(url, str(e)) from None
        self._pubs: dict[str, zenoh.Publisher] = {}
        self._sub = self._queryable = None
        # levels are heard on two threads, the subscriber's and a query's answer: one at a
        # time, each stored and told to the listeners before the next, so listeners and the
        # tap hear them in the order they were stored (a CI run heard STO_A, DI4, STO_B)
        self._heard = threading.RLock()
        self._asker = AskAgain(
            lambda: self._learn_levels(min(query_timeout, ASK_TIMEOUT_S), if_unknown=True),
            f"dio-ask-{self.key}")
        try:
            if ep.connect:
                wait_connected(self.session, connect_timeout, what=url, endpoints=ep.connect)
            self._sub = self.session.declare_subscriber(
                f"{self.key}/*", self._on_sample, allowed_origin=zenoh.Locality.REMOTE)
            self._queryable = self.session.declare_queryable(f"{self.key}/**", self._on_query)
            if ep.connect:  # learn the other side's current levels (and sync routing)
                self._learn_levels(query_timeout, if_unknown=True)
        except (ConnectionError, zenoh.ZError) as e:
            self._close_backend()
            raise TransportUrlError(url, str(e)) from None

    def _line_of(self, key: str) -> str | None:
        line = key.rsplit("/", 1)[-1]
        try:
            is_input(line)
        except ValueError:
            return None
        return line

    def _on_sample(self, sample: zenoh.Sample) -> None:
        line = self._line_of(str(sample.key_expr))
        if line is None or self.owns(line):
            return
        payload = sample.payload.to_bytes()
        if payload not in (b"0", b"1"):
            return
        source_t = None
        if sample.attachment is not None:
            raw = sample.attachment.to_bytes()
            if len(raw) >= _T.size:  # source time, then a gateway lease token if any
                source_t = _T.unpack_from(raw)[0]
        with self._heard:
            self._changed(line, payload == b"1", None, source_t)

    def _on_query(self, query: zenoh.Query) -> None:
        with self._cond:
            mine = [(line, lv, t) for line, (lv, t) in self._levels.items() if self.owns(line)]
        for line, level, t in mine:
            key = f"{self.key}/{line}"
            if zenoh.KeyExpr(key).intersects(query.key_expr):
                query.reply(key, b"1" if level else b"0", attachment=_T.pack(t))

    def _learn_levels(self, timeout_s: float, if_unknown: bool = False) -> None:
        for line, level in self.query_levels(timeout_s).items():
            if not self.owns(line):
                with self._heard:
                    self._changed(line, level, if_unknown=if_unknown)

    def _ask_levels(self) -> None:
        if not self._closed:  # a line heard of meanwhile keeps what was heard (if_unknown)
            self._asker()

    def query_levels(self, timeout_s: float = 1.0) -> dict[str, bool]:
        """Ask every side on the key for its lines' current levels."""
        out: dict[str, bool] = {}
        for reply in self.session.get(f"{self.key}/**", timeout=timeout_s):
            sample = reply.ok
            if sample is None:
                continue
            line = self._line_of(str(sample.key_expr))
            payload = sample.payload.to_bytes()
            if line is not None and payload in (b"0", b"1"):
                out[line] = payload == b"1"
        return out

    def _publish(self, line: str, level: bool, t: int) -> None:
        pub = self._pubs.get(line)
        if pub is None:
            pub = self._pubs[line] = self.session.declare_publisher(
                f"{self.key}/{line}", express=True,
                congestion_control=zenoh.CongestionControl.BLOCK,
                allowed_destination=zenoh.Locality.REMOTE)
        key = f"{self.key}/{line}"
        pub.put(b"1" if level else b"0", attachment=_T.pack(t) + (lease_token(key) or b""))

    def _close_backend(self) -> None:
        undeclare(self._sub, self._queryable, *self._pubs.values())
        self._sub = self._queryable = None
        self._pubs.clear()
        close_session(self.session)


# -- Modbus TCP remote I/O -----------------------------------------------------------------

_KINDS = {"coil": "coil", "c": "coil", "di": "di", "discrete": "di", "discrete_input": "di"}


def parse_mapping(url: str, mapping: Mapping[str, object]) -> dict[str, tuple[str, int]]:
    """line -> ("coil" | "di", address); inputs of the drive need coils, outputs need
    discrete inputs."""
    out: dict[str, tuple[str, int]] = {}
    for line, spec in mapping.items():
        try:
            natural = "coil" if is_input(line) else "di"
        except ValueError as e:
            raise TransportUrlError(url, f"mapping: {e}") from None
        if isinstance(spec, int) and not isinstance(spec, bool):
            kind, addr = natural, spec
        elif isinstance(spec, str) and ":" in spec:
            k, _, a = spec.partition(":")
            kind = _KINDS.get(k.strip().lower(), "")
            try:
                addr = int(a, 0)
            except ValueError:
                addr = -1
        elif isinstance(spec, (tuple, list)) and len(spec) == 2:
            kind, addr = _KINDS.get(str(spec[0]).lower(), ""), spec[1]
        else:
            kind, addr = "", -1
        if kind == "" or not isinstance(addr, int) or not 0 <= addr <= 0xFFFF:
            raise TransportUrlError(url, f"mapping {line}: {spec!r} must be an address "
                                         "0..65535, 'coil:<n>' or 'di:<n>'")
        if kind != natural:
            want = "a coil" if natural == "coil" else "a discrete input"
            raise TransportUrlError(url, f"mapping {line}: the harness sees it through {want}, "
                                         f"not {spec!r}")
        out[line] = (kind, addr)
    if not out:
        raise TransportUrlError(url, "modbus-tcp DI/DO needs a mapping {line: address}")
    return out


class ModbusTcpDio(DioPort):
    """Harness side over a Modbus TCP remote I/O module: inputs of the drive are written
    as coils, outputs of the drive are polled as discrete inputs every `poll_ms`."""

    def __init__(self, url: str, u: TransportUrl, role: Role, mapping: Mapping[str, object],
                 *, tap: Tap | None, name: str):
        super().__init__(url, role, tap=tap, name=name)
        if role != "harness":
            raise TransportUrlError(url, "modbus-tcp DI/DO is a remote I/O module: only "
                                         "role='harness' can use it")
        self.map = parse_mapping(url, mapping)
        self.unit = u.int_param("unit", 1, 0, 255)
        self.poll_s = u.float_param("poll_ms", 5.0, 0.5, 10_000) / 1000
        timeout = u.float_param("timeout", 1.0, 0.01, 60)
        self._io = threading.Lock()
        self.client = ModbusTcpClient(u.host, port=u.port, timeout=timeout, retries=0)
        if not self.client.connect():
            raise TransportUrlError(url, f"cannot connect to Modbus TCP {u.host}:{u.port}")
        self._dis = sorted((a, line) for line, (k, a) in self.map.items() if k == "di")
        coils = sorted((a, line) for line, (k, a) in self.map.items() if k == "coil")
        for addr, line in coils:  # start from the module's current coil states
            rr = self._call("read_coils", addr, count=1)
            self._levels[line] = (bool(rr.bits[0]), clock.time_ns())
        self._stop = threading.Event()
        self._poller = threading.Thread(target=self._poll_loop, daemon=True,
                                        name=f"dio-poll {u.host}:{u.port}")
        if self._dis:
            self._poll_once()
            self._poller.start()

    def _call(self, fn: str, *args, **kwargs):
        with self._io:
            rr = getattr(self.client, fn)(*args, device_id=self.unit, **kwargs)
        if rr.isError():
            raise OSError(f"DI/DO {self.name}: {fn}{args} on unit {self.unit} failed: {rr}")
        return rr

    def _poll_once(self) -> None:
        lo, hi = self._dis[0][0], self._dis[-1][0]
        rr = self._call("read_discrete_inputs", lo, count=hi - lo + 1)
        t = clock.time_ns()
        for addr, line in self._dis:
            self._changed(line, bool(rr.bits[addr - lo]), t, None)

    def _poll_loop(self) -> None:
        while not self._stop.wait(self.poll_s):
            try:
                self._poll_once()
            except Exception:  # a lost module must not kill the thread; retried next poll
                if self._closed:
                    return

    def _publish(self, line: str, level: bool, t: int) -> None:
        kind, addr = self.map.get(line, ("", -1))
        if kind != "coil":
            raise ValueError(f"DI/DO {self.name}: line {line} has no coil in the mapping")
        self._call("write_coil", addr, level)

    def set(self, line: str, level: bool) -> None:
        if self.owns(line) and line not in self.map:
            raise ValueError(f"DI/DO {self.name}: line {line} has no coil in the mapping "
                             f"({', '.join(sorted(self.map))})")
        super().set(line, level)

    def _close_backend(self) -> None:
        self._stop.set()
        if self._poller.is_alive():
            self._poller.join(2)
        with self._io:
            self.client.close()


def open_dio(url: str, *, role: Role, tap: Tap | None = None, name: str | None = None,
             mapping: Mapping[str, object] | None = None, **options) -> DioPort:
    """Open a DI/DO line set. `name` names it in recordings (default: the URL target);
    `mapping` is the modbus-tcp line -> coil / discrete-input map from the bench file;
    `options` go to the zenoh backend (connect_timeout, query_timeout, allow_remote)."""
    if role not in ROLES:
        raise ValueError(f"DI/DO role {role!r}: must be 'harness' or 'drive'")
    u = parse_url(url, "dio")
    label = name or u.target
    if u.scheme == "virtual":
        return VirtualDio(url, u.target, role, tap=tap, name=label)
    if u.scheme == "zenoh":
        return ZenohDio(url, u, role, tap=tap, name=label, **options)
    return ModbusTcpDio(url, u, role, mapping or {}, tap=tap, name=label)
