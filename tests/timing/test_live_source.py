"""`LiveSource`: a running plan's recording for its checks, decoded once and only where read.

The same messages through `LiveSource` (the recorder's mirror) and `RecordingSource` (the
file) must give the same messages, times and verdicts; a topic no check reads is never
decoded."""

from __future__ import annotations

import can

import hil.timing.source as source_mod
from hil.record.recorder import Recorder
from hil.timing.source import LiveSource, RecordingSource
from hil.units import MS


def _record(rec: Recorder, t0: int, n: int) -> None:
    for i in range(n):
        t = t0 + i * MS
        rec.drive_state("drive1", {"state": "OPERATION ENABLED", "speed_rpm": float(i),
                                   "periodic": True}, t=t, source_t=t)
        rec.can("can0", can.Message(arbitration_id=0x181, data=bytes([i & 0xFF, 0]),
                                    is_extended_id=False), "rx", t)
    rec.dio("drive1", "DO2", bool(n & 1), t0 + n * MS)


def test_live_source_decodes_only_what_is_read_and_matches_the_file(tmp_path, monkeypatch):
    calls: list[bytes] = []
    real = source_mod.decode
    monkeypatch.setattr(source_mod, "decode", lambda b: (calls.append(b), real(b))[1])
    path = tmp_path / "live.mcap"
    rec = Recorder(path)
    rec.keep_messages()
    live = LiveSource()
    _record(rec, 0, 50)
    rec.flush()
    live.refresh(rec)
    assert calls == []  # refreshing decodes nothing
    assert "/can/can0/raw" in live.topics() and "/drive/drive1/state" in live.topics()
    assert live.start_time() == 0 and live.end_time() == 50 * MS
    state = live.messages("/drive/drive1/state")
    assert len(state) == 50 and len(calls) == 50  # that topic only, each message once
    assert live.messages("/drive/drive1/state") is state and len(calls) == 50
    _record(rec, 50 * MS, 30)  # the plan goes on: only the new messages are decoded
    rec.flush()
    live.refresh(rec)
    assert len(live.messages("/drive/drive1/state")) == 80 and len(calls) == 80
    assert live.end_time() == 80 * MS
    rec.close()
    whole = RecordingSource(path)
    for topic in whole.topics():
        assert live.messages(topic) == whole.messages(topic), topic
    assert live.topics() == whole.topics()
    assert (live.start_time(), live.end_time()) == (whole.start_time(), whole.end_time())


def test_out_of_order_messages_are_sorted_when_decoded(tmp_path):
    path = tmp_path / "order.mcap"
    rec = Recorder(path)
    rec.keep_messages()
    live = LiveSource()
    for t in (5 * MS, 3 * MS, 4 * MS):  # stamped by their source, written as they came
        rec.dio("drive1", "DI1", t == 4 * MS, 9 * MS, source_t=t)
    rec.flush()
    live.refresh(rec)
    assert live.start_time() == 3 * MS and live.end_time() == 5 * MS
    got = live.messages("/dio/drive1/DI1")
    assert [t for t, _m in got] == [3 * MS, 4 * MS, 5 * MS]
    assert [m["level"] for _t, m in got] == [False, True, False]
    rec.close()


def test_a_file_source_decodes_only_the_topics_read(tmp_path, monkeypatch):
    """`RecordingSource` (`hil check`, reports) keeps each topic's bytes until it is read: the
    raw frames of a busy bus that no spec reads are never decoded, and what is read is what a
    full decoding of the file gives, in time order."""
    from hil.record.reader import Recording

    path = tmp_path / "file.mcap"
    rec = Recorder(path)
    _record(rec, 0, 40)
    for t in (45 * MS, 41 * MS, 43 * MS):  # stamped by their source, written as they came
        rec.dio("drive1", "DI1", t == 43 * MS, 50 * MS, source_t=t)
    rec.close()
    calls: list[bytes] = []
    real = source_mod.decode
    monkeypatch.setattr(source_mod, "decode", lambda b: (calls.append(b), real(b))[1])
    src = RecordingSource(path)
    assert calls == []
    assert (src.start_time(), src.end_time()) == (0, 45 * MS)  # DI1's latest source stamp
    assert calls == []  # first and last times come without decoding
    state = src.messages("/drive/drive1/state")
    assert len(calls) == len(state) == 40
    full = {}
    for topic, log_t, pub_t, msg in Recording.open(str(path)).messages():
        full.setdefault(topic, []).append((pub_t or log_t, msg))
    for topic in src.topics():
        assert src.messages(topic) == sorted(full[topic], key=lambda m: m[0]), topic
    assert [t for t, _m in src.messages("/dio/drive1/DI1")] == [41 * MS, 43 * MS, 45 * MS]
    assert set(src.topics()) == set(full)
