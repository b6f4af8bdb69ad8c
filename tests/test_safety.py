"""The one safe-state routine (hil/safety.py), used by the runner and the gateway (issue 17
item 5): order of actions, every action attempted, dead drives claimed nothing."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import pytest

import hil.gateway.safe_state as gateway_mod
import hil.plan.safety as plan_safety
from hil.bench.bench import SafeState
from hil.safety import run_safe_state


class FakeDrive:
    def __init__(self, name: str, *, gone: str | None = None, fail_cw: bool = False,
                 brake: bool = True) -> None:
        self.name, self._gone, self.fail_cw, self.brake = name, gone, fail_cw, brake
        self.log: list[str] = []

    def gone(self) -> str | None:
        return self._gone

    def has_controlword(self) -> bool:
        return True

    def write_controlword(self, cw: int) -> Any:
        self.log.append(f"cw {cw:#x}")
        if self.fail_cw:
            raise TimeoutError("no SDO answer")
        return "acknowledged"

    def di_wired(self, function: str) -> bool:
        return function == "SON"

    def set_di(self, function: str, active: bool) -> None:
        self.log.append(f"{function} {active}")

    def has_sto(self) -> bool:
        return True

    def set_sto(self, channel: str, on: bool) -> None:
        self.log.append(f"STO {channel} {on}")

    def has_brkr(self) -> bool:
        return True

    def brake_engaged(self, timeout_ns: int) -> str | bool:
        self.log.append(f"brake {timeout_ns}")
        return "BRKR off: brake engaged" if self.brake else False


SAFE = SafeState(controlword="disable_voltage", di={"SON": False, "EMGS": True},
                 sto={"A": False}, wait_brake=True, timeout_ns=500_000_000)


def test_servo_off_path_order_disable_voltage_son_sto_then_brake():
    """Disable voltage = controlword 0x00 (L18272-18281), SON off, STO, then BRKR off (§2.9)."""
    d = FakeDrive("a")
    seen: list[tuple] = []
    rep = run_safe_state([d], SAFE, "end", lambda *a: seen.append(a))
    assert d.log == ["cw 0x0", "SON False", "STO A False", "brake 500000000"]
    assert rep.ok and [a["action"] for a in rep.actions] == [
        "controlword disable_voltage (0x00)", "DI SON off", "STO A off",
        "wait BRKR off (brake engaged)"]
    assert len(seen) == 4 and seen[-1][3] == "BRKR off: brake engaged"


def test_a_failed_action_does_not_stop_the_others_and_is_not_confirmed():
    d = FakeDrive("a", fail_cw=True, brake=False)
    rep = run_safe_state([d], SAFE, "timeout")
    assert d.log[1:] == ["SON False", "STO A False", "brake 500000000"]
    assert not rep.ok
    bad = {a["action"]: a["detail"] for a in rep.actions if not a["ok"]}
    # a False answer says "not confirmed" (an outside audit found an empty detail)
    assert bad == {"controlword disable_voltage (0x00)": "TimeoutError: no SDO answer",
                   "wait BRKR off (brake engaged)": "not confirmed"}


def test_the_brake_not_engaging_says_so_on_the_record():
    """The session's brake wait names what it saw: BRKR still on after the timeout."""
    from types import SimpleNamespace

    from hil.plan.safety import _SessionDrive

    d = SimpleNamespace(spec=SimpleNamespace(do={"BRKR": "DO6"}), dio=object(),
                        do_active=lambda f: True)
    with pytest.raises(TimeoutError, match="BRKR still on after 20 ms"):
        _SessionDrive("d", d, None).brake_engaged(20_000_000)


def test_a_dead_drive_is_reported_and_nothing_is_claimed_for_it():
    dead, live = FakeDrive("a", gone="exit code -9"), FakeDrive("b")
    rep = run_safe_state([dead, live], SAFE, "drive died")
    assert dead.log == [] and live.log[0] == "cw 0x0"
    assert rep.actions[0] == {"drive": "a", "action": "drive process alive", "ok": False,
                              "detail": "exit code -9"}
    assert not rep.ok


def test_runner_and_gateway_both_use_the_one_routine(monkeypatch):
    calls: list[str] = []

    def spy(drives, safe, reason, record=None):
        calls.append(type(drives[0]).__name__)
        return run_safe_state(drives, safe, reason, record)

    monkeypatch.setattr(plan_safety, "run_safe_state", spy)
    monkeypatch.setattr(gateway_mod, "run_safe_state", spy)

    class Spec:
        can, dio, di, do, sto = "", "", {}, {}, {}

    class DIO:
        spec, _cia, dio = Spec(), None, None

    session = SimpleNamespace(bench=SimpleNamespace(safe_state=SAFE), drives={"d": DIO()})
    plan_safety.go_safe(session, "end")
    gw = SimpleNamespace(bench=SimpleNamespace(safe_state=SAFE, drives={"d": Spec()}), can={},
                         dio={}, recorder=None)
    gateway_mod.default_safe_state(gw, "lease lost")
    assert calls == ["_SessionDrive", "_GatewayDrive"]


def test_gateway_controlword_frame_is_the_cia301_expedited_download():
    """2Bh = expedited download of 2 bytes (L16960-L16964) to 6040h:00 on 0x600 + node."""
    m = gateway_mod.sdo_write_controlword(5, 0x06)
    assert m.arbitration_id == 0x605
    assert bytes(m.data) == bytes([0x2B, 0x40, 0x60, 0x00, 0x06, 0x00, 0x00, 0x00])


QS = SafeState(controlword="quick_stop", di={"SON": False}, wait_brake=False,
               timeout_ns=500_000_000)


def test_quick_stop_is_followed_by_disable_voltage():
    """The A3 stays in QUICK STOP ACTIVE with the servo on after the ramp (transitions 12/16
    are commands, L18262-18266): the safe state waits for the ramp where the drive can tell
    (`quick_stop_done`), then writes disable voltage; a drive that cannot tell gets it at once
    (the power stage off matters more than the ramp)."""
    class Telling(FakeDrive):
        def quick_stop_done(self, timeout_ns: int) -> str:
            self.log.append("ramp")
            return "at rest"

    told, blind = Telling("a"), FakeDrive("b")
    rep = run_safe_state([told, blind], QS, "end")
    assert told.log == ["cw 0x2", "ramp", "cw 0x0", "SON False"]
    assert blind.log == ["cw 0x2", "cw 0x0", "SON False"]
    assert rep.ok


def test_the_gateway_reads_the_quick_stop_ramp_end_over_sdo():
    """606Ch read by expedited SDO uploads (40h) until it is within 10 rpm (L8407)."""
    speeds = iter([15000, 2000, 40])

    class Export:
        def __init__(self) -> None:
            self.asked: list[int] = []

        def request(self, msg, match, timeout_s):
            index = msg.data[1] | msg.data[2] << 8
            assert msg.arbitration_id == 0x605 and msg.data[0] == 0x40
            self.asked.append(index)
            value = 0x0237 if index == 0x6041 else next(speeds)  # QUICK STOP ACTIVE
            data = bytes([0x43, msg.data[1], msg.data[2], 0]) + value.to_bytes(4, "little",
                                                                               signed=True)
            ans = SimpleNamespace(arbitration_id=0x585, data=data)
            return ans if match(ans) else None

    export = Export()
    d = SimpleNamespace(can="can0", node_id=5, di={}, do={}, sto={})
    gw = SimpleNamespace(can={"can0": export}, dio={},
                         bench=SimpleNamespace(safe_state=QS))
    drive = gateway_mod._GatewayDrive(gw, "d", d)
    assert drive.quick_stop_done(QS.timeout_ns) == "606Ch = 40 (0.1 rpm): at rest"
    assert export.asked == [0x6041, 0x606C] * 3


def _gateway_drive(answer):
    """A `_GatewayDrive` whose export answers each expedited upload with `answer(index)`
    (None: no answer)."""
    class Export:
        def request(self, msg, match, timeout_s):
            index = msg.data[1] | msg.data[2] << 8
            value = answer(index)
            if value is None:
                return None
            data = bytes([0x43, msg.data[1], msg.data[2], 0]) + value.to_bytes(4, "little",
                                                                               signed=True)
            ans = SimpleNamespace(arbitration_id=0x585, data=data)
            return ans if match(ans) else None

    d = SimpleNamespace(can="can0", node_id=5, di={}, do={}, sto={})
    gw = SimpleNamespace(can={"can0": Export()}, dio={}, bench=SimpleNamespace(safe_state=QS))
    return gateway_mod._GatewayDrive(gw, "d", d)


def test_the_gateway_sees_a_drive_that_left_quick_stop_by_itself():
    drive = _gateway_drive(lambda index: 0x0250 if index == 0x6041 else 15000)
    assert drive.quick_stop_done(QS.timeout_ns).endswith("power stage off")


def test_the_gateway_gives_up_on_a_silent_drive_at_its_deadline():
    drive = _gateway_drive(lambda index: None)
    assert drive.quick_stop_done(50_000_000) is False


def test_every_drive_gets_its_quick_stop_before_any_ramp_is_waited_for():
    """Two drives: the second's 0x02 went out only after the first's whole ramp (helper-112)."""
    order: list[str] = []

    class Shared(FakeDrive):
        def write_controlword(self, cw: int) -> Any:
            order.append(f"{self.name} cw {cw:#x}")
            return "acknowledged"

        def quick_stop_done(self, timeout_ns: int) -> str:
            order.append(f"{self.name} ramp")
            return "at rest"

    run_safe_state([Shared("a"), Shared("b")], QS, "end")
    assert order == ["a cw 0x2", "b cw 0x2", "a ramp", "a cw 0x0", "b ramp", "b cw 0x0"]


@pytest.mark.parametrize("first", [0x42, 0x4B])
def test_the_gateway_reads_upload_answers_with_or_without_a_size(first: int):
    """An expedited upload answer may give no size (42h: 4 bytes) or 2 bytes (4Bh) (CiA
    301): a statusword 8237h (bit 15 set) out of QUICK STOP ACTIVE is read as such."""
    class Export:
        def request(self, msg, match, timeout_s):
            index = msg.data[1] | msg.data[2] << 8
            value = 0x8250 if index == 0x6041 else 0  # bit 2 clear: the power stage is off
            data = bytes([first, msg.data[1], msg.data[2], 0]) + value.to_bytes(4, "little")
            ans = SimpleNamespace(arbitration_id=0x585, data=data)
            return ans if match(ans) else None

    d = SimpleNamespace(can="can0", node_id=5, di={}, do={}, sto={})
    gw = SimpleNamespace(can={"can0": Export()}, dio={}, bench=SimpleNamespace(safe_state=QS))
    drive = gateway_mod._GatewayDrive(gw, "d", d)
    assert drive.quick_stop_done(QS.timeout_ns) == "statusword 0x8250: power stage off"


def test_a_drive_whose_quick_stop_failed_is_made_safe_before_the_ramps():
    order: list[str] = []

    class Shared(FakeDrive):
        def write_controlword(self, cw: int) -> Any:
            order.append(f"{self.name} cw {cw:#x}")
            if self.fail_cw and cw == 0x02:
                raise TimeoutError("no SDO answer")
            return "acknowledged"

        def quick_stop_done(self, timeout_ns: int) -> str:
            order.append(f"{self.name} ramp")
            return "at rest"

    run_safe_state([Shared("a"), Shared("c", fail_cw=True)], QS, "end")
    assert order == ["a cw 0x2", "c cw 0x2", "c cw 0x0", "a ramp", "a cw 0x0"]
