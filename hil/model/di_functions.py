"""DI functions of table 8.1 that act on the motion (docs/manual-choices.md).

* PFQS (0x47, rising edge, PT/PR/T/S, L15253): AL35F and a ramp with the P5.003 digit C
  deceleration (L11084-11100); at zero speed AL3CF and Servo Off (L20141-20157). Clearing:
  option `pfqs_clear`.
* JOGU / JOGD (0x37 / 0x38, level, All, L15209-15212): while held and the servo is on, jog
  at P4.005 rpm (L10846-10861), capped at P1.055; both or neither held: ramp to a stop.
  Jog through P4.005 (communication, L10863-10866): 4998 jogs CCW, 4999 CW, 0 stops, any
  other value is the jog speed.
* TRQLM (0x09, level, PT/PR/S, L15101): with DI.TRQLM on or P1.002.Y = 1 (an OR, L7845) the
  torque is limited to the TCM0/TCM1 source: 00 analog T_REF x P1.041 / 10 V, 01-11
  |P1.012|-|P1.014| % (L4042-4044, L7993-8031), together with 60E0h/60E1h.
* SPDLM (0x10, level, T, L15121): with DI.SPDLM on or P1.002.X = 1 the speed in torque mode
  (T/Tz only, L7831) is limited to the SPD0/SPD1 source: 00 analog V_REF x P1.040 / 10 V,
  01-11 |P1.009|-|P1.011| x 0.1 rpm (L4034-4036, L7931-7991), together with P1.055.
* ZCLAMP (0x05, level, S, L15091): in speed mode with DI.ZCLAMP on, the ramped speed command
  below P1.038 stops the motor (L9904-9920): P2.065 bit 10 = 0 locks the position where the
  clamp began, = 1 commands 0 rpm.
* CCLR (0x04, PT/PR, L15088): clears the accumulated position error (demand := feedback);
  P2.050 = 0 on the rising edge, 1 while on (L9742-9753).
* GAINUP (0x03, level, PT/PR/S, L15085): with P2.027.X = 1 (on) / 5 (off) the gains switch
  (L9423-9466): Y = 0 position gain x P2.001 %, speed gain x P2.005 %; Y = 1 (integrator
  switch) is recorded only. `gain_switched` and the snapshot show the state.
* The S/Sz and T/Tz commands (P1.001.X = 2/4, 3/5; §6.3.1 L3709-3721, L15151-15168): with the
  servo on the motor runs at the speed SPD0/SPD1 select (00: S the analog V_REF x P1.040 /
  10 V, Sz 0; 01-11 P1.009-P1.011 x 0.1 rpm), ramped by P1.034 / P1.035 (ms from 0 to the
  rated speed, L8334-8350), at once on a change (no CTRG); in T/Tz it gives the torque
  TCM0/TCM1 select (00: T the analog T_REF x P1.041 / 10 V, Tz 0; 01-11 P1.012-P1.014 %).
  Not modelled: the P1.036 S-curve and the P1.007 torque smoothing (a trapezoid, a step).

The table's "控制模式" column is `control_mode()` (option `di_modes_follow_cia402`).
Choices: docs/manual-choices.md#di-functions.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from hil.model.absolute import AbsoluteEncoder
    from hil.model.core import DriveCore
    from hil.model.pulse_train import PulseTrain

# P1.001.YX -> table 8.1 mode; mixed modes take the first (S-P/S-T/T-P/PT-PR are not
# modelled), CANopen 0x0C has none of its own (L7749-7800).
P1001_MODES = {0: "PT", 1: "PR", 2: "S", 3: "T", 4: "Sz", 5: "Tz", 6: "PT", 7: "PT", 8: "PR",
               9: "PR", 0x0A: "S", 0x0D: "PT", 0x0E: "PT", 0x0F: "PT"}  # fmt: skip
# CiA 402 mode of operation 6061h -> table 8.1 mode (option di_modes_follow_cia402).
CIA402_MODES = {1: "PR", 6: "PR", 7: "PR", 8: "PR", 3: "S", 9: "S", 4: "T", 10: "T"}

PFQS_MODES = ("PT", "PR", "T", "S")  # L15253
POSITION_MODES = ("PT", "PR")  # CCLR L15088
TRQLM_MODES = ("PT", "PR", "S", "Sz")  # L15101; P1.012 lists Sz too (L7994)
SPDLM_MODES = ("T", "Tz")  # L15121, "只在 T / Tz 模式有效" L7831
ZCLAMP_MODES = ("S", "Sz")  # "在速度模式" L9906
GAINUP_MODES = ("PT", "PR", "S", "Sz")  # L15085, P2.027 table "P / S" (L9458)

SPEED_MODES = ("S", "Sz")  # §6.3.1, L3709-3721
TORQUE_MODES = ("T", "Tz")  # L15162-15168, L7791-7795

_TRIGGERS = ("TRQLM", "SPDLM", "TCM0", "TCM1", "SPD0", "SPD1", "ZCLAMP", "GAINUP", "PL",
             "NL")
_PARAMS = ("P1.001", "P1.002", "P1.009", "P1.010", "P1.011", "P1.012", "P1.013", "P1.014",
           "P1.034", "P1.035", "P1.036", "P1.038", "P1.040", "P1.041", "P2.001", "P2.005",
           "P2.027", "P2.065")  # fmt: skip


class DiFunctions:
    """PFQS, JOGU/JOGD, TRQLM/SPDLM, ZCLAMP, CCLR and GAINUP of one drive."""

    def __init__(self, drive: DriveCore, absolute: AbsoluteEncoder) -> None:
        self.d = drive
        self.absolute = absolute  # P4.005 jog direction follows P1.001.Z (L10865)
        self.pulse: PulseTrain | None = None  # CCLR clears the PT error (set by the drive)
        self.pfqs_stopping = False  # AL35F ramp running
        self.jog = 0  # +1 JOGU, -1 JOGD, 0 none
        self.comm_jog = 0  # P4.005 = 4998 / 4999: +1 / -1 (axis direction), 0 none
        self.jog_rpm = self._speed_of(drive.params.get("P4.005"), 20)
        self.gain_switched = False
        self._mode_cmd: tuple | None = None  # the S/T command given to the axis
        # ZCLAMP with P2.065 bit 10 = 1 on the analog command: down to 0 rpm on the
        # command's own curve, not at once (L9914-9916); `mode_command` gives it
        self._clamp_ramp = False
        self.torque_limit_pct: float | None = None  # TRQLM limit in effect (%)
        self.speed_limit_rpm: float | None = None  # SPDLM limit in effect (rpm)
        self._p1001 = drive.params.cached("P1.001")  # read every motion step (TPOS, TQL)

    # -- the table 8.1 control mode ----------------------------------------------------
    def control_mode(self) -> str:
        """"PT" "PR" "S" "T" "Sz" "Tz", or "" (CANopen mode without a CiA 402 mode)."""
        yx = self._p1001()[0] & 0xFF
        if yx in (0x0D, 0x0E, 0x0F):  # PT-PR: off PT, on PR (L15200)
            return "PR" if self.d.dio.function_active("PT-PR") else "PT"
        if yx in (0, 0x0C) and self.d.options.di_modes_follow_cia402:
            mode = CIA402_MODES.get(self.d.cia402.mode)
            if mode:
                return mode
        return P1001_MODES.get(yx, "")

    # -- PFQS ----------------------------------------------------------------------------
    def on_pfqs(self, active: bool) -> None:
        """Rising edge (L15253): AL35F, ramp with P5.003.C (L11084-11100)."""
        d = self.d
        if not active or not d.servo_on or self.control_mode() not in PFQS_MODES:
            return
        if self.pfqs_stopping or "AL3CF" in d.alarms.active:
            return
        self.pfqs_stopping = True
        self.comm_jog = 0
        self._end_jog()
        d.alarms.raise_alarm("AL35F")  # WARN, servo stays on (L19413)
        dev = d.options.dev_pfqs_ramp_ms  # deviation knob: a wrong ramp
        d.axis.ramp_stop(d.p5003_decel(6) if dev is None else dev)  # digit C = PFQS
        d.axis.lock("PFQS")  # nothing starts the motor during the quick stop
        d.cia402.drop_setpoints()
        self._end_pr()  # an emergency stop ends the PR program: no next path, no Cmd_OK

    def _pfqs_step(self) -> None:
        """At zero speed: AL3CF and Servo Off (L20153-20155)."""
        ax = self.d.axis
        if not self.pfqs_stopping or ax.mode == "stop":  # the P5.003 ramp is still running
            return
        zspd = self.d.params.get("P1.038") / 10.0
        if self.d.options.pfqs_zero == "zspd" and abs(ax.velocity_rpm) >= zspd:
            return
        self._pfqs_done()

    def _pfqs_done(self) -> None:
        self.pfqs_stopping = False
        alarms = self.d.alarms
        if not self.d.options.pfqs_keeps_al35f:
            alarms.clear("AL35F")
        alarms.raise_alarm("AL3CF")  # WARN, servo off (L19414): the drive's alarm reaction
        self._release("PFQS")

    # -- JOGU / JOGD ---------------------------------------------------------------------
    @staticmethod
    def _speed_of(value: int, old: int) -> int:
        return old if value in (0, 4998, 4999) else value

    def on_p4005(self, _name: str, _old: int, new: int) -> None:
        """P4.005 written: a jog command (4998 CCW, 4999 CW, 0 stop) or the speed (L10865)."""
        if new in (4998, 4999):
            ccw = new == 4998
            self.comm_jog = 1 if ccw != self.absolute.cw_positive else -1
        elif new == 0:
            self.comm_jog = 0
        self.jog_rpm = self._speed_of(new, self.jog_rpm)
        if not self.d.servo_on:
            self.comm_jog = 0  # jogging needs Servo On (L2937)
        self.update_jog()

    def update_jog(self, *_: object) -> None:
        """Jog while exactly one of JOGU/JOGD is on (L15209-15212), else by P4.005's command,
        and the servo is on (L2937)."""
        d = self.d
        up, down = d.dio.function_active("JOGU"), d.dio.function_active("JOGD")
        want = (1 if up else -1) if up != down else 0
        if not (up or down):
            want = self.comm_jog
        if not d.servo_on or self.pfqs_stopping or "PFQS" in d.axis.locks:
            want = 0
        if d.dio.function_active("PL" if want > 0 else "NL") and want:
            want = 0  # PL/NL forbid running towards them in every mode (L15188-15191)
        ramp = d.options.jog_ramp_ms
        if want:
            if not self.jog:
                self._end_pr()  # the jog takes the axis: the PR program ends unfinished
            rpm = min(self.jog_rpm, d.axis.mech.max_speed)  # L10857
            d.axis.lock("JOG")
            d.axis.run_velocity(want * rpm, ramp, ramp, by="JOG")
            d.cia402.drop_setpoints()
        elif self.jog:
            self._release("JOG")
            d.axis.ramp_stop(ramp)
            self._mode_cmd = None  # the S/T command takes the axis back
        self.jog = want
        if not want:
            self.mode_command()

    def _end_pr(self) -> None:
        """A PR program in progress ends without completing (Cmd_OK/MC_OK stay off)."""
        pr = getattr(self.d, "pr", None)
        if pr is not None and not pr.cmd_ok and (pr.cursor is not None or pr.cmd is not None):
            pr.abort()

    def _release(self, owner: str) -> None:
        """`owner` gives the axis back; what the host commanded meanwhile was dropped."""
        if owner in self.d.axis.locks:
            self.d.axis.unlock(owner)
            self.d.cia402.drop_setpoints()

    def _end_jog(self) -> None:
        self.jog = 0
        self._release("JOG")

    def on_servo_on(self) -> None:
        self._end_jog()
        self.update_jog()
        self.refresh()

    def on_servo_off(self) -> None:
        self._mode_cmd = None  # given again at the next servo on
        self._end_jog()  # the power stage is off: the jog ends (a held DI restarts it)
        self.comm_jog = 0
        if self.pfqs_stopping:  # another servo off cut the PFQS ramp short: it ends here
            self._pfqs_done()

    # -- CCLR ----------------------------------------------------------------------------
    def on_cclr(self, active: bool) -> None:
        """P2.050 = 0: rising edge; = 1: level, the error stays 0 while on (L9749-9753)."""
        d = self.d
        level = d.params.get("P2.050") & 1
        if not active or self.control_mode() not in POSITION_MODES:
            self._release("CCLR")
            return
        d.clear_position_error()
        self._clear_pt_error()  # PT: the accumulated pulse error (L9749)
        d.cia402.drop_setpoints()  # the pending position command is gone
        # a PR move cut short this way is not completed: TPOS is the target minus the
        # position (L8694) and MC_OK a completed PR (L15326), so the program ends
        # unfinished, as a JOG or PFQS ends it (Cmd_OK / MC_OK stay off, no AUTO path)
        self._end_pr()
        if level:
            d.axis.lock("CCLR")

    def _cclr_step(self) -> None:
        if "CCLR" in self.d.axis.locks:
            self.d.clear_position_error()
            self._clear_pt_error()

    def _clear_pt_error(self) -> None:
        if self.pulse is not None:
            self.pulse.clear_error()

    # -- TRQLM / SPDLM / ZCLAMP / GAINUP -------------------------------------------------
    def refresh(self, *_: object) -> None:
        """Recompute the limits, the clamp and the gains from DI, parameters and mode."""
        d = self.d
        on = d.dio.function_active
        get = d.params.get
        mode = self.control_mode()
        opts = d.options
        self.torque_limit_pct = None
        if mode in TRQLM_MODES and (on("TRQLM") or (get("P1.002") >> 4) & 0xF == 1):
            sel = on("TCM0") + 2 * on("TCM1")
            pct = abs(get(f"P1.{11 + sel:03d}")) if sel else abs(opts.analog_t_ref * get("P1.041")
                                                                / 10.0)
            self.torque_limit_pct = float(pct)
        d.axis.set_internal_torque_limit(
            None if self.torque_limit_pct is None else self.torque_limit_pct * 10.0
        )
        self.speed_limit_rpm = None
        if mode in SPDLM_MODES and (on("SPDLM") or get("P1.002") & 0xF == 1):
            sel = on("SPD0") + 2 * on("SPD1")
            rpm = abs(get(f"P1.{8 + sel:03d}")) / 10.0 if sel else abs(opts.analog_v_ref
                                                                      * get("P1.040") / 10.0)
            self.speed_limit_rpm = rpm
        d.axis.speed_limit_rpm = self.speed_limit_rpm
        clamp = on("ZCLAMP") and mode in ZCLAMP_MODES
        bit10 = (get("P2.065") >> 10) & 1
        # bit 10 = 1 with the analog source ramps to 0 (L9914); with the register source
        # the speed is set to 0 at once (L9918-9920), bit 10 = 0 locks the position
        self._clamp_ramp = bool(clamp and bit10 and self._analog_speed(mode))
        d.axis.zero_clamp = ("" if self._clamp_ramp else "zero" if bit10 else "lock") \
            if clamp else ""
        d.axis.zero_clamp_rpm = get("P1.038") / 10.0
        self._gains(mode)
        self.mode_command(mode)

    def _analog_speed(self, mode: str) -> bool:
        """The speed command is the analog one: S by P1.001 with SPD0/SPD1 off (L3712; a
        CiA 402 PV's 60FFh and P1.009-P1.011 are register sources)."""
        on = self.d.dio.function_active
        return (mode == "S" and P1001_MODES.get(self._p1001()[0] & 0xFF) == "S"
                and not (on("SPD0") or on("SPD1")))

    def _towards_limit(self, command: float) -> bool:
        """PL/NL forbid running towards them in every mode (L15186-15191)."""
        on = self.d.dio.function_active
        return (command > 0 and on("PL")) or (command < 0 and on("NL"))

    def mode_command(self, mode: str | None = None) -> None:
        """The S/Sz speed or T/Tz torque command the DIs select, given to the axis when it
        changes (a JOG, PFQS or CCLR holding the axis refuses it; it is given again when
        they let go)."""
        d = self.d
        mode = mode or self.control_mode()
        # P1.001 itself names the mode: a CiA 402 PV/PT mode (control_mode() "S"/"T" by
        # 6061h) runs on its own objects (60FFh, 6071h), not on these
        by_p1001 = P1001_MODES.get(self._p1001()[0] & 0xFF) == mode
        if (mode not in SPEED_MODES and mode not in TORQUE_MODES) or not by_p1001 \
                or not d.servo_on:
            self._mode_cmd = None
            return
        on, get, opts = d.dio.function_active, d.params.get, d.options
        if mode in SPEED_MODES:
            sel = on("SPD0") + 2 * on("SPD1")
            if sel:
                rpm = get(f"P1.{8 + sel:03d}") / 10.0
            else:  # S: V_REF x P1.040 / 10 V (L3712); Sz: 0 (L3713)
                rpm = opts.analog_v_ref * get("P1.040") / 10.0 if mode == "S" else 0.0
            if self._towards_limit(rpm):
                rpm = 0.0
            if self._clamp_ramp and abs(rpm) < get("P1.038") / 10.0:
                rpm = 0.0  # ZCLAMP on the analog command, bit 10 = 1 (L9914-9916)
            acc, dec = get("P1.034"), get("P1.035")
            if get("P1.036") == 0 and self._analog_speed(mode):
                # "若使用類比命令，P1.036 的設定需要大於 0 才能有梯形加減速規劃" (L8342, L8353)
                acc = dec = 0
            cmd: tuple = ("speed", rpm, acc, dec)
        else:
            sel = on("TCM0") + 2 * on("TCM1")
            if sel:
                pct = float(get(f"P1.{11 + sel:03d}"))
            else:  # T: T_REF x P1.041 / 10 V (L3955-3960); Tz: 0
                pct = opts.analog_t_ref * get("P1.041") / 10.0 if mode == "T" else 0.0
            if self._towards_limit(pct):
                pct = 0.0
            cmd = ("torque", pct)
        if cmd == self._mode_cmd or d.axis.locks:
            return
        self._mode_cmd = cmd
        if cmd[0] == "speed":
            to_3000 = 3000.0 / d.axis.mech.rated_speed  # P1.034/P1.035: 0 to rated speed
            d.axis.run_velocity(cmd[1], cmd[2] * to_3000, cmd[3] * to_3000)
        else:
            d.axis.run_torque(cmd[1] * 10.0, 0.0)

    def _gains(self, mode: str) -> None:
        """P2.027 X = 1: switched while GAINUP is on, X = 5: while off (L9437-9447)."""
        d = self.d
        p2027 = d.params.get("P2.027")
        x, y = p2027 & 0xF, (p2027 >> 4) & 0xF
        on = d.dio.function_active("GAINUP")
        self.gain_switched = mode in GAINUP_MODES and ((x == 1 and on) or (x == 5 and not on))
        if self.gain_switched and y == 0:  # gain ratio (L9454-9460)
            d.axis.set_gain_ratio(d.params.get("P2.001") / 100.0, d.params.get("P2.005") / 100.0)
        else:  # Y = 1 switches an integrator the axis does not have: recorded only
            d.axis.set_gain_ratio(1.0, 1.0)

    def after_step(self) -> None:
        if self.pfqs_stopping:
            self._pfqs_step()
        if self.d.axis.locked:
            self._cclr_step()


def attach_di_functions(drive: DriveCore, *, absolute: AbsoluteEncoder) -> DiFunctions:
    """Create the DI functions of `drive` and wire their triggers and parameters."""
    fns = DiFunctions(drive, absolute)
    dio = drive.dio
    dio.on_function("PFQS", fns.on_pfqs)
    dio.on_function("JOGU", fns.update_jog)
    dio.on_function("JOGD", fns.update_jog)
    dio.on_function("CCLR", fns.on_cclr)
    for sym in _TRIGGERS:
        dio.on_function(sym, fns.refresh)
    for name in _PARAMS:
        drive.params.on_write(name, fns.refresh)
    drive.params.on_write("P4.005", fns.on_p4005)
    drive.hooks.step.append(fns.after_step)
    drive.hooks.servo_on.append(fns.on_servo_on)
    drive.hooks.servo_off.append(fns.on_servo_off)
    drive.hooks.boot.append(fns.refresh)
    fns.refresh()
    return fns


__all__ = ["DiFunctions", "attach_di_functions"]
