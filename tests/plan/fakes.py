"""A stand-in drive side for runner tests (not the model): DI/DO over a virtual DIO board,
parameters in a dict. SON (DI1) -> BRKR (DO6) after P1.042 ms, like §2.9 in spirit. Its
timer runs on the bench's clock (`hil.clock.call_later`), so the same fake serves a run in
virtual time and one in real time."""

from __future__ import annotations

from typing import Any

from hil import clock
from hil.plan.session import DriveIO, Session
from hil.transport.dio import open_dio
from hil.virtual.world import resolve_auto


class FakeParams:
    def __init__(self) -> None:
        self.values: dict[str, int] = {"P1.042": 0, "P0.001": 0}

    def read_param(self, name: str) -> int:
        return self.values.get(name, 0)

    def write_param(self, name: str, value: int) -> None:
        self.values[name] = value


class FakeDriveSide:
    def __init__(self, url: str, params: FakeParams, *, break_brake: bool = False) -> None:
        self.params = params
        self.break_brake = break_brake
        self.port = open_dio(url, role="drive", name="fake-drive")
        self.port.set("DO1", True)  # SRDY
        self.port.set("DO6", False)  # BRKR off: brake engaged
        self.port.set("FDBK", False)
        self.timers: list[Any] = []  # threading.Timer or virtual-clock events
        self.port.subscribe(self._on)

    def _on(self, line: str, level: bool, t: int) -> None:
        if line != "DI1":
            return
        if self.break_brake and not level:
            return  # a broken drive that never engages the brake
        delay = self.params.values.get("P1.042", 0) / 1000 if level else 0
        self.timers.append(clock.call_later(delay, self.port.set, "DO6", level))

    def close(self) -> None:
        for tm in self.timers:
            tm.cancel()
        self.port.close()


class FakeWorld:
    def __init__(self, bench: Any, tmp: Any, **kw: Any) -> None:
        self.urls = resolve_auto(bench, tmp)
        self.params = FakeParams()
        self.sides = {n: FakeDriveSide(self.urls[f"dio:{n}"], self.params, **kw)
                      for n in bench.drives}
        self.injected: list = []

    def power_cycle(self, drive: str, battery: bool = True, off_ns: int = 0) -> None:
        self.params.values["P0.001"] = 0

    def inject(self, drive: str, options: Any = None, alarm: str | None = None) -> None:
        self.injected.append((options, alarm))
        if alarm:
            self.params.values["P0.001"] = int(alarm[2:], 16)

    def close(self) -> None:
        for s in self.sides.values():
            s.close()


def fake_session_factory(tmp: Any, **kw: Any):
    def factory(bench: Any, rec: Any) -> Session:
        world = FakeWorld(bench, tmp, **kw)
        s = Session(bench, rec, world)
        for name, spec in bench.drives.items():
            dio = open_dio(world.urls[f"dio:{name}"], role="harness", tap=rec, name=name)
            s._closers.append(dio.close)
            s.drives[name] = DriveIO(spec, bench, dio=dio, modbus=world.params)
        return s

    return factory


FAKE_BENCH = """\
name: fake
virtual: true
rs485: {rs485: "pty:auto"}
drives:
  drive1:
    rs485: rs485
    station: 1
    dio: "virtual:auto"
    wiring: {SON: DI1, ARST: DI5, EMGS: "DI8:b", SRDY: DO1, BRKR: DO6}
timeouts: {step: 5s, wait_until: 1s, safe_state: 500ms}
safe_state: {controlword: disable_voltage, di: {SON: off}, wait_brake: true, timeout: 500ms}
"""
