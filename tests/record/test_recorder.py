"""Recorder: every channel type round-trips through the official reader and ours."""

from __future__ import annotations

import json
import threading
import time
from dataclasses import dataclass

import pytest
from mcap.reader import make_reader
from rec_helpers import frame, schema_check

from hil.record import topics
from hil.record.reader import Recording
from hil.record.recorder import LogHandler, Recorder

T0 = 1_700_000_000_000_000_000


@dataclass(frozen=True)
class StateChanged:  # same shape as hil.model.events.StateChanged
    t: int
    old: str
    new: str


def record_mix(path, n_can: int = 500) -> list:
    """Record every channel type; return the CAN frames sent (bus, frame, dir, t)."""
    sent = []
    with Recorder(path, metadata={"bench": "virtual", "plan": "homing.yaml"}) as rec:
        rec.declare_source(topics.can_raw("gw0"), "gateway", resolution_ns=1000)
        for i in range(n_can):
            f = frame(0x181 + (i % 3), bytes([i & 0xFF, i >> 8, 0, 1]))
            bus = "can0" if i % 5 else "gw0"
            d = "rx" if i % 2 else "tx"
            t = T0 + i * 1_000
            rec.can(bus, f, d, t, t - 7 if bus == "gw0" else None)
            sent.append((bus, f, d, t))
        ext = frame(0x18FF50E5, "0102", ext=True)
        rec.can("can0", ext, "rx", T0 + 10**9, None)
        sent.append(("can0", ext, "rx", T0 + 10**9))
        rtr = frame(0x701, b"", is_remote_frame=True)
        rec.can("can0", rtr, "tx", T0 + 10**9 + 1, None)
        sent.append(("can0", rtr, "tx", T0 + 10**9 + 1))
        # SDO write P7.001 (2701h) = 300,000, manual L16979-L16993
        rec.can("can0", frame(0x60A, "23012700E0930400"), "tx", T0 + 2 * 10**9, None)
        rec.can("can0", frame(0x58A, "6001270000000000"), "rx", T0 + 2 * 10**9 + 800_000, None)
        # Modbus E3 request/response, manual L15838-L15863
        rec.serial("com1", bytes.fromhex("011001120002040BB80000FCEB"), "tx", T0, None, [0] * 13)
        rec.serial("com1", bytes.fromhex("011001120002E031"), "rx", T0 + 5_000_000, None)
        rec.dio("io", "DI1", True, T0 + 1, None)
        rec.dio("io", "DI1", False, T0 + 2, None)
        rec.plan_step("servo on", "start", plan="homing", index=0, t=T0)
        rec.plan_step("servo on", "end", status="pass", plan="homing", index=0, t=T0 + 5)
        rec.log("warning", "brake released late", name="runner", file="x.py", line=3, t=T0 + 9)
        rec.verdict(
            spec="brake.yaml",
            constraint="t_release",
            status="pass",
            measured_ms=12.0,  # the fields the checker's verdicts carry (hil.TimingVerdict)
            window_ms=[0.0, 20.0],
            margin_ms=8.0,
            t=T0 + 10,
        )
        rec.verdict({"spec": "sto.yaml", "constraint": "t_fdbk", "status": "FAIL"}, t=T0 + 11)
        rec.safety("disable", "plan aborted", t=T0 + 12)
        rec.drive_state(
            "a3",
            {
                "state": "OPERATION ENABLED",  # fields of Drive.snapshot() (hil.DriveState)
                "mode": "pp",
                "position_puu": 10,
                "speed_rpm": 1.5,
                "torque_pct": 0.0,
                "brkr": False,
                "alarms": [],
            },
            t=T0 + 13,
            source_t=T0 + 3,
        )
        rec.drive_event(
            "a3",
            StateChanged(t=3, old="SWITCHED ON", new="OPERATION ENABLED"),
            t=T0 + 14,
            source_t=T0 + 3,
        )
        rec.drive_params("a3", {"P1.042": 0, "P2.009": 2}, snapshot=True, t=T0 + 15)
        rec.write("/custom/thing", {"a": 1, "b": [1, 2]}, log_time=T0 + 16)
        rec.attach("bench.yaml", b"drives: [a3]\n", "application/yaml")
        rec.add_metadata("drive.params", {"P1.042": "0", "count": 2})
    return sent


def test_mix_reads_back_with_official_reader(tmp_path):
    p = tmp_path / "mix.mcap"
    sent = record_mix(p)
    with open(p, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        schemas = {s.id: s for s in summary.schemas.values()}
        channels = {c.topic: c for c in summary.channels.values()}
        msgs = list(reader.iter_messages())
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
        attachments = list(reader.iter_attachments())
    assert summary.statistics.message_count == len(msgs)
    # one channel per topic, every one JSON with a parseable jsonschema
    assert len(channels) == len(summary.channels)
    for ch in channels.values():
        assert ch.message_encoding == "json"
        s = schemas[ch.schema_id]
        assert s.encoding == "jsonschema"
        assert json.loads(s.data)["title"] == s.name
        assert ch.metadata["publish_time_source"] in ("model", "adapter", "gateway", "harness")
    assert channels["/can/gw0/raw"].metadata["publish_time_source"] == "gateway"
    assert channels["/drive/a3/state"].metadata["publish_time_source"] == "model"
    assert schemas[channels["/log"].schema_id].name == "foxglove.Log"
    assert schemas[channels["/can/can0/raw"].schema_id].name == "hil.CanFrame"
    # every message valid JSON matching its schema
    for _s, ch, m in msgs:
        obj = json.loads(m.data)
        schema = json.loads(schemas[ch.schema_id].data)
        assert schema_check(schema, obj) == [], (ch.topic, obj)
    # each CAN frame exactly once, same content
    raw = [
        (ch.topic, m.log_time, json.loads(m.data))
        for _s, ch, m in msgs
        if ch.topic.startswith("/can/")
    ]
    assert len(raw) == len(sent) + 2  # + the two SDO frames
    by_time = {(topic, t): obj for topic, t, obj in raw}
    assert len(by_time) == len(raw)
    for bus, f, d, t in sent:
        obj = by_time[(topics.can_raw(bus), t)]
        assert obj["id"] == f.arbitration_id
        assert bytes.fromhex(obj["data"]) == bytes(f.data)
        assert obj["dir"] == d and obj["ext"] == f.is_extended_id
        assert obj["rtr"] == f.is_remote_frame
    assert metadata["hil.run"]["bench"] == "virtual"
    assert metadata["hil.versions"]["mcap"] == "1.6.0"
    assert metadata["hil.close"]["drops"] == "0"
    assert metadata["hil.close"]["verdicts_fail"] == "1"
    assert metadata["drive.params"] == {"P1.042": "0", "count": "2"}
    assert [a.name for a in attachments] == ["bench.yaml"]


def test_mix_reads_back_with_our_reader(tmp_path):
    p = tmp_path / "mix.mcap"
    sent = record_mix(p)
    rec = Recording.open(p)
    assert not rec.truncated and rec.error is None
    counts = rec.counts()
    assert counts["/can/can0/raw"] + counts["/can/gw0/raw"] == len(sent) + 2
    (gw_ch,) = [c for c in rec.channels() if c.topic == "/can/gw0/raw"]
    assert gw_ch.metadata == {"publish_time_source": "gateway", "resolution_ns": "1000"}
    gw = list(rec.messages("/can/gw0/raw"))
    assert all(pt == lt - 7 for _t, lt, pt, _o in gw)  # publish_time = source time
    # SDO transaction: the manual's P7.001 write (L16979-L16993)
    (sdo,) = [o for _t, _l, _p, o in rec.messages(topics.canopen_sdo("can0"))]
    assert (sdo["node"], sdo["index"], sdo["sub"]) == (10, 0x2701, 0)
    assert sdo["access"] == "download" and sdo["status"] == "ok"
    assert sdo["value"] == 300_000 and sdo["latency_ns"] == 800_000
    # Modbus transaction E3 (L15838-L15863): response pairs with a 5 ms round trip
    mb = [o for _t, _l, _p, o in rec.messages(topics.modbus("com1"))]
    assert [m["role"] for m in mb] == ["request", "response"]
    assert mb[1]["rtt_ns"] == 5_000_000 and mb[1]["function"] == 0x10
    raw485 = [o for _t, _l, _p, o in rec.messages(topics.rs485_raw("com1"))]
    assert raw485[0]["gaps_us"] == [0] * 13 and raw485[0]["n"] == 13
    # ground truth, logs, verdicts
    (state,) = [o for *_x, o in rec.messages("/drive/a3/state")]
    assert state["state"] == "OPERATION ENABLED"
    assert rec.series("/drive/a3/state", "position_puu") == [(T0 + 3, 10)]
    assert rec.series("/drive/a3/state", "position_puu", time="log") == [(T0 + 13, 10)]
    (ev,) = [o for *_x, o in rec.messages("/drive/a3/events")]
    assert ev == {"type": "StateChanged", "t": 3, "old": "SWITCHED ON", "new": "OPERATION ENABLED"}
    (log,) = [o for *_x, o in rec.messages(topics.LOG)]
    assert log == {
        "timestamp": {"sec": T0 // 10**9, "nsec": 9},
        "level": 3,
        "message": "brake released late",
        "name": "runner",
        "file": "x.py",
        "line": 3,
    }
    verdicts = [o["status"] for *_x, o in rec.messages(topics.TIMING_VERDICTS)]
    assert verdicts == ["pass", "fail"]
    assert rec.edges("/dio/io/DI1") == [(T0 + 1, True), (T0 + 2, False)]
    assert rec.metadata()["hil.close"]["verdicts_not_passed"] == "t_fdbk"
    assert rec.attachments()[0].data == b"drives: [a3]\n"
    assert rec.series("/custom/thing", "b.1") == [(T0 + 16, 2)]


def test_edges_keep_only_changes(tmp_path):
    p = tmp_path / "dio.mcap"
    with Recorder(p) as rec:
        for i, level in enumerate([False, False, True, True, True, False, True]):
            rec.dio("io", "DO1", level, T0 + i, None)
    rec_ = Recording.open(p)
    assert rec_.edges(topics.dio("io", "DO1")) == [
        (T0, False),
        (T0 + 2, True),
        (T0 + 5, False),
        (T0 + 6, True),
    ]
    with pytest.raises(ValueError, match="time 'wall'"):
        rec_.series(topics.dio("io", "DO1"), "level", time="wall")


def test_many_threads_no_loss(tmp_path):
    p = tmp_path / "threads.mcap"
    rec = Recorder(p)
    per_thread = 2_000

    def bus(k: int) -> None:
        for i in range(per_thread):
            rec.can(f"can{k}", frame(0x200 + k, i.to_bytes(4, "little")), "rx", T0 + i, None)

    threads = [threading.Thread(target=bus, args=(k,)) for k in range(4)]
    for th in threads:
        th.start()
    rec.log("info", "from main thread")
    for th in threads:
        th.join(timeout=30)
    rec.close()
    assert rec.drops == 0 and rec.errors == 0
    r = Recording.open(p)
    for k in range(4):
        vals = [
            int.from_bytes(bytes.fromhex(o["data"]), "little")
            for *_x, o in r.messages(topics.can_raw(f"can{k}"))
        ]
        assert sorted(vals) == list(range(per_thread))


def test_full_queue_drops_and_counts_never_blocks(tmp_path):
    p = tmp_path / "drops.mcap"
    rec = Recorder(p, max_queue=10)
    gate = threading.Event()
    rec._control((lambda item: gate.wait(10),))  # stall the writer thread
    deadline = time.monotonic() + 5
    while rec.queued and time.monotonic() < deadline:
        time.sleep(0.001)
    for i in range(100):
        rec.can("can0", frame(0x181, bytes([i])), "rx", T0 + i, None)
    assert rec.drops == 90
    gate.set()
    rec.close()
    r = Recording.open(p)
    assert r.counts()["/can/can0/raw"] == 10
    assert r.metadata()["hil.close"]["drops"] == "90"


def test_bad_input_is_a_precise_error(tmp_path):
    with Recorder(tmp_path / "bad.mcap") as rec:
        with pytest.raises(ValueError, match="log level 7"):
            rec.log(7, "x")
        with pytest.raises(ValueError, match="log level 'loud'"):
            rec.log("loud", "x")
        with pytest.raises(ValueError, match="verdict status 'ok'"):
            rec.verdict(status="ok")
        with pytest.raises(ValueError, match="plan_step event 'middle'"):
            rec.plan_step("x", "middle")
        with pytest.raises(ValueError, match="publish_time_source 'gps'"):
            rec.declare_source("/x", "gps")
        with pytest.raises(ValueError, match="Modbus mode 'tcp' for port 'p'"):
            rec.serial_mode("p", "tcp")
    with pytest.raises(ValueError, match="flush_interval"):
        Recorder(tmp_path / "x.mcap", flush_interval=0.5)


def test_log_handler_and_levels(tmp_path):
    import logging

    p = tmp_path / "log.mcap"
    with Recorder(p) as rec:
        lg = logging.getLogger("hil.test.recorder")
        lg.setLevel(logging.DEBUG)
        h = LogHandler(rec, logging.DEBUG)
        lg.addHandler(h)
        try:
            lg.error("boom %d", 3)
            lg.debug("fine")
        finally:
            lg.removeHandler(h)
        rec.log(logging.CRITICAL, "x")
        rec.log(1, "y")
    levels = [(o["level"], o["message"]) for *_x, o in Recording.open(p).messages("/log")]
    assert levels == [(4, "boom 3"), (1, "fine"), (5, "x"), (1, "y")]


def test_log_handler_on_the_forwarding_logger_records_each_line_once(tmp_path):
    """Recorder.log forwards to Python logging; a LogHandler there must neither loop nor
    record the line a second time."""
    import logging

    p = tmp_path / "log.mcap"
    lg = logging.getLogger("hil")
    with Recorder(p) as rec:
        h = LogHandler(rec, logging.DEBUG)
        lg.addHandler(h)
        try:
            rec.log(logging.WARNING, "once")
            logging.getLogger("hil.child").warning("from logging")
        finally:
            lg.removeHandler(h)
    messages = [o["message"] for *_x, o in Recording.open(p).messages("/log")]
    assert messages == ["once", "from logging"]


def test_flush_makes_data_readable_before_close(tmp_path):
    p = tmp_path / "live.mcap"
    rec = Recorder(p)
    try:
        for i in range(50):
            rec.can("can0", frame(0x181, bytes([i])), "rx", T0 + i, None)
        assert rec.flush(5)
        r = Recording.open(p)
        assert r.truncated and r.error is None  # no footer yet, nothing broken
        assert r.counts()["/can/can0/raw"] == 50
    finally:
        rec.close()


def test_an_unencodable_or_self_containing_payload_is_an_error_object(tmp_path):
    """A payload JSON cannot encode (an object, a dict that contains itself) is recorded as an
    `error` object naming why; the messages around it are recorded as they are."""
    from hil.record.reader import Recording

    path = tmp_path / "bad.mcap"
    rec = Recorder(path)
    loop: dict = {"state": "x"}
    loop["self"] = loop
    rec.drive_state("drive1", {"state": "A", "n": 1}, t=1)
    rec.drive_state("drive1", loop, t=2)
    rec.drive_event("drive1", {"type": "X", "obj": {(1, 2): 3}}, t=3)  # a tuple key
    rec.drive_state("drive1", {"state": "B", "n": 2}, t=4)
    rec.close()
    got = Recording.open(str(path))
    state = [m for _topic, _lt, _pt, m in got.messages() if _topic == "/drive/drive1/state"]
    assert state[0] == {"state": "A", "n": 1} and state[2] == {"state": "B", "n": 2}
    assert state[1]["error"].startswith("unencodable payload: maximum recursion depth")
    [event] = [m for _topic, _lt, _pt, m in got.messages() if _topic == "/drive/drive1/events"]
    assert event["error"].startswith("unencodable payload:")


def test_the_git_revision_says_when_the_checkout_differs_from_it(tmp_path, monkeypatch):
    """A report's revision must not look clean when hil/, fixtures/ or plans/ were edited
    since the commit (an outside review)."""
    import subprocess

    from hil.record import recorder

    calls = []

    def fake_run(cmd, **kw):
        calls.append(cmd)
        out = "abc123\n" if "rev-parse" in cmd else " M hil/model/cia402.py\n"
        return subprocess.CompletedProcess(cmd, 0, out, "")

    monkeypatch.setattr(recorder.subprocess, "run", fake_run)
    recorder.versions.cache_clear()
    try:
        assert recorder.versions()["git_revision"] == "abc123+dirty"
        assert any("status" in c for c in calls)
    finally:
        recorder.versions.cache_clear()
