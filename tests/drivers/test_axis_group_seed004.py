"""Rules of seed 004 (TG Motion v4, "Servo group") written from the seed by an outside probe
(helper-98), each on the group driver in-process: WritePosition never jumps when a
generator joins or leaves, and odd COMMAND registers are refused, never run.

- WritePosition = PG.APos + GEA part + Offset + Correction by Servo.Mode (004:216-218); the
  seed connects a generator only after setting it up where the axis stands (PG.APos =
  WritePosition - Offset - Correction, 004:222-226; GEA.Offset likewise, 004:236).
- COMMAND 7 (sync off) ramps the ratio to 0 and "the drive starts to brake" (004:244-246).
- PG.Acc / PG.Dec are maxima (004:220): a tiny one is a slow move, not a jump.
- COMMAND 6 Par12 is ServoMode (004:242); the functions are 1-7 (004:240).
"""

from __future__ import annotations

from itertools import pairwise

from hil.drivers.axis_group import AxisGroup, ServoAxis


class _Net:
    """No bus: the group's frames go nowhere (the rules are the driver's own)."""

    class bus:
        @staticmethod
        def send(_m: object) -> None:
            return None

    def subscribe(self, *_a: object) -> None:
        return None

    def send_message(self, *_a: object) -> None:
        return None


def group(n: int = 2) -> tuple[AxisGroup, list[ServoAxis]]:
    axes = [ServoAxis(f"a{i}", i + 1) for i in range(n)]
    g = AxisGroup(_Net(), axes, 0.001, sdo_write=lambda *a: None)
    for a in axes:
        a.status = 3  # under torque
    return g, axes


def command(g: AxisGroup, ax: ServoAxis, code: int, par: dict[int, float]) -> str:
    """COMMAND `code` with `par`: '' once accepted, else why it was refused."""
    ax.par = [float(par.get(k, 0.0)) for k in range(15)]
    ax.command = code
    g.command_errors.pop(ax.name, None)
    for _ in range(20000):
        if not ax.command:
            return ""
        if ax.name in g.command_errors:
            ax.command = 0
            return g.command_errors.pop(ax.name)
        g.cycle()
    raise AssertionError(f"never accepted (Control {ax.command})")


def trace(g: AxisGroup, ax: ServoAxis, n: int) -> list[float]:
    out = []
    for _ in range(n):
        g.cycle()
        out.append(ax.write_position)
    return out


def geared_follower(g: AxisGroup, m: ServoAxis, f: ServoAxis) -> None:
    """f geared 1:1 to m (Servo.Mode 4), m moved to 30000."""
    assert command(g, f, 6, {0: 0, 1: 1, 2: 1, 3: 1, 4: 1, 12: 4}) == ""
    assert command(g, m, 2, {0: 1e6, 1: 1e6, 2: 1e5, 3: 30000, 5: 3}) == ""
    trace(g, f, 600)
    assert round(f.write_position) == 30000


def test_sync_off_under_a_pg_move_on_top_does_not_jump() -> None:
    g, (m, f) = group()
    geared_follower(g, m, f)
    assert command(g, f, 3, {0: 1e5, 1: 1e5, 2: 5000, 3: 20000, 4: 1, 5: 3}) == ""  # on top
    trace(g, f, 500)
    f.par = [0.0] * 15
    f.par[5] = 0.05
    f.command = 7  # sync off, the ratio ramped down over 20 cycles
    w = trace(g, f, 60)
    assert f.command == 0 and f.mode == 1
    assert max(abs(b - a) for a, b in pairwise(w)) <= 5.0 + 1e-6  # the PG's 5000 inc/s
    w = trace(g, f, 5000)
    assert f.pg.rdy and round(w[-1]) == 30000 + 20000  # the move on top ends where it would


def test_sync_off_under_a_pg_speed_run_keeps_the_run() -> None:
    g, (m, f) = group()
    geared_follower(g, m, f)
    assert command(g, f, 1, {0: 1e5, 2: 5000, 4: 1, 5: 3}) == ""  # speed on top
    trace(g, f, 500)
    f.par = [0.0] * 15
    f.par[5] = 0.05
    f.command = 7
    w = trace(g, f, 60)
    steps = [b - a for a, b in pairwise(w)]
    assert all(abs(s - 5.0) < 1e-6 for s in steps[-10:]), steps[-10:]  # still 5000 inc/s


def test_a_servo_mode_change_keeps_the_write_position() -> None:
    g, (a, f) = group()
    assert command(g, a, 2, {0: 5e5, 1: 5e5, 2: 1e5, 3: 50000, 5: 3}) == ""
    trace(g, a, 1000)
    assert round(a.write_position) == 50000
    for mode in (3, 1, 4, 1):
        a.set_mode(mode)
        assert trace(g, a, 3) == [50000.0] * 3, mode
    g, (m, f) = group()
    geared_follower(g, m, f)
    f.set_mode(1)
    assert [round(x) for x in trace(g, f, 3)] == [30000] * 3


def test_a_tiny_acc_or_dec_is_refused_and_the_least_one_is_a_slow_move() -> None:
    """Acc 1e-300 had landed the axis on its target in one cycle, below the profile's
    arithmetic. An Acc or Dec under PG_MIN is refused; at PG_MIN the move is slow, from where
    the axis stands, also on the fly (a running 5000 inc/s keeps going)."""
    from hil.drivers.axis_group import PG_MIN

    for par in ({0: 1e-300, 1: 1e5}, {0: 1e5, 1: 1e-300}, {0: 1e-40, 1: 1e-40}):
        g, (a, _f) = group()
        assert "at least" in command(g, a, 2, {**par, 2: 50000, 3: 200000, 5: 3}), par
        assert trace(g, a, 3) == [0.0] * 3
    g, (a, _f) = group()
    assert command(g, a, 2, {0: PG_MIN, 1: PG_MIN, 2: 50000, 3: 10**9, 5: 3}) == ""
    w = trace(g, a, 3)
    assert all(0 <= x < 1.0 for x in w) and not a.pg.rdy, w
    g, (a, _f) = group()  # PosSpeed 1e15 over the least Acc: below the search's resolution
    assert command(g, a, 2, {0: PG_MIN, 1: PG_MIN, 2: 1e15, 3: 1000, 5: 3}) == ""
    w = trace(g, a, 3)
    assert all(0 <= x < 1.0 for x in w) and not a.pg.rdy, w  # it had landed at once
    g, (a, _f) = group()
    assert command(g, a, 1, {0: 1e6, 2: 5000, 5: 3}) == ""
    trace(g, a, 100)
    assert command(g, a, 2, {0: PG_MIN, 1: 1e5, 2: 50000, 3: 10**9, 5: 3}) == ""
    w = trace(g, a, 10)
    assert all(abs((y - x) - 5.0) < 1e-3 for x, y in pairwise(w)), w  # on at 5000 inc/s


def test_a_speed_run_after_a_mode_change_starts_where_the_axis_stands() -> None:
    """COMMAND 1 on an axis put in Servo.Mode 3 with no gear set Servo.Mode 1 alone: the
    set-point jumped by the PG's position (helper-99)."""
    g, (a, _f) = group()
    assert command(g, a, 2, {0: 5e5, 1: 5e5, 2: 1e5, 3: 50000, 5: 3}) == ""
    trace(g, a, 1000)
    a.set_mode(3)
    assert command(g, a, 1, {0: 1e5, 2: 0, 5: 3}) == ""
    assert trace(g, a, 3) == [50000.0] * 3


def test_odd_command_registers_are_refused_and_nothing_moves() -> None:
    g, (m, f) = group()
    nan = float("nan")
    for code, par, said in [
        (2, {0: 1e5, 1: 1e5, 2: 5e4, 3: nan, 5: 3}, "Par3 nan"),
        (2, {0: nan, 1: 1e5, 2: 5e4, 3: 1000, 5: 3}, "Par0 nan"),
        (1, {0: 1e5, 2: 5e4, 5: float("inf")}, "Par5 inf"),
        (99, {}, "Control 99"),
        (-1, {}, "Control -1"),
        (6, {0: 0, 1: 1, 2: 1, 3: 1, 4: 1, 12: 6}, "Par12 6"),
        (6, {0: 0, 1: 1, 2: 1, 3: 1, 4: 1, 12: 1}, "Par12 1"),
    ]:
        why = command(g, f, code, par)
        assert said in why, (code, par, why)
        assert f.write_position == 0.0 and f.pg.rdy
    f.pg.start_speed(1000.0)
    assert command(g, f, 5, {1: 1e6, 5: 3, 9: nan}) == ""  # an abort with an unread NaN acts
    trace(g, f, 50)
    assert f.pg.aspeed == 0.0
    g, (m, f) = group()
    geared_follower(g, m, f)
    assert "Par5 -1" in command(g, f, 7, {5: -1})
    assert f.gea.mode == 1 and round(f.write_position) == 30000  # still geared


def test_sdo_numberbyte_is_the_objects_size() -> None:
    """NumberByte is 1-4, the size of the object (004:248-250): another count is refused
    with Status 2 and nothing is sent; a read of an object longer than NumberByte gives Status
    2 (CiA 301 0607 0010h, length does not match), not the value cut to NumberByte bytes
    (123456 read in 2 bytes had reported 57920 with Status 0); a shorter one reads whole."""
    from hil.drivers.axis_group import SDO_LENGTH_MISMATCH, SdoInterface

    sent: list = []
    obj = {(0x607A, 0): (123456).to_bytes(4, "little")}
    for n in (0, 5, 8, -1):
        sdo = SdoInterface(control=1, number_byte=n, index=0x607A, sub=0, data=70000)
        sdo.execute(lambda i, s: obj[(i, s)], lambda i, s, raw: sent.append(raw))
        assert (sdo.control, sdo.status, sdo.data, sent) == (0, 2, SDO_LENGTH_MISMATCH, []), n
    sdo = SdoInterface(control=2, number_byte=2, index=0x607A, sub=0)
    sdo.execute(lambda i, s: obj[(i, s)], lambda i, s, raw: None)
    assert (sdo.status, sdo.data) == (2, SDO_LENGTH_MISMATCH)
    # the seed's own read: 6060h, one byte, with NumberByte 2 (004:250)
    sdo = SdoInterface(control=2, number_byte=2, index=0x6060, sub=0)
    sdo.execute(lambda i, s: b"\x07", lambda i, s, raw: None)
    assert (sdo.status, sdo.data) == (0, 7)
    sdo = SdoInterface(control=2, number_byte=4, index=0x607A, sub=0)
    sdo.execute(lambda i, s: obj[(i, s)], lambda i, s, raw: None)
    assert (sdo.status, sdo.data) == (0, 123456)
