"""Bench files: the drives on a bench, their transports, wiring, timeouts and safe state.

Format: docs/benches.md. `load_bench(path)` returns a validated `Bench` or raises
`PlanFileError` (`file:line: field: problem`) before anything is opened or moved.
"""

from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from hil.bench import virtual_rules
from hil.bench.param_rules import check_param
from hil.bench.yamlio import (
    MS,
    Checker,
    LDict,
    PlanFileError,
    S,
    join,
    level,
    load_yaml_file,
    load_yaml_text,
    text_number_hint,
)
from hil.paths import fixture
from hil.profile.dio import (
    DEFAULT_PULSE_WIRING,
    DI_PARAMS,
    DI_SYMBOLS,
    DO_PARAMS,
    DO_SYMBOLS,
    N_DO,
    N_PHYSICAL_DI,
)
from hil.protocol import modbus as mb
from hil.transport.urls import TransportUrlError, parse_url

# Named timeouts (ns) and their defaults; a bench overrides any of them. The CiA 402 ones
# are handed to hil.drivers.cia402.Cia402Driver (same names).
DEFAULT_TIMEOUTS: dict[str, int] = {
    "step": 60 * S,  # any one step, whatever it does
    "wait_until": 5 * S,  # wait_until without its own timeout
    "modbus": 500 * MS,  # one Modbus transaction
    "sdo": 500 * MS,  # one SDO round trip
    "state": 1 * S,  # one CiA 402 power-state transition
    "mode": 500 * MS,  # 6061h echoes 6060h
    "setpoint_ack": 1 * S,
    "target_reached": 30 * S,
    "homing": 60 * S,
    "fault_reset": 1 * S,
    "safe_state": 3 * S,  # reaching the safe state (incl. waiting for the brake)
    "ready": 10 * S,  # virtual drive processes answering
}
CIA402_TIMEOUTS = ("sdo", "state", "mode", "setpoint_ack", "target_reached", "homing",
                   "fault_reset")
CONTROLWORDS = ("disable_voltage", "quick_stop", "shutdown", "none")
PROCESSES = ("inproc", "subprocess")
CLOCKS = ("virtual", "real")  # docs/clock.md
PROFILES = ("asda-a3",)
PARAM_VIAS = ("modbus", "sdo")
STO_CHANNELS = {"A": "STO_A", "B": "STO_B"}
_LINE_RE = re.compile(r"^(DI|DO)([0-9]{1,2})(?::([ab]))?\Z")
_PARAM_RE = re.compile(r"^P[0-7]\.[0-9]{3}\Z")
_NAME_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_-]*\Z")

_TOP = {"name", "description", "virtual", "process", "clock", "can", "rs485", "drives", "timeouts",
        "timing", "gateway",
        "safe_state", "motion_allowed", "features", "faults_allowed"}
_DRIVE = {"node_id", "station", "profile", "can", "rs485", "dio", "dio_map", "pulse",
          "pulse_wiring", "wiring", "sto",
          "params", "param_via", "mechanics", "options", "modbus_mode"}
_VIRTUAL_ONLY = ("mechanics", "options")
_SAFE = {"controlword", "di", "sto", "wait_brake", "timeout"}


@dataclass(frozen=True)
class Wire:
    """One drive function on one drive line: `line` like DI8, `contact` a or b.

    The contact is the drive's P2.0xx setting for that line: for a b-contact the function
    is active when the contact is open, so `di: {EMGS: on}` opens DI8."""

    function: str
    line: str
    contact: str = "a"

    @property
    def kind(self) -> str:
        return self.line[:2]

    @property
    def number(self) -> int:
        return int(self.line[2:])

    def level_for(self, active: bool) -> bool:
        """Electrical level that makes the function active (True) or inactive."""
        return active if self.contact == "a" else not active

    def active_from(self, electrical: bool) -> bool:
        return electrical if self.contact == "a" else not electrical

    @property
    def binding(self) -> str:
        """`DI8:b` form used by timing specs (hil.timing.spec.Spec.binding)."""
        return self.line + (":b" if self.contact == "b" else "")

    def mapping_param(self) -> tuple[str, int]:
        """(P2.0xx, value) that puts this function on this line (L9238-9256, L9323-9339)."""
        code = DI_SYMBOLS[self.function] if self.kind == "DI" else DO_SYMBOLS[self.function]
        params = DI_PARAMS if self.kind == "DI" else DO_PARAMS
        return params[self.number - 1], (0x100 if self.contact == "a" else 0) | code


@dataclass
class DriveSpec:
    name: str
    line: int
    node_id: int | None = None
    station: int | None = None
    profile: str = "asda-a3"
    can: str | None = None  # name of a bus in Bench.can
    rs485: str | None = None  # name of a line in Bench.rs485
    dio: str | None = None  # DI/DO URL (harness side)
    dio_map: dict[str, Any] = field(default_factory=dict)  # modbus-tcp line -> coil/di
    pulse: str | None = None  # pulse line URL (docs/pulse.md)
    pulse_wiring: dict[str, str] | None = None  # DOG/NL/PL -> X<n>, Y<n> -> DI<n>
    di: dict[str, Wire] = field(default_factory=dict)  # DI function -> wire
    do: dict[str, Wire] = field(default_factory=dict)  # DO function -> wire
    sto: dict[str, str] = field(default_factory=lambda: dict(STO_CHANNELS))
    params: dict[str, int] = field(default_factory=dict)
    param_via: str = "modbus"
    modbus_mode: str = "rtu"
    mechanics: dict[str, Any] = field(default_factory=dict)
    options: dict[str, Any] = field(default_factory=dict)

    def binding(self) -> dict[str, str]:
        """Function -> line map for timing specs, plus the recording place names."""
        out = {w.function: w.binding for w in (*self.di.values(), *self.do.values())}
        return out | {"drive": self.name, "dio": self.name}


@dataclass
class SafeState:
    controlword: str = "disable_voltage"
    di: dict[str, bool] = field(default_factory=lambda: {"SON": False})
    sto: dict[str, bool] = field(default_factory=dict)
    wait_brake: bool = True
    timeout_ns: int = DEFAULT_TIMEOUTS["safe_state"]


@dataclass
class Bench:
    name: str
    path: str
    text: str
    virtual: bool
    drives: dict[str, DriveSpec]
    description: str = ""
    process: str = "inproc"
    can: dict[str, str] = field(default_factory=dict)  # bus name -> URL
    rs485: dict[str, str] = field(default_factory=dict)  # line name -> URL
    timeouts: dict[str, int] = field(default_factory=lambda: dict(DEFAULT_TIMEOUTS))
    safe_state: SafeState = field(default_factory=SafeState)
    motion_allowed: bool = True
    # `fault:` steps (docs/faults.md); default: true on a virtual bench, false on a real one
    faults_allowed: bool = False
    features: set[str] = field(default_factory=set)
    # Timing-spec constants this bench overrides (e.g. a transport's input latency widens
    # `fw_tol`): the same as `hil check --const NAME=VALUE`, in ms.
    timing_constants: dict[str, float] = field(default_factory=dict)
    timing_constant_lines: dict[str, int] = field(default_factory=dict)  # name -> file line
    gateway: GatewaySpec | None = None  # buses reached through a `hil gateway` (a lease)
    # "virtual": the run on the model's clock (docs/clock.md); "real": the wall clock
    clock: str = "real"

    @property
    def default_drive(self) -> str:
        return next(iter(self.drives))

    def provides(self) -> set[str]:
        """Features a plan's `bench_requires` may ask for."""
        out = set(self.features)
        out.add("virtual" if self.virtual else "real")
        if self.motion_allowed:
            out.add("motion")
        if any(d.can for d in self.drives.values()):
            out.update({"can", "sdo"})
        if any(d.rs485 for d in self.drives.values()):
            out.update({"rs485", "modbus"})
        if any(d.dio for d in self.drives.values()):
            out.add("dio")
        if any(d.pulse for d in self.drives.values()):
            out.add("pulse")
        return out


@dataclass
class GatewaySpec:
    """`gateway: {lab, bench, connect, holder}`: the bench is exported by `hil gateway`.

    Transports written as `gateway` (or `gateway?baud=...` for RS-485) are taken from the
    lease: `zenoh:<lab>/<bench>/can/<bus>`, `.../rs485/<line>`, `.../dio/<drive>`."""

    lab: str
    bench: str
    connect: list[str]
    holder: str | None = None
    mode: str = "peer"


GATEWAY = "gateway"


def builtin_bench_path() -> Path:
    return fixture("benches", "virtual.yaml")


def load_bench(path: str | Path | None = None) -> Bench:
    """Load and validate a bench file (default: the built-in virtual bench)."""
    p = Path(path) if path is not None else builtin_bench_path()
    data = load_yaml_file(p)
    return parse_bench(data, str(p), p.read_text(encoding="utf-8"))


def loads_bench(text: str, file: str = "<string>") -> Bench:
    return parse_bench(load_yaml_text(text, file), file, text)


def parse_bench(data: Any, file: str, text: str = "") -> Bench:
    v = Checker(file)
    top = v.mapping(data, 1, "(top)")
    v.keys(top, _TOP, "", required=("name", "drives"))
    name = v.text(top, "name", "")
    virtual = v.boolean(top, "virtual", "", False)
    process = v.text(top, "process", "", "inproc")
    if process not in PROCESSES:
        raise v.err(top.kline("process"), "process", f"{process!r}: one of {', '.join(PROCESSES)}")
    if "process" in top and not virtual:
        raise v.err(top.kline("process"), "process", "only for a virtual bench (virtual: true)")
    gateway = _gateway(v, top)
    if gateway is not None and virtual:
        raise v.err(top.kline("gateway"), "gateway", "a virtual bench starts its own drives; "
                    "a gateway exports a real bench (virtual: false)")
    can = _urls(v, top, "can", "can", gateway is not None)
    rs485 = _urls(v, top, "rs485", "serial", gateway is not None)
    timeouts = _timeouts(v, top)
    drives_map = v.mapping(top["drives"], top.kline("drives"), "drives")
    if not drives_map:
        raise v.err(drives_map.line, "drives", "a bench needs at least one drive")
    drives: dict[str, DriveSpec] = {}
    nodes: dict[tuple[str, int], str] = {}
    stations: dict[tuple[str, int], str] = {}
    for dname, d in drives_map.items():
        where = join("drives", dname)
        if not _NAME_RE.match(dname):
            raise v.err(drives_map.kline(dname), where, "drive names are letters, digits, _ -")
        spec = _drive(v, dname, v.mapping(d, drives_map.kline(dname), where), where, virtual,
                      can, rs485, process)
        if spec.dio == GATEWAY and gateway is None:
            raise v.err(d.kline("dio"), join(where, "dio"),
                        "`gateway` needs a top-level gateway: section")
        if spec.node_id is not None and spec.can:
            other = nodes.get((spec.can, spec.node_id))
            if other:
                raise v.err(d.kline("node_id"), join(where, "node_id"),
                            f"node id {spec.node_id} on bus {spec.can} is already drive {other}")
            nodes[(spec.can, spec.node_id)] = dname
        if spec.station is not None and spec.rs485:
            other = stations.get((spec.rs485, spec.station))
            if other:
                raise v.err(d.kline("station"), join(where, "station"),
                            f"station {spec.station} on {spec.rs485} is already drive {other}")
            stations[(spec.rs485, spec.station)] = dname
        drives[dname] = spec
    for kind, urls in (("can", can), ("rs485", rs485)):
        used = {getattr(d, kind) for d in drives.values()}
        for bname in urls:
            if bname not in used:
                m = v.mapping(top[kind], top.kline(kind), kind)
                raise v.err(m.kline(bname), join(kind, bname), "no drive uses this transport")
    safe = _safe_state(v, top, drives, timeouts)
    features: set[str] = set()
    if "features" in top:
        lst = v.seq(top["features"], top.kline("features"), "features")
        for i, f in enumerate(lst):
            if not isinstance(f, str):
                raise v.err(lst.item_lines[i], f"features[{i}]", "must be a name")
            features.add(f)
    clock = _clock(v, top, virtual, process, can, rs485, drives)
    constants, constant_lines = _timing(v, top)
    return Bench(
        name=name, path=file, text=text, virtual=virtual, drives=drives, clock=clock,
        description=str(top.get("description") or ""), process=process, can=can, rs485=rs485,
        timeouts=timeouts, safe_state=safe,
        motion_allowed=v.boolean(top, "motion_allowed", "", True), features=features,
        faults_allowed=v.boolean(top, "faults_allowed", "", virtual),
        timing_constants=constants, timing_constant_lines=constant_lines, gateway=gateway,
    )


def _scheme_target(url: str) -> tuple[str, str]:
    """A URL's scheme (lower case, as `parse_url` reads it) and target (before any `?`)."""
    scheme, _, rest = url.strip().partition(":")
    return scheme.lower(), rest.partition("?")[0]


def clock_blocker(virtual: bool, process: str, can: dict[str, str], rs485: dict[str, str],
                  dio: list[str]) -> str | None:
    """Why a bench cannot run on the virtual clock (None: it can). Only an in-process
    virtual bench whose buses are `virtual:`, RS-485 lines `pty:auto` (nobody else's to
    open) and DI/DO `virtual:` can: zenoh, named ptys, processes and hardware keep wall time."""
    if not virtual:
        return "a real bench runs on the wall clock"
    if process != "inproc":
        return "process: subprocess runs its drives in other processes (wall clock)"
    for name, url in can.items():
        if _scheme_target(url)[0] != "virtual":
            return f"CAN bus {name} ({url}) is not an in-process virtual: bus"
    for name, url in rs485.items():
        if _scheme_target(url) != ("pty", "auto"):
            return f"RS-485 line {name} ({url}) is not pty:auto (another program may open it)"
    for url in dio:
        if _scheme_target(url)[0] != "virtual":
            return f"DI/DO or pulse line {url} is not in-process virtual:"
    return None


def wall_clock_preferred(can: dict[str, str]) -> str | None:
    """Why a bench that could run in virtual time defaults to the wall clock (None: it does
    not): a named `virtual:<channel>` CAN bus is there for another bus of this process to
    open, a python-can `can.Bus(interface="virtual", channel=...)` sniffer, which hears a
    virtual-time bus only through `hil.transport.can_bus.open_can` (docs/clock.md). `clock: virtual`
    still runs it in virtual time."""
    for name, url in can.items():
        scheme, target = _scheme_target(url)
        if scheme == "virtual" and target != "auto":
            return (f"CAN bus {name} ({url}) is a named channel: a plain python-can virtual "
                    "bus on it hears only the wall clock's")
    return None


def line_warnings(bench: Bench) -> list[str]:
    """`file:line: drives.<d>: problem` for each drive whose Modbus UART cannot read its RS-485
    line as the bench declares it: the line's URL (baud, data bits, parity) and the harness's
    `modbus_mode` against the drive's P3.001 X and P3.002 (L10509-L10557). The bench's `params`
    set those; a virtual drive without them is set to its line (`hil.virtual.stack.line_params`)
    unless the A3 offers no such setting. A warning, not an error: a plan may mean it."""
    out = []
    for name, d in bench.drives.items():
        url = bench.rs485.get(d.rs485 or "")
        if url is None:
            continue
        try:
            st = parse_url(url, "serial").serial()
        except (TransportUrlError, ValueError):
            continue
        fmt = mb.CharFormat(st.bytesize, st.parity, int(st.stopbits))
        x, proto = mb.uart_for_line(st.baud, fmt, d.modbus_mode)
        p3001, p3002 = d.params.get("P3.001"), d.params.get("P3.002")
        if bench.virtual:  # as `line_params` sets them (the A3's defaults where it cannot)
            p3001 = p3001 if p3001 is not None else (0x0200 | x if x is not None else 0x0203)
            p3002 = p3002 if p3002 is not None else (proto if proto is not None else 6)
        why = []
        uart_baud = mb.P3001_BAUD.get(p3001 & 0xF) if isinstance(p3001, int) else None
        uart_mode, uart_fmt = mb.P3002_PROTOCOLS.get(p3002, (None, None)) if isinstance(
            p3002, int) else (None, None)
        if uart_baud is not None or uart_fmt is not None:
            garbled = mb.uart_mismatch(st.baud, fmt, uart_baud or st.baud, uart_fmt or fmt)
            if garbled:
                why.append(garbled)
        if uart_mode is not None and uart_mode != d.modbus_mode:
            why.append(f"the harness speaks {d.modbus_mode.upper()}, P3.002 = {p3002} is "
                       f"{uart_mode.upper()}")
        if why:
            out.append(f"{bench.path or bench.name}:{d.line}: {join('drives', name)}: "
                       f"{'; '.join(why)} (P3.001 X / P3.002, L10509-L10557): the drive will "
                       "not answer over Modbus")
    return out


def _lines_of(drives: dict[str, DriveSpec]) -> list[str]:
    """The DI/DO and pulse-line URLs of the drives (for the clock choice)."""
    return [u for d in drives.values() for u in (d.dio, d.pulse) if u and u != GATEWAY]


def with_clock(bench: Bench, clock: str | None) -> Bench:
    """`bench` on `clock` ("virtual" / "real"; None: as the bench says), e.g. `--clock`.
    Raises ValueError naming why a bench cannot run on the virtual clock."""
    if clock is None or clock == bench.clock:
        return bench
    if clock not in CLOCKS:
        raise ValueError(f"clock {clock!r}: one of {', '.join(CLOCKS)}")
    if clock == "virtual":
        why = clock_blocker(bench.virtual, bench.process, bench.can, bench.rs485,
                            _lines_of(bench.drives))
        if why:
            raise ValueError(f"bench {bench.name} cannot run on the virtual clock: {why}")
    return dataclasses.replace(bench, clock=clock)


def _clock(v: Checker, top: LDict, virtual: bool, process: str, can: dict[str, str],
           rs485: dict[str, str], drives: dict[str, DriveSpec]) -> str:
    why = clock_blocker(virtual, process, can, rs485, _lines_of(drives))
    if "clock" not in top:
        return "real" if why or wall_clock_preferred(can) else "virtual"
    clock = v.text(top, "clock", "")
    if clock not in CLOCKS:
        raise v.err(top.kline("clock"), "clock", f"{clock!r}: one of {', '.join(CLOCKS)}")
    if clock == "virtual" and why:
        raise v.err(top.kline("clock"), "clock", f"virtual: {why}")
    return clock


def _gateway(v: Checker, top: LDict) -> GatewaySpec | None:
    if "gateway" not in top:
        return None
    m = v.mapping(top["gateway"], top.kline("gateway"), "gateway")
    v.keys(m, {"lab", "bench", "connect", "holder", "mode"}, "gateway",
           required=("lab", "bench", "connect"))
    connect = m["connect"]
    if isinstance(connect, str):
        connect = [connect]
    if not isinstance(connect, list) or not connect or not all(isinstance(c, str)
                                                                 for c in connect):
        raise v.err(m.kline("connect"), "gateway.connect", "one or more zenoh endpoints, "
                    "e.g. tcp/127.0.0.1:7447")
    mode = v.text(m, "mode", "gateway", "peer")
    if mode not in ("peer", "client"):
        raise v.err(m.kline("mode"), "gateway.mode", f"{mode!r}: peer or client")
    holder = m.get("holder")
    return GatewaySpec(lab=v.text(m, "lab", "gateway"), bench=v.text(m, "bench", "gateway"),
                       connect=[str(c) for c in connect], mode=mode,
                       holder=None if holder is None else str(holder))


def _timing(v: Checker, top: LDict) -> tuple[dict[str, float], dict[str, int]]:
    """`timing: {constants: {fw_tol: 3}}`: spec constants (ms) overridden on this bench, and
    the line of each (a name no shipped spec defines is warned of where the specs are known:
    `hil.plan.plan.bench_constant_warnings`)."""
    if "timing" not in top:
        return {}, {}
    m = v.mapping(top["timing"], top.kline("timing"), "timing")
    v.keys(m, {"constants"}, "timing")
    if "constants" not in m:
        return {}, {}
    c = v.mapping(m["constants"], m.kline("constants"), "timing.constants")
    out = {}
    for k, x in c.items():
        # False for NaN, inf and an int too long for a float (isfinite raised on it)
        ok = not isinstance(x, bool) and isinstance(x, int | float) and abs(x) <= 1e12
        if not ok:
            raise v.err(c.kline(k), join("timing.constants", k),
                        f"{repr(x)[:40]}: a number of ms (finite, within ±1e12, as "
                        "`hil check --const`)")
        out[str(k)] = float(x)
    return out, {str(k): c.kline(k) for k in c}


def _urls(v: Checker, top: LDict, key: str, kind: str, gateway: bool = False) -> dict[str, str]:
    if key not in top:
        return {}
    m = v.mapping(top[key], top.kline(key), key)
    out = {}
    for bname, url in m.items():
        where = join(key, bname)
        if not _NAME_RE.match(bname):
            raise v.err(m.kline(bname), where, "transport names are letters, digits, _ -")
        if not isinstance(url, str):
            raise v.err(m.kline(bname), where, "must be a transport URL (text)")
        if url.partition("?")[0] == GATEWAY:
            if not gateway:
                raise v.err(m.kline(bname), where, "`gateway` needs a top-level gateway: section")
            out[bname] = url
            continue
        try:
            parse_url(url, kind)  # type: ignore[arg-type]
        except (TransportUrlError, ValueError) as e:
            raise v.err(m.kline(bname), where, str(e)) from None
        out[bname] = url
    return out


def _timeouts(v: Checker, top: LDict) -> dict[str, int]:
    out = dict(DEFAULT_TIMEOUTS)
    if "timeouts" in top:
        m = v.mapping(top["timeouts"], top.kline("timeouts"), "timeouts")
        v.keys(m, DEFAULT_TIMEOUTS, "timeouts")
        for k in m:
            out[k] = v.duration(m, k, "timeouts")
            if out[k] <= 0:
                raise v.err(m.kline(k), join("timeouts", k), "must be > 0")
    return out


def _drive(v: Checker, name: str, d: LDict, where: str, virtual: bool, can: dict,
           rs485: dict, process: str) -> DriveSpec:
    v.keys(d, _DRIVE, where)
    for k in _VIRTUAL_ONLY:
        if k in d and not virtual:
            raise v.err(d.kline(k), join(where, k), "only for a virtual bench (virtual: true)")
    spec = DriveSpec(name=name, line=d.line)
    spec.profile = v.text(d, "profile", where, "asda-a3")
    if spec.profile not in PROFILES:
        raise v.err(d.kline("profile"), join(where, "profile"),
                    f"{spec.profile!r}: known profiles: {', '.join(PROFILES)}")
    _drive_buses(v, spec, d, where, can, rs485)
    if process == "subprocess" and virtual:
        for kind, urls, bname in (("can", can, spec.can), ("rs485", rs485, spec.rs485)):
            if bname and _scheme_target(urls[bname])[0] == "virtual":
                raise v.err(d.kline(kind), join(where, kind),
                            "a virtual: bus is in-process only; process: subprocess needs "
                            "zenoh: or socketcan:")
    _drive_dio(v, spec, d, where, subprocess_virtual=process == "subprocess" and virtual,
               virtual=virtual)
    _drive_pulse(v, spec, d, where, subprocess_virtual=process == "subprocess" and virtual)
    if not (spec.can or spec.rs485 or spec.dio or spec.pulse):
        raise v.err(d.line, where, "a drive needs at least one of can, rs485, dio, pulse")
    _drive_lines(v, spec, d, where, virtual)
    _pulse_outputs_free(v, spec, d, where, virtual)
    if "params" in d:
        spec.params = _params(v, d["params"], d.kline("params"), join(where, "params"),
                              virtual=virtual)
    _drive_param_via(v, spec, d, where)
    _drive_model(v, spec, d, where)
    return spec


def _drive_buses(v: Checker, spec: DriveSpec, d: LDict, where: str, can: dict,
                 rs485: dict) -> None:
    """`can:` + `node_id:`, `rs485:` + `station:` + `modbus_mode:`."""
    if "can" in d:
        spec.can = v.text(d, "can", where)
        if spec.can not in can:
            raise v.err(d.kline("can"), join(where, "can"),
                        f"no CAN bus {spec.can!r} (bench `can:` has {', '.join(can) or 'none'})")
        spec.node_id = v.integer(d, "node_id", where, 1, 127)  # CiA 301 node ids
    elif "node_id" in d:
        raise v.err(d.kline("node_id"), join(where, "node_id"), "needs `can:` (a CAN bus)")
    if "rs485" in d:
        spec.rs485 = v.text(d, "rs485", where)
        if spec.rs485 not in rs485:
            raise v.err(d.kline("rs485"), join(where, "rs485"),
                        f"no RS-485 line {spec.rs485!r} (bench `rs485:` has "
                        f"{', '.join(rs485) or 'none'})")
        spec.station = v.integer(d, "station", where, 1, 0x7F)  # P3.000 1..127 (L10497)
        spec.modbus_mode = v.text(d, "modbus_mode", where, "rtu")
        if spec.modbus_mode not in ("rtu", "ascii"):
            raise v.err(d.kline("modbus_mode"), join(where, "modbus_mode"), "rtu or ascii")
    elif "station" in d:
        raise v.err(d.kline("station"), join(where, "station"), "needs `rs485:` (a line)")


def _drive_dio(v: Checker, spec: DriveSpec, d: LDict, where: str,
               subprocess_virtual: bool, virtual: bool = False) -> None:
    """`dio:` (a URL or the gateway's) and `dio_map:` (modbus-tcp only)."""
    if "dio" in d and d["dio"] == GATEWAY:
        spec.dio = GATEWAY  # from the gateway's lease (checked by parse_bench)
    elif "dio" in d:
        spec.dio = v.text(d, "dio", where)
        try:
            u = parse_url(spec.dio, "dio")
        except (TransportUrlError, ValueError) as e:
            raise v.err(d.kline("dio"), join(where, "dio"), str(e)) from None
        if subprocess_virtual and u.scheme == "virtual":
            raise v.err(d.kline("dio"), join(where, "dio"),
                        "a virtual: DI/DO set is in-process only; use zenoh: with subprocess")
        if virtual and u.scheme == "modbus-tcp":  # the harness's side of a real I/O module
            raise v.err(d.kline("dio"), join(where, "dio"),
                        "modbus-tcp is a remote I/O module on a real bench; a virtual drive's "
                        "DI/DO is virtual: or zenoh:")
        if "dio_map" in d:
            spec.dio_map = dict(v.mapping(d["dio_map"], d.kline("dio_map"), join(where, "dio_map")))
            if u.scheme != "modbus-tcp":
                raise v.err(d.kline("dio_map"), join(where, "dio_map"), "only for modbus-tcp:")
    elif "dio_map" in d:
        raise v.err(d.kline("dio_map"), join(where, "dio_map"), "needs `dio:`")


_PULSE_SOURCES = ("DOG", "NL", "PL")
# a PLC's inputs and outputs X0-X255, Y0-Y255, written as the pulse line names them (no
# leading zero: `X00` names no line the bench drives, docs/pulse.md)
_X_RE = re.compile(r"^X(0|[1-9][0-9]?|1[0-9][0-9]|2[0-4][0-9]|25[0-5])\Z")
_Y_RE = re.compile(r"^Y(0|[1-9][0-9]?|1[0-9][0-9]|2[0-4][0-9]|25[0-5])\Z")


def _drive_pulse(v: Checker, spec: DriveSpec, d: LDict, where: str,
                 subprocess_virtual: bool) -> None:
    """`pulse:` (a pulse line URL) and `pulse_wiring:` (docs/pulse.md)."""
    if "pulse" in d:
        spec.pulse = v.text(d, "pulse", where)
        try:
            u = parse_url(spec.pulse, "pulse")
        except (TransportUrlError, ValueError) as e:
            raise v.err(d.kline("pulse"), join(where, "pulse"), str(e)) from None
        if subprocess_virtual and u.scheme == "virtual":
            raise v.err(d.kline("pulse"), join(where, "pulse"),
                        "a virtual: pulse line is in-process only; use zenoh: with subprocess")
    if "pulse_wiring" in d:
        fld = join(where, "pulse_wiring")
        if not spec.pulse:
            raise v.err(d.kline("pulse_wiring"), fld, "needs `pulse:`")
        m = v.mapping(d["pulse_wiring"], d.kline("pulse_wiring"), fld)
        out: dict[str, str] = {}
        for k, val in m.items():
            val = str(val)
            if k in _PULSE_SOURCES and _X_RE.match(val):
                out[k] = val
            elif _Y_RE.match(str(k)) and re.match(r"^DI([1-9]|10)\Z", val):
                out[str(k)] = val
            else:
                raise v.err(m.kline(k), join(fld, str(k)),
                            f"{k}: {val!r}: DOG/NL/PL take a PLC input X0-X255, a PLC "
                            "output Y0-Y255 takes a drive input DI1-DI10")
            other = next((o for o, ov in out.items() if ov == val and o != k), None)
            if other is not None:  # one line, one source (helper-139: NL and DOG on X0)
                raise v.err(m.kline(k), join(fld, str(k)),
                            f"{k}: {val} is {other}'s already: one source a line")
        spec.pulse_wiring = out


def _pulse_outputs_free(v: Checker, spec: DriveSpec, d: LDict, where: str,
                        virtual: bool) -> None:
    """A PLC output `Y<n>` drives a DI line no `wiring:` function takes: the harness drives
    those itself, and two drivers on one line fight (the last edge of either wins). A virtual
    bench's pulse line without `pulse_wiring:` has the defaults (CLR Y8 on DI2)."""
    given = spec.pulse_wiring is not None
    wiring = spec.pulse_wiring if given else (
        DEFAULT_PULSE_WIRING if spec.pulse and virtual else {})
    taken = {w.line: f for f, w in spec.di.items()}
    for k, val in wiring.items():
        if not (k.startswith("Y") and val in taken):
            continue
        if given:
            raise v.err(d["pulse_wiring"].kline(k), join(join(where, "pulse_wiring"), k),
                        f"{k}: {val} carries {taken[val]} in `wiring:` (the harness drives "
                        "it): two drivers on one line; give the PLC output a line of its own")
        raise v.err(d.kline("pulse"), join(where, "pulse"),
                    f"the pulse line's default wiring puts the PLC's {k} on {val}, which "
                    f"carries {taken[val]} in `wiring:`: two drivers on one line; give "
                    f"`pulse_wiring:` with {k} on a line of its own")


def _drive_lines(v: Checker, spec: DriveSpec, d: LDict, where: str, virtual: bool) -> None:
    """`wiring:` (DI/DO functions on lines) and `sto:` (channels on lines)."""
    if "wiring" in d:
        if not spec.dio:
            raise v.err(d.kline("wiring"), join(where, "wiring"), "needs `dio:` (the lines)")
        _wiring(v, spec, v.mapping(d["wiring"], d.kline("wiring"), join(where, "wiring")),
                join(where, "wiring"), virtual)
    if "sto" in d:
        m = v.mapping(d["sto"], d.kline("sto"), join(where, "sto"))
        v.keys(m, STO_CHANNELS, join(where, "sto"))
        spec.sto = {}
        for ch, line in m.items():
            if line not in ("STO_A", "STO_B"):
                raise v.err(m.kline(ch), join(where, f"sto.{ch}"), "STO_A or STO_B")
            other = next((c for c, ln in spec.sto.items() if ln == line), None)
            if other is not None:  # two channels on one line: cutting "B" would cut A
                raise v.err(m.kline(ch), join(where, f"sto.{ch}"),
                            f"{line} already carries channel {other}: each STO channel "
                            "needs its own line")
            spec.sto[ch] = line


def _drive_param_via(v: Checker, spec: DriveSpec, d: LDict, where: str) -> None:
    """`param_via:` modbus (default with rs485) or sdo, and the bus it needs."""
    default_via = "modbus" if spec.rs485 else "sdo"
    spec.param_via = v.text(d, "param_via", where, default_via)
    if spec.param_via not in PARAM_VIAS:
        raise v.err(d.kline("param_via"), join(where, "param_via"), "modbus or sdo")
    needs = "rs485" if spec.param_via == "modbus" else "can"
    if not getattr(spec, needs):
        if spec.rs485 or spec.can:
            raise v.err(d.kline("param_via"), join(where, "param_via"),
                        f"{spec.param_via} needs {needs}")
        spec.param_via = ""


def _drive_model(v: Checker, spec: DriveSpec, d: LDict, where: str) -> None:
    """A virtual drive's `mechanics:` and model `options:`, validated by the model's own
    classes."""
    if "mechanics" in d:
        m = v.mapping(d["mechanics"], d.kline("mechanics"), join(where, "mechanics"))
        rules = virtual_rules()
        _known(v, m, rules.Mechanics, join(where, "mechanics"))
        for key, val in m.items():  # each number at its own line, before the model's rules
            if key == "brake_do" or val is None:
                continue
            if isinstance(val, bool) or not isinstance(val, int | float):
                raise v.err(m.kline(key), join(join(where, "mechanics"), key),
                            f"{val!r} is not a number{text_number_hint(val)}")
            if not abs(val) <= 1e12:  # NaN, inf, an int too long for a float (no OverflowError)
                raise v.err(m.kline(key), join(join(where, "mechanics"), key),
                            f"{str(val)[:40]} is not a finite number within ±1e12")
        try:
            rules.Mechanics.from_dict(dict(m))
        except (ValueError, TypeError) as e:
            raise v.err(m.line, join(where, "mechanics"), str(e)) from None
        spec.mechanics = dict(m)
    if "options" in d:
        m = v.mapping(d["options"], d.kline("options"), join(where, "options"))
        rules = virtual_rules()
        _known(v, m, rules.ModelOptions, join(where, "options"))
        try:
            rules.model_options(_plain(m), where=join(where, "options"))
        except (ValueError, TypeError) as e:
            raise v.err(m.line, join(where, "options"), str(e)) from None
        spec.options = _plain(m)


def _plain(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {k: _plain(x) for k, x in obj.items()}
    if isinstance(obj, list):
        return tuple(_plain(x) for x in obj)
    return obj


def _known(v: Checker, m: LDict, cls: type, where: str) -> None:
    known = {f.name for f in fields(cls)}
    v.keys(m, known, where)


def _wiring(v: Checker, spec: DriveSpec, m: LDict, where: str, virtual: bool) -> None:
    """`wiring:` FUNCTION: LINE[:b]. A virtual bench refuses a DI function its drive does not
    model; a real drive has them all."""
    used: dict[str, str] = {}
    for key, value in m.items():
        fw = join(where, key)
        kind_hint, _, func = key.rpartition(".")
        if kind_hint not in ("", "DI", "DO"):
            raise v.err(m.kline(key), fw, "write FUNCTION or DI.FUNCTION / DO.FUNCTION")
        if not isinstance(value, str) or not (mt := _LINE_RE.match(value.strip())):
            raise v.err(m.kline(key), fw,
                        f"{value!r}: a drive line like DI1, DI8:b (b-contact) or DO6")
        kind, n, contact = mt.group(1), int(mt.group(2)), mt.group(3) or "a"
        if kind_hint and kind_hint != kind:
            raise v.err(m.kline(key), fw, f"{kind_hint} function on a {kind} line")
        table = DI_SYMBOLS if kind == "DI" else DO_SYMBOLS
        if func not in table:
            raise v.err(m.kline(key), fw, f"unknown {kind} function {func!r} (manual table "
                        f"8.{1 if kind == 'DI' else 2}); known: {', '.join(sorted(table))}")
        rules = virtual_rules() if virtual else None
        inert = {} if rules is None else (
            rules.INERT_DI_FUNCTIONS if kind == "DI" else rules.INERT_DO_FUNCTIONS)
        if func in inert:  # a DI or DO function the virtual drive does not model
            raise v.err(m.kline(key), fw, f"{kind} function {func} is not modelled by the "
                        f"virtual drive: {inert[func]}")
        limit = N_PHYSICAL_DI if kind == "DI" else N_DO
        if not 1 <= n <= limit:
            raise v.err(m.kline(key), fw, f"{kind}{n}: the A3 has {kind}1..{kind}{limit}")
        line = f"{kind}{n}"
        if line in used:
            raise v.err(m.kline(key), fw, f"{line} already carries {used[line]}")
        used[line] = func
        target = spec.di if kind == "DI" else spec.do
        if func in target:
            raise v.err(m.kline(key), fw, f"{func} is already wired to {target[func].line}")
        target[func] = Wire(func, line, contact)


def _params(v: Checker, obj: Any, line: int, where: str, *, virtual: bool = False
            ) -> dict[str, int]:
    """`params:` Pn.nnn: value. With `virtual`, a mapping of a DI function the virtual drive
    does not model is refused; plans are checked against the bench later."""
    m = v.mapping(obj, line, where)
    out: dict[str, int] = {}
    for k, val in m.items():
        if not _PARAM_RE.match(k):
            raise v.err(m.kline(k), join(where, k), "a parameter name like P1.042")
        if isinstance(val, bool) or not isinstance(val, int):
            raise v.err(m.kline(k), join(where, k),
                        f"must be an integer (raw communication units), got {val!r}")
        if virtual and (why := virtual_rules().inert_mapping(k, val)):  # not modelled
            raise v.err(m.kline(k), join(where, k), f"0x{val:04X} maps {why}")
        check_param(v, m.kline(k), join(where, k), k, val, write=True)
        out[k] = val
    return out


def _safe_state(v: Checker, top: LDict, drives: dict[str, DriveSpec],
                timeouts: dict[str, int]) -> SafeState:
    safe = SafeState(timeout_ns=timeouts["safe_state"])
    if "safe_state" not in top:
        if not any("SON" in d.di for d in drives.values()):
            safe.di = {}
        return safe
    m = v.mapping(top["safe_state"], top.kline("safe_state"), "safe_state")
    v.keys(m, _SAFE, "safe_state")
    safe.controlword = v.text(m, "controlword", "safe_state", "disable_voltage")
    if safe.controlword not in CONTROLWORDS:
        raise v.err(m.kline("controlword"), "safe_state.controlword",
                    f"{safe.controlword!r}: one of {', '.join(CONTROLWORDS)}")
    if "di" in m:
        dm = v.mapping(m["di"], m.kline("di"), "safe_state.di")
        safe.di = {}
        for func, val in dm.items():
            lv = level(val)
            if lv is None:
                raise v.err(dm.kline(func), f"safe_state.di.{func}", "on or off")
            if not any(func in d.di for d in drives.values()):
                raise v.err(dm.kline(func), f"safe_state.di.{func}",
                            "no drive has this DI function in its wiring")
            safe.di[func] = lv
    if "sto" in m:
        sm = v.mapping(m["sto"], m.kline("sto"), "safe_state.sto")
        v.keys(sm, STO_CHANNELS, "safe_state.sto")
        for ch, val in sm.items():
            lv = level(val)
            if lv is None:
                raise v.err(sm.kline(ch), f"safe_state.sto.{ch}", "on or off")
            safe.sto[ch] = lv
    safe.wait_brake = v.boolean(m, "wait_brake", "safe_state", True)
    if safe.wait_brake and not any("BRKR" in d.do for d in drives.values()):
        raise v.err(m.kline("wait_brake"), "safe_state.wait_brake",
                    "no drive has BRKR in its wiring, so the brake cannot be watched")
    safe.timeout_ns = v.duration(m, "timeout", "safe_state", timeouts["safe_state"])
    if safe.timeout_ns <= 0:  # no time to see the brake engage: never confirmed
        raise v.err(m.kline("timeout"), "safe_state.timeout", "must be > 0")
    return safe


__all__ = [
    "DEFAULT_TIMEOUTS",
    "Bench",
    "DriveSpec",
    "PlanFileError",
    "SafeState",
    "Wire",
    "builtin_bench_path",
    "load_bench",
    "loads_bench",
    "parse_bench",
]
