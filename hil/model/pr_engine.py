"""The PR executor (A3 manual §7.1.5-7.1.6): triggers, scheduler, executor, motion generator.

`attach_pr(core, homing=...)` wires a `PrEngine` into a drive through its public pieces
(core.py), like
`homing.attach_homing`. PR#0 stays in `homing.py`; its PATH (P6.000.YX) continues here.

Rules, each from the manual (choices: docs/manual-choices.md#pr, `PrOptions`):

* Triggers: DI.CTRG rising edge with POS0-POS6 = n (L4834-4840, L15098), P5.007 = 1..99
  (L11174), EV1-EV4 edges through P5.098/P5.099, nibble v -> PR#50+v (L12497-12551);
  DI.STP rising / P5.007 = 1000 stop (L11183, L15249). DI functions act after the P2.009
  filter (dio.py). A trigger acts on the next 1 ms tick (commands are updated every 1 ms,
  L4909); of the triggers of one ms the highest priority runs, the next one a ms later and a
  third is dropped: CTRG > P5.007 > Event rising > Event falling (L4916).
* Executor (L4918-4924): a dispatched lead PR replaces the running group; jump and write PRs
  complete when read; at most `group_limit` PRs per ms (">= 20", L5022); of the motion PRs
  read in one ms only the last one is executed (L5022, L5077).
* Sequencing: a PR without INS waits until the motion command before it and its DLY are done
  (position: the command reached the target; speed: the target speed; L4934-4961); a PR with
  INS is read right after the previous one, after the previous one's DLY counted from its
  start (internal interrupt, L4982-4986). A non-INS PR after a write/jump runs in the next ms
  (L5083). OVLP: the command counts as done when its deceleration starts, its DLY counts
  from the command start (L5051-5057); INS beats OVLP. A jump's DLY counts from its read
  and the target is read when it ran out (L4505, L4982).
* Targets (L4468-4471, L5000): ABS = data; INC = previous Cmd_E + data; REL = Fb_PUU + data
  when triggered, previous Cmd_E + data inside a chain (internal interrupt); CAP = last
  capture + data (`capture_puu`, set by capture.py for every captured point). STP keeps
  Cmd_E, so INC 0 finishes the move and REL 0 discards it (000:605).
* Completion (L4195-4201, L8596-8633, L15319-15326): Cmd_OK when the program has nothing
  left and the last command plus its DLY is done (a last WRITE's, or homing's with PATH 0,
  counted from its issue, L4533); MC_OK = Cmd_OK and TPOS; P1.048.X holds
  MC_OK, P1.048.Y raises AL380 when TPOS drops after MC_OK; a new trigger clears both.
  P5.007 reads n / n+10000 / n+20000 (L11185).
* Software limits P5.008/P5.009 in PR mode, judged on the command position in whole PUU,
  strictly beyond (L20105-20116):
  AL283/AL285 and DO.SPL/SNL, stop with the P5.003 Z/U deceleration, auto-clear when the
  command is back inside.
* Alarms: AL249 path > 99 (L20099), AL237 index before homing (L4593), AL207/AL209/AL213/
  AL215/AL231 write PR errors (L20044-20081), AL380.
* Data array (L5104-5147): P5.011 address, P5.012/P5.013 windows with auto-increment on every
  communication read and write, P5.100-P5.103 at address +0..+3.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Any

from hil.model.errors import (
    ModelError,
    OutOfRange,
    ParamError,
    ProtectedParameter,
    ReadOnly,
    ServoOnLocked,
)
from hil.model.motion import counts_to_puu, puu_per_s_to_rpm, puu_to_counts
from hil.model.timebase import Timer, ms
from hil.profile.pr import (
    ARRAY_SIZE,
    INDEX,
    JUMP,
    SPEED,
    WRITE,
    PrError,
    PrPath,
    read_path,
    source_error,
)
from hil.units import MS, s32

if TYPE_CHECKING:
    from hil.model.core import DriveCore
    from hil.model.counters import PositionCounters
    from hil.model.homing import Homing

POS_BITS = ("POS0", "POS1", "POS2", "POS3", "POS4", "POS5", "POS6")  # L15123-15133
PRIORITY = {"CTRG": 0, "P5.007": 1, "EV_RISE": 2, "EV_FALL": 3}  # L4916
DEFAULT_P5008, DEFAULT_P5009 = 2147483647, -2147483648


@dataclass
class PrOptions:
    """Choices (manual gaps) and deviation knobs (`dev_*`: a deliberately wrong drive)."""

    group_limit: int = 20  # PRs read per 1 ms group: "at least 20" (L4924, L5022)
    # a non-INS PR after a write/jump waits for the next 1 ms tick (L5083, statement note)
    next_ms_after_statement: bool = True
    # an empty path (definition 0) read in a chain ends the program (manual silent)
    stop_on_empty: bool = True
    # --- deviations ---
    dev_start_delay_ms: float = 0.0  # every trigger acts this much later
    dev_dly_offset_ms: float = 0.0  # added to every DLY
    dev_cmd_ok_ignores_dly: bool = False  # Cmd_OK at command end, DLY forgotten
    dev_mc_ok_ignores_tpos: bool = False  # MC_OK = Cmd_OK
    dev_soft_limit_on_feedback: bool = False  # P5.008/P5.009 judged on the feedback
    # sequential DLY counted from the command start, not from reaching the target (L4934)
    dev_dly_from_start: bool = False
    dev_ovlp_ignored: bool = False  # OVLP acts as a sequential command (L5051-5057)
    # OVLP re-targets the running move at the next PR's speed and ramps (the model before
    # wave 3 session 26) instead of summing the next PR's acceleration with the running
    # deceleration (figure 7.1.6.11, L5051-5057)
    dev_ovlp_retargets: bool = False
    dev_jump_ignores_dly: bool = False  # the jump target is read at once (DLY: L4505, L4982)
    dev_jump_falls_through: bool = False  # a jump continues with PR n+1 (target: L4505-4527)
    # software-limit stop with this deceleration (ms per 3000 rpm) instead of P5.003 Z/U
    dev_soft_limit_decel_ms: float | None = None

    def __post_init__(self) -> None:
        if self.group_limit < 1:
            raise ValueError("pr.group_limit: must be >= 1")

    @classmethod
    def from_dict(cls, data: dict[str, Any] | None) -> PrOptions:
        data = dict(data or {})
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"options.extra.pr: unknown key(s) {unknown}; known: {sorted(known)}")
        return cls(**data)


@dataclass
class _Cmd:
    """The motion command in the generator."""

    path: PrPath | None  # None: a stop ramp (STP / software limit)
    start: int
    dly_ns: int
    done: int | None = None  # time the command output finished (or its decel began: OVLP)
    dly_from_start: bool = False  # OVLP: the DLY counts from the command start (L5051)
    overlaps: bool = False  # OVLP with a next motion PR: done once the decel begins
    short_of_cmd_e: bool = False  # a stop that cut a position PR short of Cmd_E (TPOS, L8694)

    def end(self) -> int | None:
        """When the command and its DLY are over (None: still running)."""
        if self.done is None:
            return None
        if self.dly_from_start:
            return max(self.done, self.start + self.dly_ns)
        return self.done + self.dly_ns


class PrEngine:
    """One PR executor per drive."""

    def __init__(self, drive: DriveCore, options: PrOptions | None = None,
                 homing: Homing | None = None) -> None:
        self.drive = drive
        self._limit_params = drive.params.cached("P5.008", "P5.009")  # read every step
        self.options = options or PrOptions.from_dict(drive.options.extra.get("pr"))
        self.homing = homing  # PR#0 (homing.py)
        self.counters: PositionCounters | None = None  # AL235 after an overflow (counters.py)
        self.array = drive.array  # the data array (L5097), shared with CAPTURE/COMPARE
        self.capture_puu = 0  # last CAPTURE value, base of CAP commands (L4471)
        self.lead: int | None = None  # PR number of the last trigger (P5.007 read-back)
        self._failed = False  # the program ended unfinished on an alarm (`_fail`)
        self._readback: int | None = None  # P5.007 of a finished program a servo off ended
        self.cursor: int | None = None  # next PR to read
        self.cmd: _Cmd | None = None
        self.cmd_e = 0  # Cmd_E, monitor 064 [PUU] (L4180)
        self.cmd_ok = False
        self.mc_ok = False
        self.trace: list[tuple[int, str]] = []  # (t, what) for tests and recordings
        self._mc_was_on = False
        # TPOS off from a trigger until the command reached its target (L8624, L8689-8693)
        self.tpos_off = False
        self._home_at: int | None = None  # a jump to PR#0: homing starts then (its DLY)
        # a triggered lead's motion (no INS) waiting in the generator's one-command buffer for
        # the running command (L4928) while the rest of its group is read and run (L4924)
        self._buffered: tuple[PrPath, bool] | None = None
        self._prev_t = 0  # read time of the previous PR of the chain
        self._prev_dly = 0  # its DLY, ns
        self._prev_motion = False
        self._external = False  # the next read is a triggered lead PR
        self._queue: list[tuple[int, int, str]] = []  # (priority, seq, "n:source")
        self._seq = 0
        self._tick: Timer | None = None
        self._wake: Timer | None = None
        self._wake_t: int | None = None
        self._limits = {"AL283": False, "AL285": False}

    # ---------------------------------------------------------------- triggers
    def trigger(self, n: int, source: str) -> None:
        """PR#n triggered by `source` (CTRG, P5.007, EV_RISE, EV_FALL)."""
        d = self.drive
        if not d.servo_on or not pr_mode(d):
            return
        self._seq += 1
        self._queue.append((PRIORITY.get(source, 9), self._seq, f"{n}:{source}"))
        self.trace.append((d.now, f"trigger:{source}:{n}"))
        if self._tick is None:
            delay = ms(self.options.dev_start_delay_ms)
            tick = (d.now // MS + 1) * MS + delay
            self._tick = d.sched.at(tick, self._on_tick)

    def _on_tick(self) -> None:
        self._tick = None
        queue = sorted(self._queue)
        self._queue = []
        if not queue:
            return
        first, rest = queue[0], queue[1:]
        if rest:  # the second runs in the next ms, a third is dropped (L4916)
            self._queue = [rest[0]]
            self._tick = self.drive.sched.after(MS, self._on_tick)
            for dropped in rest[1:]:
                self.trace.append((self.drive.now, f"dropped:{dropped[2]}"))
        n, source = first[2].split(":")
        self.dispatch(int(n), source)

    def dispatch(self, n: int, source: str = "") -> None:
        """The scheduler hands lead PR#n to the executor (replacing its group)."""
        d = self.drive
        if not d.servo_on:
            return
        if n > 99:
            d.alarms.raise_alarm("AL249")  # PR path number > 99 (L20099)
            return
        homing = self.homing
        if homing is not None and homing.route == "pr":
            homing.stop()  # the new group replaces PR#0 (L4920)
        self.trace.append((d.now, f"dispatch:{n}"))
        self._new_lead(n)
        self.cursor = n
        self._buffered = None  # the new group replaces the old (L4920-4924)
        self.tpos_off = True  # "清除信號 2、4、5、6" (L8624): Cmd_OK, TPOS, MC_OK
        self._external = True
        self._prev_t = d.now
        self._prev_dly = 0
        self._prev_motion = False
        self._set_cmd_ok(False)
        d.refresh_outputs()
        self._service()

    def stop(self, source: str = "STP") -> None:
        """DI.STP / P5.007 = 1000: stop the program and decelerate (L11183, L15249)."""
        d = self.drive
        if not pr_mode(d):
            return  # STP and P5.007 are PR-mode functions (L15249, L11168)
        self.trace.append((d.now, f"stop:{source}"))
        self.cursor = None
        self._buffered = None  # a buffered motion does not run after the stop either
        self._cancel_wake()
        if d.axis.power and (d.axis.moving or d.axis.velocity != 0.0):
            d.axis.ramp_stop(d.p5003_decel(7))  # P5.003.D: STP decel (L11091-11100)
            self.cmd = _Cmd(None, d.now, 0, short_of_cmd_e=self._cuts_a_position())
        self._service()

    def after_homing(self) -> None:
        """PR#0 finished: Cmd_E = ORG_DEF (L4396); run PATH after DLY (P6.000, L12607-12631)."""
        d = self.drive
        p6000 = d.params.get("P6.000")
        self.cmd_e = d.params.get("P6.001")
        path = p6000 & 0xFF
        self._new_lead(0)
        self._prev_t = d.now
        self._prev_dly = self._dly_ns((p6000 >> 20) & 0xF)
        self._prev_motion = False
        if not 1 <= path <= 0x63:  # PATH 0 "Stop": Cmd_OK once its DLY ran out (L4195)
            self.cursor = None
            self._update_cmd_ok()
            return
        self.cursor = path
        self._external = False
        self._service()

    def power_up(self) -> None:
        """At power-up Cmd_E is where the motor is (the coordinate the drive starts with:
        0 incremental, the absolute position): an INC path adds to it (L4180)."""
        self.abort()
        self._new_lead(None)  # nothing ran yet: P5.007 reads what was written
        d = self.drive
        self.cmd_e = round(counts_to_puu(d.axis.user_position, d.params.get("P1.044"),
                                         d.params.get("P1.045")))

    def _new_lead(self, n: int | None) -> None:
        """A new program (or none): P5.007 follows it, whatever ended the last one."""
        self.lead = n
        self._failed = False
        self._readback = None

    def homing_started(self) -> None:
        """PR#0 (SHOM, CTRG with POS 0, BOOT) replaces the program: P5.007 follows PR#0,
        "0" while it runs (L11185-11189), not the program before."""
        self.abort()
        self._new_lead(0)

    def servo_off(self) -> None:
        """Servo off ends the program (`abort`); one that had finished keeps reading its
        n+20000 / n+10000 in P5.007 (it is not running, L11185-11189)."""
        if self.cmd_ok and self.lead is not None and self._readback is None:
            self._readback = self.p5007_readback()
        self.abort()

    def abort(self) -> None:
        """The program ends without finishing (servo off, homing started, alarm)."""
        self.cursor = None
        self._home_at = None
        self._buffered = None
        self.cmd = None
        self.tpos_off = False
        self._cancel_wake()
        self._set_cmd_ok(False)

    # ---------------------------------------------------------------- executor
    def _service(self) -> None:
        """Read PRs while they are ready (one 1 ms group), then execute the group's motion."""
        d = self.drive
        now = d.now
        if self._home_at is not None:
            self._jump_home()
            return
        if self._buffered is not None:
            idle = self._generator_idle()
            if idle is not None and idle <= now:
                self._issue(*self._buffered)  # the generator took it from its buffer
            elif idle is not None:
                self._wake_at(idle)
        count = 0
        motion: tuple[PrPath, bool] | None = None
        while self.cursor is not None:
            if count >= self.options.group_limit:
                self._wake_at(now + MS)
                break
            try:
                path = read_path(d.params.get, self.cursor)
            except PrError as exc:
                self._fail(exc.alarm, str(exc))
                break
            if path.type == 0 and self.options.stop_on_empty:
                self.cursor = None
                break
            ready = self._ready(path, motion is not None or self._buffered is not None)
            if ready is None:
                break  # waits for the motion command (after_step)
            if ready > now:
                self._wake_at(ready)
                break
            external = self._external
            self._external = False
            count += 1
            self.trace.append((now, f"read:{path.number}:{path.name}"))
            if path.is_motion:
                motion = (path, external)  # only the last motion PR of a group runs
            elif path.type == WRITE and not self._write(path):
                break
            self._advance_cursor(path)
        if motion is not None and not self._failed:  # an alarm ended the group: no motion
            path, external = motion
            idle = self._generator_idle()
            if external and not path.ins and (idle is None or idle > now):
                self._buffered = motion  # the one-command buffer (L4928)
                if idle is not None:
                    self._wake_at(idle)
            else:
                self._issue(*motion)
        if self._home_at is not None:
            self._jump_home()
        self._update_cmd_ok()

    def _jump_home(self) -> None:
        """A jump to PR#0: homing, triggered once the jump's DLY ran out (L4505)."""
        at = self._home_at
        if at is not None and at > self.drive.now:
            self._wake_at(at)
            return
        self._home_at = None
        if self.homing is not None:
            self.homing.trigger_pr("jump")

    def _ready(self, path: PrPath, motion_in_group: bool) -> int | None:
        """Earliest time PR `path` may be read; None = after the running command is done."""
        now = self.drive.now
        if self._external:  # the lead: read at once, its motion buffered if need be (L4924)
            return now
        base = self._prev_t + self._prev_dly
        if path.ins:
            return base  # internal interrupt (L4982-4986)
        if motion_in_group:
            return None  # the group's motion must run (and finish) first
        idle = self._generator_idle()
        if idle is None:
            return None
        t = max(base, idle)
        if not self._prev_motion and self.options.next_ms_after_statement:
            t = max(t, self._prev_t + MS)  # L5083
        return t

    def _generator_idle(self) -> int | None:
        """Time the motion generator is free: command done + its DLY (L4934)."""
        c = self.cmd
        if c is None:
            return 0
        return c.end()

    def _advance_cursor(self, path: PrPath) -> None:
        d = self.drive
        o = self.options
        self._prev_t = d.now
        self._prev_dly = self._dly_ns(path.dly)  # from the read = the command start (L5051)
        if path.type == JUMP and o.dev_jump_ignores_dly:
            self._prev_dly = 0
        self._prev_motion = path.is_motion
        if path.type == JUMP:  # DLY counts from the jump's read (L4505)
            target = path.number + 1 if o.dev_jump_falls_through else path.data
            if target == 0 and self.homing is not None:  # PR#0 is homing (L4505, L4516)
                self.cursor = None  # ... triggered once the jump's DLY ran out (L4505)
                self._home_at = self._prev_t + self._prev_dly
            else:
                self.cursor = target
        elif path.continues:
            self.cursor = path.number + 1
            if self.cursor > 99:
                self._fail("AL249", f"PR#{path.number} continues to PR#100 (L20099)")
        else:
            self.cursor = None

    def _dly_ns(self, index: int) -> int:
        """DLY entry #index = P5.040 + index, ms (L11546)."""
        return ms(self.drive.params.get(f"P5.{40 + index:03d}") + self.options.dev_dly_offset_ms)

    def _fail(self, alarm: str, reason: str) -> None:
        """The program ends there. An alarm that turns the servo off (AL249, AL809) ends it
        unfinished: no Cmd_OK, no motion of its group, P5.007 reads n ("not finished",
        L11189) until the next trigger; after a warning (AL213, the servo on) Cmd_OK follows
        as after STP (docs/manual-choices.md)."""
        self.trace.append((self.drive.now, f"error:{reason}"))
        self.cursor = None
        if alarm:
            self.drive.alarms.raise_alarm(alarm)
        self._failed = not self.drive.servo_on

    # ---------------------------------------------------------------- motion generator
    def _issue(self, path: PrPath, external: bool) -> None:
        """Send a motion PR to the generator, merged with the running command (L4468-4471)."""
        self._buffered = None  # run, or replaced by a later motion PR (INS) of the group
        d = self.drive
        ax = d.axis
        get = d.params.get
        g44, g45 = get("P1.044"), get("P1.045")
        acc = float(get(f"P5.{20 + path.acc:03d}"))
        dec = float(get(f"P5.{20 + path.dec:03d}"))
        # OVLP: the PR the overlapping one continues to (not an INS one, which beats OVLP,
        # nor a new trigger) starts from rest, summed with the running deceleration (L5051)
        prev = self.cmd
        overlap = (not external and not path.ins and prev is not None and prev.overlaps
                   and prev.done is not None and not self.options.dev_ovlp_retargets)
        if path.type == SPEED:
            rpm = puu_per_s_to_rpm(path.data, g44, g45) if path.unit_pps else path.data / 10.0
            ax.run_velocity(rpm, acc, dec, overlap=overlap)
            direction = rpm
        else:
            # 0.1 rpm (L11783); an index PR with S_LOW in 0.01 rpm (OPT2 bit 0, L4637)
            rpm = get(f"P5.{60 + path.spd:03d}") / (100.0 if path.s_low else 10.0)
            target = self._target(path, external, g44, g45)
            if target is None:
                return
            self.cmd_e = target
            counts = puu_to_counts(target, g44, g45) + ax.origin
            direction = counts - ax.demand
            ax.move_to(counts, rpm, acc, dec, overlap=overlap)
        self.trace.append((d.now, f"motion:{path.number}"))
        self._limit_inhibit(direction)
        ovlp = path.ovlp and not self.options.dev_ovlp_ignored
        from_start = ovlp or self.options.dev_dly_from_start
        self.cmd = _Cmd(path, d.now, self._dly_ns(path.dly), dly_from_start=from_start,
                        overlaps=ovlp and self._next_is_motion(path))

    def _next_is_motion(self, path: PrPath) -> bool:
        """OVLP overlaps the next PR's motion (L5051-5057): there must be one, the PR this
        one continues to. Without it the command completes as any other (Cmd_OK at its end,
        L15319)."""
        if not path.continues or path.number >= 99:
            return False
        try:
            return read_path(self.drive.params.get, path.number + 1).is_motion
        except PrError:
            return False

    def _limit_inhibit(self, direction: float) -> None:
        """PL/NL already active: "正向/反向運轉禁止極限" in every mode (L15188-15191) - a PR
        towards it stops at once with P5.003 X (PL) / Y (NL), as an NL/PL edge stops one."""
        d = self.drive
        fn = "PL" if direction > 0 else "NL"
        if direction and d.dio.function_active(fn):
            d.axis.ramp_stop(d.p5003_decel(0 if fn == "PL" else 1))
            self.trace.append((d.now, f"inhibit:{fn}"))

    def _target(self, path: PrPath, external: bool, g44: int, g45: int) -> int | None:
        d = self.drive
        v = path.data
        if path.type == INDEX:
            homing = self.homing
            if homing is None or not homing.homed:
                self._fail("AL237", f"PR#{path.number}: index coordinate undefined (L4593)")
                return None
            span = max(1, d.params.get("P2.052"))
            here = self.cmd_e % span
            fwd = (v - here) % span
            rev = fwd - span if fwd else 0
            step = {"forward": fwd, "reverse": rev}.get(
                path.direction, fwd if fwd <= -rev else rev
            )
            return self.cmd_e + step
        if self.counters is not None and self.counters.refuse():
            self._fail("", f"PR#{path.number}: position counter overflowed (AL235, L20085)")
            return None
        cmd = path.cmd
        if cmd == "ABS":
            return v
        # REL acts as INC in an internal interrupt (an INS PR of the chain, L5000); any other
        # REL is the motor's position plus the data (L4469), a sequential one's too
        if cmd == "INC" or (cmd == "REL" and not external and path.ins):
            return self.cmd_e + v
        if cmd == "REL":
            return round(counts_to_puu(d.axis.user_position, g44, g45)) + v
        return self.capture_puu + v  # CAP

    def _write(self, path: PrPath) -> bool:
        """Execute a write PR (L4545-4589); False (and an alarm) when the drive refuses."""
        d = self.drive
        try:
            value = self._source(path)
        except PrError as exc:
            self._fail(exc.alarm, str(exc))
            return False
        except ModelError as exc:
            self._fail("AL209", str(exc))
            return False
        # a constant is the PR's 32-bit data word (L4585): a parameter whose range is the
        # unsigned 0x00000000~0xFFFFFFFF (P5.003, L11085) reads it unsigned, a data-array
        # entry (signed 32-bit, P5.012) signed
        if path.dest_array:
            self.array[path.dest] = s32(value)
        else:
            spec = d.params.table.spec(path.dest_param)
            if value < 0 and spec.min >= 0 and spec.max > 0x7FFFFFFF:
                value &= 0xFFFFFFFF
            try:
                d.params.write(path.dest_param, value, ram_only=not path.rom)  # ROM: L4533
            except ReadOnly as exc:
                self._fail("AL215", str(exc))  # read-only (L20059-20063)
                return False
            except ServoOnLocked as exc:
                self._fail("AL217", str(exc))  # "伺服 ON 不可寫入" (L20065-20069)
                return False
            except ProtectedParameter as exc:
                self._fail("AL219", str(exc))  # P5.097 write protection (L20071-20075)
                return False
            except ParamError as exc:
                self._fail("AL213", str(exc))  # value outside its range (L20054-20057)
                return False
        self.trace.append((d.now, f"write:{path.number}"))
        return True

    def _source(self, path: PrPath) -> int:
        d = self.drive
        if path.source == "constant":
            return path.data
        if path.source == "array":
            return self.array[path.data]
        if path.source == "parameter":
            source_error(path, f"PR#{path.number}")
            return d.params.read(path.source_param)
        return self.monitor(path.data)

    def monitor(self, code: int) -> int:
        """Monitor variables of PR mode (L4178-4183): 064 Cmd_E here; 000 Fb_PUU, 001 Cmd_O,
        002 Err_PUU and the rest as every reader of them has them (`Hooks.monitors`)."""
        d = self.drive
        part = d.hooks.monitors.get(code)  # every part's codes (000-006, 037, 064 here ...)
        if part is None:
            raise PrError(f"monitor code {code} not available (AL231)", "AL231")
        return part()

    # ---------------------------------------------------------------- every motion step
    def after_step(self) -> None:
        d = self.drive
        h = self.homing
        if h is not None and h.route == "pr":  # PR#0 runs (L4396): Cmd_E = Cmd_O until the
            if h.home_counts is None:         # reference, then the reference's coordinate
                self.cmd_e = round(counts_to_puu(d.axis.user_demand, d.params.get("P1.044"),
                                                 d.params.get("P1.045")))
            else:
                self.cmd_e = d.params.get("P6.001")
        c = self.cmd
        if c is not None and c.done is None and self._command_done(c):
            c.done = d.now
            self.tpos_off = False
            self.trace.append((d.now, f"done:{c.path.number if c.path else 'stop'}"))
            if d.now % MS == 0:
                self._service()
            else:
                self._wake_at((d.now // MS + 1) * MS)
        if self._limit_check:
            self._soft_limits()
        self.refresh_outputs()

    def refresh_outputs(self) -> None:
        """MC_OK and AL380 follow TPOS whenever it changes, moving or not (L8608-8632)."""
        if self.cmd_ok:
            self._update_mc_ok()

    def _command_done(self, c: _Cmd) -> bool:
        ax = self.drive.axis
        if c.path is None:  # a stop (STP, a software limit): done when its ramp ended
            return ax.demand_velocity == 0.0 or not ax.moving  # (docs/manual-choices.md)
        if c.path.type == SPEED:
            return ax.at_target
        if ax.mode != "position":
            return True  # replaced by a stop / another mode
        if c.overlaps:  # OVLP into the next motion: the decel began (L5051)
            r = abs(ax.profile_remaining)  # its own profile: an earlier OVLP's tail aside
            v = abs(ax.profile_velocity)
            return ax.at_target or (v > 0 and r <= v * v / (2.0 * ax.profile_decel) + v * 1e-3)
        return ax.at_target

    # ---------------------------------------------------------------- software limits
    @property
    def _limit_check(self) -> bool:
        p5008, p5009 = self._limit_params()
        return (
            p5008 != DEFAULT_P5008 or p5009 != DEFAULT_P5009
            or self._limits["AL283"] or self._limits["AL285"]
        )

    def _soft_limits(self) -> None:
        """AL283/AL285 on the command position, PR mode only (L20105-20116, L11191-11207)."""
        d = self.drive
        get = d.params.get
        ax = d.axis
        pr_mode = get("P1.001") & 0xF == 1
        pos = ax.user_position if self.options.dev_soft_limit_on_feedback else ax.user_demand
        puu = round(counts_to_puu(pos, get("P1.044"), get("P1.045")))  # integer PUU (L4180)
        for code, over, sym, digit, sign in (
            ("AL283", puu > get("P5.008"), "SPL", 2, 1),
            ("AL285", puu < get("P5.009"), "SNL", 3, -1),
        ):
            over = over and pr_mode
            if over != self._limits[code]:
                self._limits[code] = over
                d.alarms.set_cause(code, over)  # clears itself when back inside (L20109)
                d.dio.set_do_function(sym, over)  # L15313-15316
                self.trace.append((d.now, f"{code}:{int(over)}"))
            if over and ax.demand_velocity * sign > 0 and ax.mode != "stop":
                self.cursor = None
                self._buffered = None  # the limit ends the program, a buffered lead too
                decel = self.options.dev_soft_limit_decel_ms
                if decel is None:
                    decel = d.p5003_decel(digit)  # P5.003 Z SPL / U SNL (L11091-11100)
                ax.ramp_stop(decel)
                self.cmd = _Cmd(None, d.now, 0, short_of_cmd_e=self._cuts_a_position())

    # ---------------------------------------------------------------- outputs
    def _update_cmd_ok(self) -> None:
        """Cmd_OK: nothing left to read and the command plus its DLY done (L15319); when the
        program ended on a statement (a WRITE PR, or homing's PATH 0), its DLY too, counted
        from its read ("驅動器即開始計算延遲時間" L4533; "待延遲時間終了 ... Cmd_OK 才會輸出"
        L4195-4197)."""
        if (self.cursor is not None or self.lead is None or self._home_at is not None
                or self._buffered is not None or self._failed):
            return
        if self.homing is not None and self.homing.pr_busy:
            return  # PR#0 runs: Cmd_OK comes after it (`after_homing`)
        c = self.cmd
        end = None
        if c is not None:
            if c.done is None:
                return
            end = c.done
            if not self.options.dev_cmd_ok_ignores_dly:
                end = c.end() or end
        if self.tpos_off:  # the command is out: TPOS judges again, during the DLY too (L4195)
            self.tpos_off = False
            self.drive.refresh_outputs()
        if not self._prev_motion and not self.options.dev_cmd_ok_ignores_dly:
            last = self._prev_t + self._prev_dly
            end = last if end is None else max(end, last)
        if end is not None and end > self.drive.now:
            self._wake_at(end)
            return
        self._set_cmd_ok(True)

    def _set_cmd_ok(self, on: bool) -> None:
        d = self.drive
        if on == self.cmd_ok and (on or not self.mc_ok):
            return
        self.cmd_ok = on
        d.dio.set_do_function("Cmd_OK", on)
        self.trace.append((d.now, f"Cmd_OK:{int(on)}"))
        if not on:  # a new trigger clears Cmd_OK and MC_OK (L8624)
            self._mc_was_on = False
            self._set_mc_ok(False)
        else:  # the command is output (a write / jump / stop ended it too): TPOS judges again
            self.tpos_off = False
            d.refresh_outputs()

    def stopped_short(self) -> bool:
        """The last command was a stop (STP, a software limit) that cut a position PR short of
        Cmd_E: TPOS then judges Cmd_E (L8694), which the stop kept. (A stopped speed PR has no
        set target: TPOS stays the following error's.)"""
        c = self.cmd
        return c is not None and c.short_of_cmd_e

    def _cuts_a_position(self) -> bool:
        """The command a stop replaces is a position PR (or a stop that had cut one)."""
        c = self.cmd
        if c is None:
            return False
        if c.path is None:
            return c.short_of_cmd_e
        return c.path.type != SPEED

    def _tpos(self) -> bool:
        return self.drive.tpos()

    def _update_mc_ok(self) -> None:
        d = self.drive
        tpos = self._tpos() or self.options.dev_mc_ok_ignores_tpos
        p1048 = d.params.get("P1.048")
        on = self.cmd_ok and tpos
        if self._mc_was_on and not tpos:
            if (p1048 >> 4) & 0xF == 1:
                d.alarms.raise_alarm("AL380")  # displaced after positioning (L8632, L20147)
            if p1048 & 0xF == 1:
                on = True  # hold (L8609-8611)
        self._set_mc_ok(on)

    def _set_mc_ok(self, on: bool) -> None:
        if on != self.mc_ok:
            self.mc_ok = on
            self.drive.dio.set_do_function("MC_OK", on)
            self.trace.append((self.drive.now, f"MC_OK:{int(on)}"))
        if on:
            self._mc_was_on = True

    def p5007_readback(self) -> int:
        """n while running, n+10000 command sent, n+20000 and TPOS on (L11185)."""
        if self.lead is None:
            return self.drive.params.stored("P5.007")
        if self._readback is not None:  # finished before a servo off ended it
            return self._readback
        if not self.cmd_ok:
            return self.lead
        return self.lead + (20000 if self._tpos() else 10000)

    # ---------------------------------------------------------------- timers
    def _wake_at(self, t: int) -> None:
        w = self._wake_t
        if self._wake is not None and w is not None and self.drive.now <= w <= t:
            return  # an earlier wake re-evaluates anyway
        self._cancel_wake()
        self._wake_t = t
        self._wake = self.drive.sched.at(t, self._on_wake)

    def _on_wake(self) -> None:
        self._wake = None
        self._wake_t = None
        self._service()

    def _cancel_wake(self) -> None:
        if self._wake is not None:
            self._wake.cancel()
        self._wake = None
        self._wake_t = None

    # ---------------------------------------------------------------- data array
    def array_entry(self) -> int:
        """The data-array entry at P5.011, read without advancing it."""
        addr = self.drive.params.stored("P5.011")
        return self.array[addr] if 0 <= addr < ARRAY_SIZE else 0

    def array_window(self, name: str, value: int | None = None) -> int:
        """Read (value None) or write P5.012/P5.013 at P5.011, then P5.011 += 1 (L5111-5114)."""
        params = self.drive.params
        addr = params.stored("P5.011")
        if not 0 <= addr < ARRAY_SIZE:
            return 0
        if value is None:
            value = self.array[addr]
        else:
            self.array[addr] = value
        params.set_internal("P5.011", (addr + 1) % ARRAY_SIZE)
        return value


PR_MODES = (0x01, 0x08, 0x09, 0x0D, 0x0E, 0x0F)  # P1.001.YX with PR (L7749-7800)


def pr_mode(drive: DriveCore) -> bool:
    """PR triggers act: P1.001.YX selects a mode with PR (or the option says any mode)."""
    if not drive.options.pr_triggers_need_pr_mode:
        return True
    yx = drive.params.get("P1.001") & 0xFF
    if yx in (0x0D, 0x0E, 0x0F):  # PT-PR: the PR side only while DI.PT-PR is on (L15200)
        return drive.control_mode() == "PR"
    return yx in PR_MODES


def _pos_number(dio: Any) -> int:
    return sum(1 << i for i, f in enumerate(POS_BITS) if dio.function_active(f))


def attach_pr(drive: DriveCore, options: PrOptions | None = None, *,
              homing: Homing | None = None, counters: PositionCounters | None = None
              ) -> PrEngine:
    """Create the PR engine of `drive` and wire triggers, hooks and parameters."""
    pr = PrEngine(drive, options, homing)
    pr.counters = counters
    drive.hooks.monitors[64] = lambda: pr.cmd_e  # Cmd_E, PR command end point (L15497)
    # AL237 (index coordinate undefined) "can also be cleared at Servo On" (L20096)
    drive.hooks.servo_on.append(lambda: drive.alarms.clear("AL237"))
    dio = drive.dio
    params = drive.params

    def on_ctrg(active: bool) -> None:  # CTRG + POS0-6 = n (L4834-4840); 0 is homing
        n = _pos_number(dio)
        if active and n:
            pr.trigger(n, "CTRG")

    dio.on_function("CTRG", on_ctrg)
    dio.on_function("STP", lambda a: a and pr.stop("STP"))  # rising edge (L15249)
    for i, ev in enumerate(("EV1", "EV2", "EV3", "EV4")):

        def on_event(active: bool, i: int = i) -> None:  # L12497-12551
            reg = params.get("P5.098" if active else "P5.099")
            v = (reg >> (4 * i)) & 0xF
            if v:
                pr.trigger(50 + v, "EV_RISE" if active else "EV_FALL")

        dio.on_function(ev, on_event)

    def check_p5007(_name: str, value: int) -> None:
        if 100 <= value <= 999:
            raise OutOfRange("P5.007", f"{value}: 100~999 may not be written (L11176)")

    def on_p5007(_n: str, _old: int, new: int) -> None:
        if 1 <= new <= 99:
            pr.trigger(new, "P5.007")
        elif new == 1000:
            pr.stop("P5.007")
        elif new == 0:
            pr.abort()  # homing (homing.py) replaces the program
            pr._new_lead(None)

    params.on_validate("P5.007", check_p5007)
    params.on_write("P5.007", on_p5007)
    params.on_read("P5.007", pr.p5007_readback)
    for name in ("P5.012", "P5.013"):
        params.on_write(name, lambda n, _o, new: pr.array_window(n, new))
        params.on_read(name, lambda n=name: pr.array_window(n))
        params.on_peek(name, pr.array_entry)  # a one-word write keeps the entry's other half
    for k in range(4):  # P5.100-P5.103: address +0..+3, no increment (L5138-5147)

        def window(k: int = k) -> int:
            addr = params.stored("P5.011") + k
            return pr.array[addr] if addr < ARRAY_SIZE else 0

        def write(_n: str, _o: int, new: int, k: int = k) -> None:
            addr = params.stored("P5.011") + k
            if addr < ARRAY_SIZE:
                pr.array[addr] = new

        params.on_read(f"P5.{100 + k:03d}", window)
        params.on_peek(f"P5.{100 + k:03d}", window)
        params.on_write(f"P5.{100 + k:03d}", write)
    params.on_read("P5.010", lambda: ARRAY_SIZE)

    if homing is not None:
        homing.on_pr_done = pr.after_homing
        homing.on_pr_start = pr.homing_started
    drive.hooks.step.append(pr.after_step)
    drive.hooks.boot.append(pr.power_up)
    drive.hooks.servo_off.append(pr.servo_off)  # servo off ends the program, a DLY's too
    return pr


__all__ = ["PrEngine", "PrOptions", "attach_pr"]
