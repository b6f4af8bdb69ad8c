"""Pulse lines: `open_pulse(url, role=...)` -> `PulsePort` (docs/pulse.md).

A pulse line is the cable between a PLC's high-speed pulse output and a drive's CN1: it
carries *segments*, never one message per pulse:

- `seg` (master -> drive): from now on `count` pulses (0: until the next segment) at `freq`
  Hz in `direction` +1 / -1, output `form` ab | cw_ccw | pulse_sign, `logic` 0 / 1, and
  `total`, the signed pulses the master output before it (the drive reconciles its count
  with it, so a late message over a network costs time, never pulses);
- `oab` (drive -> master): the encoder output OA/OB over a window: `count` quadrature
  counts at `freq` in `direction`, `total` the signed counts before it;
- `oz` (drive -> master): one Z pulse (OCZ) of `width_ns`;
- levels: the PLC's inputs `X<n>` (DOG, stroke limit, PG0: set by the drive side, which on
  the virtual bench is the machine) and outputs `Y<n>` (CLR: set by the master).

Backends:
- `virtual:<name>`: in-process, shared by every port of that name;
- `zenoh:<key>?connect=tcp/127.0.0.1:<port>`: `<key>/seg`, `<key>/oab`, `<key>/oz` (JSON),
  `<key>/X<n>`, `<key>/Y<n>` (b"1" / b"0"); the source time as an 8-byte little-endian
  attachment; a queryable on `<key>/**` answers each side's current levels.

A real pulse generator / high-speed counter implements `PulsePort` (see `PulseAdapter`).
"""

from __future__ import annotations

import json
import math
import re
import struct
import threading
from collections.abc import Callable
from typing import Any, Literal

import zenoh

from hil import clock
from hil.transport.urls import TransportUrl, TransportUrlError, parse_url
from hil.transport.zenoh_net import (
    ASK_TIMEOUT_S,
    AskAgain,
    close_session,
    config_from,
    open_session,
    undeclare,
    wait_connected,
)

Role = Literal["master", "drive"]
ROLES = ("master", "drive")
KINDS = ("seg", "oab", "oz")
FORMS = ("ab", "cw_ccw", "pulse_sign")
MAX_FREQ_HZ = 100e6  # no pulse line carries more; a larger value is refused as malformed
Listener = Callable[[str, dict[str, Any], int, int | None], None]
_X = re.compile(r"^X[0-9]{1,3}\Z")
_Y = re.compile(r"^Y[0-9]{1,3}\Z")
_T = struct.Struct("<q")
ERRORS_KEPT = 20  # reasons kept of the messages refused (as the faces keep theirs)


class PulseError(ValueError):
    """A malformed segment or level (the message names the field)."""


def check_segment(kind: str, data: Any) -> dict[str, Any]:
    """Validate one message body; returns it normalised, raises PulseError naming the field."""
    if kind not in KINDS:
        raise PulseError(f"pulse message kind {kind!r}: one of {', '.join(KINDS)}")
    if not isinstance(data, dict):
        raise PulseError(f"pulse {kind}: body must be an object, got {type(data).__name__}")
    out: dict[str, Any] = {}
    if kind in ("seg", "oab"):
        freq = data.get("freq")
        if (not isinstance(freq, int | float) or isinstance(freq, bool)
                or not math.isfinite(freq) or not 0 <= freq <= MAX_FREQ_HZ):
            raise PulseError(f"pulse {kind}.freq: {freq!r} is not a frequency "
                             f"0..{MAX_FREQ_HZ:g} Hz")
        direction = data.get("direction", 1)
        if direction not in (1, -1) or isinstance(direction, bool):
            raise PulseError(f"pulse {kind}.direction: {direction!r} is not 1 or -1")
        count = data.get("count", 0)
        if not isinstance(count, int) or isinstance(count, bool) or not 0 <= count < 2**62:
            raise PulseError(f"pulse {kind}.count: {count!r} is not a pulse count >= 0")
        out = {"freq": float(freq), "direction": direction, "count": count}
        total = data.get("total")
        if total is not None:
            if not isinstance(total, int) or isinstance(total, bool) or abs(total) >= 2**62:
                raise PulseError(f"pulse {kind}.total: {total!r} is not a signed pulse count")
            out["total"] = total
        if kind == "seg":
            form = data.get("form", "pulse_sign")
            if form not in FORMS:
                raise PulseError(f"pulse seg.form: {form!r} is not one of {', '.join(FORMS)}")
            logic = data.get("logic", 0)
            if logic not in (0, 1) or isinstance(logic, bool):
                raise PulseError(f"pulse seg.logic: {logic!r} is not 0 or 1")
            out |= {"form": form, "logic": logic}
    else:
        width = data.get("width_ns", 0)
        if not isinstance(width, int) or isinstance(width, bool) or not 0 <= width < 10**12:
            raise PulseError(f"pulse oz.width_ns: {width!r} is not a width in ns")
        out = {"width_ns": width}
    return out


def _owns(role: str, what: str) -> bool:
    """The master sends `seg` and Y<n>; the drive side sends `oab`, `oz` and X<n>."""
    if role == "master":
        return what == "seg" or bool(_Y.match(what))
    return what in ("oab", "oz") or bool(_X.match(what))


class PulsePort:
    """One end of a pulse line. role="master": the PLC; role="drive": the drive's CN1 and
    the machine's sensors."""

    def __init__(self, url: str, role: Role, *, tap: Any = None, name: str) -> None:
        if role not in ROLES:
            raise ValueError(f"pulse role {role!r}: must be 'master' or 'drive'")
        self.url, self.role, self.tap, self.name = url, role, tap, name
        self._levels: dict[str, bool] = {}
        self._subs: list[Listener] = []
        self._lock = threading.Lock()
        self.errors: list[str] = []  # the last malformed messages received (and ignored)
        self.refused = 0  # how many in all: a flood keeps only the last ERRORS_KEPT reasons
        self.closed = False

    # -- sending ---------------------------------------------------------------------------
    def send(self, kind: str, data: dict[str, Any], source_t: int | None = None) -> None:
        """Send a segment / output message this role owns."""
        self._check_open()
        if not _owns(self.role, kind):
            raise PulseError(f"pulse {self.role} port cannot send {kind!r}")
        body = check_segment(kind, data)
        t = clock.time_ns()
        if self.tap is not None:
            self.tap.pulse(self.name, kind, body, t, source_t)
        self._publish(kind, body, t if source_t is None else source_t)

    def set(self, line: str, level: bool, source_t: int | None = None) -> None:
        """Set one of this role's levels (master: Y<n>, drive: X<n>); published on change."""
        self._check_open()
        if not _owns(self.role, line):
            raise PulseError(f"pulse {self.role} port cannot set line {line!r}")
        level = bool(level)
        if not self._store_level(line, level):
            return
        t = clock.time_ns()
        if self.tap is not None:
            self.tap.dio(self.name, line, level, t, source_t)
        self._publish_level(line, level, t if source_t is None else source_t)

    def _store_level(self, line: str, level: bool, if_unknown: bool = False) -> bool:
        """Keep `level` of `line`; False when it was that already (nothing to publish), or,
        with `if_unknown`, when the line was heard of at all."""
        with self._lock:
            old = self._levels.get(line)
            if old == level or (if_unknown and old is not None):
                return False
            self._levels[line] = level
            return True

    def get(self, line: str) -> bool:
        """Last known level of `line` (False if never seen)."""
        with self._lock:
            level = self._levels.get(line)
        if level is None and not _owns(self.role, line):
            self._ask_levels()
        return bool(level)

    def _ask_levels(self) -> None:
        """Ask the other side again, in the background, for levels never heard of (a backend
        that can): a level set before this side's subscriber was routed is not published
        again while it does not change. Never blocks the caller."""

    def levels(self) -> dict[str, bool]:
        with self._lock:
            return dict(self._levels)

    def subscribe(self, fn: Listener) -> Callable[[], None]:
        """fn(kind, data, t, source_t) for every message from the other side; a level comes
        as kind "level" with data {"line": ..., "level": ...}."""
        self._subs.append(fn)
        return lambda: self._subs.remove(fn) if fn in self._subs else None

    # -- receiving ---------------------------------------------------------------------------
    def _received(self, kind: str, data: Any, source_t: int | None) -> None:
        """A message from the other side: validated, recorded, handed to the listeners."""
        if self.closed or _owns(self.role, kind):
            return
        try:
            body = check_segment(kind, data)
        except PulseError as e:
            self._refuse(str(e))
            return
        t = clock.time_ns()
        if self.tap is not None:
            self.tap.pulse(self.name, kind, body, t, source_t)
        self._deliver(kind, body, t, source_t)

    def _received_level(self, line: str, level: bool, source_t: int | None,
                        if_unknown: bool = False) -> None:
        if self.closed or _owns(self.role, line) or not (_X.match(line) or _Y.match(line)):
            return
        if not self._store_level(line, level, if_unknown):
            return
        t = clock.time_ns()
        if self.tap is not None:
            self.tap.dio(self.name, line, level, t, source_t)
        self._deliver("level", {"line": line, "level": level}, t, source_t)

    def _deliver(self, kind: str, body: dict[str, Any], t: int, source_t: int | None) -> None:
        for fn in list(self._subs):
            try:
                fn(kind, body, t, source_t)
            except Exception as e:
                self._refuse(f"listener {fn!r}: {e!r}")

    def _refuse(self, reason: str) -> None:
        self.refused += 1
        self.errors.append(reason)
        del self.errors[:-ERRORS_KEPT]

    # -- backend -------------------------------------------------------------------------------
    def _publish(self, kind: str, body: dict[str, Any], t: int) -> None:
        raise NotImplementedError

    def _publish_level(self, line: str, level: bool, t: int) -> None:
        raise NotImplementedError

    def _check_open(self) -> None:
        if self.closed:
            raise RuntimeError(f"pulse line {self.url!r} is closed")

    def _close_backend(self) -> None:
        pass

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            self._close_backend()

    def __enter__(self) -> PulsePort:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.url!r} role={self.role}>"


class PulseAdapter(PulsePort):
    """The interface a real pulse generator / high-speed counter implements (docs/pulse.md):
    `_publish("seg", ...)` loads a segment into the generator, `_publish_level` sets an
    output (CLR); the adapter calls `_received("oab", ...)` with its counter's increments,
    `_received("oz", ...)` per Z pulse and `_received_level("X<n>", ...)` per input edge."""


# -- virtual -------------------------------------------------------------------------------

_lines: dict[str, list[VirtualPulse]] = {}
_levels: dict[str, dict[str, bool]] = {}
_lines_lock = threading.Lock()


class VirtualPulse(PulsePort):
    """In-process line shared by every VirtualPulse of the same name."""

    def __init__(self, url: str, line: str, role: Role, *, tap: Any, name: str) -> None:
        super().__init__(url, role, tap=tap, name=name)
        self.line = line
        with _lines_lock:
            _lines.setdefault(line, []).append(self)
            known = dict(_levels.get(line, {}))
        for ln, level in known.items():
            if not _owns(role, ln):
                self._levels[ln] = level

    def _others(self) -> list[VirtualPulse]:
        with _lines_lock:
            return [p for p in _lines.get(self.line, []) if p is not self and p.role != self.role]

    def _publish(self, kind: str, body: dict[str, Any], t: int) -> None:
        for p in self._others():
            p._received(kind, dict(body), t)

    def _publish_level(self, line: str, level: bool, t: int) -> None:
        with _lines_lock:
            _levels.setdefault(self.line, {})[line] = level
        for p in self._others():
            p._received_level(line, level, t)

    def _close_backend(self) -> None:
        with _lines_lock:
            ports = _lines.get(self.line, [])
            if self in ports:
                ports.remove(self)
            if not ports:
                _lines.pop(self.line, None)
                _levels.pop(self.line, None)


# -- zenoh ---------------------------------------------------------------------------------


class ZenohPulse(PulsePort):
    """A pulse line over zenoh: `<key>/seg|oab|oz` JSON, `<key>/X<n>|Y<n>` b"1" / b"0"."""

    def __init__(self, url: str, u: TransportUrl, role: Role, *, tap: Any, name: str,
                 connect_timeout: float = 5.0, query_timeout: float = 1.0,
                 allow_remote: bool = False) -> None:
        super().__init__(url, role, tap=tap, name=name)
        self.key = u.target
        ep = u.zenoh()
        try:
            config = config_from(ep, allow_remote=allow_remote)
            self.session = open_session(config, what=f"zenoh pulse line {self.key!r}")
        except (ValueError, ConnectionError) as e:
            raise TransportUrlError(url, str(e)) from None
        self._pubs: dict[str, zenoh.Publisher] = {}
        self._sub = self._queryable = None
        # heard on two threads (the subscriber's, a query's answer): one at a time, each told
        # before the next, so listeners hear the order the levels were stored (as ZenohDio)
        self._heard = threading.RLock()
        self._asker = AskAgain(
            lambda: self._learn_levels(min(query_timeout, ASK_TIMEOUT_S), if_unknown=True),
            f"pulse-ask-{self.key}")
        try:
            if ep.connect:
                wait_connected(self.session, connect_timeout, what=url, endpoints=ep.connect)
            self._sub = self.session.declare_subscriber(
                f"{self.key}/*", self._on_sample, allowed_origin=zenoh.Locality.REMOTE)
            self._queryable = self.session.declare_queryable(f"{self.key}/**", self._on_query)
            if ep.connect:
                self._learn_levels(query_timeout, if_unknown=True)
        except (ConnectionError, zenoh.ZError) as e:
            self._close_backend()
            raise TransportUrlError(url, str(e)) from None

    def _learn_levels(self, timeout_s: float, if_unknown: bool = False) -> None:
        for reply in self.session.get(f"{self.key}/**", timeout=timeout_s):
            if reply.ok is not None:
                with self._heard:
                    self._level_sample(reply.ok, if_unknown)

    def _ask_levels(self) -> None:
        if not self.closed:  # a line heard of meanwhile keeps what was heard (if_unknown)
            self._asker()

    @staticmethod
    def _source_t(sample: zenoh.Sample) -> int | None:
        if sample.attachment is None:
            return None
        raw = sample.attachment.to_bytes()
        return _T.unpack_from(raw)[0] if len(raw) >= _T.size else None

    def _level_sample(self, sample: zenoh.Sample, if_unknown: bool = False) -> None:
        line = str(sample.key_expr).rsplit("/", 1)[-1]
        payload = sample.payload.to_bytes()
        if payload in (b"0", b"1"):
            self._received_level(line, payload == b"1", self._source_t(sample), if_unknown)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        with self._heard:
            self._on_sample_heard(sample)

    def _on_sample_heard(self, sample: zenoh.Sample) -> None:
        last = str(sample.key_expr).rsplit("/", 1)[-1]
        if last in KINDS:
            try:
                data = json.loads(sample.payload.to_bytes())
            except (ValueError, UnicodeDecodeError) as e:
                self._refuse(f"pulse {last}: not JSON ({e})")
                return
            self._received(last, data, self._source_t(sample))
        else:
            self._level_sample(sample)

    def _on_query(self, query: zenoh.Query) -> None:
        with self._lock:
            mine = [(ln, lv) for ln, lv in self._levels.items() if _owns(self.role, ln)]
        for line, level in mine:
            key = f"{self.key}/{line}"
            if zenoh.KeyExpr(key).intersects(query.key_expr):
                query.reply(key, b"1" if level else b"0")

    def _pub(self, last: str) -> zenoh.Publisher:
        pub = self._pubs.get(last)
        if pub is None:
            pub = self._pubs[last] = self.session.declare_publisher(
                f"{self.key}/{last}", express=True,
                congestion_control=zenoh.CongestionControl.BLOCK,
                allowed_destination=zenoh.Locality.REMOTE)
        return pub

    def _publish(self, kind: str, body: dict[str, Any], t: int) -> None:
        self._pub(kind).put(json.dumps(body, separators=(",", ":")), attachment=_T.pack(t))

    def _publish_level(self, line: str, level: bool, t: int) -> None:
        self._pub(line).put(b"1" if level else b"0", attachment=_T.pack(t))

    def _close_backend(self) -> None:
        undeclare(self._sub, self._queryable, *self._pubs.values())
        self._sub = self._queryable = None
        self._pubs.clear()
        close_session(self.session)


def open_pulse(url: str, *, role: Role, tap: Any = None, name: str | None = None,
               **options: Any) -> PulsePort:
    """Open a pulse line (`virtual:<name>` or `zenoh:<key>?...`); `options` go to zenoh."""
    if role not in ROLES:
        raise ValueError(f"pulse role {role!r}: must be 'master' or 'drive'")
    u = parse_url(url, "pulse")
    label = name or u.target
    if u.scheme == "virtual":
        return VirtualPulse(url, u.target, role, tap=tap, name=label)
    if u.scheme == "zenoh":
        return ZenohPulse(url, u, role, tap=tap, name=label, **options)
    raise TransportUrlError(url, f"a pulse line is virtual:<name> or zenoh:<key>, "
                                 f"not {u.scheme}:")
