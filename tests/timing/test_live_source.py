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
        rec.can("can0", can.Message(arbitration_id=0x181, data=bytes([i & 0xFF, t0 // MS & 0xFF]),
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
    assert len(state) == 50 and calls == []  # the ground truth comes as the recorder's dicts
    frames = live.messages("/canopen/can0")
    assert len(frames) == 50 and len(calls) == 50  # that topic only, each message once
    assert live.messages("/canopen/can0") is frames and len(calls) == 50
    _record(rec, 50 * MS, 30)  # the plan goes on: only the new messages are decoded
    rec.flush()
    live.refresh(rec)
    assert len(live.messages("/drive/drive1/state")) == 80
    assert len(live.messages("/canopen/can0")) == 80 and len(calls) == 80
    assert live.end_time() == 80 * MS
    _record(rec, 0, 20)  # the same frames again (a statusword poll): decoded once, shared
    rec.flush()
    live.refresh(rec)
    again = live.messages("/canopen/can0")
    assert len(again) == 100 and len(calls) == 80
    assert [t for t, _m in again] == sorted(t for t, _m in again)  # in time order
    for i in range(20):  # each of the first 20 ms now has its frame twice, alike
        [a, b] = [m for t, m in again if t == i * MS]
        assert a == b and a["data"] == bytes([i, 0]).hex()
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


def test_a_live_source_grown_in_steps_derives_what_a_fresh_one_derives(tmp_path):
    """The samples, runs and sampling index a live source extends at each refresh (runs that
    go on across a refresh, a `where` filter, messages that arrive out of order) are what a
    source holding all of it at once derives from scratch."""
    import random

    from hil.timing.checker import Context
    from hil.timing.source import samples

    rnd = random.Random(7)
    path = tmp_path / "grow.mcap"
    rec = Recorder(path)
    rec.keep_messages()
    live = LiveSource()
    fresh_ctx = Context.__new__(Context)
    sent: dict[str, list[tuple[int, dict]]] = {}
    t = 0
    for _round in range(12):
        for i in range(rnd.randint(0, 40)):
            t += MS
            speed = rnd.choice([0.0, 0.0, 0.0, 10.5, 20.0])
            msg = {"state": rnd.choice(["A", "A", "B"]), "speed_rpm": speed,
                   "periodic": rnd.random() < 0.8}
            # now and then stamped by its source a little in the past, before messages an
            # earlier refresh brought (the topic re-sorts)
            late = rnd.random() < (0.5 if i == 0 else 0.05)
            ts = t - rnd.randint(2, 4) * MS if late else t
            rec.drive_state("drive1", msg, t=t, source_t=ts)
            sent.setdefault("/drive/drive1/state", []).append((ts, msg))
            if rnd.random() < 0.2:  # an edge stamped a little in the past now and then
                ts = t - rnd.randint(0, 3) * MS
                rec.dio("drive1", "DO2", rnd.random() < 0.5, t, source_t=ts)
        rec.flush()
        live.refresh(rec)
        whole = RecordingSource(path)  # the file as it stands, read from scratch

        def same_samples(whole=whole):
            for topic, field, where in (("/drive/drive1/state", "speed_rpm", None),
                                        ("/drive/drive1/state", "speed_rpm", {"state": "A"}),
                                        ("/drive/drive1/state", "state", None),
                                        ("/dio/drive1/DO2", "level", None)):
                for runs in (False, True):
                    got = samples(live, topic, field, where, runs)
                    assert list(got) == list(samples(whole, topic, field, where, runs)), \
                        (topic, field, where, runs)

        def same_sampling_index(whole=whole):
            for topic in whole.topics():
                fresh_ctx.source, fresh_ctx._topic_sampling = whole, {}
                want = Context._sampling_index(fresh_ctx, topic)
                fresh_ctx.source = live
                have = Context._sampling_index(fresh_ctx, topic)
                assert (want is None) == (have is None), topic
                if want is not None:
                    times = [m[0] for m in whole.messages(topic)]
                    assert list(have[2]) == list(want[2]) == times
                    assert [have[0](x) for x in times] == [want[0](x) for x in times]

        # either may be the first to read what the refresh brought (and re-sort a topic)
        for check in ((same_samples, same_sampling_index) if _round % 2
                      else (same_sampling_index, same_samples)):
            check()
    assert len(sent["/drive/drive1/state"]) > 100
    rec.close()


def test_the_mirror_holds_the_ground_truth_as_decoding_gives_it(tmp_path):
    """The recorder hands a live check the model's own state dict instead of its bytes only
    where decoding the bytes gives exactly that dict, types included; anything JSON would
    change (a tuple, an enum, an int key) is decoded from the bytes as before."""
    import enum
    import json

    from hil.model.drive import Drive

    def deep_types(x):
        if isinstance(x, dict):
            return {k: deep_types(v) for k, v in x.items()}
        if isinstance(x, list):
            return [deep_types(v) for v in x]
        return type(x).__name__

    class Mode(enum.IntEnum):
        PP = 1

    rec = Recorder(tmp_path / "mirror.mcap")
    mirror = rec.keep_messages()
    drive = Drive(inputs={8: True})
    drive.write_object(0x6060, 0, 1)
    for cw in (0x06, 0x07, 0x0F):
        drive.write_object(0x6040, 0, cw)
    drive.write_object(0x607A, 0, 200_000)
    drive.write_object(0x6040, 0, 0x1F)
    for _ in range(20):
        drive.advance(5 * MS)
        rec.drive_state("drive1", {**drive.snapshot(), "periodic": True})
    rec.drive_state("drive1", {"mode": Mode.PP})  # JSON makes it 1, an int
    rec.drive_state("drive1", {"do": (True, False)})  # JSON makes it a list
    rec.drive_state("drive1", {"pt": {1: 2.0}})  # JSON makes the key "1"
    rec.drive_state("drive1", {"n": 10**5000})  # too long to encode: an `error` object
    alarms = ["AL013"]
    rec.drive_state("drive1", {"alarms": alarms})
    alarms.append("AL014")  # the caller's list changes after: the mirror keeps what was sent
    rec.flush()
    kept = [(data, obj) for _cid, _lt, _pt, data, obj in mirror]
    assert len(kept) == 25
    assert kept[23][1] is None and "error" in json.loads(kept[23][0])
    assert kept[24][1] == json.loads(kept[24][0]) == {"alarms": ["AL013"]}
    kept = kept[:23]
    for data, obj in kept[:20]:  # the model's snapshots: all kept, all exact
        assert obj is not None
        assert json.loads(data) == obj and deep_types(json.loads(data)) == deep_types(obj)
    assert [obj for _data, obj in kept[20:]] == [None, None, None]
    live = LiveSource().refresh(rec)
    got = live.messages("/drive/drive1/state")
    assert [m for _t, m in got[20:23]] == [{"mode": 1}, {"do": [True, False]}, {"pt": {"1": 2.0}}]
    rec.close()


def test_a_live_source_takes_the_files_head_from_the_recorder_as_a_read_would_give_it(
        tmp_path, monkeypatch):
    """While the recorder is open, the metadata, resolutions and schemas come from what it
    wrote (the file's head had been read again at every new channel or metadata record: 108
    reads in the shipped plans); they equal a read of the file at every refresh."""
    path = tmp_path / "head.mcap"
    rec = Recorder(path, metadata={"plan": "p"})
    rec.keep_messages()
    live = LiveSource()
    reads: list[object] = []
    real = source_mod.RecordingSource.__init__
    monkeypatch.setattr(source_mod.RecordingSource, "__init__",
                        lambda self, *a, **k: (reads.append(a), real(self, *a, **k))[1])

    def same() -> None:
        rec.flush()
        live.refresh(rec)
        n = len(reads)
        head = RecordingSource(path, topics=[])
        del reads[n:]
        assert (live.meta, live._res, live.schemas, live.path, live.error, live.corrupt,
                live.truncated) == (head.meta, head._res, head.schemas, head.path,
                                    head.error, head.corrupt, head.truncated)

    _record(rec, 0, 5)
    same()
    rec.add_metadata("timing", {"resolution_ns": '{"/drive/drive1/state": 1000000}'})
    rec.declare_source("/dio/drive1/DO3", "model", resolution_ns=250_000)
    rec.dio("drive1", "DO3", True, 9 * MS)
    same()
    rec.add_metadata("timing", {"specs": '["emgs"]'})  # a name again: merged, later wins
    same()
    assert reads == []  # none of the refreshes read the file
    rec.close()
    live.refresh(rec)  # closed: the footer and hil.close are read from the file
    assert "hil.close" in live.meta and not live.truncated and len(reads) == 1
