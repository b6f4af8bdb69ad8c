"""`hil check` on a real MCAP written with the `mcap` package (read via hil.record.reader)."""

from __future__ import annotations

import json

import pytest
from mcap.writer import Writer

from hil.timing.cli import configure, main
from hil.timing.source import RecordingSource

MS = 1_000_000


def write_mcap(path, brkr_ms: float, meta: dict | None = None) -> None:
    """SON at 100 ms, servo on 2 ms later (P2.009 = 2), BRKR `brkr_ms` after (P1.042 = 150)."""
    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        sid = w.register_schema("hil.Any", "jsonschema", b'{"type": "object"}')
        chans = {}

        def put(topic, t_ms, payload, res=None):
            if topic not in chans:
                md = {"resolution_ns": str(res)} if res is not None else {}
                chans[topic] = w.register_channel(topic, "json", sid, md)
            t = round(t_ms * MS)
            w.add_message(chans[topic], log_time=t + 50_000, publish_time=t,
                          data=json.dumps(payload).encode())

        put("/drive/drive1/params", 0, {"snapshot": True, "values": {"P1.042": 150, "P2.009": 2}})
        put("/dio/drive1/DI1", 0, {"level": False})
        put("/dio/drive1/DO1", 0, {"level": True}, res=MS)
        put("/dio/drive1/DO6", 0, {"level": False}, res=MS)
        put("/drive/drive1/state", 0, {"servo_on": False, "alarms": []})
        put("/dio/drive1/DI1", 100, {"level": True})
        put("/drive/drive1/state", 102, {"servo_on": True, "alarms": []})
        put("/dio/drive1/DO6", 102 + brkr_ms, {"level": True}, res=MS)
        # the run goes on: the servo is seen on past P1.042 (servo_on_brake judges a servo
        # on that lasts that long; a shorter one leaves the brake engaged)
        put("/drive/drive1/state", 102 + brkr_ms + 100, {"servo_on": True, "alarms": []})
        for name, data in (meta or {}).items():
            w.add_metadata(name, data)
        w.finish()


def run(argv: list[str]) -> int:
    import argparse

    p = argparse.ArgumentParser()
    configure(p)
    return main(p.parse_args(argv))


def test_recording_source_reads_params_and_channel_resolution(tmp_path):
    path = tmp_path / "run.mcap"
    write_mcap(path, 150)
    src = RecordingSource(path)
    assert src.resolution("/dio/drive1/DO6") == MS
    assert src.messages("/dio/drive1/DI1")[-1] == (100 * MS, {"level": True})


@pytest.mark.parametrize("brkr,code", [(150, 0), (155, 1), (152, 3)])
def test_hil_check_exit_codes(tmp_path, capsys, brkr, code):
    path = tmp_path / "run.mcap"
    write_mcap(path, brkr)
    assert run([str(path), "--spec", "servo_on_brake"]) == code
    out = capsys.readouterr().out
    assert "BRKR rises P1.042 after servo on" in out


def test_hil_check_json_param_override_and_svg(tmp_path, capsys):
    path = tmp_path / "run.mcap"
    write_mcap(path, 155)
    assert run([str(path), "--spec", "servo_on_brake", "--param", "P1.042=155", "--json",
                "--svg", str(tmp_path / "svg")]) == 0
    data = json.loads(capsys.readouterr().out)
    assert {d["status"] for d in data} == {"pass"}
    assert (tmp_path / "svg" / "servo_on_brake.svg").read_text().startswith("<svg")


def test_hil_check_uses_the_specs_named_in_the_recording(tmp_path, capsys):
    path = tmp_path / "run.mcap"
    write_mcap(path, 150, meta={"timing": {"specs": json.dumps(["servo_on_brake"])}})
    assert run([str(path)]) == 0
    out = capsys.readouterr().out
    assert "servo_on_brake" in out and "sto" not in out.split("\n")[-1]


def test_hil_check_bad_input(tmp_path, capsys):
    assert run([str(tmp_path / "nope.mcap")]) == 2
    path = tmp_path / "run.mcap"
    write_mcap(path, 150)
    assert run([str(path), "--spec", "no_such_spec"]) == 2
    assert run([str(path), "--param", "P1.042"]) == 2
    assert "no shipped spec" in capsys.readouterr().err


@pytest.mark.virtual_time
def test_spec_ids_the_plan_checked_are_re_judged_as_the_plan_judged_them(tmp_path, capsys):
    """An outside audit: `hil check REC --spec homing_pr` on a passing homing_pr recording gave
    7 fails (the spec over the whole file); a spec the plan checked is re-judged at its steps,
    as the plan did, and --whole still judges it once over the whole file."""
    from hil.bench.bench import load_bench
    from hil.paths import plans_dir
    from hil.plan.plan import load_plan
    from hil.plan.runner import run_plan

    res = run_plan(load_plan(plans_dir() / "homing_pr.yaml"), load_bench(None), tmp_path)
    assert res.passed

    def verdicts(*extra: str) -> list[tuple]:
        capsys.readouterr()
        run([str(res.recording), "--json", *extra])
        out = json.loads(capsys.readouterr().out)
        return sorted((v["spec"], v["constraint"], v["status"], v["occurrence"]) for v in out)

    as_run = [v for v in verdicts() if v[0] == "homing_pr"]
    assert as_run and not [v for v in as_run if v[2] == "fail"]
    assert verdicts("--spec", "homing_pr") == as_run
    assert [v for v in verdicts("--spec", "homing_pr", "--whole") if v[2] == "fail"]


def test_hil_check_of_an_aborted_run_is_incomplete(tmp_path, capsys):
    """A run stopped by Ctrl-C leaves a whole file whose later checks never ran: `hil check`
    passed it silently (exit 0), so a CI gate passed an aborted run (an outside review)."""
    path = tmp_path / "run.mcap"
    write_mcap(path, 150, meta={"hil.result": {"status": "aborted",
                                               "reason": "interrupted (SIGINT (Ctrl-C))"}})
    assert run([str(path), "--spec", "servo_on_brake"]) == 4
    assert "the run was aborted (interrupted (SIGINT (Ctrl-C)))" in capsys.readouterr().err
    write_mcap(path, 150, meta={"hil.result": {"status": "pass", "reason": "end of plan"}})
    assert run([str(path), "--spec", "servo_on_brake"]) == 0
