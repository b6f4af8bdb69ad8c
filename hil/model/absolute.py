"""Absolute encoder, chapter 10 (L16100-16575): multi-turn position, origin setting,
P0.049-P0.052, the 80-bit DI/DO handshake (ABSE/ABSQ/ABSR/ABSD/ABSW) and battery memory.

The encoder knows no other model module. The Drive injects what it needs:

* `scheduler` (hil.model.timebase.Scheduler) for T_S/T_Q/T_N/T_R and the P0.049 latch;
* `params` with `get(name)`, `set_internal(name, value)`, `on_write(name, fn(name, old, new))`;
* `set_cause(code, present)`: an alarm cause appeared / went away ("AL06A", ...); the alarm
  manager decides latching and clearing from the chapter 13 table;
* `set_output(symbol, active)`: DO *functions* "ABSR", "ABSD", "ABSW" (the DigitalIO maps
  them to lines and applies a/b contacts);
* `set_overlay(active)`: switch DI4/DO2/DO3 to ABSQ/ABSR/ABSD and back (L16504, L16519).

Inputs are DI *functions* (already a/b-contact resolved): `on_abse`, `on_absc`, `on_absq`,
and the motor position in encoder counts, CCW positive as the encoder counts (L16404).
Choices (⚠ in the manual) are options of `AbsoluteOptions`; see docs/manual-choices.md#absolute.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, fields
from typing import Any, Protocol

from hil.model.errors import ModelError
from hil.model.timebase import Scheduler, Timer, ms

COUNTS_PER_REV = 16_777_216  # single-turn resolution 0 ~ 16777215 (L16406)
TURNS_MIN, TURNS_MAX = -32768, 32767  # multi-turn range, wraps (L16404)
PUU_MIN, PUU_MAX = -(2**31), 2**31 - 1  # L16417 (its upper bound 2147438647 is a misprint)
FRAME_BITS = 80  # bit 0 ~ bit 79 (L16464-16486, L16519)

# P0.050 status bits (L7493-7516)
STATUS_LOST = 0x01  # bit0 absolute position lost
STATUS_BATTERY_LOW = 0x02  # bit1 battery low
STATUS_TURN_OVERFLOW = 0x04  # bit2 turns overflow
STATUS_PUU_OVERFLOW = 0x08  # bit3 PUU overflow
STATUS_NOT_ESTABLISHED = 0x10  # bit4 coordinate not yet established

BATTERY_LOW_V = 3.1  # AL061 below 3.1 V, clears by itself (L16379, L19769-19773)
BATTERY_LOSS_V = 2.45  # data lost below 2.45 V (L16381, L19761)
BATTERY_OVER_V = 3.8  # AL028 above 3.8 V (L19639-19640)
BATTERY_MONITOR = 38  # monitor 038 (26h): battery voltage (L15477)

# Checksum constants (L16476-16486)
_CS_K = (0xA700, 0x605A, 0x30A5, 0x5A06)

COORDINATE_STATES = ("unset", "valid", "lost")
BIT_ORDERS = ("lsb_first", "msb_first")


class AbsoluteError(ModelError):
    """Bad option or persisted state of the absolute encoder (names the field and the rule)."""


# -- frame and checksum (pure functions, also used by tests and the timing room) -----------


def checksum(w0: int, w1: int, w2: int, w3: int) -> int:
    """CS = ((((((W0 + 0xA700) ^ W1) + 0x605A) ^ W2) + 0x30A5) ^ W3) + 0x5A06, 16-bit unsigned.

    W0 = status (bits 15-0), W1 = turns (31-16), W2/W3 = position bits 47-32 / 63-48
    (L16476-16486). Truncating at the end equals truncating each step: XOR with 16-bit words
    never touches the carries above bit 15. All-zero words give 0x9205.
    """
    for name, w in (("W0", w0), ("W1", w1), ("W2", w2), ("W3", w3)):
        if not 0 <= w <= 0xFFFF:
            raise AbsoluteError(f"checksum word {name} = {w} is not a 16-bit unsigned value")
    cs = w0 + _CS_K[0]
    cs = ((cs ^ w1) + _CS_K[1]) & 0xFFFF
    cs = ((cs ^ w2) + _CS_K[2]) & 0xFFFF
    cs = ((cs ^ w3) + _CS_K[3]) & 0xFFFF
    return cs


def frame_words(status: int, turns: int, position: int) -> tuple[int, int, int, int]:
    """The four 16-bit data words of a frame (turns and position as two's complement)."""
    pos = position & 0xFFFF_FFFF
    return status & 0xFFFF, turns & 0xFFFF, pos & 0xFFFF, pos >> 16


def build_frame(status: int, turns: int, position: int, *, bad_checksum: bool = False) -> int:
    """80-bit frame value: checksum(79-64) | position(63-32) | turns or 0(31-16) | status(15-0)."""
    w0, w1, w2, w3 = frame_words(status, turns, position)
    cs = checksum(w0, w1, w2, w3)
    if bad_checksum:
        cs ^= 0x0001  # deviation knob dev_bad_checksum
    return w0 | (w1 << 16) | (w2 << 32) | (w3 << 48) | (cs << 64)


def split_frame(frame: int) -> tuple[int, int, int, int]:
    """(status, turns signed 16, position signed 32, checksum) of an 80-bit frame value."""
    status = frame & 0xFFFF
    turns = _signed((frame >> 16) & 0xFFFF, 16)
    position = _signed((frame >> 32) & 0xFFFF_FFFF, 32)
    return status, turns, position, (frame >> 64) & 0xFFFF


def frame_bits(frame: int, order: str = "lsb_first") -> list[int]:
    """The 80 bits in transfer order (lsb_first: bit 0 first)."""
    bits = [(frame >> i) & 1 for i in range(FRAME_BITS)]
    return bits if order == "lsb_first" else bits[::-1]


def _signed(value: int, width: int) -> int:
    half = 1 << (width - 1)
    return value - (1 << width) if value & half else value


def _wrap(value: int, width: int) -> int:
    return _signed(value & ((1 << width) - 1), width)


def _trunc_div(a: int, b: int) -> int:
    q = abs(a) // abs(b)
    return q if (a >= 0) == (b > 0) else -q


# -- options and persisted memory -----------------------------------------------------------


@dataclass(frozen=True)
class AbsoluteOptions:
    """Choices (manual gaps, ⚠) and deviation knobs (`dev_`) of the absolute encoder."""

    motor_absolute: bool = True  # ECM-A3..Y absolute motor; False + P2.069.X=1 -> AL069 (L16123)
    # P1.001.Z value meaning "CW is the positive direction"; any other Z = CCW positive.
    # The encoding is only in a missing figure (L7805); 1 = CW as on the ASDA-A2.
    cw_positive_z: int = 1
    # Drive timings as P2.009 + margin (ms). Manual window P2.009+2 .. P2.009+10 (L16495-16499).
    t_s_margin_ms: float = 4.0
    t_q_margin_ms: float = 4.0
    t_n_margin_ms: float = 4.0
    t_r_ms: float = 200.0  # max wait for ABSQ on after ABSR on (L16497, L19789)
    # ABSC held P2.009 + margin -> origin; manual min P2.009+2, max P2.009+250 (L16448-16450).
    origin_hold_margin_ms: float = 2.0
    origin_max_rpm: float = 200.0  # clear command above this -> AL07C (L19855-19859)
    # The DigitalIO applies the P2.009 filter before calling on_abse/on_absq/on_absc; the
    # encoder then shortens its timers so the windows hold at the terminals.
    di_filtered_upstream: bool = True
    bit_order: str = "lsb_first"  # bit 0 first (gap, L16519)
    absd_one_active: bool = True  # bit value 1 = ABSD on (gap)
    # ABSW on while any of these is present; the handshake is refused then (L15294, L16521).
    absw_warnings: tuple[str, ...] = ("AL060", "AL061", "AL062", "AL289", "AL06A")
    block_handshake_on_warning: bool = True
    p0049_ready_ms: float = 1.0  # P0.049 -> 0 and P0.050-P0.052 filled after this (L7477-7491)
    p2071_returns_to_zero: bool = True  # P2.071 reads 0 after the reset (gap, L10074-10081)
    # --- deviations ---
    dev_bad_checksum: bool = False  # frame checksum off by one bit
    dev_no_t_r: bool = False  # late ABSQ never raises ABSW / AL068
    dev_swap_bit_order: bool = False  # send the frame in the other bit order

    def __post_init__(self) -> None:
        if self.bit_order not in BIT_ORDERS:
            raise AbsoluteError(
                f"absolute option bit_order: one of {', '.join(BIT_ORDERS)}, got {self.bit_order!r}"
            )
        for name in (
            "t_s_margin_ms",
            "t_q_margin_ms",
            "t_n_margin_ms",
            "t_r_ms",
            "origin_hold_margin_ms",
            "p0049_ready_ms",
        ):
            if getattr(self, name) < 0:
                raise AbsoluteError(f"absolute option {name}: must be >= 0 ms")
        if not 0 <= self.cw_positive_z <= 0xF:
            raise AbsoluteError("absolute option cw_positive_z: one hex digit 0..F (P1.001.Z)")
        object.__setattr__(self, "absw_warnings", tuple(self.absw_warnings))

    @classmethod
    def from_dict(cls, data: Mapping[str, Any] | None) -> AbsoluteOptions:
        """From a bench file's `options.extra.absolute` mapping; unknown keys are an error."""
        data = dict(data or {})
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise AbsoluteError(
                f"unknown absolute option(s) {', '.join(unknown)};"
                f" known: {', '.join(sorted(known))}"
            )
        return cls(**data)

    @property
    def send_order(self) -> str:
        if not self.dev_swap_bit_order:
            return self.bit_order
        return "msb_first" if self.bit_order == "lsb_first" else "lsb_first"


@dataclass
class EncoderMemory:
    """What the battery keeps across a power cycle (and `hil drive` keeps in its state file)."""

    pulse_value: int = 0  # m x 16777216 + pulse, relative to the origin, CCW positive (L16406)
    coordinate: str = "unset"  # unset (AL06A) / valid / lost (AL060)
    turn_overflow: bool = False  # sticky until a new origin (L16404)
    puu_overflow: bool = False  # sticky until a new origin (L16417)
    al07c: bool = False  # clear command refused at speed (L19855)
    al07d: bool = False  # power cycled with AL07C pending (L19861)
    battery_v: float = 3.6  # ER14505 nominal (L16165)

    def to_dict(self) -> dict[str, Any]:
        return {"format": "hil.absolute/1", **asdict(self)}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> EncoderMemory:
        if not isinstance(data, Mapping):
            raise AbsoluteError(f"absolute state: expected a mapping, got {type(data).__name__}")
        if data.get("format", "hil.absolute/1") != "hil.absolute/1":
            raise AbsoluteError(f"absolute state: unknown format {data.get('format')!r}")
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known - {"format"})
        if unknown:
            raise AbsoluteError(f"absolute state: unknown key(s) {', '.join(unknown)}")
        mem = cls()
        for f in fields(cls):
            if f.name not in data:
                continue
            value = data[f.name]
            want = type(getattr(mem, f.name))
            if want is float and isinstance(value, int) and not isinstance(value, bool):
                value = float(value)
            if type(value) is not want:
                raise AbsoluteError(
                    f"absolute state: {f.name} must be {want.__name__}, got {value!r}"
                )
            setattr(mem, f.name, value)
        if mem.coordinate not in COORDINATE_STATES:
            raise AbsoluteError(
                f"absolute state: coordinate must be one of {', '.join(COORDINATE_STATES)},"
                f" got {mem.coordinate!r}"
            )
        return mem


class Params(Protocol):
    def get(self, name: str) -> int: ...
    def cached(self, *names: str) -> Callable[[], tuple[int, ...]]: ...
    def set_internal(self, name: str, value: int) -> None: ...
    def on_write(self, name: str, fn: Callable[[str, int, int], None]) -> Any: ...


# Handshake states (drive side)
IDLE, WAIT_TS, BLOCKED, READY, PREP, WAIT_ACK, ACK, DONE, ERROR = (
    "idle",
    "wait_ts",
    "blocked",
    "ready",
    "prep",
    "wait_ack",
    "ack",
    "done",
    "error",
)


class AbsoluteEncoder:
    """The absolute encoder and the drive's absolute-system functions (chapter 10)."""

    WATCHED_PARAMS = ("P0.049", "P2.070", "P2.071")

    def __init__(
        self,
        scheduler: Scheduler,
        params: Params,
        *,
        set_cause: Callable[[str, bool], None],
        set_output: Callable[[str, bool], None],
        set_overlay: Callable[[bool], None] = lambda active: None,
        clear_position_error: Callable[[], None] | None = None,
        speed_rpm: Callable[[], float] | None = None,
        motor_counts: Callable[[], int] | None = None,
        read_absq: Callable[[], bool] | None = None,
        options: AbsoluteOptions | None = None,
        memory: EncoderMemory | None = None,
        hook_params: bool = True,
        clear_alarm: Callable[[str], None] | None = None,
    ) -> None:
        self.scheduler = scheduler
        self.on_origin: Callable[[], None] | None = None  # ABSC / P2.071 origin set
        self.params = params
        self._puu_params = params.cached("P1.045", "P1.044", "P1.001", "P6.001")  # each step
        self._safe_for: tuple[int, ...] | None = None  # the values `_safe_pulse` is for
        self._safe_pulse = -1.0
        self.options = options or AbsoluteOptions()
        self.mem = memory or EncoderMemory()
        self._set_cause = set_cause
        self._clear_alarm = clear_alarm  # ends a "special" alarm whose procedure is done
        self._set_output = set_output
        self._set_overlay = set_overlay
        self._clear_position_error = clear_position_error
        self._speed_rpm = speed_rpm
        self._motor_counts = motor_counts
        self._read_absq = read_absq
        self._causes: dict[str, bool] = {}
        self._outputs: dict[str, bool] = {}
        self._last_counts: int | None = None
        self._abse = self._absq = self._absc = False
        self._armed = False  # ABSE on and T_S elapsed (ABSC allowed, L16440)
        self._overlay = False
        self.state = IDLE
        self.bit = 0  # index of the bit being transferred
        self.last_error = ""
        self.last_frame: int | None = None
        self._bits: list[int] = []
        self._timer: Timer | None = None
        self._origin_timer: Timer | None = None
        self._latch_timer: Timer | None = None
        self._hs_error = False
        self.enabled = False  # P2.069.X = 1 at the last power-up, on an absolute motor
        self._p2069x = 0
        if hook_params:
            for name in self.WATCHED_PARAMS:
                params.on_write(name, self.on_param_write)
        self._power_up(battery=True)

    # -- position ---------------------------------------------------------------------------

    def on_motor_position(self, counts: int) -> None:
        """Motor position in encoder counts, positive in the drive's positive direction. The
        encoder counts the difference CCW positive (L16404-16406): with P1.001.Z = CW positive
        (L16413, "馬達的正旋轉方向是由 P1.001.Z 定義") a positive move is CW and counts down, so
        the PUU formula's -1 (L16410) gives the same sign as 6064h."""
        if self._last_counts is not None:
            d = counts - self._last_counts
            if (self._puu_params()[2] >> 8) & 0xF == self.options.cw_positive_z:
                d = -d
            self.mem.pulse_value += d
        self._last_counts = counts
        self._check_overflow()

    def refresh(self) -> None:
        """Pull the motor position from the `motor_counts` getter, if one was given."""
        if self._motor_counts is not None:
            self.on_motor_position(int(self._motor_counts()))

    @property
    def turns(self) -> int:
        """Multi-turn value as the encoder reports it, wrapped to -32768..32767 (L16404)."""
        return _wrap(self.mem.pulse_value // COUNTS_PER_REV, 16)

    @property
    def single_turn(self) -> int:
        """Pulses within the turn, 0 ~ 16777215 (L16406)."""
        return self.mem.pulse_value % COUNTS_PER_REV

    @property
    def cw_positive(self) -> bool:
        return (self.params.get("P1.001") >> 8) & 0xF == self.options.cw_positive_z

    def puu_unwrapped(self) -> int:
        """PUU = ±pulse × P1.045/P1.044 + P6.001, sign from P1.001.Z (L16408-16410)."""
        n, m, p1001, p6001 = self._puu_params()
        sign = -1 if (p1001 >> 8) & 0xF == self.options.cw_positive_z else 1
        return _trunc_div(sign * self.mem.pulse_value * n, m) + p6001

    @property
    def puu(self) -> int:
        """Absolute PUU, signed 32-bit with wrap (L16417)."""
        return _wrap(self.puu_unwrapped(), 32)

    @property
    def coordinate_valid(self) -> bool:
        return self.mem.coordinate == "valid"

    @property
    def status(self) -> int:
        """P0.050 bits (L7493-7516)."""
        s = 0
        if self.mem.coordinate == "lost":
            s |= STATUS_LOST
        if self.mem.battery_v < BATTERY_LOW_V:
            s |= STATUS_BATTERY_LOW
        if self.mem.turn_overflow:
            s |= STATUS_TURN_OVERFLOW
        if self.mem.puu_overflow:
            s |= STATUS_PUU_OVERFLOW
        if self.mem.coordinate == "unset":
            s |= STATUS_NOT_ESTABLISHED
        return s

    def values(self, pulse_unit: bool) -> tuple[int, int, int]:
        """(status, turns or 0, pulses or PUU) in the unit a P2.070 bit selects."""
        self.refresh()
        if pulse_unit:
            return self.status, self.turns, self.single_turn
        return self.status, 0, self.puu

    def frame(self) -> int:
        """The 80-bit DI/DO frame now, unit per P2.070 bit0 (L16464-16486)."""
        status, turns, pos = self.values(bool(self.params.get("P2.070") & 0x1))
        return build_frame(status, turns, pos, bad_checksum=self.options.dev_bad_checksum)

    # -- battery and power ------------------------------------------------------------------

    def battery_monitor(self) -> int:
        """Monitor 038 (26h): the battery in 0.1 V (P0.002 shows 31 below 3.1 V, L16379),
        with the absolute function on (P2.069), else 0 (L15477)."""
        return round(self.mem.battery_v * 10) if self.enabled else 0

    def set_battery_voltage(self, volts: float) -> None:
        """Battery voltage (0 = removed). < 3.1 V AL061; > 3.8 V AL028; loss at power-off."""
        self.mem.battery_v = float(volts)
        self._evaluate()

    def power_cycle(self, battery: bool = True) -> None:
        """Control power off and on. battery=False: no battery during the off time (AL060)."""
        self._power_down()
        self._power_up(battery=battery)

    def to_dict(self) -> dict[str, Any]:
        """Battery-backed memory for a state file (`hil drive` restart)."""
        self.refresh()
        return self.mem.to_dict()

    def restore(self, data: Mapping[str, Any], battery: bool = True) -> None:
        """Load a state file written by `to_dict()`; acts as a power-up with that memory.

        The first motor position after this re-anchors the count (the process restarted).
        """
        mem = EncoderMemory.from_dict(data)
        self._power_down()
        self.mem = mem
        self._last_counts = None
        self._power_up(battery=battery)

    def _power_down(self) -> None:
        for t in (self._timer, self._origin_timer, self._latch_timer):
            if t is not None:
                t.cancel()
        self._timer = self._origin_timer = self._latch_timer = None
        if self._overlay:
            self._overlay = False
            self._set_overlay(False)
        self._abse = self._absq = self._absc = self._armed = False
        self._hs_error = False
        self.state = IDLE

    def _power_up(self, battery: bool) -> None:
        mem = self.mem
        if not battery or mem.battery_v < BATTERY_LOSS_V:
            # multi-turn data lost; single turn survives (L16381, L19759-19767)
            mem.pulse_value %= COUNTS_PER_REV
            mem.turn_overflow = mem.puu_overflow = False
            if mem.coordinate == "valid":
                mem.coordinate = "lost"
        if mem.al07c:
            mem.al07d = True  # power cycled without clearing AL07C (L19861-19865)
        self._p2069x = self.params.get("P2.069") & 0xF  # ● power-cycle parameter (L10042)
        self.enabled = self._p2069x == 1 and self.options.motor_absolute
        old = self._causes
        self._causes = {}
        self._outputs = {}
        self._evaluate()
        for code, present in old.items():
            if present and not self._causes.get(code, False):
                self._set_cause(code, False)

    # -- origin -----------------------------------------------------------------------------

    def establish_origin(self, at_counts: int | None = None) -> None:
        """Set the origin (PR homing, L16458): pulse value 0 at motor counts `at_counts`
        (default: here), PUU = P6.001 there. Clears AL06A/AL060 and the overflow flags."""
        self.refresh()
        offset = 0
        if at_counts is not None and self._last_counts is not None:
            offset = self._last_counts - at_counts
        self._apply_origin(offset)

    def _clear_command(self, source: str) -> bool:
        """ABSC or P2.071: refused above origin_max_rpm with AL07C (L19855-19859)."""
        self.refresh()
        speed = abs(self._speed_rpm()) if self._speed_rpm is not None else 0.0
        if speed > self.options.origin_max_rpm:
            self.mem.al07c = True
            self.last_error = f"{source}: origin refused at {speed:g} rpm > 200 rpm (AL07C)"
            self._evaluate()
            return False
        self._apply_origin(0)
        if self.on_origin is not None:
            self.on_origin()  # the drive's own coordinate follows (6064h = P6.001 here)
        return True

    def _apply_origin(self, offset: int) -> None:
        m = self.mem
        m.pulse_value = offset  # pulses = 0 and PUU = P6.001 at the origin (L16436, L16441)
        m.coordinate = "valid"  # AL06A / AL060 clear by themselves (L16397)
        m.turn_overflow = m.puu_overflow = False  # AL062 / AL289 cleared (L16404, L16417)
        m.al07c = m.al07d = False
        self._evaluate()
        if self._clear_alarm is not None:
            # AL060's clearing procedure is rebuilding the origin (L19767, L16397); a normal
            # clear of the absolute position "releases AL07C by itself" (L19857), and AL07D
            # with it (docs/manual-choices.md)
            # AL3F1, the communication-type absolute coordinate undefined, is cleared by
            # building the absolute origin (L20175)
            for code in ("AL060", "AL07C", "AL07D", "AL3F1"):
                self._clear_alarm(code)

    def on_arst(self) -> None:
        """DI.ARST clears AL07D, after which AL07C is there again (L19864): its cause goes."""
        if self.mem.al07d:
            self.mem.al07d = False
            self._evaluate()

    # -- parameters -------------------------------------------------------------------------

    def on_param_write(self, name: str, old: int, new: int) -> None:
        """Write hook for P0.049, P2.070, P2.071 (register with params.on_write)."""
        if name == "P0.049":
            if new in (1, 2):
                if self._latch_timer is not None:
                    self._latch_timer.cancel()
                delay = ms(self.options.p0049_ready_ms)
                if delay <= 0:
                    self._latch(new)
                else:
                    self._latch_timer = self.scheduler.after(delay, lambda: self._latch(new))
        elif name == "P2.070":
            self._evaluate()
        elif name == "P2.071" and new == 1:
            if self.enabled:  # needs P2.069.X = 1 (L10081); P2.008 = 271 is the store's job
                self._clear_command("P2.071")
            if self.options.p2071_returns_to_zero:
                self.params.set_internal("P2.071", 0)

    def _latch(self, mode: int) -> None:
        """P0.049 = 1/2: fill P0.050-P0.052 (unit P2.070 bit1), then P0.049 = 0 (L16529)."""
        self._latch_timer = None
        status, turns, pos = self.values(bool(self.params.get("P2.070") & 0x2))
        self.params.set_internal("P0.050", status)
        self.params.set_internal("P0.051", turns)
        self.params.set_internal("P0.052", pos)
        if mode == 2 and self._clear_position_error is not None:
            self._clear_position_error()  # motor position becomes the command end (L7489)
        self.params.set_internal("P0.049", 0)

    # -- DI functions -----------------------------------------------------------------------

    def _p2009_ns(self) -> int:
        return ms(self.params.get("P2.009"))

    def _delay(self, margin_ms: float) -> int:
        """Timer for 'P2.009 + margin' measured at the terminals."""
        filt = self._p2009_ns() if self.options.di_filtered_upstream else 0
        return max(0, self._p2009_ns() + ms(margin_ms) - filt)

    def on_abse(self, active: bool) -> None:
        """DI.ABSE (0x1D, level): enter / leave absolute mode (L15137, L16503)."""
        active = bool(active)
        if active == self._abse:
            return
        self._abse = active
        if active:
            if not self.enabled:
                return
            self.state = WAIT_TS
            self._timer = self.scheduler.after(self._delay(self.options.t_s_margin_ms), self._on_ts)
        else:
            self._end_handshake()
            self._armed = False
            if self._origin_timer is not None:
                self._origin_timer.cancel()
                self._origin_timer = None
            self._evaluate()  # ABSW off once ABSE is off (L16515)

    def on_absc(self, active: bool) -> None:
        """DI.ABSC (0x1F, rising edge, only with ABSE on after T_S): held T_Q -> origin."""
        active = bool(active)
        if active == self._absc:
            return
        self._absc = active
        if active and self._armed:
            # a duration, not a reaction: both edges come through the P2.009 filter, so the
            # pulse the drive sees is as long as the one at the terminals, and must itself
            # last P2.009 + margin (L16448-16450); a shorter one that passes the filter does
            # nothing
            hold = self._p2009_ns() + ms(self.options.origin_hold_margin_ms)
            self._origin_timer = self.scheduler.after(hold, self._on_absc_held)
        elif not active and self._origin_timer is not None:
            self._origin_timer.cancel()  # released before T_Q: nothing happens
            self._origin_timer = None

    def _on_absc_held(self) -> None:
        self._origin_timer = None
        if self._abse and self._absc:
            self._clear_command("DI.ABSC")

    def on_absq(self, active: bool) -> None:
        """DI.ABSQ (DI4 while the overlay is on; both edges, L15145). Without the overlay
        there is no ABSQ: DI4 going back to its own function when the handshake ends is no
        request."""
        active = bool(active)
        if active == self._absq:
            return
        self._absq = active
        if not self._overlay:
            return
        st = self.state
        if st == READY and not active:  # read request (L16505)
            self.state = PREP
            self._timer = self.scheduler.after(self._delay(self.options.t_q_margin_ms), self._on_tq)
        elif st == PREP and active:
            self._violation(f"bit {self.bit}: ABSQ on before ABSR on (L19789 (B))")
        elif st == WAIT_ACK and active:  # host took the bit (L16507)
            self._cancel_timer()
            self.state = ACK
            self._timer = self.scheduler.after(self._delay(self.options.t_n_margin_ms), self._on_tn)
        elif st == ACK and not active:
            self._violation(f"bit {self.bit}: ABSQ off before ABSR off (L19789 (A))")

    # -- handshake --------------------------------------------------------------------------

    def _on_ts(self) -> None:
        self._timer = None
        self._armed = True
        if self.options.block_handshake_on_warning and self._warning_present():
            self.state = BLOCKED  # ABSW stays on; clear the warnings first (L16521)
            return
        self.last_frame = self.frame()
        self._bits = frame_bits(self.last_frame, self.options.send_order)
        self._overlay = True
        self._set_overlay(True)  # DI4/DO2/DO3 -> ABSQ/ABSR/ABSD (L16504)
        if self._read_absq is not None:
            self._absq = bool(self._read_absq())
        self._output("ABSR", False)
        self._output("ABSD", False)
        self.bit = 0
        self.state = READY

    def _on_tq(self) -> None:
        self._timer = None
        level = bool(self._bits[self.bit]) == self.options.absd_one_active
        self._output("ABSD", level)
        self._output("ABSR", True)  # data ready (L16506)
        self.state = WAIT_ACK
        if not self.options.dev_no_t_r:
            filt = self._p2009_ns() if self.options.di_filtered_upstream else 0
            # "exceeds 200 ms" (L19789): an answer at exactly T_R is still in time
            self._timer = self.scheduler.after(ms(self.options.t_r_ms) + filt + 1, self._on_tr)

    def _on_tr(self) -> None:
        self._timer = None
        self._violation(f"bit {self.bit}: no ABSQ on within T_R after ABSR on (L16513, L19789)")

    def _on_tn(self) -> None:
        self._timer = None
        self._output("ABSR", False)  # ready for the next bit (L16508)
        self.bit += 1
        if self.bit < FRAME_BITS:
            self.state = READY
            return
        # 80 bits sent: the exchange is complete when the host has seen this last ABSR off,
        # so the pins return to their functions when it ends the cycle, ABSE off (L16519,
        # `_end_handshake`). At once, a DO2 whose own function is on (ZSPD, the factory)
        # hid the last ABSR off and the reader never finished (helper-102)
        self.state = DONE
        self._output("ABSD", False)

    def _violation(self, reason: str) -> None:
        """ABSW + AL068, handshake aborted until ABSE goes off (L16513-16517, L19787-19790)."""
        self._cancel_timer()
        self.last_error = reason
        self.state = ERROR
        self._hs_error = True
        self._output("ABSR", False)
        self._output("ABSD", False)
        self._evaluate()

    def _end_handshake(self) -> None:
        """ABSE off: the cycle ends, ABSR/ABSD off, the pins back to their functions (L16515,
        L16519). Nothing the pins' return does is read as a handshake step."""
        self.state = IDLE
        self._cancel_timer()
        if self._overlay:
            self._output("ABSR", False)
            self._output("ABSD", False)
            self._overlay = False
            self._set_overlay(False)
        self._hs_error = False
        self.state = IDLE

    def _cancel_timer(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None

    # -- alarms and outputs -----------------------------------------------------------------

    def _check_overflow(self) -> None:
        m = self.mem
        changed = False
        if not m.turn_overflow and not (TURNS_MIN <= m.pulse_value // COUNTS_PER_REV <= TURNS_MAX):
            m.turn_overflow = changed = True
        if not m.puu_overflow and not self._puu_surely_inside(m.pulse_value) \
                and not PUU_MIN <= self.puu_unwrapped() <= PUU_MAX:
            m.puu_overflow = changed = True
        if changed:
            self._evaluate()

    def _puu_surely_inside(self, pulse: int) -> bool:
        """Whether the PUU of `pulse` is surely inside PUU_MIN..PUU_MAX without working it
        out: |pulse| × P1.045/P1.044 stays 1 PUU (the truncation) and 1 more (float) inside
        the room P6.001 leaves (the bound is worked out again after a parameter change)."""
        got = self._puu_params()
        if got is not self._safe_for:
            n, m, _p1001, p6001 = got
            room = min(PUU_MAX - p6001, p6001 - PUU_MIN) - 2
            self._safe_pulse = room * m / n if room > 0 and n > 0 and m > 0 else -1.0
            self._safe_for = got
        return abs(pulse) <= self._safe_pulse

    def _warning_present(self) -> bool:
        return any(self._causes.get(code, False) for code in self.options.absw_warnings)

    def causes(self) -> dict[str, bool]:
        """Alarm causes as last reported (code -> present)."""
        return dict(self._causes)

    def _evaluate(self) -> None:
        m, on = self.mem, self.enabled
        warn_overflow = not self.params.get("P2.070") & 0x4  # bit2 = 1: no warning (L10064-10068)
        want = {
            "AL069": self._p2069x == 1 and not self.options.motor_absolute,
            "AL06A": on and m.coordinate == "unset",
            "AL060": on and m.coordinate == "lost",
            "AL061": on and m.battery_v < BATTERY_LOW_V,
            "AL028": on and m.battery_v > BATTERY_OVER_V,
            "AL062": on and m.turn_overflow and warn_overflow,
            "AL289": on and m.puu_overflow and warn_overflow,
            "AL07C": on and m.al07c,
            "AL07D": on and m.al07d,
            "AL068": on and self._hs_error,
        }
        for code, present in want.items():
            if self._causes.get(code, False) != present:
                self._causes[code] = present
                self._set_cause(code, present)
        self._output("ABSW", self._hs_error or self._warning_present())

    def _output(self, symbol: str, active: bool) -> None:
        if self._outputs.get(symbol) != active:
            self._outputs[symbol] = active
            self._set_output(symbol, active)

    def output(self, symbol: str) -> bool:
        """Current state of the DO function ABSR / ABSD / ABSW."""
        return self._outputs.get(symbol, False)

    def snapshot(self) -> dict[str, Any]:
        """Ground truth for the recorder."""
        self.refresh()
        return {
            "enabled": self.enabled,
            "coordinate": self.mem.coordinate,
            "pulse_value": self.mem.pulse_value,
            "turns": self.turns,
            "single_turn": self.single_turn,
            "puu": self.puu,
            "status": self.status,
            "battery_v": self.mem.battery_v,
            "handshake": self.state,
            "bit": self.bit,
            "error": self.last_error,
        }
