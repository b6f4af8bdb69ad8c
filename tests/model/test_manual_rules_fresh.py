"""Manual rules checked afresh against the virtual drive (injected clock).

Each test states one rule of the ASDA-A3 manual (lines L… of shared/seeds/002_…) as read
before looking at the model: table 8.1 DI functions (L15075-15255), P4.005 jog
(L10846-10866), P1.009-P1.014 limits (L7931-8031), PR mode (chapter 7, P5.007 L11165-11187,
P5.008/P5.009 L11189-11201, AL283/AL285 L20105-20115), CAPTURE/COMPARE (P5.036-P5.039
L11470-11535, P5.059 L11740-11766), communication alarms (table 13.1 L19325-19480).
"""

from __future__ import annotations

import pytest

from hil.model.drive import Drive
from hil.model.errors import ModelError
from hil.model.events import AlarmChanged
from hil.model.options import ModelOptions
from hil.profile.pr import encode, pr_params
from hil.units import MS
from tests.model.test_di_functions import enable

PV, PT, PP = 3, 4, 1  # 6060h modes
# EMGS wired closed (DI8), BRKR on DO6; NL (DI6, b) and PL (DI7, b) closed, no sensors.
BENCH = {"P2.041": 0x0108, "P2.014": 0x0000, "P2.037": 0x0000}


def make(di5: int = 0, di10: int = 0, **params: int) -> tuple[Drive, list]:
    """A drive with DI5 = `di5` and DI10 = `di10` (a-contacts)."""
    bench = BENCH | {"P2.014": di5 and 0x0100 | di5, "P2.037": di10 and 0x0100 | di10}
    drive = Drive(inputs={6: True, 7: True, 8: True}, params=bench | params, sensors={})
    events: list = []
    drive.subscribe(events.append)
    return drive, events




def press(drive: Drive, n: int, closed: bool = True) -> int:
    """Set DI n; return when the P2.009 filter accepted it."""
    drive.set_di(n, closed)
    drive.advance(drive.params.get("P2.009") * MS)
    return drive.now


def raised(events: list, code: str) -> list[int]:
    return [e.t for e in events if isinstance(e, AlarmChanged) and e.active and e.code == code]


def rpm(drive: Drive) -> float:
    return drive.axis.velocity_rpm


# -- JOGU / JOGD (table 8.1 "All", L15209-15212) ---------------------------------------------


@pytest.mark.parametrize("mode", [PV, PP, PT])  # speed, position, profile torque
def test_jogu_jogs_in_every_control_mode(mode: int) -> None:
    """JOGU 0x37 "此訊號接通時，馬達正方向轉寸動轉動", control mode All (L15209)."""
    drive, _ = make(di5=0x37, **{"P4.005": 100})
    enable(drive, mode)
    press(drive, 5)
    drive.advance(600 * MS)
    assert rpm(drive) == pytest.approx(100, abs=2)


def test_jogd_is_refused_at_the_reverse_limit_jogu_leaves_it() -> None:
    """NL = reverse run forbidden (b contact, L15188); a jog into it does not run, a jog out
    of it does (PL/NL are all-mode limits, L15188-15191)."""
    drive, _ = make(di5=0x38, di10=0x37, **{"P4.005": 100})
    enable(drive, PV)
    press(drive, 6, False)  # NL open: at the reverse limit
    press(drive, 5)  # JOGD
    drive.advance(300 * MS)
    assert rpm(drive) == pytest.approx(0, abs=0.5)
    press(drive, 5, False)
    press(drive, 10)  # JOGU: away from the limit
    drive.advance(600 * MS)
    assert rpm(drive) == pytest.approx(100, abs=2)


def test_jog_stops_at_emgs_and_servo_off() -> None:
    """EMGS (L15184) stops the motor whatever the function; a jog is no exception."""
    drive, _ = make(di5=0x37, **{"P4.005": 100})
    enable(drive, PV)
    press(drive, 5)
    drive.advance(600 * MS)
    press(drive, 8, False)  # EMGS (b contact) active
    drive.advance(300 * MS)
    assert not drive.servo_on
    assert "AL013" in drive.alarms.active
    assert rpm(drive) == pytest.approx(0, abs=1)


# -- SPDLM / TRQLM: "正負值結果相同" (P1.009 L7940, P1.012 L8007) -----------------------------


def test_spdlm_negative_p1009_limits_both_directions() -> None:
    """P1.009 = -1000 as a speed limit: ±100 rpm, the sign does not matter (L7940-7944);
    SPD0 on, SPD1 off selects P1.009 (L15216-15222)."""
    drive, _ = make(di5=0x10, di10=0x14, **{"P1.009": -1000})
    enable(drive, 4)  # profile torque (Tz-like in CiA 402, T family)
    press(drive, 5)
    press(drive, 10)
    drive.write_object(0x6087, 0, 10000)  # torque slope (0.1 %/s)
    drive.write_object(0x6071, 0, 300)  # +30 % rated torque
    drive.advance(1000 * MS)
    assert 0 < rpm(drive) <= 101


def test_trqlm_negative_p1012_limits_the_torque_magnitude() -> None:
    """P1.012 = -30 as a torque limit: ±30 % (L8007-8010), TCM0 selects P1.012 (L15231)."""
    drive, _ = make(di5=0x09, di10=0x16, **{"P1.012": -30})
    enable(drive, PV)
    press(drive, 5)
    press(drive, 10)
    drive.write_object(0x6083, 0, 1)
    drive.write_object(0x60FF, 0, 30000)  # 3000 rpm in 1 ms: the torque would saturate
    peak = 0.0
    for _ in range(50):
        drive.advance(1 * MS)
        peak = max(peak, abs(drive.axis.torque) / 10)
    assert 25 <= peak <= 30.5


# -- PFQS in PR mode (table 8.1 "PT、PR、T、S", L15253) ----------------------------------------

PR_BENCH = {"P1.001": 0x0001, "P2.010": 0x0101, "P2.011": 0x0108, "P2.012": 0x0111,
            "P2.013": 0x0112, "P2.014": 0x0147, "P2.015": 0x0146, "P2.016": 0, "P2.036": 0}


def make_pr(**params: int) -> tuple[Drive, list]:
    """PR mode: DI1 SON, DI2 CTRG, DI3 POS0, DI4 POS1, DI5 PFQS, DI6 STP."""
    d = Drive(inputs={8: True}, params=PR_BENCH | params, sensors={})
    events: list = []
    d.subscribe(events.append)
    d.set_di(1, True)
    d.advance(400 * MS)
    assert d.servo_on
    return d, events


def put(d: Drive, n: int, **kw) -> None:
    p_def, p_data = pr_params(n)
    definition, data = encode(**kw)
    d.params.write(p_def, definition)
    d.params.write(p_data, data)


def test_pfqs_stops_a_pr_move_al35f_then_al3cf() -> None:
    """PFQS rising edge in PR: AL35F, ramp with P5.003.C, at 0 AL3CF and servo off (L15253,
    L20141-20157)."""
    d, events = make_pr()
    put(d, 1, type_="single", data=10_000_000, spd=4)  # far away, P5.064 = 300 rpm
    d.params.write("P5.007", 1)
    d.advance(300 * MS)
    assert rpm(d) > 10
    t0 = press(d, 5)
    assert raised(events, "AL35F") == [t0]
    d.advance(200 * MS)
    assert raised(events, "AL3CF")
    assert not d.servo_on
    assert rpm(d) == pytest.approx(0, abs=1)




def interrupt_a_chain(d: Drive, di: int) -> tuple[int, set]:
    """PR#1 AUTO 1 000 000 PUU -> PR#2, started by P5.007; DI `di` pressed 200 ms in; then
    300 ms of (P5.007, MC_OK) pairs as seen each ms. Returns (press time, pairs)."""
    put(d, 1, type_="auto", data=1_000_000, spd=4)
    put(d, 2, type_="single", data=0, spd=4)
    d.params.write("P5.007", 1)
    d.advance(200 * MS)
    t0 = press(d, di)
    seen = set()
    for _ in range(300):
        d.advance(1 * MS)
        seen.add((d.params.read("P5.007"), d.dio.do_function_state("MC_OK")))
    return t0, seen


def test_pfqs_ends_the_pr_program_no_next_path_no_completion() -> None:
    """PFQS is an emergency stop (L15253, AL35F "緊急停止 (減速過程中)" L20141): an AUTO chain
    does not go on to its next path, and the stopped command is no completed one - Cmd_OK /
    MC_OK stay off and P5.007 never reads n + 10000 / n + 20000 (L11185, L15319)."""
    d, _ = make_pr()
    t0, seen = interrupt_a_chain(d, di=5)
    assert seen == {(1, False)}
    assert [w for t, w in d.pr.trace if t >= t0 and w.startswith("read")] == []
    assert d.snapshot()["position_puu"] > 50_000  # stopped where the quick stop left it


@pytest.mark.parametrize("kind", ["single", "speed"])
def test_pr_towards_an_active_pl_does_not_run_away_from_it_does(kind: str) -> None:
    """PL = "正向運轉禁止極限" in every control mode (L15191, AL015 L19565): a PR that would
    run forwards while PL is already active does not move; one backwards does."""
    d, _ = make_pr(**{"P2.016": 0x0023})  # DI7 = PL (b contact)
    d.set_di(7, False)  # at the forward limit
    d.advance(10 * MS)
    assert "AL015" in d.alarms.active
    fwd, back = (200_000, -50_000) if kind == "single" else (1000, -1000)
    put(d, 1, type_=kind, data=fwd, spd=4)
    put(d, 2, type_=kind, data=back, spd=4)
    d.params.write("P5.007", 1)
    d.advance(500 * MS)
    assert d.snapshot()["position_puu"] == pytest.approx(0, abs=5)
    d.params.write("P5.007", 2)
    d.advance(500 * MS)
    assert d.snapshot()["position_puu"] < -20_000


def test_a_jog_during_a_pr_program_ends_it_without_completion() -> None:
    """JOGU acts in every mode (L15209) and takes the axis: the PR program it interrupts is
    not completed - no next path, Cmd_OK/MC_OK off, P5.007 reads the bare number (L11185)."""
    d, _ = make_pr(**{"P2.014": 0x0137, "P4.005": 100})  # DI5 = JOGU
    t0, seen = interrupt_a_chain(d, di=5)
    assert rpm(d) == pytest.approx(100, abs=2)
    assert seen == {(1, False)}
    assert [w for t, w in d.pr.trace if t >= t0 and w.startswith("read")] == []


def test_trqlm_limits_the_torque_of_a_pr_move() -> None:
    """TRQLM "PT、PR、S" (L15101): in PR mode TCM0 selects P1.012 = 20 % (L15231, L7993)."""
    peaks = []
    for on in (False, True):
        d, _ = make_pr(**{"P2.014": 0x0109, "P2.015": 0x0116, "P1.012": 20, "P5.020": 1})
        if on:
            press(d, 5)  # TRQLM
            press(d, 6)  # TCM0
        put(d, 1, type_="single", data=500_000, spd=4, acc=0, dec=0)  # P5.020 = 1 ms ramps
        d.params.write("P5.007", 1)
        peak = 0.0
        for _ in range(300):
            d.advance(1 * MS)
            peak = max(peak, abs(d.axis.torque) / 10)
        peaks.append(peak)
    assert peaks[0] > 100
    assert peaks[1] == pytest.approx(20, abs=0.5)


def test_comm_jog_towards_an_active_limit_does_not_run() -> None:
    """P4.005 = 4999 (CW, here the negative direction) with NL active (L10863-10866,
    L15188)."""
    drive, _ = make(**{"P4.005": 100})
    enable(drive, PV)
    press(drive, 6, False)  # NL open
    drive.params.write("P4.005", 4999)
    drive.advance(300 * MS)
    assert rpm(drive) == pytest.approx(0, abs=0.5)
    drive.params.write("P4.005", 4998)  # CCW: away from NL
    drive.advance(300 * MS)
    assert rpm(drive) == pytest.approx(100, abs=2)

# -- P5.007 read-back (L11185-11187) ----------------------------------------------------------


def test_p5007_reads_back_a_di_triggered_command() -> None:
    """"由 DI 觸發的命令也適用" (L11185): PR#1 by CTRG + POS0 reads 1, then 10001, then 20001."""
    d, _ = make_pr()
    put(d, 1, type_="single", data=20_000)
    d.set_di(3, True)  # POS0
    d.advance(5 * MS)
    d.set_di(2, True)  # CTRG rising edge
    d.advance(5 * MS)
    assert d.params.read("P5.007") == 1
    d.advance(2000 * MS)
    assert d.params.read("P5.007") == 20001


def test_p5007_1000_stops_the_running_command() -> None:
    """"寫入 1000，執行停止命令，相當於 DI.STOP" (L11181)."""
    d, _ = make_pr()
    put(d, 1, type_="single", data=10_000_000, spd=4)
    d.params.write("P5.007", 1)
    d.advance(300 * MS)
    assert rpm(d) > 10
    d.params.write("P5.007", 1000)
    d.advance(300 * MS)
    assert rpm(d) == pytest.approx(0, abs=0.5)


# -- PR external interruption (L5036-5040) and sequential commands (L4934) --------------------


def _peak_after(d: Drive, ms: int) -> int:
    top = d.snapshot()["position_puu"]
    for _ in range(ms):
        d.advance(1 * MS)
        top = max(top, d.snapshot()["position_puu"])
    return top


def test_external_ins_acts_at_once_whatever_the_running_dly() -> None:
    """External interruption: a triggered PR with INS goes to the motion generator at once,
    "延遲時間的設定與否，則不對外部插斷命令造成影響" (L5036-5040)."""
    d, _ = make_pr()
    put(d, 1, type_="single", data=200_000, spd=4, dly=2)  # DLY P5.042 = 200 ms
    put(d, 2, type_="single", data=0, spd=4, ins=True)
    d.params.write("P5.007", 1)
    d.advance(100 * MS)
    at_trigger = d.snapshot()["position_puu"]
    d.params.write("P5.007", 2)
    top = _peak_after(d, 2000)
    assert top < at_trigger + 10_000  # turned back at once (within one stop ramp)
    assert d.snapshot()["position_puu"] == 0


def test_triggered_pr_without_ins_waits_for_the_running_command() -> None:
    """Sequential: "後面的命令會在前面的命令及其設定的延遲時間完成後，才能夠接續執行" (L4934);
    the motion generator buffers the next motion command (L4924-4930)."""
    d, _ = make_pr()
    put(d, 1, type_="single", data=200_000, spd=4)
    put(d, 2, type_="single", data=0, spd=4)
    d.params.write("P5.007", 1)
    d.advance(100 * MS)
    d.params.write("P5.007", 2)
    assert _peak_after(d, 2500) == pytest.approx(200_000, abs=500)  # the feedback settles
    assert d.snapshot()["position_puu"] == 0



@pytest.mark.parametrize(("p1001", "runs"), [(0x0000, False), (0x0002, False), (0x0001, True),
                                             (0x0008, True)])
def test_pr_triggers_act_only_in_a_mode_with_pr(p1001: int, runs: bool) -> None:
    """P5.007 "控制模式：PR" (L11168), CTRG "PR" (L15098); P1.001.YX 00 PT, 02 S, 01 PR,
    08 PR-S (L7749-7800). Option `pr_triggers_need_pr_mode=False` lets them act anywhere."""
    for gate in (True, False):
        opts = ModelOptions(pr_triggers_need_pr_mode=gate)
        d = Drive(options=opts, inputs={8: True}, params=PR_BENCH | {"P1.001": p1001},
                  sensors={})
        d.set_di(1, True)
        d.advance(400 * MS)
        assert d.servo_on
        put(d, 1, type_="single", data=20_000, spd=4)
        d.params.write("P5.007", 1)
        d.set_di(3, True)  # POS0: CTRG selects PR#1 too
        d.set_di(2, True)
        d.advance(500 * MS)
        moved = d.snapshot()["position_puu"] == 20_000
        assert moved is (runs or not gate)


@pytest.mark.parametrize("how", ["STP", "P5.007"])
def test_stp_is_a_pr_mode_function(how: str) -> None:
    """STP "馬達停止, 正緣, PR" (L15249) and P5.007 = 1000 (L11181, "控制模式：PR" L11168)
    leave a CiA 402 profile-velocity motion alone."""
    drive, _ = make(di5=0x46)
    enable(drive, PV)
    drive.write_object(0x60FF, 0, 1000)  # 100 rpm
    drive.advance(300 * MS)
    if how == "STP":
        press(drive, 5)
    else:
        drive.params.write("P5.007", 1000)
    drive.advance(100 * MS)
    assert rpm(drive) == pytest.approx(100, abs=1)

# -- alarm classes and servo state (table 13.1, L19325-19480) --------------------------------


@pytest.mark.parametrize(("code", "servo", "alm"), [
    ("AL020", True, False),  # WARN, servo ON (L19345)
    ("AL111", True, True),  # ALM, servo ON (L19433)
    ("AL112", True, True),
    ("AL180", False, True),  # ALM, servo OFF (L19453)
    ("AL185", False, True),
    ("AL301", True, False),  # WARN, servo ON
    ("AL3E2", True, False),
    ("AL3E3", True, False),  # WARN, servo ON (L19461)
])
def test_comm_alarm_class_and_servo_state(code: str, servo: bool, alm: bool) -> None:
    """Table 13.1 columns ALM/WARN and servo ON/OFF; all clear with a 6040h fault reset
    ("使用 0x6040 重置", L19937, L19945, L20025, L20031, L20163, L20169; AL020 L19602)."""
    drive, _ = make()
    enable(drive, PV)
    drive.write_object(0x60FF, 0, 1000)  # 100 rpm
    drive.advance(300 * MS)
    drive.raise_alarm(code)
    drive.advance(300 * MS)
    assert drive.servo_on is servo
    assert drive.dio.do_function_state("ALRM") is alm
    assert drive.dio.do_function_state("WARN") is not alm
    assert rpm(drive) == pytest.approx(100 if servo else 0, abs=1)
    drive.write_object(0x6040, 0, 0x8F)
    drive.advance(5 * MS)
    assert drive.alarms.active == ()


@pytest.mark.parametrize("p3003", [0, 1])
def test_al020_p3003_warn_and_run_or_ramp_with_p5003_b(p3003: int) -> None:
    """P3.003 = 0 "警告並繼續運轉", 1 "警告且減速停止(減速時間設於參數 P5.003.B)" (L10563-10566);
    P5.003.B = 3 -> P5.023 (L11090-11100)."""
    drive, _ = make(**{"P3.003": p3003, "P5.003": 0xEE3FEEFF, "P5.023": 600})
    enable(drive, PV)
    drive.write_object(0x60FF, 0, 15000)  # 1500 rpm
    drive.advance(500 * MS)
    drive.raise_alarm("AL020")
    drive.advance(150 * MS)  # 600 ms per 3000 rpm: 1500 rpm takes 300 ms
    assert drive.servo_on
    assert rpm(drive) == pytest.approx(1500 if p3003 == 0 else 1500 - 750, abs=30)
    drive.advance(200 * MS)
    assert rpm(drive) == pytest.approx(1500 if p3003 == 0 else 0, abs=30)


# -- CAPTURE axis registers (P5.037 L11485, P5.039.Y note L11528 / L11766) --------------------


def test_p5037_is_not_writable_on_a_cn2_capture_axis() -> None:
    """"當 CAPTURE 來源為 CN2 時，CAPTURE 軸位置等於馬達回授位置，本參數禁止寫入" (L11485)."""
    drive = Drive(inputs={6: True, 7: True, 8: True})
    drive.params.write("P5.039", 0x0030)  # Y = 3 CN2, stopped
    with pytest.raises(ModelError, match="L11485"):
        drive.params.write("P5.037", 123)
    drive.params.write("P5.039", 0x0010)  # Y = 1 CN5: writable while stopped
    drive.params.write("P5.037", 123)
    assert drive.params.read("P5.037") == 123


@pytest.mark.parametrize("y_lock", ["running", "always"])
def test_capture_source_locked_when_compare_uses_the_capture_axis(y_lock: str) -> None:
    """P5.059.Y = 0 (COMPARE on the capture axis): "CAPTURE 來源 Y 無法更改" (L11528, L11766);
    while COMPARE runs in any reading, with COMPARE stopped only under `y_lock: always`."""
    opts = ModelOptions(extra={"capture": {"y_lock": y_lock}})
    drive = Drive(options=opts, inputs={6: True, 7: True, 8: True})
    drive.params.write("P5.039", 0x0010)
    drive.params.write("P5.059", 0x00640000)  # COMPARE source = capture axis, stopped
    if y_lock == "always":
        with pytest.raises(ModelError, match="L11528"):
            drive.params.write("P5.039", 0x0030)
    else:
        drive.params.write("P5.039", 0x0030)
        drive.params.write("P5.039", 0x0010)
    drive.params.write("P5.058", 1)
    drive.params.write("P5.059", 0x00640001)  # COMPARE runs
    with pytest.raises(ModelError, match="L11528"):
        drive.params.write("P5.039", 0x0030)
