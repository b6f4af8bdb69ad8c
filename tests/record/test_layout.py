"""The Foxglove layout points at what recordings really hold: every panel path resolves in a
real recording of the virtual bench (topic recorded, field present in its messages), and the
DI/DO panel shows the bench's wired lines under their function names."""

from __future__ import annotations

import io
import json
from pathlib import Path

import pytest

from hil.bench.bench import load_bench
from hil.plan.plan import find_plans, load_plan
from hil.plan.runner import run_plans
from hil.record.reader import Recording

LAYOUT = Path(__file__).resolve().parents[2] / "fixtures" / "foxglove" / "hil-drive-layout.json"
PANELS = {"Plot", "StateTransitions", "RawMessages", "RosOut", "Table"}
# the recording is the built-in bench's, in virtual time: never rerun (tests/conftest.py)
pytestmark = pytest.mark.virtual_time


def _leaves(node):
    if isinstance(node, str):
        yield node
    else:
        yield from _leaves(node["first"])
        yield from _leaves(node["second"])


def _paths(doc: dict) -> list[tuple[str, str]]:
    """(panel id, message path or topic) of every panel."""
    out = []
    for panel_id, cfg in doc["configById"].items():
        out += [(panel_id, p["value"]) for p in cfg.get("paths", [])]
        out += [(panel_id, cfg[k]) for k in ("topicPath", "topicToRender") if k in cfg]
    return out


def resolve(path: str, rec: Recording) -> str | None:
    """Why `path` (Foxglove message path `/topic.a.b`) does not resolve in `rec`, or None.

    Topics contain slashes and no dots, so the topic is everything before the first dot."""
    topic, _, field = path.partition(".")
    if topic not in rec.topics():
        return f"{path}: topic {topic} not in the recording"
    if not field:
        return None
    for _t, _lt, _pt, msg in rec.messages(topic):
        cur = msg
        for part in field.split("."):
            if not isinstance(cur, dict) or part not in cur:
                break
            cur = cur[part]
        else:
            return None
    return f"{path}: no message of {topic} has field {field}"


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Recording:
    out = tmp_path_factory.mktemp("layout")
    [r] = run_plans([load_plan(p) for p in find_plans(["servo_on_off_brake"])], load_bench(),
                    out, stream=io.StringIO(), allow_inconclusive=True)
    return Recording.open(r.recording)


def test_layout_tree_and_panels():
    doc = json.loads(LAYOUT.read_text())
    assert set(_leaves(doc["layout"])) == set(doc["configById"])
    assert {pid.split("!")[0] for pid in doc["configById"]} <= PANELS


@pytest.mark.integration
def test_every_layout_path_resolves_in_a_real_recording(recording: Recording):
    doc = json.loads(LAYOUT.read_text())
    paths = _paths(doc)
    assert len(paths) > 20
    problems = [why for _pid, p in paths if (why := resolve(p, recording))]
    assert not problems, "\n".join(problems)
    # the motion plots: the fields the recorder writes (hil.record.schemas DriveState)
    plotted = {p for pid, p in paths if pid.startswith("Plot!")}
    assert plotted == {f"/drive/drive1/state.{f}"
                       for f in ("position_puu", "speed_rpm", "torque_pct")}
    brake = {p for pid, p in paths if pid == "StateTransitions!brake"}
    assert "/drive/drive1/state.brkr" in brake


def test_resolve_rejects_a_stale_path(recording: Recording):
    """The check can fail: the layout's old field names are not in a recording."""
    assert resolve("/drive/drive1/state.position", recording)
    assert resolve("/dio/drive1/DO9.level", recording)
    assert resolve("/drive/drive1/state.brkr", recording) is None


def test_dio_panel_shows_the_bench_wiring():
    """Every wired DI/DO of the virtual bench (fixtures/benches/virtual.yaml) is in the DI/DO
    panel under its line and function, and nothing else is (plus STO_A/B and FDBK)."""
    bench = load_bench()
    spec = bench.drives["drive1"]
    wired = {w.line: f for f, w in (spec.di | spec.do).items()}
    doc = json.loads(LAYOUT.read_text())
    shown = {p["value"].split("/")[3].split(".")[0]: p["label"]
             for p in doc["configById"]["StateTransitions!dio"]["paths"]}
    assert set(shown) == set(wired) | {"STO_A", "STO_B", "FDBK"}
    for line, func in wired.items():
        assert shown[line] == f"{line} {func}"


REAL_LAYOUT = LAYOUT.with_name("hil-real-bench-layout.json")


def resolve_filtered(path: str, rec: Recording) -> str | None:
    """`resolve` with a Foxglove filter `/topic{field=="value"}.path` on the topic."""
    head, _, field = path.partition(".")
    topic, _, cond = head.partition("{")
    if not cond:
        return resolve(path, rec)
    key, _, want = cond.rstrip("}").partition("==")
    want = want.strip('"')
    if topic not in rec.topics():
        return f"{path}: topic {topic} not in the recording"
    for _t, _lt, _pt, msg in rec.messages(topic):
        if str(msg.get(key)) == want and field in msg:
            return None
    return f"{path}: no message of {topic} with {key} == {want} has {field}"


def test_the_real_bench_layout_needs_no_ground_truth_and_resolves(recording, tmp_path):
    """A real bench has no /drive/* topics: its layout plots 6041h, 6064h, 606Ch from PDOs
    (decoded with the bus's own mapping) or from SDO polls; each path resolves either in a
    virtual-bench recording (SDO polls) or in one with a configured TPDO."""
    import struct

    import can
    from test_pdo_decode import _download

    from hil.record.recorder import Recorder

    doc = json.loads(REAL_LAYOUT.read_text())
    assert set(_leaves(doc["layout"])) == set(doc["configById"])
    paths = _paths(doc)
    assert not [p for _pid, p in paths if p.startswith("/drive/")]
    pdo_path = tmp_path / "pdo.mcap"
    t = 10**9
    with Recorder(pdo_path) as rec:
        def pair(req: can.Message, resp: can.Message) -> None:
            nonlocal t
            rec.can("can0", req, "tx", t, None)
            rec.can("can0", resp, "rx", t + 1000, None)
            t += 10**6

        for index, sub, value, size in (
                (0x1A00, 0, 0, 1), (0x1A00, 1, 0x60410010, 4), (0x1A00, 2, 0x60640020, 4),
                (0x1A00, 0, 2, 1), (0x1A01, 0, 0, 1), (0x1A01, 1, 0x606C0020, 4),
                (0x1A01, 0, 1, 1), (0x1600, 0, 0, 1), (0x1600, 1, 0x60400010, 4),
                (0x1600, 2, 0x60610008, 4), (0x1600, 0, 2, 1), (0x6040, 0, 0x0F, 2)):
            pair(*_download(index, sub, value, size))
        for index in (0x6041, 0x6064, 0x606C):  # polled by SDO upload (40h -> 43h)
            pair(can.Message(arbitration_id=0x601, data=struct.pack("<BHB", 0x40, index, 0)
                             + bytes(4), is_extended_id=False),
                 can.Message(arbitration_id=0x581, data=struct.pack("<BHBi", 0x43, index, 0,
                                                                     1234),
                             is_extended_id=False))
        for cob, data, way in ((0x181, struct.pack("<Hi", 0x1637, 500), "rx"),
                               (0x281, struct.pack("<i", -20), "rx"),
                               (0x201, b"\x0f\x00\x01", "tx")):
            rec.can("can0", can.Message(arbitration_id=cob, data=data, is_extended_id=False),
                    way, t, None)
    pdo_rec = Recording.open(pdo_path)
    problems = [why for _pid, p in paths
                if (why := resolve_filtered(p, recording)) and resolve_filtered(p, pdo_rec)]
    assert not problems, "\n".join(problems)
