"""Every choice the manual leaves open, and every deliberate deviation, as named options.

Two kinds of fields:

* **choices** resolve an ambiguity or gap of the ASDA-A3 manual; the default is the reading
  documented in `docs/manual-choices.md` with its manual line. A real drive may prove another
  reading right: set the option in the bench file instead of editing code.
* **deviations** (prefix `dev_`) make the virtual drive deliberately *wrong*, so tests can
  prove that the timing checker catches a drive that breaks the manual. They default to the
  faithful behaviour (0 / False / None).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, fields
from typing import Any

# STO FDBK output per (STO_A on, STO_B on): True = closed. As printed in the state table
# §3.10.3, L2454-2468 ("Open, Close, Open, Open"), which the digest flags as doubtful.
FDBK_AS_PRINTED: dict[tuple[bool, bool], bool] = {
    (True, True): False,
    (True, False): True,
    (False, True): False,
    (False, False): False,
}
# Alternative reading: FDBK closes whenever STO has cut the torque (any channel lost).
FDBK_STO_ACTIVE: dict[tuple[bool, bool], bool] = {
    (True, True): False,
    (True, False): True,
    (False, True): True,
    (False, False): True,
}

STO_SERVO_OFF = ("acknowledged", "at_loss")


@dataclass
class ModelOptions:
    """Choices and deviation knobs of the virtual drive (see docs/manual-choices.md)."""

    # --- brake, §2.9 ---
    # Negative P1.043 on a normal servo off is never defined (L8503-8516). "brake_first":
    # BRKR drops at once and torque is held |P1.043| ms longer; "as_zero": treated as 0.
    negative_p1043: str = "brake_first"
    # Reference event of P1.043: the servo-off instant (L1361) rather than SRDY off (L8510).
    # "Below P1.038" is a level test, so a motor already at rest engages at once (L1362).
    # --- STO, §3.10 ---
    sto_torque_cut_ms: float = 1.0  # hardware cuts torque "within 20 ms" (L2474)
    sto_both_lost_ms: float = 10.0  # both lost 10 ms -> AL500 (L2478)
    sto_one_lost_ms: float = 1000.0  # one lost 1 s -> AL501 / AL502 (L2482, L2487)
    # Torque returns when both channels are back before any alarm (gap in §3.10.4, L2482).
    sto_resume_after_dropout: bool = True
    # When the firmware enters Servo Off on an STO loss (L2474-2482): "acknowledged" = only
    # when it acknowledges the loss (both lost 10 ms -> AL500, one lost 1 s -> AL501/AL502);
    # a shorter glitch cuts torque in hardware but DO.SON, BRKR and the CiA 402 state stay.
    # "at_loss" = servo off at the first lost channel (an earlier reading).
    sto_servo_off: str = "acknowledged"
    fdbk_table: dict[tuple[bool, bool], bool] = field(
        default_factory=lambda: dict(FDBK_AS_PRINTED)
    )
    # --- servo on / CiA 402 ---
    # Servo-on request = DI.SON or the CiA 402 state OPERATION ENABLED (both routes exist
    # on an A3-M; the manual does not say one disables the other).
    son_sources: tuple[str, ...] = ("DI", "CANOPEN")
    # SON held through an alarm reset re-enables the servo (SON is level-triggered, L15079).
    son_level_reenables: bool = True
    # Stop at a servo off: 605Bh (0 free run, 1 dynamic brake, L18342-18358) decides when the
    # CiA 402 state machine switched the servo off; P1.032.Y ("Servo Off 或 Alarm (含 EMGS)",
    # L8321) for SON off, alarms and EMGS. "never": P1.032.Y always, 605Bh has no effect.
    shutdown_option_scope: str = "state_machine"
    # --- timing of the model's outputs ---
    motion_step_ms: float = 1.0  # integration substep while anything moves
    state_publish_ms: float = 10.0  # ground-truth snapshots when recorded
    # --- communication faults (docs/faults.md) ---
    # AL111: "more than one SDO received within 1 ms" overflows the SDO Rx buffer
    # (L19933-19937). Counted only for a request the master sent before the drive answered
    # the previous one: a master that waits for each answer never overflows a one-deep buffer.
    sdo_flood_window_us: int = 1000
    # AL112: "more than one PDO with the same COB-ID within 1 ms" (L19941-19945), by the
    # frames' sender timestamps; counted only for a PDO sent before the drive had processed
    # the previous one with that COB-ID (same one-deep buffer reading as AL111).
    pdo_overflow_window_us: int = 1000
    # SYNC monitoring in IP mode (6061h = 7, 1006h > 0, NMT OPERATIONAL); the manual gives no
    # numbers (docs/manual-choices.md, SYNC supervision): AL3E2 when a SYNC interval is shorter than
    # sync_early_ratio x 1006h (L20159-20163); AL3E3 when no SYNC for sync_timeout_cycles x
    # 1006h (L20165-20169); AL301 when the mean of the last sync_fail_window intervals is off
    # 1006h by more than sync_fail_tolerance (L20123-20127).
    sync_early_ratio: float = 0.5
    sync_timeout_cycles: float = 3.0
    sync_fail_window: int = 8
    sync_fail_tolerance: float = 0.1
    # P3.009 E (sync error range, 1-9 x 10 us; digits E T D M listed from the lowest, as
    # every digit table of chapter 8, so 0x5055 is E = 5, T = 5 -> 450 us, L10629-10645):
    # "p3009" = a SYNC interval shorter than 1006h - E x 10 us is early (AL3E2), and an
    # AL301 cycle mean off 1006h by more than E x 10 us fails; widening E is the remedy the
    # alarm table gives (L20159-20169). "ratio" (default) = sync_early_ratio and
    # sync_fail_tolerance above: the manual measures E on the SYNC's arrival inside the
    # drive's cycle, not on the interval, and a harness SYNC producer on a host that is not
    # real-time jitters 0.5-2 ms, 10-40 x the default E (docs/manual-choices.md).
    sync_tolerance: str = "ratio"
    # NMT reset node / reset communication re-initialise the CiA 402 state machine: FAULT
    # while a servo-off alarm remains, else SWITCH ON DISABLED (transition 15, L18265;
    # AL180 cleared by "NMT 重置", L20025). False: the state stays until a 6040h fault reset.
    nmt_reset_reinit_402: bool = True
    # NMT Stop while the servo is on (the manual is silent on motion, L17089-17095): the
    # stopped node takes no RPDO/controlword, so "servo_off" disables (the P1.032.Y stop,
    # BRKR engages) and raises nothing; "none" keeps the axis as it is (unreachable but by NMT).
    nmt_stop_action: str = "servo_off"
    # AL020 (P3.004 timeout) after an alarm reset with the line still silent: "reset" = the
    # timeout counts again from the reset (a new AL020 after P3.004); "frame" = only the
    # next valid frame re-arms it (L10571-10578, L19598-19602 say neither).
    al020_rearm: str = "reset"
    # What a 6040h fault reset (bit 7, L18231) clears: "alarm_reset" = what an alarm reset
    # clears (DI.ARST / P0.001 = 0) plus the "NMT or 6040h" alarms; "listed" = only the alarms
    # whose row names 0x6040 (AL180 ..., AL500), so AL020 ("異警重置" only, L19602) stays.
    fault_reset_clears: str = "alarm_reset"
    # 603Fh and the EMCY object carry one alarm (L17063): "class" = the highest-priority one
    # (ALM over WARN; of one class the first raised: only a higher priority overrides, ⚠ the
    # manual ranks no further), an EMCY sent when that alarm changes and 0000h when none is
    # left; "latest" = the alarm raised last, an EMCY per alarm raised and 0000h per clear.
    emcy_priority: str = "class"
    # A node guarding request (RTR on 700h + node) while the heartbeat producer runs (1017h
    # != 0): the A3 manual lists both protocols (L17097-L17126) and says nothing of the two
    # together; CiA 301 uses the heartbeat then, as drives do ("heartbeat" = no answer and no
    # life guarding while 1017h != 0); "both" = answered and watched as without heartbeat.
    guarding_with_heartbeat: str = "heartbeat"
    # A DI/DO mapping write (P2.010-P2.022, P2.036-P2.041): the parameter table marks none of
    # them "power cycle" and L2979-2981 clears the alarms of an unmapped EMGS/NL/PL by an
    # alarm reset, so "write" = in effect at once; L9256 / L9339 advise a restart after a
    # change: "power_cycle" = read at power-up only.
    mapping_effect: str = "write"
    # AL185 "Rx/Tx error counter > 128" (L20027-20031): an error frame adds this to the
    # receive error counter, a valid frame subtracts 1 (ISO 11898-1 fault confinement).
    can_error_frame_weight: int = 8
    # AL019 "communication address / value incorrect" (L19592-19596): the Modbus exception
    # codes that raise it (02 illegal address, 03 illegal value). () = never.
    modbus_al019_exceptions: tuple[int, ...] = (2, 3)
    # --- DI functions of table 8.1 (hil/model/di_functions.py) ---
    # Which table 8.1 "控制模式" column the drive is in when P1.001 is PT (0) or CANopen (0x0C)
    # and a CiA 402 mode runs (the table names PT/PR/S/T only, L15075-15255): True = the mode
    # of operation 6061h decides (PP/HM/IP/CSP -> PR, PV/CSV -> S, PT/CST -> T); False =
    # P1.001 alone (CANopen mode is then none of PT/PR/S/T: only "All" functions act).
    di_modes_follow_cia402: bool = True
    # PR triggers (CTRG, P5.007, EV1-4, SHOM, CAPTURE/COMPARE PR#50/#45) and STP act only when
    # P1.001.YX selects a mode with PR (01, 08, 09, 0D-0F): "控制模式 PR" of P5.007 (L11168),
    # CTRG/POS/SHOM/EV rows of table 8.1 (L15098, L15133, L15197, L15218-15227), P1.001
    # L7749-7800. False: they act in any control mode.
    pr_triggers_need_pr_mode: bool = True
    # AL35F/AL3CF (PFQS) clear: "power_cycle" per chapter 13 (L20145, L20157) or "reset" per
    # the DI table ("需要異警重置", L15253).
    pfqs_clear: str = "power_cycle"
    # AL35F stays active next to AL3CF once the PFQS ramp reached 0 (L15253 "跳出 AL3CF"
    # names no clearing of AL35F); False: AL3CF replaces it (AL35F means "decelerating").
    pfqs_keeps_al35f: bool = False
    # "減速至 0 後" (L15253, L20143): "command" = the P5.003.C ramp of the command reached 0;
    # "zspd" = and the motor speed is below P1.038 (ZSPD, L15269).
    pfqs_zero: str = "command"
    # Jog ramp (DI.JOGU/JOGD at P4.005): the manual gives no DI jog ramp; the one number it
    # gives for jogging is ASDA-Soft's 500 ms default (L3237). ms per 3000 rpm.
    jog_ramp_ms: float = 500.0
    # The virtual drive has no analog inputs: the voltage on V_REF / T_REF that TRQLM / SPDLM
    # use when TCM0/TCM1 (SPD0/SPD1) select the analog source (00, L4036-4044).
    analog_v_ref: float = 0.0  # V, x P1.040 / 10 V -> speed limit (L8453)
    analog_t_ref: float = 0.0  # V, x P1.041 / 10 V -> torque limit (L3955-3960)
    # --- PT mode and the encoder output (hil/model/pulse_train.py, docs/pulse.md) ---
    # The CN1 pulse input wired to the PLC: "line_driver" 4 Mpps or "open_collector"
    # 200 kpps (L7700-7707); above it AL008 (L19535) and the pulses are not counted.
    pulse_interface: str = "line_driver"
    # 1/4 < Nx/M < 262144 (L8547): the manual raises AL045 at the next power-up (L19699-19703,
    # modelled whatever this says); in a PT mode "refuse" also refuses a write that leaves the
    # range (SDO abort / Modbus exception); "off" accepts it, as the manual's drive does.
    pt_gear_check: str = "refuse"
    # OCZ (C11, L1851): the manual gives no pulse width.
    ocz_width_us: float = 100.0
    # OA/OB published as one segment per window of this many ms while the motor turns.
    output_window_ms: float = 10.0
    # --- IP mode (docs/group.md) ---
    # The IP section recommends P1.036 (S-curve) and P1.068 (moving filter) to smooth the
    # set-points (L17232), while P1.068's own mode column lists PT/PR only (L8832):
    # "manual" applies both to IP set-points (P1.068 ms moving average, then a P1.036 ms one,
    # the S-curve of a ramp); "off" leaves IP set-points unfiltered.
    ip_smoothing: str = "manual"
    # --- deviations (deliberately wrong drive) ---
    dev_brake_on_delay_ms: float = 0.0  # added to P1.042 (e.g. 5: BRKR 5 ms late)
    dev_brake_off_delay_ms: float = 0.0  # added to the P1.043 rule
    dev_ignore_speed_rule: bool = False  # BRKR off waits P1.043 even when stopped
    dev_sto_both_lost_ms: float | None = None  # e.g. 15: AL500 acknowledged after 15 ms
    dev_sto_one_lost_ms: float | None = None  # e.g. 500: AL501 too early
    dev_al501_cleared_by_arst: bool = False  # AL501/AL502 wrongly cleared by ARST
    dev_arst_on_falling_edge: bool = False  # alarm reset on the wrong edge
    dev_emgs_ignores_negative_rule: bool = False  # negative P1.043 honoured on EMGS stops
    dev_di_levels_ignored_at_power_up: bool = False  # EMGS/NL/PL open at power-up unseen
    dev_heartbeat_extra_ms: float = 0.0  # AL180 raised this much after the consumer time
    dev_sync_timeout_extra_ms: float = 0.0  # AL3E3 raised this much late
    dev_ignore_sdo_flood: bool = False  # no AL111
    dev_ignore_pdo_overflow: bool = False  # no AL112
    dev_bus_error_limit: int | None = None  # AL185 above this counter instead of 128
    dev_comm_timeout_extra_ms: float = 0.0  # AL020 raised this much after P3.004
    dev_1029h_behaviour: int | None = None  # AL180 acts as if 1029h sub1 were this (e.g. 1)
    dev_di_filter_delay_only: bool = False  # P2.009 delays each DI edge, drops no bounce
    dev_di_filter_extra_ms: float = 0.0  # each DI edge taken this much after P2.009
    dev_ignore_early_sync: bool = False  # no AL3E2 for a SYNC that comes too early
    dev_ignore_sync_cycle: bool = False  # no AL301 for a SYNC cycle off 1006h
    dev_pfqs_ramp_ms: float | None = None  # PFQS ramps with this (ms / 3000 rpm), not P5.003.C
    extra: dict[str, Any] = field(default_factory=dict)  # options of other rooms (homing, abs)

    @classmethod
    def from_dict(cls, data: dict[str, Any] | None, where: str = "options",
                  faces: Mapping[str, Callable[[dict], Any]] | None = None) -> ModelOptions:
        """Build from a bench file's `options:` mapping; unknown keys are an error. `faces`:
        the faces' rooms of `extra:` and their checks (`_check_extra`)."""
        data = dict(data or {})
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(
                f"{where}: unknown model option(s) {', '.join(unknown)}; "
                f"known: {', '.join(sorted(known))}"
            )
        defaults = cls()
        for key, value in data.items():
            _check_type(key, value, getattr(defaults, key), where)
        if "extra" in data:
            _check_extra(data["extra"], f"{where}.extra", faces)
        if "fdbk_table" in data and isinstance(data["fdbk_table"], str):
            tables = {"as_printed": FDBK_AS_PRINTED, "sto_active": FDBK_STO_ACTIVE}
            if data["fdbk_table"] not in tables:
                raise ValueError(f"{where}.fdbk_table: one of {', '.join(tables)}")
            data["fdbk_table"] = dict(tables[data["fdbk_table"]])
        for key, allowed in _CHOICES.items():
            if key in data and data[key] not in allowed:
                raise ValueError(f"{where}.{key}: {' or '.join(map(repr, allowed))}")
        if data.get("sto_servo_off", "acknowledged") not in STO_SERVO_OFF:
            raise ValueError(f"{where}.sto_servo_off: one of {', '.join(STO_SERVO_OFF)}")
        return cls(**data)


# The text options and the readings each may take (the first is the default)
_CHOICES: dict[str, tuple[str, ...]] = {
    "shutdown_option_scope": ("never", "state_machine"),
    "negative_p1043": ("brake_first", "as_zero"),
    "pfqs_clear": ("power_cycle", "reset"),
    "pfqs_zero": ("command", "zspd"),
    "sync_tolerance": ("ratio", "p3009"),
    "nmt_stop_action": ("servo_off", "none"),
    "al020_rearm": ("reset", "frame"),
    "fault_reset_clears": ("alarm_reset", "listed"),
    "pulse_interface": ("line_driver", "open_collector"),
    "pt_gear_check": ("refuse", "off"),
    "emcy_priority": ("class", "latest"),
    "guarding_with_heartbeat": ("heartbeat", "both"),
    "mapping_effect": ("write", "power_cycle"),
    "ip_smoothing": ("manual", "off"),
}
# Numeric options that may be negative (volts on V_REF / T_REF); every other is >= 0
_SIGNED = {"analog_v_ref", "analog_t_ref"}
# Options that must be strictly positive: a 0 ms motion step would never end
_POSITIVE = {"output_window_ms", "motion_step_ms", "state_publish_ms", "sync_fail_window",
             "sync_timeout_cycles"}


# the least a time option may be: a finer motion step or state sample would make a plan of
# seconds run for hours (an outside fuzz: 1e-9 ms never finished)
_FLOOR_MS = {"motion_step_ms": 0.01, "state_publish_ms": 0.1}


def _check_extra(extra: Any, where: str,
                 faces: Mapping[str, Callable[[dict], Any]] | None = None) -> None:
    """`extra:` holds the options of other rooms, each checked by its own options class
    (a wrong one failed the run with a bare TypeError, a misspelled room was ignored).
    `faces`: the rooms of the drive's faces, which the model does not import (the virtual
    world's `hil.virtual.options.FACE_ROOMS`); without them such a room is unknown."""
    from hil.model.absolute import AbsoluteOptions
    from hil.model.capture import CaptureOptions
    from hil.model.cia402 import Cia402Options
    from hil.model.homing import HomingOptions
    from hil.model.pr_engine import PrOptions

    rooms: dict[str, Any] = {
        "absolute": AbsoluteOptions.from_dict, "capture": CaptureOptions.from_dict,
        "cia402": lambda d: Cia402Options(**d), "homing": HomingOptions.from_dict,
        "pr": PrOptions.from_dict, **(faces or {})}
    if not isinstance(extra, dict):
        raise ValueError(f"{where}: a mapping of {', '.join(sorted(rooms))}")
    for room, values in extra.items():
        if room not in rooms:
            raise ValueError(f"{where}: unknown room {room!r}; known: {', '.join(sorted(rooms))}")
        if not isinstance(values, dict):
            raise ValueError(f"{where}.{room}: a mapping of that room's options")
        try:
            rooms[room](dict(values))
        except (TypeError, ValueError, KeyError) as e:
            raise ValueError(f"{where}.{room}: {e}") from None


def _check_type(key: str, value: Any, default: Any, where: str) -> None:
    """A bench's (or an `inject:`) option value has the type of the option's default (a flag
    true/false, a count an integer, a time a finite number, a choice text, a list of the
    default's element type) and a sane range (no negative times, no 0 ms motion step)."""
    def number(x: Any) -> bool:
        # abs(x) <= 1e12 is False for NaN and inf, and compares an int too long for a float
        # exactly (math.isfinite raised OverflowError on a 400-digit one)
        return isinstance(x, int | float) and not isinstance(x, bool) and abs(x) <= 1e12

    if key == "fdbk_table":  # a table name; in code, the full table keyed (STO_A, STO_B)
        pairs = {(a, b) for a in (True, False) for b in (True, False)}
        ok = isinstance(value, str) or (
            isinstance(value, dict) and set(value) == pairs
            and all(isinstance(x, bool) for x in value.values()))
        want = "a table name (as_printed, sto_active)"
    elif default is None:  # an optional number (the deviation knobs)
        ok, want = value is None or number(value), "a finite number or null"
    elif isinstance(default, bool):
        ok, want = isinstance(value, bool), "true or false"
    elif isinstance(default, int):
        ok, want = number(value) and isinstance(value, int), "an integer"
    elif isinstance(default, float):
        ok, want = number(value), "a finite number"
    elif isinstance(default, str):
        ok, want = isinstance(value, str), "text"
    elif isinstance(default, tuple):
        kind = type(default[0]) if default else int
        ok = isinstance(value, list | tuple) and all(
            isinstance(x, kind) and not isinstance(x, bool) for x in value)
        want = f"a list of {'integers' if kind is int else 'names'}"
    else:
        ok, want = isinstance(value, type(default)), type(default).__name__
    if ok and number(value) and key not in _SIGNED:
        if value < 0 or (key in _POSITIVE and value <= 0):
            ok, want = False, "> 0" if key in _POSITIVE else ">= 0"
        elif key == "motion_step_ms" and value > 1:
            ok, want = False, "at most 1 (ms): the drive's command cycle"
        elif key in _FLOOR_MS and value < _FLOOR_MS[key]:  # a run of 10^9 steps never ends
            ok, want = False, f"at least {_FLOOR_MS[key]:g} (ms)"
    if not ok:
        shown = repr(value)
        shown = shown if len(shown) <= 40 else shown[:35] + "..."
        raise ValueError(f"{where}.{key}: {shown} is not {want}")
