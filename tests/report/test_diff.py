"""`hil diff`: the virtual drive against itself with one deviation knob set per run; the diff
must name every knob and estimate its size within 10 %.

servo_on_off_brake (§2.9, L1351-1382) on the shipped virtual bench (A) and on copies with
`dev_brake_on_delay_ms: 30` (BRKR late after servo on, P1.042 L8492-8501), `P2.009: 12`
(DI response filter L9229-9236; factory 2 ms) and `mechanics.brake_release_ms: 40`
(brake mechanics, factory 20 ms)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from hil.cli import main
from hil.record.recorder import Recorder
from hil.report.diff import diff

ROOT = Path(__file__).resolve().parents[2]
# the runs are on the built-in bench's clock (virtual): never rerun (tests/conftest.py)
pytestmark = pytest.mark.virtual_time
KNOBS = {  # name -> (bench edit, option the diff must name, set size in ms)
    "on": (lambda d: d["options"].update(dev_brake_on_delay_ms=30), "dev_brake_on_delay_ms", 30),
    "scan": (lambda d: d["params"].update({"P2.009": 12}), "P2.009", 12),
    "release": (lambda d: d["mechanics"].update(brake_release_ms=40),
                "mechanics.brake_release_ms", 40),
}


def _run(tmp: Path, name: str, edit=None) -> Path:
    data = yaml.safe_load((ROOT / "fixtures/benches/virtual.yaml").read_text())
    drive = data["drives"]["drive1"]
    drive["options"] = dict(drive.get("options") or {})
    if edit:
        edit(drive)
    bench = tmp / f"{name}.yaml"
    bench.write_text(yaml.safe_dump(data, sort_keys=False))
    out = tmp / name
    main(["run", "servo_on_off_brake", "--bench", str(bench), "--out", str(out), "-q",
          "--plans", str(ROOT / "plans")])
    return out / "servo_on_off_brake.mcap"


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[str, Path]:
    tmp = tmp_path_factory.mktemp("diff")
    out = {"base": _run(tmp, "base")}
    for k, (edit, _opt, _size) in KNOBS.items():
        out[k] = _run(tmp, k, edit)
    return out


@pytest.mark.integration
@pytest.mark.parametrize("knob", list(KNOBS))
def test_diff_names_the_knob_and_its_size(runs, knob, tmp_path, capsys):
    _edit, option, size = KNOBS[knob]
    html, js = tmp_path / "d.html", tmp_path / "d.json"
    assert main(["diff", str(runs["base"]), str(runs[knob]), "-o", str(html),
                 "--json", str(js)]) == 0
    d = json.loads(js.read_text())
    assert "<table id='explanations'>" in html.read_text()
    [e] = d["explanations"]  # one knob, one explanation: nothing else is blamed
    assert e["option"].split(" ")[0] == option
    assert abs(e["estimate"] - size) <= 0.1 * size, e
    assert option in capsys.readouterr().out
    assert d["same_plan"] and d["same_steps"]
    assert any(s["differs"] for s in d["signals"])


@pytest.mark.integration
def test_diff_side_by_side_verdicts_and_edges(runs):
    d = diff(runs["base"], runs["on"])
    brkr = next(v for v in d["verdicts"] if v["constraint"] == "BRKR rises P1.042 after servo on")
    assert brkr["a_status"] == "pass" and brkr["b_status"] == "fail"
    assert 27 <= brkr["delta_ms"] <= 33 and brkr["step"] == 7
    do6 = next(s for s in d["signals"] if s["signal"] == "DO6 BRKR")
    rise = next(r for r in do6["edges"] if r["value"] is True)
    assert 27 <= rise["delta_ms"] <= 33 and rise["step"] == 2  # `wait_until BRKR on`
    son = next(s for s in d["signals"] if s["signal"] == "DI1 SON")
    # the harness's own edges line up step by step: within scheduling jitter, far below the
    # 30 ms knob (a busy machine can delay a step's first action by a few ms)
    assert son["max_delta_ms"] is not None and son["max_delta_ms"] < 10, son


@pytest.mark.integration
def test_diff_of_a_recording_with_itself_finds_nothing(runs):
    d = diff(runs["base"], runs["base"])
    assert d["explanations"] == [] and d["states"] == [] and d["params"] == {}
    assert not any(s["differs"] for s in d["signals"])


def _real(path: Path, shift_ms: float, states: list[int]) -> None:
    """A real-bench-like recording: no ground truth, SON in, two DO reactions, statuswords."""
    t0 = 1_000_000_000
    with Recorder(path, metadata={"plan": "p", "bench": "real"}) as rec:
        rec.attach("bench.yaml", yaml.safe_dump({"drives": {"d": {"wiring": {
            "SON": "DI1", "SRDY": "DO1", "BRKR": "DO6"}}}}).encode(), "application/yaml")
        rec.plan_step("di SON=on", "start", index=0, plan="p", t=t0)
        for line in ("DI1", "DO1", "DO6"):
            rec.dio("d", line, False, t0)
        rec.dio("d", "DI1", True, t0 + 1_000_000)
        rec.dio("d", "DO1", True, t0 + int((5 + shift_ms) * 1e6))
        rec.dio("d", "DO6", True, t0 + int((105 + shift_ms) * 1e6))
        rec.dio("d", "DI1", False, t0 + 200_000_000)
        rec.dio("d", "DO6", False, t0 + int((205 + shift_ms) * 1e6))
        for i, sw in enumerate(states):
            rec.write("/canopen/can0", {"statusword": sw}, log_time=t0 + i * 1_000_000)


def test_real_bench_constant_shift_and_state_sequence(tmp_path):
    """Without ground truth: every DO reaction 8 ms later is a scan delay of 8 ms; a
    statusword sequence that differs is listed."""
    a, b = tmp_path / "a.mcap", tmp_path / "b.mcap"
    _real(a, 0, [0x250, 0x231, 0x233, 0x237])
    _real(b, 8, [0x250, 0x231, 0x237])
    d = diff(a, b)
    [e] = d["explanations"]
    assert e["signature"] == "scan" and abs(e["estimate"] - 8) <= 0.8
    [s] = d["states"]
    assert s["a"] == ["0x0250", "0x0231", "0x0233", "0x0237"]  # 592, 561, 563, 567
    assert s["b"] == ["0x0250", "0x0231", "0x0237"]
    assert any("0x0233" in x for x in s["differences"])


@pytest.mark.integration
@pytest.mark.parametrize(("knob", "option", "size"), [(0, "P1.042", 80),
                                                       (5, "dev_brake_on_delay_ms", 5)])
def test_a_parameter_that_differs_is_taken_out_before_a_knob_is_blamed(runs, tmp_path, capsys,
                                                                       knob, option, size):
    """B's plan writes P1.042 = 80 (A's 100): BRKR comes 20 ms earlier by the parameter alone.
    The diff named dev_brake_on_delay_ms ~ -15 ms (an impossible negative delay) although it
    listed the parameter; it now gives P1.042 its part and the knob only the rest."""
    plan = (ROOT / "plans/servo_on_off_brake.yaml").read_text()
    assert "P1.042: 100" in plan
    (tmp_path / "plans").mkdir()
    (tmp_path / "plans/servo_on_off_brake.yaml").write_text(
        plan.replace("P1.042: 100", "P1.042: 80", 1))
    data = yaml.safe_load((ROOT / "fixtures/benches/virtual.yaml").read_text())
    data["drives"]["drive1"]["options"] = {"dev_brake_on_delay_ms": knob} if knob else {}
    bench = tmp_path / "b.yaml"
    bench.write_text(yaml.safe_dump(data, sort_keys=False))
    main(["run", "servo_on_off_brake", "--bench", str(bench), "--out", str(tmp_path / "o"),
          "-q", "--plans", str(tmp_path / "plans")])
    d = diff(runs["base"], tmp_path / "o/servo_on_off_brake.mcap")
    assert d["params"]["P1.042"] == [100, 80]
    [e] = [e for e in d["explanations"] if e["signature"] == "brake_on"]
    assert e["option"] == option and abs(e["estimate"] - size) <= 0.1 * size, e
