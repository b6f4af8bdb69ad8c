"""Safe Torque Off, two channels (section 3.10, L2378-2515). A3-M only (L2384).

* Either channel lost: the hardware cuts motor current within 20 ms (L2474);
  `ModelOptions.sto_torque_cut_ms` (default 1 ms) is when the model's power stage drops.
* Both channels lost for 10 ms: servo off + AL500 (L2478). Clearable by ARST / P0.001 = 0 /
  6040h fault reset once both channels are back (L2493, L20199).
* One channel lost for 1 s: servo off + AL501 (A lost) or AL502 (B lost) (L2482, L2487,
  L20203, L20209), counted from that channel's own loss whatever the other does meanwhile
  (a brief dip of the other channel does not restart it); cleared only by a power cycle
  (L20205, L20211).
* Restored signals never clear an alarm by themselves (L2493).
* Before the 10 ms / 1 s acknowledgement the firmware is still Servo On (DO.SON, BRKR and the
  CiA 402 state stay): only the hardware has cut the torque (`ModelOptions.sto_servo_off`,
  applied in drive.py).

The printed state table (L2454-2468) maps the alarms the other way round; the notes and
chapter 13 agree with the mapping above (see docs/manual-choices.md). When both channels
are lost, they are no longer out of step: a channel's 1 s that ends while both are lost
raises nothing. If that loss of both raised AL500, a new second of mismatch counts from the
other channel's return (an E-stop released with its two contacts a few ms apart gives AL500
alone); after a shorter dip of the other, the channel's own second is up at the return.
"""

from __future__ import annotations

from collections.abc import Callable

from hil.model.options import ModelOptions
from hil.model.timebase import Scheduler, Timer, ms


class Sto:
    """STO_A / STO_B inputs, torque cut, AL500/AL501/AL502 and the FDBK output.

    `set_cause(code, present)` is the alarm manager's: present=True raises the alarm (the
    timers above decide when), present=False says the condition behind it has ended.
    """

    def __init__(
        self,
        sched: Scheduler,
        set_cause: Callable[[str, bool], None],
        on_torque_cut: Callable[[bool], None],
        on_fdbk: Callable[[bool], None],
        options: ModelOptions,
    ) -> None:
        self._sched = sched
        self._set_cause = set_cause
        self._on_cut = on_torque_cut
        self._on_fdbk = on_fdbk
        self._opt = options
        self.a = True  # 24 V present on STO_A
        self.b = True
        self.torque_cut = False
        self.fdbk = options.fdbk_table[(True, True)]
        self._cut_timer: Timer | None = None
        self._both_timer: Timer | None = None
        self._one_timers: dict[str, Timer | None] = {"A": None, "B": None}
        self._al500_raised = False  # in this loss of both channels
        # a channel's second ran out while both were lost (`_one_lost`): judged when the
        # other comes back
        self._one_expired: dict[str, bool] = {"A": False, "B": False}
        self._off = False  # control power off (power_off): nothing is judged

    @property
    def ok(self) -> bool:
        """Both channels present and torque not cut."""
        return self.a and self.b and not self.torque_cut

    def set_channel(self, channel: str, on: bool) -> None:
        """Electrical level of STO_A ("A") or STO_B ("B"): True = 24 V present."""
        ch = channel.upper().removeprefix("STO_")
        if ch not in ("A", "B"):
            raise ValueError(f"unknown STO channel {channel!r}: use 'A' or 'B'")
        if (self.a if ch == "A" else self.b) == on:
            return
        if ch == "A":
            self.a = on
        else:
            self.b = on
        self._update()

    def power_off(self) -> None:
        """Control power off: the firmware's timers stop (`reset()` judges the inputs
        afresh at power-up)."""
        self._cancel_timers()
        self._off = True

    def reset(self) -> None:
        """Power cycle: timers gone, state from the current inputs."""
        self._off = False
        self._cancel_timers()
        self.torque_cut = False
        self._on_cut(False)
        self._update()

    # -- internals -------------------------------------------------------------------------
    def _cancel_timers(self) -> None:
        for t in (self._cut_timer, self._both_timer, *self._one_timers.values()):
            if t:
                t.cancel()
        self._cut_timer = self._both_timer = None
        self._one_timers = {"A": None, "B": None}
        self._one_expired = {"A": False, "B": False}

    def _update(self) -> None:
        if self._off:  # inputs change while the drive is off: judged at power-up
            return
        a, b = self.a, self.b
        fdbk = self._opt.fdbk_table[(a, b)]
        if fdbk != self.fdbk:
            self.fdbk = fdbk
            self._on_fdbk(fdbk)
        # a condition that ended is no longer a cause (the alarm, if raised, stays). AL500's
        # cause ends only when both channels are back ("皆回復", L2493, L20199).
        for code, gone in (("AL500", a and b), ("AL501", a), ("AL502", b)):
            if gone:
                self._set_cause(code, False)
        lost = not (a and b)
        # hardware torque cut (L2474)
        if lost and not self.torque_cut and self._cut_timer is None:
            self._cut_timer = self._sched.after(ms(self._opt.sto_torque_cut_ms), self._cut)
        if not lost:
            if self._cut_timer:
                self._cut_timer.cancel()
                self._cut_timer = None
            if self.torque_cut and self._opt.sto_resume_after_dropout:
                self.torque_cut = False
                self._on_cut(False)
        al500 = self._al500_raised  # in the loss of both that may end now
        # both lost for 10 ms -> AL500 (L2478)
        if not a and not b:
            if self._both_timer is None:
                both = self._opt.dev_sto_both_lost_ms or self._opt.sto_both_lost_ms
                self._both_timer = self._sched.after(ms(both), self._both_lost)
        else:
            self._al500_raised = False
            if self._both_timer:
                self._both_timer.cancel()
                self._both_timer = None
        # a channel lost for 1 s -> AL501 (A) / AL502 (B) (L2482, L2487), from its own loss
        for ch, present in (("A", a), ("B", b)):
            timer = self._one_timers[ch]
            code = "AL501" if ch == "A" else "AL502"
            if present:
                self._one_expired[ch] = False
                if timer is not None:
                    timer.cancel()
                    self._one_timers[ch] = None
            elif al500 and (a or b):  # a loss of both that raised AL500 ended, this one
                if timer is not None:  # still lost: a new second of mismatch counts from now
                    timer.cancel()  # (an E-stop whose contacts close a few ms apart must
                self._one_expired[ch] = False  # not give AL501/AL502, cleared only by a
                self._arm_one(ch, code)  # power cycle, L20205)
            elif self._one_expired[ch] and (a or b):  # the other is back from a dip shorter
                self._one_expired[ch] = False  # than AL500's 10 ms: this one's second,
                self._set_cause(code, True)  # counted from its own loss, is up
            elif timer is None and not self._one_expired[ch]:
                self._arm_one(ch, code)

    def _arm_one(self, ch: str, code: str) -> None:
        one = self._opt.dev_sto_one_lost_ms or self._opt.sto_one_lost_ms
        self._one_timers[ch] = self._sched.after(ms(one),
                                                 lambda c=ch, k=code: self._one_lost(c, k))

    def _cut(self) -> None:
        self._cut_timer = None
        self.torque_cut = True
        self._on_cut(True)

    def _both_lost(self) -> None:
        """Both channels lost for the 10 ms (L2478): AL500."""
        self._both_timer = None
        self._al500_raised = True
        self._set_cause("AL500", True)  # raises the alarm; the cause is present now

    def _one_lost(self, channel: str, code: str) -> None:
        """A channel lost for its 1 s (L2482): AL501 / AL502, unless the other is lost too:
        then the two are no longer out of step ("沒有同步且差距達 1 秒以上", L20203, L20209)
        and AL500's 10 ms decides; when the other comes back, this one's alarm comes then
        after a dip shorter than AL500's 10 ms, or a new second counts after AL500
        (`_update`)."""
        self._one_timers[channel] = None
        if not (self.a or self.b):
            self._one_expired[channel] = True
            return
        self._set_cause(code, True)
