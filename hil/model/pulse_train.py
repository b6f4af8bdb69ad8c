"""PT mode: the pulse-train command input (CN1 PULSE/SIGN) and the encoder pulse output.

The line between a PLC and the drive carries *segments*: from time `t` on, `count` pulses
at `freq` Hz in `direction` (+1 forward / -1 reverse), `count = 0` meaning "until the next
segment". A new segment replaces what is left of the previous one (docs/pulse.md).

Input (A3 manual §6.2, P1.000 L7660-7745):
* P1.000.X input form: 0 A/B phase (4x: four counts per A period), 1 CW + CCW, 2 pulse +
  sign; a segment of another form is not decoded (its pulses are lost, `lost_format`).
  P1.000.Z logic: with pulse + sign, a logic other than the PLC's inverts the sign.
* Interface limit: line driver 4 Mpps, open collector 200 kpps (L7700-7707, L3503). Above
  it AL008 "abnormal pulse command" (L19535-19538) unless P2.065 bit 6 = 1 (L9892), and
  the pulses are not counted (`lost_limit`, a choice: the manual does not say what the
  counter sees beyond the interface's rating).
* P1.000.UY input filter: a pulse whose half period is shorter than the filter width is
  filtered out (L7712-7745); the table's kHz column is the frequency 1 / (2 x width).
* Electronic gear: counts = pulses x Nx / M, Nx = P1.044 / P2.060 / P2.061 / P2.062 by
  GNUM0/GNUM1 (L9850), M = P1.045; allowed 1/4 < Nx/M < 262144 (L8547): a write that
  leaves it is refused (option `pt_gear_check`).
* INHP (DI 0x45) stops accepting pulses, only on DI8 (L3550, L15244), at the terminal edge
  ("real-time", L15244: not through P2.009's filter); P2.065 bit 11: at a
  limit, pulses towards it are not accepted (L9926-9930); with bit 11 = 0 they are (L9928),
  but PL / NL still forbid the motor to run towards the limit (L15186-15191).
* CCLR (P2.050, L9742-9753): the accumulated position error is cleared: the command
  position becomes the feedback position and the pulses still to come count from there.
* Smoothing: P1.068 moving filter (ms, L8832) then P1.008 low-pass (10 ms, L7921), on the
  1 ms command grid; the axis follows the smoothed command one cycle later.
* AL009 when the error exceeds P2.035 (L9556) is the drive's usual check; TPOS in PT is
  |command - feedback| < P1.054 (L8689).
* Servo on in PT: the axis follows the pulses received (L3503, L3510), also those of a train
  that began while the servo was off or the PR side of PT-PR was selected.
* P2.069.Y = 0: no pulse is accepted while AL060 / AL06A is active (L10027-10029).
* Monitors: pulse command count (accepted pulses, `accepted`) and frequency in kpps
  (monitor 006, L15446); P5.018 / monitor 049 the pulses CN1 decodes (L11298, L15483).

Output (P1.046 L8556-8571): OA/OB with P1.046 pulses per revolution and phase (4 x P1.046
quadrature counts; P1.046 / P1.097 with P1.097 != 0, L9053-9081; P1.003.Y = 1 reversed,
L7866-7869), summed over `output_window_ms` windows into segments; OZ (C11, L1851)
one pulse per revolution at the encoder's index, `ocz_width_us` wide (a choice: the manual
gives no width). AL018 when rpm / 60 x those counts > 19.8 MHz (L8569) unless P2.065 bit 13.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from hil.model.dio import N_DI
from hil.model.errors import OutOfRange
from hil.model.mechanics import COUNTS_PER_REV
from hil.units import s32

if TYPE_CHECKING:
    from hil.model.core import DriveCore

FORMS = ("ab", "cw_ccw", "pulse_sign")  # P1.000.X = 0, 1, 2 (L7670-7674)
LIMIT_PPS = {"line_driver": 4_000_000, "open_collector": 200_000}  # L7700-7707
OUTPUT_MAX_HZ = 19.8e6  # L8569
GEAR_MIN, GEAR_MAX = 0.25, 262144.0  # 1/4 < Nx/M < 262144 (L8547)
# not in the manual: a segment slower than a pulse in 1000 s is no train (its end time would
# overflow); 0 Hz is the line at rest
MIN_FREQ_HZ = 1e-3
PT_YX = (0x00, 0x06, 0x07, 0x0D, 0x0E, 0x0F)  # P1.001.YX with a PT side (L7749-7800)
CRUISE_NS = 200_000_000  # the longest cruise before an exact resync
# the parameters `_Config` reads: a write of one ends a cruise (P0.046, P4.009 ... do not)
_CONFIG_PARAMS = frozenset({"P1.000", "P1.001", "P1.003", "P1.008", "P1.044", "P1.045",
                            "P1.046", "P1.068", "P1.097", "P2.017", "P2.060", "P2.061",
                            "P2.062", "P2.065", "P2.069", "P3.006"})
_INTERP_MODE = 5  # Axis._INTERP


@dataclass(frozen=True)
class _Config:
    form: str
    logic: int
    max_hz: float
    numerators: tuple[int, int, int, int]
    m: int
    inhp_di8: bool
    inhp_a: bool  # DI8's contact: a (on when closed) or b (P2.017 digit Z)
    inhp_sdi: bool  # DI8 from the software DI (P3.006 bit 7, L10585-10606)
    p2065: int
    p1068: int
    tau_ms: float
    pt_yx: bool
    out_per_rev: float  # OA/OB quadrature counts per revolution (P1.046, P1.097)
    out_sign: int  # P1.003.Y: 0 forward, 1 reverse output (L7866-7869)
    abs_lost_blocks: bool  # P2.069.Y = 0 (L10027-10029)


@dataclass(frozen=True)
class Segment:
    """`count` pulses (0: until replaced) at `freq` Hz from `t` ns, `direction` +1 / -1."""

    t: int
    freq: float
    direction: int
    count: int = 0
    form: str = "pulse_sign"
    logic: int = 0

    def pulses_at(self, t: int) -> int:
        """Pulses output by time `t` (one per period, the first a full period after `t`)."""
        if t <= self.t or self.freq <= 0:
            return 0
        n = int((t - self.t) * self.freq // 1_000_000_000)
        return min(n, self.count) if self.count else n

    @property
    def end(self) -> int | None:
        """Time of the last pulse, or None for a continuous segment (a kept segment always
        has freq > 0: `PulseTrain.segment` drops a 0 Hz one)."""
        return self.t + math.ceil(self.count * 1e9 / self.freq) if self.count else None

    def counts(self, logic: int) -> int:
        """Signed decoder counts per pulse: A/B counts 4 (L7670); pulse + sign read with the
        other logic runs the other way (P1.000.Z, L7676)."""
        sign = -self.direction if self.form == "pulse_sign" and self.logic != logic \
            else self.direction
        return sign * (4 if self.form == "ab" else 1)


def output_per_rev(p1046: int, p1097: int) -> float:
    """OA/OB quadrature counts per motor revolution (CN2 the source, P1.074.Y = 0): 4 x P1.046
    with P1.097 = 0, else P1.046 / P1.097 with no x4 (L9060-9081: 2500 / 7 is 2500 per seven
    turns)."""
    return 4.0 * p1046 if p1097 == 0 else p1046 / p1097


def filter_max_hz(p1_000: int) -> float | None:
    """Highest frequency P1.000.UY lets through (half period >= width), None without a
    filter (L7716-7733: Y 0 none; width Y+1 us for U = 0, (Y+1)/10 us for U = 1)."""
    y = (p1_000 >> 4) & 0xF
    u = (p1_000 >> 12) & 0xF
    if y == 0 or y > 0xE:
        return None
    width_us = (y + 1) / (10.0 if u == 1 else 1.0)
    return 1e6 / (2.0 * width_us)


class PulseTrain:
    """The PT input and the OA/OB/OZ output of one drive."""

    def __init__(self, drive: DriveCore) -> None:
        self.d = drive
        self.seg: Segment | None = None
        self._taken = 0  # pulses of `seg` already taken
        self.accepted = 0  # signed pulses counted since power-up (monitor: command count)
        self.line_total = 0  # signed pulses seen on the line (before any filter)
        self._machine: dict[str, bool] = {}  # DOG / NL / PL as the PLC's inputs see them
        self.lost_format = self.lost_limit = self.lost_inhibit = self.lost_off = 0
        self.lost_held = 0  # pulses that came while JOG, PFQS or a level CCLR held the axis
        self.lost_alarm = 0  # refused while AL060 / AL06A (P2.069.Y = 0)
        self.cn1 = 0  # decoded pulses at CN1 whatever the mode (P5.018, monitor 049)
        self._cn1_base = 0  # P5.018 as last written (the counter presets to it)
        self.command = 0.0  # PT command position, physical counts (before smoothing)
        self._base = 0.0  # the command before the pulses began (the filters start from it)
        self._rem = (0, 1)  # gear remainder (numerator, M): counts = numerator / M, exactly
        self._ma: deque[float] = deque()
        self._lpf: float | None = None
        self._active = False  # the axis follows the PT command
        self.used = False  # a segment came since power-up: TPOS judges the PT error
        self.freq_hz = 0.0  # frequency now being accepted (monitor 006, kpps = /1000)
        self.listeners: list[Callable[[str, dict[str, Any]], None]] = []
        self._cfg: _Config | None = None
        self._pt_now = False  # in PT at the last step with pulses
        # Cruise: a constant-frequency segment, settled filters: the axis is handed one linear
        # set-point to `_cruise_end` instead of one per 1 ms step; any change ends it with an
        # exact resync of the count, the filter window and the set-point. In between the
        # command is the straight line through the pulses (within one pulse of the per-step
        # staircase; tests/model/test_pulse_train.py compares both).
        self._cruise_end = 0
        self._cruise_mode = 0
        self._cruise_gain = 0.0
        self._cruise_gear: tuple[int, int] = (1, 1)
        self._rebuild: tuple[Segment, int, int, float, float] | None = None
        self._steady_since = 0
        for f in ("INHP", "GNUM0", "GNUM1", "PL", "NL", "PT-PR", "CCLR", "SON"):
            drive.dio.on_function(f, self._input_changed)
        drive.params.subscribe(self._on_param)
        drive.dio.on_raw(self._on_terminal)
        # encoder output (OA/OB window, OZ)
        self._out_t = 0
        self._out_pos = 0.0
        self._out_pos0 = 0.0  # the position the output counts from
        self._out_sent = 0  # counts output since then
        self._out_scale: tuple[float, int] | None = None

    # ------------------------------------------------------------------ configuration
    def _config(self) -> _Config:
        """The parameters the input uses, read once per parameter change (a step is 1 ms)."""
        c = self._cfg
        if c is None:
            get = self.d.params.get
            p1000 = get("P1.000")
            x = p1000 & 0xF
            flt = filter_max_hz(p1000)
            c = self._cfg = _Config(
                form=FORMS[x] if x < len(FORMS) else "reserved",
                logic=(p1000 >> 8) & 1,
                max_hz=min(LIMIT_PPS[self.d.options.pulse_interface],
                           flt if flt is not None else math.inf),
                numerators=(get("P1.044"), get("P2.060"), get("P2.061"), get("P2.062")),
                m=get("P1.045"),
                inhp_di8=get("P2.017") & 0xFF == 0x45,
                inhp_a=bool((get("P2.017") >> 8) & 0xF),
                inhp_sdi=bool((get("P3.006") >> 7) & 1),
                p2065=get("P2.065"),
                p1068=get("P1.068"),
                tau_ms=get("P1.008") * 10.0,
                pt_yx=(get("P1.001") & 0xFF) in PT_YX,
                out_per_rev=output_per_rev(get("P1.046"), get("P1.097")),
                out_sign=-1 if (get("P1.003") >> 4) & 0xF == 1 else 1,
                abs_lost_blocks=(get("P2.069") >> 4) & 0xF == 0,
            )
        return c

    def _on_param(self, name: str, _value: int) -> None:
        if name in _CONFIG_PARAMS:
            self._cfg = None
            self._input_changed(False)

    def _input_changed(self, _active: bool) -> None:
        """Something that decides how pulses count changed: end a cruise, and wait for the
        filter window to hold only samples from after the change before the next one."""
        if self._cruise_end:
            self._resync()
        self._steady_since = self.d.now

    @property
    def form(self) -> str:
        return self._config().form

    def gear(self) -> tuple[int, int]:
        """(Nx, M) with Nx selected by GNUM0/GNUM1 (L9850; P1.044 when neither is wired)."""
        dio = self.d.dio
        idx = int(dio.function_active("GNUM0")) | (int(dio.function_active("GNUM1")) << 1)
        c = self._config()
        return c.numerators[idx], c.m

    def in_pt_cached(self) -> bool:
        """`in_pt()` as the last motion step saw it while following, else computed."""
        return self._pt_now if self._active else self.in_pt()

    def in_pt(self) -> bool:
        return self._config().pt_yx and self.d.control_mode() == "PT"

    # ------------------------------------------------------------------ the line
    def segment(self, freq: float, direction: int, count: int = 0, *,
                form: str = "pulse_sign", logic: int = 0, total: int | None = None) -> None:
        """A segment from the line, starting now (replaces the rest of the previous one).
        `total`: the signed pulses the master output before it; the count is reconciled
        with it (a segment that came late over a network ran on too long here)."""
        d = self.d
        if (not math.isfinite(freq) or not (freq == 0 or freq >= MIN_FREQ_HZ) or count < 0
                or direction not in (1, -1)):
            raise ValueError(f"pulse segment: freq {freq!r} (0 or {MIN_FREQ_HZ:g} Hz and up), "
                             f"direction {direction!r}, count {count!r}")
        if form not in FORMS:
            raise ValueError(f"pulse segment: form {form!r} not one of {', '.join(FORMS)}")
        d.commit_cycle()
        if self._cruise_end:
            self._resync()
        self._take(d.now)
        if not self._active and d.servo_on and self.in_pt():
            self._follow()  # before the reconciliation: its pulses move the motor too
        if total is not None and total != self.line_total:
            old = self.seg or Segment(d.now, float(freq), direction, 0, form, int(logic) & 1)
            diff = total - self.line_total
            self.line_total = total
            self._count(abs(diff), Segment(old.t, old.freq, 1 if diff > 0 else -1, 0,
                                           old.form, old.logic))
        self.seg = (Segment(d.now, float(freq), direction, int(count), form, int(logic) & 1)
                    if freq > 0 else None)  # a 0 Hz segment: the line stops pulsing
        # monitor 006, "the frequency of the pulse command the drive receives" (L15446):
        # the line's, in any servo state, once the input decodes its form
        self.freq_hz = (float(freq) if self.seg is not None and form == self._config().form
                        else 0.0)
        self._taken = 0
        self._steady_since = d.now
        self._check_limit()
        self._kick()

    def stop(self) -> None:
        """The line stops pulsing (no segment)."""
        self.segment(0.0, 1, 0)

    def pending(self) -> int:
        """Pulses of the current segment still to come (0 for a continuous one)."""
        s = self.seg
        if s is None or not s.count:
            return 0
        taken = s.pulses_at(self.d.now) if self._cruise_end else self._taken
        return s.count - taken

    # ------------------------------------------------------------------ counting
    def _take(self, t: int, pt: bool | None = None) -> None:
        """Count the pulses of the segment up to `t`; `pt`: in PT now (None: look it up)."""
        s = self.seg
        if s is None:
            return
        n = s.pulses_at(t) - self._taken
        if n <= 0:
            return
        self._taken += n
        self.line_total += s.direction * n
        self._count(n, s, pt)
        if s.count and self._taken >= s.count:  # its last pulse: none come now (monitor 006)
            self.seg = None
            self.freq_hz = 0.0

    def _count(self, n: int, s: Segment, pt: bool | None = None, force: bool = False) -> None:
        d = self.d
        c = self._config()
        counts = s.counts(c.logic)
        if force:  # a cruise's pulses: every condition held, as checked when it began, and
            self.cn1 += n * counts  # the gear was the one it began with (a GNUM edge or a
            self._add(n, s, counts, self._cruise_gear)  # P2.060 write that ends it acts on
            return  # the pulses after it, L9843-9850)
        if s.form == c.form and s.freq <= c.max_hz:  # the input decodes them: CN1 counts
            self.cn1 += n * counts
        if s.form != c.form:
            self.lost_format += n
            return
        if not d.servo_on or not (self.in_pt() if pt is None else pt):
            self.lost_off += n
            return
        if self._abs_lost():
            self.lost_alarm += n
            return
        if s.freq > c.max_hz:  # beyond the interface or the P1.000.UY filter
            self.lost_limit += n
            return
        if d.axis.locked:  # JOG, PFQS or a level CCLR holds the axis: dropped, not queued
            self.lost_held += n  # (docs/manual-choices.md, JOGU / JOGD)
            return
        dio = d.dio
        if self._inhibited(c):
            self.lost_inhibit += n
            return
        if c.p2065 & (1 << 11) and (  # single-direction inhibit at a limit
                (counts > 0 and dio.function_active("PL"))
                or (counts < 0 and dio.function_active("NL"))):
            self.lost_inhibit += n
            return
        self._add(n, s, counts)

    def cn1_count(self) -> int:
        """P5.018 / monitor 049: the pulse command count at CN1 (L11298-11305, L15483), in
        decoder counts (A/B: four a period, as monitor 001), signed 32-bit, preset by a write
        of P5.018. It counts what the input decodes in any mode and servo state: P5.018 is
        also how PR mode's E-cam watches CN1 (L5585)."""
        s = self.seg
        n = self.cn1 + self._cn1_base
        if self._cruise_end and s is not None:  # a cruise takes its pulses at its end
            n += s.counts(self._config().logic) * (s.pulses_at(self.d.now) - self._taken)
        return s32(n)

    def preset_cn1(self, _name: str, _old: int, value: int) -> None:
        self._cn1_base = value - self.cn1

    def _inhibited(self, c: _Config) -> bool:
        """INHP on DI8 acts at the terminal, not after P2.009's filter: DI8 only, "to
        guarantee a real-time pulse inhibit" (L15244); a software DI8 (P3.006) as mapped."""
        if not c.inhp_di8:
            return False
        dio = self.d.dio
        if c.inhp_sdi:
            return dio.function_active("INHP")
        return dio.input_level(8) == c.inhp_a

    def _on_terminal(self, n: int, _closed: bool) -> None:
        """A DI terminal edge, before the filter (and before the level changes): with INHP on
        DI8, the pulses up to now count under the state before the edge."""
        if n != 8 or self.seg is None or not self._config().inhp_di8:
            return
        if self._cruise_end:
            self._resync()
        self._take(self.d.now)
        self._steady_since = self.d.now

    def _abs_lost(self) -> bool:
        """P2.069.Y = 0: no pulse command is accepted while AL060 or AL06A is active
        (L10027-10029). Both arise at power-up or from the handshake, never inside a cruise."""
        if not self._config().abs_lost_blocks:
            return False
        active = self.d.alarms.active
        return "AL060" in active or "AL06A" in active

    def _add(self, n: int, s: Segment, counts: int,
              gear: tuple[int, int] | None = None) -> None:
        self.accepted += n * counts
        nx, m = gear or self.gear()
        # counts = pulses x N/M (L3578-3598), in integers: a float sum of 1677.7216-count
        # steps fell just below a whole count and lost it on every move
        rem, m0 = self._rem
        whole, rem = divmod(n * counts * nx + (rem if m0 == m else rem * m // m0), m)
        self._rem = (rem, m)
        self.command += whole
        self.freq_hz = s.freq

    def _check_limit(self) -> None:
        """AL008 above the interface's rating (L19535-19538), unless P2.065 bit 6 (L9892)."""
        s = self.seg
        d = self.d
        if s is None or not d.powered or d.params.get("P2.065") & (1 << 6):
            return
        if s.freq > LIMIT_PPS[d.options.pulse_interface] and self.in_pt():
            d.alarms.raise_alarm("AL008")

    # ------------------------------------------------------------------ following
    def _kick(self) -> None:
        """Start following: the axis steps while pulses come or the filter settles."""
        d = self.d
        if not (d.servo_on and self.in_pt()):
            return
        self._follow()
        if not self._at_limit():  # a limit's ramp stop (drive._on_limit) runs on
            d.axis.interpolate_to(d.axis.demand, d.step_ns, by="PT")

    def _follow(self) -> None:
        """The axis follows the PT command from here on, starting from its own demand."""
        if not self._active:
            self._active = self.used = True
            if self.d.axis.demand != self.command:  # moved since (another mode): anew
                self._rem = (0, 1)
            # else the last train's remainder is carried: 20 one-pulse moves at 1677.7216
            # counts a pulse are 33554 counts, not 20 x 1677
            self.command = self._base = self.d.axis.demand
            self._ma.clear()
            self._lpf = None

    def _at_limit(self) -> bool:
        dio = self.d.dio
        return dio.function_active("PL") or dio.function_active("NL")

    def _towards_limit(self, target: float) -> bool:
        """PL / NL forbid running forward / in reverse in every mode (L15186-15191): with
        P2.065 bit 11 = 0 the pulses still enter the drive (L9928), the motor does not go."""
        dio = self.d.dio
        demand = self.d.axis.demand
        return ((target > demand and dio.function_active("PL"))
                or (target < demand and dio.function_active("NL")))

    def _smoothed(self) -> float:
        """P1.068 moving average (ms samples) then P1.008 low-pass (10 ms)."""
        x = self.command
        c = self._config()
        n = c.p1068
        if n > 1:
            if not self._ma:  # the window starts full of the command before the pulses
                self._ma.extend([self._base] * (n - 1))
            self._ma.append(x)
            while len(self._ma) > n:
                self._ma.popleft()
            x = sum(self._ma) / len(self._ma)
        else:
            self._ma.clear()
        tau_ms = c.tau_ms
        if tau_ms > 0:
            y = self._base if self._lpf is None else self._lpf
            y += (x - y) * (1.0 - math.exp(-self.d.step_ns / 1e6 / tau_ms))
            if abs(x - y) < 0.5:
                y = x
            self._lpf = y
            x = y
        return x

    def after_step(self) -> None:
        d = self.d
        if not d.servo_on and self.used and not self._active:  # the command follows the
            pos = d.axis.position                                # feedback (a coasting motor)
            self._rem = (0, 1)  # and the gear's remainder goes, as clear_error() does
            if self.command != pos:
                self.command = self._base = pos
        if self.seg is None and not self._active:
            self._pt_now = False
            if self.listeners or d.axis.velocity:
                self._encoder_output()
            if self.listeners:
                self._machine_lines()
            return
        # AL008 is a condition: an over-rate train still on the line raises it again after an
        # alarm reset, or once the mode has a PT side (L19535-19538)
        if (self.seg is not None and self.seg.freq > LIMIT_PPS[d.options.pulse_interface]
                and "AL008" not in d.alarms.active):
            self._check_limit()
        if self._cruise_end:
            ax = d.axis
            if (d.now < self._cruise_end and d.servo_on and ax._mode == _INTERP_MODE
                    and not ax._locks and d.cia402.mode == self._cruise_mode):
                if self.listeners or ax.velocity:
                    self._encoder_output()
                if self.listeners:
                    self._machine_lines()
                return
            self._resync()
        self._pt_now = pt = self.in_pt()  # once per step (TPOS reads it too)
        if self.seg is not None:
            if not self._active and pt and d.servo_on:
                self._follow()  # a train already running as the servo came on / PT began
            self._take(d.now, pt)
        if d.axis.locked:  # a level CCLR keeps the error at 0 (L9753); while JOG or PFQS
            self.clear_error()  # holds the axis the command follows it, and pulses drop
        if self._rebuild is not None:
            self._rebuild_window()
        if self._active:
            if not (d.servo_on and pt):
                self._active = False
                self.clear_error()  # servo off: the command follows the feedback
            else:
                target = self._smoothed()
                settled = (self.seg is None and target == self.command
                           and all(v == self.command for v in self._ma))
                if not settled or d.axis.demand != target:
                    if not self._towards_limit(target):  # else the limit's stop holds it
                        d.axis.interpolate_to(target, d.step_ns, by="PT")
                        self._maybe_cruise(pt)
                else:
                    self._active = False
        if self.listeners or d.axis.velocity:
            self._encoder_output()
        if self.listeners:
            self._machine_lines()

    # -- cruise ----------------------------------------------------------------------------
    def _gain(self, s: Segment) -> float | None:
        """Command counts per pulse of `s` (signed), or None when its pulses are not taken
        as they come (another form, the filter, INHP, a limit: then no cruise)."""
        c = self._config()
        d = self.d
        if s.form != c.form or s.freq > c.max_hz or not d.servo_on or self._abs_lost():
            return None
        dio = d.dio
        if self._inhibited(c):
            return None
        if c.p2065 & (1 << 11) and (dio.function_active("PL") or dio.function_active("NL")):
            return None
        nx, m = self.gear()
        return s.counts(c.logic) * nx / m

    def _command_at(self, t: int, s: Segment, gain: float) -> float:
        """The command at time `t` (the segment running from its start to past `t`)."""
        return self.command + gain * (s.pulses_at(t) - self._taken)

    def _maybe_cruise(self, pt: bool) -> None:
        d = self.d
        s = self.seg
        c = self._config()
        step = d.step_ns
        if s is None or not pt or c.tau_ms > 0 or d.axis._locks:
            return
        n = max(1, c.p1068)
        if d.now - max(self._steady_since, s.t) < (n + 2) * step:
            return  # the window still holds samples from before this segment
        end = s.end
        t1 = d.now + CRUISE_NS if end is None else min(d.now + CRUISE_NS,
                                                        (end - 1) // step * step)
        if t1 - d.now < 5 * step:
            return
        gain = self._gain(s)
        if gain is None:
            return
        target = sum(self._command_at(t1 - k * step, s, gain) for k in range(n)) / n
        d.axis.interpolate_to(target, t1 + step - d.now, by="PT")
        self._cruise_end = t1
        self._cruise_gain = gain
        self._cruise_mode = d.cia402.mode
        self._cruise_gear = self.gear()  # a cruise's pulses count at the gear it began with

    def _resync(self) -> None:
        """End a cruise: count its pulses up to the last 1 ms grid point (the per-step path
        takes the rest, under the conditions of then); the next step rebuilds the filter
        window from the grid samples, as the per-step path would have them."""
        d = self.d
        self._cruise_end = 0
        s = self.seg
        if s is None:
            return
        grid = d.now - d.now % d.step_ns
        n_new = s.pulses_at(grid) - self._taken
        if n_new > 0:
            self._taken += n_new
            self.line_total += s.direction * n_new
            self._count(n_new, s, force=True)
        self._rebuild = (s, grid, s.pulses_at(grid), self.command, self._cruise_gain)
        self._steady_since = d.now

    def _rebuild_window(self) -> None:
        """The filter window of the per-step path at the first step after a cruise."""
        s, grid, pulses, command, gain = self._rebuild
        self._rebuild = None
        n = self._config().p1068
        if n <= 1:
            return
        step = self.d.step_ns
        self._ma = deque(command + gain * (s.pulses_at(min(t, grid)) - pulses)
                         for t in (self.d.now - k * step for k in range(n - 1, 0, -1)))

    def _machine_lines(self) -> None:
        """The machine's sensors as a PLC sees them: DOG (the home cam), NL, PL switches."""
        d = self.d
        pos = d.axis.position
        nl, pl = d.mech.limit_states(pos)
        for name, level in (("DOG", d.mech.home_sensor(pos)), ("NL", nl), ("PL", pl)):
            if self._machine.get(name) != level:
                self._machine[name] = level
                self.emit("X", {"name": name, "level": level})

    def machine_lines(self) -> dict[str, bool]:
        """The sensors now (for a line that connects later)."""
        pos = self.d.axis.position
        nl, pl = self.d.mech.limit_states(pos)
        self._machine = {"DOG": self.d.mech.home_sensor(pos), "NL": nl, "PL": pl}
        return dict(self._machine)

    def clear_error(self) -> None:
        """CCLR: the command position becomes the feedback (L9749)."""
        d = self.d
        if self._cruise_end and self.seg is not None:  # the cleared error takes them along,
            self._cruise_end = 0  # but they were received: P5.018, monitors 049 and 001 count
            s = self.seg  # them (L11298-11305, L15483, L15441; helper-100 found them lost)
            n = s.pulses_at(d.now) - self._taken
            if n > 0:
                self._taken += n
                self.line_total += s.direction * n
                self._count(n, s, force=True)
        self.command = self._base = d.axis.position
        self._rem = (0, 1)
        self._ma.clear()
        self._lpf = None

    def live_command(self) -> float:
        """The command now (during a cruise the pulses since it began are not yet taken)."""
        s = self.seg
        if not self._cruise_end or s is None:
            return self.command
        return self._command_at(self.d.now, s, self._cruise_gain)

    def error(self) -> float:
        """PT position error, counts: the command minus the feedback."""
        return self.live_command() - self.d.axis.position

    # ------------------------------------------------------------------ encoder output
    def _encoder_output(self) -> None:
        """OA/OB counts summed per window; OZ at each index crossing; AL018 (L8569).

        The counts output are those of the motor's travel since the reference position
        `_out_pos0`, converted at once (not summed from increments, whose rounding drifts):
        a motor back at its start has output exactly zero. P1.003.Y = 1 reverses them."""
        d = self.d
        ax = d.axis
        c = self._config()
        per_rev = c.out_per_rev
        if (ax.velocity and not c.p2065 & (1 << 13)
                and abs(ax.velocity) / COUNTS_PER_REV * per_rev > OUTPUT_MAX_HZ):
            d.alarms.raise_alarm("AL018")
        if not self.listeners:  # nothing to output: a listener's output starts where it joins
            self._out_scale = None
            return
        if (per_rev, c.out_sign) != self._out_scale:  # a listener joined, or a new scale
            self._out_scale = (per_rev, c.out_sign)
            self._out_pos0 = self._out_pos = ax.position
            self._out_sent = 0
            self._out_t = d.now
        for z in d.mech.index_crossed(ax.last_position, ax.position):
            span = ax.position - ax.last_position
            frac = (z - ax.last_position) / span if span else 1.0
            t = d.now - d.step_ns + int(frac * d.step_ns)
            self.emit("OZ", {"t": t, "width_ns": int(d.options.ocz_width_us * 1000)})
        window = int(d.options.output_window_ms * 1_000_000)
        if ax.position == self._out_pos:  # at rest: the next window starts now
            self._out_t = d.now
            return
        if d.now - self._out_t < window and ax.position != ax.last_position:
            return  # the window runs on (a motor coming to rest flushes it at once)
        total = c.out_sign * math.floor(
            (ax.position - self._out_pos0) * per_rev / COUNTS_PER_REV + 1e-6)
        whole = total - self._out_sent
        self._out_sent = total
        dt = d.now - self._out_t
        if whole:
            self.emit("OAB", {"t": self._out_t, "freq": abs(whole) * 1e9 / dt,
                               "direction": 1 if whole > 0 else -1, "count": abs(whole)})
        self._out_pos = ax.position
        self._out_t = d.now

    def emit(self, kind: str, data: dict[str, Any]) -> None:
        for fn in list(self.listeners):
            fn(kind, data)

    # ------------------------------------------------------------------ power
    def power_up(self) -> None:
        self.seg = None
        self._taken = 0
        self.accepted = self.line_total = 0
        self.lost_format = self.lost_limit = self.lost_inhibit = self.lost_off = 0
        self.lost_held = 0  # pulses that came while JOG, PFQS or a level CCLR held the axis
        self.lost_alarm = 0
        self.cn1 = 0
        self._cn1_base = self.d.params.stored("P5.018")
        self._cruise_end = 0
        self._rebuild = None
        self._active = self.used = False
        self._rem = (0, 1)
        self.freq_hz = 0.0

    def snapshot(self) -> dict[str, Any]:
        s = self.seg
        accepted = self.accepted
        if self._cruise_end and s is not None:  # a cruise takes its pulses at its end
            accepted += s.counts(self._config().logic) * (s.pulses_at(self.d.now) - self._taken)
        return {"pt_count": accepted, "pt_freq_kpps": self.freq_hz / 1000.0,
                "pt_command": round(self.live_command()), "pt_pending": self.pending(),
                "pt_error": round(self.error()) if self.used else 0}


def _gnum_wired(d: DriveCore) -> bool:
    """GNUM0 or GNUM1 on a DI: N2-N4 can be selected (without them Nx is P1.044, L9850)."""
    dio = d.dio
    return any(dio.di_function(n) in ("GNUM0", "GNUM1") for n in range(1, N_DI + 1))


def gear_problem(d: DriveCore) -> str | None:
    """AL045 (L19699-19703): an e-gear ratio outside 1/4 ~ 262144 found at power-up, in any
    mode (Nx: P1.044, and P2.060-P2.062 when GNUM0/GNUM1 can select them, L9850)."""
    m = d.params.get("P1.045")
    for nx in _numerators(d):
        if not m or not GEAR_MIN < nx / m < GEAR_MAX:
            return f"{nx}/{m}"
    return None


def _numerators(d: DriveCore) -> list[int]:
    """The Nx a ratio may use: P1.044, and P2.060-P2.062 when GNUM0/GNUM1 can select them."""
    p = d.params
    return [p.get("P1.044")] + ([p.get(n) for n in ("P2.060", "P2.061", "P2.062")]
                                if _gnum_wired(d) else [])


def _check_gear(d: DriveCore) -> Callable[[str, int], None]:
    def validate(name: str, value: int) -> None:
        # the range is of the command *pulse* input ratio (L8543-8547): PT modes only
        if d.options.pt_gear_check != "refuse" or (d.params.get("P1.001") & 0xFF) not in PT_YX:
            return
        p = d.params
        m = value if name == "P1.045" else p.get("P1.045")
        nums = [value] if name != "P1.045" else _numerators(d)
        for nx in nums:
            if not GEAR_MIN < nx / m < GEAR_MAX:
                other = "numerator" if name == "P1.045" else "denominator P1.045"
                raise OutOfRange(name, f"{name} = {value}: e-gear ratio {nx}/{m} outside "
                                 f"1/4 < Nx/M < 262144 (L8547); write the {other} first "
                                 "if the pair is changing")
    return validate


def _position_monitor(d: DriveCore, pt: PulseTrain, code: int) -> int:
    """The position codes 000-006 of the monitor table (L15440-15446) and 049, the CN1 pulse
    count (L15483)."""
    if code == 49:  # pulse command count at CN1 (L15483), = P5.018
        return pt.cn1_count()
    ax = d.axis
    n, m = d.params.get("P1.044"), d.params.get("P1.045")
    fb, cmd = ax.user_position, ax.user_demand
    if pt.used and pt.in_pt():
        cmd = pt.live_command() - ax.origin
    if code == 6:  # pulse command frequency, kpps
        return round(pt.freq_hz / 1000.0)
    if code == 1 and pt.in_pt():  # PT: the pulses received (L15441), none yet at first
        return int(pt.snapshot()["pt_count"])
    values = {0: fb * m / n, 1: cmd * m / n, 2: (cmd - fb) * m / n, 3: fb, 4: cmd,
              5: cmd - fb}
    return round(values[code])


#: the codes this part keeps for every reader (`Hooks.monitors`: P0.009-P0.013 and a PR
#: WRITE's monitor source alike, L4178-4183)
SHARED_MONITORS = (0, 1, 2, 3, 4, 5, 6, 49)


def attach_pulse_train(drive: DriveCore) -> PulseTrain:
    pt = PulseTrain(drive)
    for code in SHARED_MONITORS:
        drive.hooks.monitors[code] = lambda c=code: _position_monitor(drive, pt, c)
    drive.params.on_read("P5.018", pt.cn1_count)
    drive.params.on_write("P5.018", pt.preset_cn1)
    drive.hooks.step.append(pt.after_step)
    validate = _check_gear(drive)
    for name in ("P1.044", "P1.045", "P2.060", "P2.061", "P2.062"):
        drive.params.on_validate(name, validate)
    return pt
