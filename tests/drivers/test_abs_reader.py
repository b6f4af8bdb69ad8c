"""Host-side absolute reader against the model on the injected clock (L16460-16521)."""

from __future__ import annotations

import pytest

from hil.drivers.abs_reader import (
    AbsChecksumError,
    AbsPositionReader,
    AbsReadError,
    AbsTimingError,
    checksum,
)
from hil.model.absolute import COUNTS_PER_REV, AbsoluteEncoder, AbsoluteOptions, build_frame
from hil.model.timebase import Scheduler, ms
from hil.units import MS
from hil.virtual.model_lines import ModelLines

REV = COUNTS_PER_REV


class Params:
    def __init__(self, **values: int) -> None:
        self.values = {
            "P0.049": 0, "P0.050": 0, "P0.051": 0, "P0.052": 0,
            "P1.001": 0, "P1.044": 16777216, "P1.045": 100000, "P6.001": 0,
            "P2.008": 0, "P2.009": 2, "P2.069": 1, "P2.070": 0, "P2.071": 0,
        }  # fmt: skip
        self.values.update({k.replace("_", "."): v for k, v in values.items()})

    def get(self, name: str) -> int:
        return self.values[name]

    def cached(self, *names: str):
        return lambda: tuple(self.values[n] for n in names)

    def set_internal(self, name: str, value: int) -> None:
        self.values[name] = value

    def on_write(self, name: str, fn) -> None:
        pass


class Bench:
    """Encoder + a fake DigitalIO: P2.009 filter on inputs, DI4/DO2/DO3 overlay, a-contacts.

    Lines: DI9 = ABSE (0x1D), DI10 = ABSC (0x1F), DI4 = ABSQ under the overlay, DO2 = ABSR,
    DO3 = ABSD (overlay), DO4 = ABSW (0x0D), as bound in fixtures/timing/abs_*.yaml.
    Records line levels and alarms as the recorder topics the timing checker reads.
    """

    def __init__(self, options: AbsoluteOptions | None = None, **params: int) -> None:
        self.sched = Scheduler()
        self.params = Params(**params)
        self.causes: dict[str, bool] = {}
        self.functions: dict[str, bool] = {}
        self.overlay = False
        self.di4 = False  # filtered DI4 level as the drive sees it
        self.messages: dict[str, list[tuple[int, dict]]] = {}
        self._levels: dict[str, bool] = {}
        self.enc = AbsoluteEncoder(
            self.sched,
            self.params,
            set_cause=self._cause,
            set_output=self._function,
            set_overlay=self._set_overlay,
            read_absq=lambda: self.di4,
            options=options,
        )
        self.enc.on_motor_position(0)
        for line in ("DI4", "DI9", "DI10"):  # initial levels, as the recorder publishes them
            self._record(f"/dio/drive1/{line}", {"level": False})
        self.advance_to(10 * MS)  # start after the initial samples
        self.lines = ModelLines(
            now=lambda: self.sched.now,
            advance_to=self.advance_to,
            write=self._write,
            read=self._read,
            next_deadline=self.sched.next_deadline,
        )

    def _record(self, topic: str, payload: dict) -> None:
        self.messages.setdefault(topic, []).append((self.sched.now, payload))

    def _outputs_changed(self) -> None:
        for line in ("DO2", "DO3", "DO4"):
            level = self._read(line)
            if self._levels.get(line) != level:
                self._levels[line] = level
                self._record(f"/dio/drive1/{line}", {"level": level})

    def _cause(self, code: str, present: bool) -> None:
        self.causes[code] = present
        self._record("/drive/drive1/state", {"alarms": sorted(self.active())})

    def _function(self, symbol: str, active: bool) -> None:
        self.functions[symbol] = active
        self._outputs_changed()

    def _set_overlay(self, on: bool) -> None:
        self.overlay = on
        self._outputs_changed()

    def _write(self, line: str, level: bool) -> None:
        self._record(f"/dio/drive1/{line}", {"level": level})
        delay = ms(self.params.get("P2.009"))  # DI filter (L9229)
        self.sched.after(delay, lambda: self._deliver(line, level))

    def _deliver(self, line: str, level: bool) -> None:
        if line == "DI9":
            self.enc.on_abse(level)
        elif line == "DI10":
            self.enc.on_absc(level)
        elif line == "DI4":
            self.di4 = level
            if self.overlay:
                self.enc.on_absq(level)

    def _read(self, line: str) -> bool:
        if line == "DO2":
            return self.overlay and self.functions.get("ABSR", False)
        if line == "DO3":
            return self.overlay and self.functions.get("ABSD", False)
        if line == "DO4":
            return self.functions.get("ABSW", False)
        raise KeyError(line)

    def advance_to(self, t: int) -> None:
        while (nd := self.sched.next_deadline()) is not None and nd <= t:
            self.sched.now = max(nd, self.sched.now)
            self.sched.run_due()
        self.sched.now = max(t, self.sched.now)

    def reader(self, lines=None, **kw) -> AbsPositionReader:
        kw.setdefault("absw", "DO4")
        return AbsPositionReader(
            lines or self.lines, abse="DI9", absc="DI10", clock=self.lines.clock, **kw
        )

    def ready(self, counts: int) -> None:
        """Origin at 0, then move the motor to `counts`."""
        self.enc.establish_origin()
        self.enc.on_motor_position(counts)

    def active(self) -> set[str]:
        return {c for c, p in self.causes.items() if p}


class LateLines:
    """Wraps lines: the host answers `late_ms` late (ABSQ on) for bit `bit` of the first try."""

    def __init__(self, bench: Bench, bit: int, late_ms: float, times: int = 1) -> None:
        self.b = bench
        self.inner = bench.lines
        self.clock = bench.lines.clock
        self.bit, self.late_ms, self.times = bit, late_ms, times
        self.acks = 0

    def set(self, line: str, level: bool) -> None:
        if line == "DI4" and level and self.b.overlay:
            if self.acks == self.bit and self.times > 0:
                self.times -= 1
                self.clock.sleep(self.late_ms / 1000)
            self.acks += 1
        if line == "DI9" and not level:
            self.acks = 0
        self.inner.set(line, level)

    def get(self, line: str) -> bool:
        return self.inner.get(line)

    def wait_for(self, line: str, level: bool, timeout_s: float):
        return self.inner.wait_for(line, level, timeout_s)


def test_reader_checksum_matches_model():
    for words in [(0, 0, 0, 0), (0x1F, 0xFFFF, 0x1234, 0xABCD), (4, 1, 2, 3)]:
        frame = build_frame(words[0], words[1], words[2] | (words[3] << 16))
        assert checksum(*words) == frame >> 64


@pytest.mark.parametrize(
    ("counts", "turns", "pulses"),
    [
        (3 * REV + 1234, 3, 1234),
        (-REV - 5, -2, REV - 5),
        (-32768 * REV, -32768, 0),
        (32768 * REV + 7, -32768, 7),  # wrapped past 32767 (L16404); status has overflow
    ],
)
def test_read_pulse_unit(counts, turns, pulses):
    b = Bench(P2_070=0x1 | 0x4)  # DI/DO unit pulse; overflow warning off so ABSW stays low
    b.ready(counts)
    r = b.reader().read()
    assert (r.turns, r.position) == (turns, pulses)
    assert r.status == b.enc.status
    assert r.attempts == 1 and r.violations == ()
    assert len(r.timings) == 80
    t0 = r.timings[0]
    assert t0.t_q_ns == 6 * MS and t0.t_n_ns == 6 * MS  # P2.009 + 4 ms (L16495-16499)
    # the pins go back when the drive sees ABSE off, the end of the cycle (L16519): ABSR
    # stays the pin's until then, so the last ABSR off shows whatever DO2's own function is
    assert b.overlay and not b.lines.get("DO2")
    b.advance_to(b.sched.now + 3 * MS)  # ABSE off through the P2.009 filter (2 ms)
    assert not b.overlay and not b.lines.get("DO2")  # pins back, ABSE dropped


def test_read_puu_unit_negative():
    b = Bench(P6_001=-250)
    b.ready(-7 * REV - REV // 2)
    r = b.reader().read()
    assert (r.status, r.turns, r.position) == (0, 0, -750000 - 250)  # bits 31-16 = 0 (L16468)


def test_read_msb_first_both_sides():
    b = Bench(options=AbsoluteOptions(bit_order="msb_first"), P2_070=1)
    b.ready(11 * REV + 3)
    r = b.reader(bit_order="msb_first").read()
    assert (r.turns, r.position) == (11, 3)


def test_late_host_gets_absw_and_the_retry_succeeds():
    b = Bench(P2_070=1)
    b.ready(-2 * REV + 99)
    lines = LateLines(b, bit=5, late_ms=250)
    r = b.reader(lines).read()
    assert r.attempts == 2 and (r.turns, r.position) == (-2, 99)
    assert "bit 5: ABSW on" in r.errors[0]
    assert b.causes["AL068"] is False  # raised, then ABSE off (the manager latches it)
    assert r.t_abse > 250 * MS  # the second attempt, after ABSE off and T_B


@pytest.mark.parametrize(("late_ms", "attempts"), [(200.0, 1), (200.001, 2)])
def test_t_r_boundary(late_ms, attempts):
    b = Bench(P2_070=1)
    b.ready(REV)
    r = b.reader(LateLines(b, bit=7, late_ms=late_ms)).read()
    assert r.attempts == attempts  # "exceeds 200 ms" -> ABSW (L19789)
    assert r.violations == ()


def test_late_host_without_absw_line_retries_on_missing_absr():
    b = Bench(P2_070=1)
    b.ready(REV + 1)
    lines = LateLines(b, bit=0, late_ms=300)
    r = b.reader(lines, absw=None).read()
    assert r.attempts == 2 and "no ABSR rise" in r.errors[0]


def test_retries_exhausted_names_every_attempt():
    b = Bench()
    b.ready(0)
    lines = LateLines(b, bit=3, late_ms=250, times=5)
    with pytest.raises(AbsReadError, match=r"after 2 attempts.*attempt 1.*attempt 2"):
        b.reader(lines, retries=1).read()


def test_warning_blocks_the_handshake():
    b = Bench()  # AL06A: first use, no origin (L16391)
    with pytest.raises(AbsReadError, match="L16521"):
        b.reader(retries=0).read()


def test_origin_by_dido_then_read():
    b = Bench(P6_001=12345)
    b.enc.on_motor_position(5 * REV + 17)
    assert "AL06A" in b.active()
    b.reader().set_origin()
    assert b.active() == set()
    r = b.reader().read()
    assert (r.status, r.turns, r.position) == (0, 0, 12345)  # PUU = P6.001 (L16441)


def test_origin_by_dido_held_too_short_is_ignored():
    b = Bench()
    b.reader().set_origin(hold_ms=1)
    assert "AL06A" in b.active()


def test_dev_bad_checksum_fails_the_check():
    b = Bench(options=AbsoluteOptions(dev_bad_checksum=True), P2_070=1)
    b.ready(3 * REV)
    with pytest.raises(AbsChecksumError) as exc:
        b.reader().read()
    assert exc.value.expected == exc.value.received ^ 1
    assert "expected 0x" in str(exc.value) and "received 0x" in str(exc.value)


def test_dev_swapped_bit_order_fails_the_check():
    b = Bench(options=AbsoluteOptions(dev_swap_bit_order=True), P2_070=1)
    b.ready(3 * REV + 5)
    with pytest.raises(AbsChecksumError):
        b.reader().read()


def test_dev_no_t_r_is_reported_as_a_timing_violation():
    b = Bench(options=AbsoluteOptions(dev_no_t_r=True), P2_070=1)
    b.ready(REV)
    r = b.reader(LateLines(b, bit=2, late_ms=250)).read()
    assert r.attempts == 1 and len(r.violations) == 1
    assert "bit 2: host answered 250.000 ms" in r.violations[0]
    with pytest.raises(AbsTimingError, match="did not raise ABSW"):
        b.reader(LateLines(b, bit=2, late_ms=250), strict_timing=True).read()


def test_slow_drive_t_q_out_of_window():
    b = Bench(options=AbsoluteOptions(t_q_margin_ms=15), P2_070=1)  # T_Q = 17 ms > 12 ms
    b.ready(REV)
    r = b.reader().read()
    assert r.violations and "T_Q 17.000 ms > max 12 ms" in r.violations[0]
    with pytest.raises(AbsTimingError):
        b.reader(strict_timing=True).read()
    with pytest.raises(AbsReadError, match="no ABSR rise within T_Q max"):
        b.reader(io_slack_ms=1, retries=0).read()


def test_bad_reader_arguments():
    b = Bench()
    with pytest.raises(ValueError, match="bit_order"):
        b.reader(bit_order="x")
    with pytest.raises(ValueError, match=r"P2\.009"):
        b.reader(p2009_ms=30)
    with pytest.raises(ValueError, match="ABSC"):
        AbsPositionReader(b.lines, clock=b.lines.clock).set_origin()


# -- the timing specs fixtures/timing/abs_*.yaml on a recorded model run ----------------------


def _verdicts(b: Bench, name: str) -> dict[str, set[str]]:
    from hil.paths import fixture
    from hil.timing.checker import check
    from hil.timing.source import MemorySource
    from hil.timing.spec import load_spec

    spec = load_spec(fixture("timing") / f"{name}.yaml")
    out: dict[str, set[str]] = {}
    for v in check(spec, MemorySource(b.messages), params={"P2.009": 2}):
        out.setdefault(v.constraint, set()).add(v.status)
    return out


def test_handshake_spec_passes_on_a_faithful_read():
    b = Bench(P2_070=1)
    b.ready(-3 * REV + 5)
    b.reader().read()
    got = _verdicts(b, "abs_handshake")
    for rule in ("T_Q", "T_N", "T_R"):
        (name,) = [n for n in got if n.startswith(rule)]
        assert "pass" in got[name]
    assert all(s <= {"pass", "skipped"} for s in got.values()), got


def test_handshake_spec_late_host_and_the_absw_rules():
    b = Bench(P2_070=1)
    b.ready(REV)
    b.reader(LateLines(b, bit=4, late_ms=250)).read()
    got = _verdicts(b, "abs_handshake")
    assert "fail" in got["T_R - host raises ABSQ within 200 ms of ABSR on"]  # the host's fault
    assert got["ABSW when T_R passes without ABSQ on"] == {"pass"}
    assert got["ABSE off clears ABSW"] == {"pass"}
    assert got["host waits T_B before restarting"] == {"pass"}


def test_handshake_spec_catches_dev_no_t_r():
    b = Bench(options=AbsoluteOptions(dev_no_t_r=True), P2_070=1)
    b.ready(REV)
    b.reader(LateLines(b, bit=4, late_ms=250)).read()
    got = _verdicts(b, "abs_handshake")
    assert got["ABSW when T_R passes without ABSQ on"] == {"fail"}


def test_handshake_spec_catches_a_slow_t_q():
    b = Bench(options=AbsoluteOptions(t_q_margin_ms=15), P2_070=1)
    b.ready(REV)
    b.reader().read()
    assert "fail" in _verdicts(b, "abs_handshake")["T_Q - ABSR on after each request"]


def test_origin_spec():
    b = Bench()
    b.reader().set_origin()
    got = _verdicts(b, "abs_origin")
    assert all(s == {"pass"} for s in got.values()), got
    b2 = Bench()
    b2.reader().set_origin(hold_ms=1)  # too short: host rule fails, no origin
    got = _verdicts(b2, "abs_origin")
    assert got["host holds ABSC for T_Q"] == {"fail"}
    assert got["origin set within P2.009 + 250 ms of ABSC on"] == {"fail"}


def test_wired_to_the_real_parameter_store_and_digital_io():
    """The wiring the Drive uses: DigitalIO functions and overlay, P2.009 filter in DigitalIO."""
    from hil.model.dio import DigitalIO
    from hil.model.params import ParameterStore

    sched = Scheduler()
    store = ParameterStore()
    for name, value in {
        "P2.069": 1, "P2.070": 1,
        "P2.013": 0, "P2.019": 0, "P2.020": 0,  # DI4/DO2/DO3 idle, as L16504 suggests
        "P2.021": 0x010D,  # DO4 = ABSW, a-contact
        "P2.036": 0x011D,  # DI9 = ABSE
        "P2.037": 0x011F,  # DI10 = ABSC
    }.items():  # fmt: skip
        store.write(name, value)
    store.power_cycle()
    dio = DigitalIO(store, sched)
    causes: dict[str, bool] = {}
    enc = AbsoluteEncoder(
        sched,
        store,
        set_cause=causes.__setitem__,
        set_output=dio.set_do_function,
        set_overlay=lambda on: dio.overlay() if on else dio.clear_overlay(),
        read_absq=lambda: dio.function_active("ABSQ"),
    )
    for fn, handler in (("ABSE", enc.on_abse), ("ABSC", enc.on_absc), ("ABSQ", enc.on_absq)):
        dio.on_function(fn, handler)
    enc.on_motor_position(0)

    def advance_to(t: int) -> None:
        while (nd := sched.next_deadline()) is not None and nd <= t:
            sched.now = max(nd, sched.now)
            sched.run_due()
        sched.now = max(t, sched.now)

    lines = ModelLines(
        now=lambda: sched.now,
        advance_to=advance_to,
        write=lambda line, level: dio.set_input(int(line[2:]), level),
        read=lambda line: dio.do_level(int(line[2:])),
        next_deadline=sched.next_deadline,
    )
    reader = AbsPositionReader(lines, abse="DI9", absc="DI10", absw="DO4", clock=lines.clock)
    assert causes["AL06A"]
    reader.set_origin()
    assert not causes["AL06A"]
    enc.on_motor_position(-4 * REV + 321)
    r = reader.read()
    assert (r.status, r.turns, r.position, r.attempts) == (0, -4, 321, 1)
    assert r.timings[0].t_q_ns == 6 * MS and r.violations == ()
