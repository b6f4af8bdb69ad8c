"""`Gateway`: a bench's CAN buses, RS-485 lines and DI/DO sets exported over zenoh.

One zenoh session per gateway; keys under `<lab>/<bench>` (hil.gateway.keys). Wire formats
are the transports' own, so a runner opens the exported buses with plain `zenoh:` URLs:

- CAN: `hil.transport.zenoh_can` samples; the sender time is the gateway's capture time
  (the adapter's timestamp, mapped onto the wall clock), so `ZenohMessage.sender_time_ns`
  on the runner is the bench's time, and its recorder uses it as publish_time.
- RS-485: `hil.transport.serial_line` chunks (`<key>/s2m` from the bench, `<key>/m2s` to
  it) with each character's end time, so Modbus line timing survives the hop.
- DI/DO: `<key>/<line>` = b"1"/b"0", attachment = capture wall ns (docs/transports.md).

Only the lease holder may send: every incoming sample must carry the holder's 16-byte token
as attachment (after the 8-byte time for DI/DO); anything else is dropped and counted
(`refused` in the health report). When a lease ends because its holder vanished
(liveliness token gone) or stopped renewing, the gateway drives the bench to its safe state
and records each action on `/safety` of its own MCAP recording.

Modules: `exports.py` (the exported buses), `lease.py` (who may send), `safe_state.py`
(what happens when a lease ends badly), this file (the gateway that ties them together).
"""

from __future__ import annotations

import contextlib
import json
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import zenoh

from hil.gateway import keys
from hil.gateway.exports import (
    CanExport,
    CanFactory,
    DioExport,
    DioFactory,
    SerialExport,
    SerialFactory,
    _Export,
)
from hil.gateway.lease import LeaseInfo, LeaseTable, iso
from hil.gateway.safe_state import default_safe_state, sdo_write_controlword
from hil.gateway.tls import TlsFiles, acl_section, check_exposure
from hil.record.recorder import Recorder
from hil.transport.can_bus import open_can
from hil.transport.dio import open_dio
from hil.transport.serial_line import open_serial
from hil.transport.zenoh_net import close_session, make_config, open_session, wait_connected
from hil.units import S

log = logging.getLogger(__name__)

LEASE_TOPIC = "/gateway/lease"
HEALTH_TOPIC = "/gateway/health"

SafeStateFn = Callable[["Gateway", str], list[dict] | None]


HOLDER_MAX = 128  # characters of a lease holder's name (shown in /health and the logs)


@dataclass
class GatewayConfig:
    """How a gateway is reached and behaves (the `hil gateway` flags)."""

    lab: str = "lab"
    bench: str | None = None  # default: the bench file's `name`
    listen: list[str] = field(default_factory=list)
    connect: list[str] = field(default_factory=list)
    mode: str = "peer"
    tls: TlsFiles | None = None
    allow_cn: list[str] = field(default_factory=list)
    lease_timeout_s: float = 3.0
    health_period_s: float = 1.0
    record: Path | None = None
    safe_on_release: bool = True
    backoff_s: tuple[float, float] = (0.05, 2.0)  # reopen delay: first, max (doubling)
    # A chunk for the network ends after this much idle line; None: the line's Modbus t3.5,
    # so one chunk is one ADU however the adapter or pty delivers the bytes.
    serial_silence_s: float | None = None
    connect_timeout_s: float = 10.0


class Gateway:
    """Export `bench` (hil.bench.bench.Bench) under `<lab>/<bench>` (see module docstring).

    Factories replace how buses are opened (tests inject unpluggable adapters);
    `safe_state(gateway, reason)` replaces the bench file's safe state.
    """

    def __init__(self, bench: Any, config: GatewayConfig | None = None, *,
                 can_factory: CanFactory | None = None,
                 serial_factory: SerialFactory | None = None,
                 dio_factory: DioFactory | None = None,
                 safe_state: SafeStateFn | None = None,
                 recorder: Any = None) -> None:
        self.bench = bench
        self.config = config = config or GatewayConfig()
        self.name = config.bench or bench.name
        self.prefix = keys.prefix(config.lab, self.name)
        if not config.listen and not config.connect:
            raise ValueError("hil gateway: give at least one --listen or --connect endpoint")
        period = config.health_period_s
        if not 0.01 <= period <= 3600:  # NaN too: a negative period published ~100 a second
            raise ValueError(f"--health-period {period:g} s: must be 0.01..3600 s")
        self._remote = check_exposure(config.listen, config.connect, config.tls,
                                      config.allow_cn)
        if config.tls is not None:
            config.tls.check()
        self.lease = LeaseTable(config.lease_timeout_s)
        self._own_recorder = recorder is None and config.record is not None
        if self._own_recorder:
            recorder = Recorder(config.record, metadata={"gateway": self.prefix,
                                                         "bench_file": bench.path})
        self.recorder = recorder
        self._safe_state = safe_state or default_safe_state
        self.safe_reports: list[dict] = []
        self._stop = threading.Event()
        self._health_dirty = threading.Event()
        self._threads: list[threading.Thread] = []
        self._entities: list[Any] = []
        self.session: zenoh.Session | None = None
        self.started_ns = 0
        can_factory = can_factory or (lambda _n, url: open_can(url))
        serial_factory = serial_factory or (
            lambda n, url: open_serial(url, tap=self.recorder, name=n))
        dio_factory = dio_factory or (lambda n, url, m: open_dio(
            url, role="harness", tap=self.recorder, name=n, mapping=m or None))
        self.can = {n: CanExport(self, n, u, can_factory) for n, u in bench.can.items()}
        self.rs485 = {n: SerialExport(self, n, u, serial_factory) for n, u in bench.rs485.items()}
        self.dio = {n: DioExport(self, n, d.dio, dict(d.dio_map), dio_factory)
                    for n, d in bench.drives.items() if d.dio}

    # -- lifecycle ------------------------------------------------------------------------
    def start(self) -> Gateway:
        try:
            self._start()
        except BaseException:
            self.stop()
            raise
        return self

    def _start(self) -> None:
        c = self.config
        cfg = make_config(c.mode, listen=c.listen, connect=c.connect, allow_remote=self._remote,
                          tls=c.tls.section() if c.tls else None)
        if c.allow_cn:
            cfg.insert_json5("access_control", json.dumps(acl_section(c.allow_cn)))
        self.session = s = open_session(cfg, what=f"hil gateway {self.prefix}")
        self.started_ns = time.time_ns()
        if c.connect:
            wait_connected(s, c.connect_timeout_s, what=f"hil gateway {self.prefix}",
                           endpoints=c.connect)
        if self.recorder is not None:
            self.recorder.add_metadata("hil.gateway", {
                "lab": c.lab, "bench": self.name, "prefix": self.prefix,
                "listen": c.listen, "connect": c.connect, "mode": c.mode,
                "tls": c.tls is not None, "allow_cn": c.allow_cn,
                "lease_timeout_s": c.lease_timeout_s, "zid": str(s.zid())})
            if getattr(self.bench, "text", ""):
                self.recorder.attach("bench.yaml", self.bench.text.encode(), "application/yaml")
        for export in self.exports():
            export.start()
        self._health_pub = s.declare_publisher(keys.health(self.prefix))
        self._entities += [
            self._health_pub,
            s.declare_queryable(keys.health(self.prefix),
                                lambda q: q.reply(keys.health(self.prefix), self._health_json())),
            s.declare_queryable(keys.info(self.prefix),
                                lambda q: q.reply(keys.info(self.prefix),
                                                  json.dumps(self.info()))),
            s.declare_queryable(keys.lease(self.prefix), self._on_lease_query),
            s.liveliness().declare_subscriber(keys.lease_alive(self.prefix), self._on_alive,
                                              history=True),
        ]
        t = threading.Thread(target=self._housekeeping, daemon=True, name="gw-housekeeping")
        t.start()
        self._threads.append(t)
        self._log("info", f"gateway {self.prefix} started: {self.describe()}")

    def exports(self) -> list[_Export]:
        return [*self.can.values(), *self.rs485.values(), *self.dio.values()]

    def wait_ready(self, timeout_s: float = 10.0) -> bool:
        """Wait until every export's link is up."""
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if all(e.health.link == "up" for e in self.exports()):
                return True
            time.sleep(0.005)
        return False

    def stop(self) -> None:
        """Stop exporting; a lease still held ends with the safe state."""
        if self.session is not None and self.lease.current is not None:
            info = self.lease.current
            self.lease.release(info.token)
            self._end(info, "gateway stopping", safe=True, wait=True)
        self._stop.set()
        for t in self._threads:
            t.join(5)
        for e in self._entities:
            with contextlib.suppress(zenoh.ZError):
                e.undeclare()
        self._entities.clear()
        for export in self.exports():
            export.stop()
        if self.session is not None:
            close_session(self.session)
            self.session = None
        if self._own_recorder and self.recorder is not None:
            self.recorder.close()
            self._own_recorder = False

    def __enter__(self) -> Gateway:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -- description and health ---------------------------------------------------------------
    def describe(self) -> str:
        parts = [f"{e.kind} {e.name} -> {e.key}" for e in self.exports()]
        eps = ", ".join(self.config.listen + self.config.connect)
        return f"{self.prefix} on {eps}: " + ("; ".join(parts) or "no buses")

    def info(self) -> dict:
        return {
            "lab": self.config.lab, "bench": self.name, "prefix": self.prefix,
            "can": {n: e.key for n, e in self.can.items()},
            "rs485": {n: e.key for n, e in self.rs485.items()},
            "dio": {n: e.key for n, e in self.dio.items()},
            "drives": {n: {"node_id": d.node_id, "can": d.can, "station": d.station,
                           "rs485": d.rs485, "dio": n if d.dio else None}
                       for n, d in self.bench.drives.items()},
            "lease_timeout_s": self.config.lease_timeout_s,
            "safe_state": self.bench.safe_state.controlword,
        }

    def health(self) -> dict:
        return {"lab": self.config.lab, "bench": self.name, "t_ns": time.time_ns(),
                "up_since_ns": self.started_ns, "lease": self.lease.status(),
                "buses": {f"{e.kind}/{e.name}": self._bus_health(e) for e in self.exports()}}

    def _bus_health(self, e: _Export) -> dict:
        snap = e.health.snapshot()
        if isinstance(e, CanExport) and e._bus is not None and snap["state"] != "bus-off":
            with contextlib.suppress(Exception):
                state = e._bus.state  # python-can: ACTIVE / PASSIVE / ERROR where offered
                snap["can_state"] = getattr(state, "name", str(state)).lower()
        return snap

    def _health_json(self) -> bytes:
        return json.dumps(self.health()).encode()

    def _link_changed(self, export: _Export, what: str) -> None:
        self._log("warning" if export.health.link == "down" else "info",
                  f"{export.kind} {export.name}: link {export.health.link} ({what})")
        self._health_dirty.set()

    def _housekeeping(self) -> None:
        period = self.config.health_period_s
        next_health = 0.0
        while not self._stop.wait(0.01):
            info = self.lease.expired()
            if info is not None:
                self._end(info, f"lease of {info.holder} expired: no keep-alive within "
                                f"{info.timeout_ns / S:g} s", safe=True)
            now = time.monotonic()
            if self._health_dirty.is_set() or now >= next_health:
                self._health_dirty.clear()
                next_health = now + period
                doc = self.health()
                with contextlib.suppress(zenoh.ZError):
                    self._health_pub.put(json.dumps(doc))
                if self.recorder is not None:
                    self.recorder.write(HEALTH_TOPIC, doc)

    # -- leases ----------------------------------------------------------------------------
    def _on_lease_query(self, query: zenoh.Query) -> None:
        try:
            req = json.loads(query.payload.to_bytes()) if query.payload is not None else {}
            if not isinstance(req, dict):
                raise ValueError("not a JSON object")
            reply = self._lease_op(req)
        except (ValueError, TypeError, RecursionError) as e:  # RecursionError: nested JSON
            why = "nested too deep" if isinstance(e, RecursionError) else str(e)[:200]
            reply = {"granted": False, "reason": f"bad request: {why}"}
        query.reply(keys.lease(self.prefix), json.dumps(reply))

    def _lease_op(self, req: dict) -> dict:
        op = req.get("op", "status")
        if op == "status":
            return self.lease.status()
        token = bytes.fromhex(str(req.get("token", "")))
        if op == "acquire":
            holder = req.get("holder", "")
            if not isinstance(holder, str) or len(holder) > HOLDER_MAX \
                    or not holder.isprintable():
                raise ValueError(f"holder: a printable text of at most {HOLDER_MAX} "
                                 "characters (it is shown in /health and the logs)")
            before = self.lease.current
            granted, info = self.lease.acquire(holder, token, str(req.get("alive", "")))
            if granted and (before is None or before.token != token):
                self._lease_event("granted", holder, info)
            elif not granted:
                self._lease_event("refused", holder, info)
            return {"granted": granted, **info}
        if op == "renew":
            ok = self.lease.renew(token)
            return {"granted": ok, **self.lease.status()}
        if op == "release":
            ended = self.lease.release(token)
            if ended is not None:
                self._end(ended, f"released by {ended.holder}",
                          safe=self.config.safe_on_release)
            return {"released": ended is not None}
        raise ValueError(f"op {op!r}: must be acquire, renew, release or status")

    def _on_alive(self, sample: zenoh.Sample) -> None:
        if sample.kind != zenoh.SampleKind.DELETE:
            return
        alive_id = str(sample.key_expr).rsplit("/", 1)[-1]
        info = self.lease.gone(alive_id)
        if info is not None:
            self._end(info, f"holder {info.holder} disappeared (liveliness token gone)",
                      safe=True)

    def _lease_event(self, event: str, holder: str, info: dict) -> None:
        self._log("info", f"lease {event}: {holder} ({info.get('reason') or info.get('since')})")
        if self.recorder is not None:
            self.recorder.write(LEASE_TOPIC, {"event": event, "requester": holder, **info})

    def _end(self, info: LeaseInfo, reason: str, *, safe: bool, wait: bool = False) -> None:
        self._lease_event("ended", info.holder, {**info.public(), "reason": reason})
        for export in self.rs485.values():  # the holder's bytes still queued for the line
            export.discard_output()  # never reach the bench after its lease (helper-126)
        if not safe:
            self.lease.safe_done()
            return

        def run() -> None:
            try:
                self.go_safe(reason, holder=info.holder)
            finally:
                self.lease.safe_done()

        if wait:
            run()
        else:
            t = threading.Thread(target=run, daemon=True, name="gw-safe-state")
            t.start()
            self._threads.append(t)

    # -- safe state --------------------------------------------------------------------------
    def go_safe(self, reason: str, *, holder: str = "") -> dict:
        """Drive the bench to its safe state now; every action recorded on /safety."""
        t0 = time.time_ns()
        if self.recorder is not None:
            self.recorder.safety("safe state start", reason, source="gateway", holder=holder)
        try:
            actions = self._safe_state(self, reason) or []
        except Exception as e:  # the safe state must never kill the gateway
            actions = [{"action": "safe state", "ok": False, "detail": f"{type(e).__name__}: {e}"}]
        ok = all(a.get("ok", True) for a in actions)
        report = {"reason": reason, "holder": holder, "ok": ok, "actions": actions,
                  "t_ns": t0, "duration_ms": (time.time_ns() - t0) / 1e6}
        self.safe_reports.append(report)
        if self.recorder is not None:
            self.recorder.safety("safe state done" if ok else "safe state INCOMPLETE", reason,
                                 source="gateway", holder=holder, ok=ok,
                                 duration_ms=report["duration_ms"])
        self._log("warning", f"safe state {'reached' if ok else 'INCOMPLETE'} ({reason})")
        return report

    def record_action(self, reason: str, drive: str, action: str, fn: Callable[[], Any],
                      **extra: Any) -> dict:
        """Run one safe-state action, never raising; record and return its outcome."""
        try:
            detail = fn()
            ok = detail is not False
            msg = detail if isinstance(detail, str) else ""
        except Exception as e:
            ok, msg = False, f"{type(e).__name__}: {e}"
        if self.recorder is not None:
            self.recorder.safety(action, reason, source="gateway", drive=drive, ok=ok,
                                 detail=msg, **extra)
        return {"drive": drive, "action": action, "ok": ok, "detail": msg, **extra}

    def _log(self, level: str, message: str) -> None:
        """To Python logging once: through the recorder, which forwards it there, when
        there is one (a line went to stderr twice, helper-126)."""
        if self.recorder is not None:
            self.recorder.log(level, message, name="hil.gateway")
        else:
            getattr(log, level)(message)


__all__ = [
    "Gateway",
    "GatewayConfig",
    "default_safe_state",
    "iso",
    "sdo_write_controlword",
]
