"""Helpers for the recording tests (imported as `rec_helpers`)."""

from __future__ import annotations

import json
from importlib.metadata import entry_points

import can

from hil.record.recorder import Recorder

EP_TEXT = """[can.io.message_writer]
.mcap = hil.record.canio:McapCanWriter

[can.io.message_reader]
.mcap = hil.record.canio:McapCanReader
"""


def frame(cid: int, data: bytes | str, ext: bool = False, **kw) -> can.Message:
    if isinstance(data, str):
        data = bytes.fromhex(data)
    return can.Message(arbitration_id=cid, data=data, is_extended_id=ext, **kw)


def canio_registered() -> bool:
    return any(ep.name == ".mcap" for ep in entry_points(group="can.io.message_writer"))


def schema_check(schema: dict, obj: dict) -> list[str]:
    """A tiny JSON-schema subset check (type object, required, property types)."""
    types = {
        "object": dict,
        "array": list,
        "string": str,
        "boolean": bool,
        "null": type(None),
        "integer": int,
        "number": (int, float),
    }
    errs = []
    for key in schema.get("required", []):
        if key not in obj:
            errs.append(f"missing {key}")
    for key, sub in schema.get("properties", {}).items():
        if key not in obj or "type" not in sub:
            continue
        allowed = sub["type"] if isinstance(sub["type"], list) else [sub["type"]]
        ok = any(
            isinstance(obj[key], types[a])
            and not (a in ("integer", "number") and isinstance(obj[key], bool))
            for a in allowed
        )
        if not ok:
            errs.append(f"{key}={obj[key]!r} is not {allowed}")
    if schema.get("additionalProperties") is False:
        extra = set(obj) - set(schema.get("properties", {}))
        if extra:
            errs.append(f"extra keys {sorted(extra)}")
    return errs


def load_schema(data: bytes) -> dict:
    return json.loads(data)


T0 = 1_700_000_000_123_456_000


def make(path):
    """A small recording: five CAN frames on two buses (std, ext, RTR, FD, empty) + DI1."""
    with Recorder(path) as rec:
        rec.can("can0", frame(0x123, "DEADBEEF"), "rx", T0, None)
        rec.can("can0", frame(0x1ABCDEF0, "01", ext=True), "tx", T0 + 1_000_000, None)
        rec.can("can1", frame(0x701, b"", is_remote_frame=True), "tx", T0 + 2_000_000, None)
        rec.can(
            "can0",
            frame(0x181, "0011", is_fd=True, bitrate_switch=True),
            "rx",
            T0 + 3_000_000,
            None,
        )
        rec.can("can0", frame(0x181, b""), "rx", T0 + 500_000_000, None)
        rec.dio("io", "DI1", True, T0, None)
    return path


def first_changed(topic_wanted: str, change):
    """A `copy_mcap` message hook changing the first message of `topic_wanted` that
    `change(obj)` accepts (returns the new object, or None to pass it by)."""
    done = []

    def message(topic: str, data: bytes, lt: int) -> tuple[bytes, int]:
        if topic == topic_wanted and not done:
            new = change(json.loads(data))
            if new is not None:
                done.append(1)
                return json.dumps(new).encode(), lt
        return data, lt
    return message


def copy_mcap(src, dst, message=None, *, metadata=None, attachment=None,
              compression=None, drop=(), publish=None):
    """`src` copied to `dst` with the `mcap` library's writer (another writer than hil's):
    each message through `message(topic, data, log_time) -> (data, log_time)` (None: as it
    is), the metadata `metadata` added (a name given replaces the original's record), and
    `attachment` (name, bytes) as a YAML attachment; the topics in `drop` left out, their
    channels too; `publish(topic, publish_time) -> publish_time` changes publish times."""
    from mcap.reader import make_reader
    from mcap.writer import CompressionType, Writer

    with open(src, "rb") as f, open(dst, "wb") as g:
        r = make_reader(f)
        w = Writer(g, compression=compression or CompressionType.ZSTD)
        w.start(profile="", library="test")
        ids: dict[int, int] = {}
        sids: dict[int, int] = {}
        for schema, ch, msg in r.iter_messages(log_time_order=False):
            if ch.topic in drop:
                continue
            if schema is not None and schema.id not in sids:
                sids[schema.id] = w.register_schema(schema.name, schema.encoding, schema.data)
            if ch.id not in ids:
                ids[ch.id] = w.register_channel(ch.topic, ch.message_encoding,
                                                sids.get(schema.id, 0) if schema else 0,
                                                dict(ch.metadata))
            data, lt = msg.data, msg.log_time
            if message is not None:
                data, lt = message(ch.topic, data, lt)
            pt = msg.publish_time if publish is None else publish(ch.topic, msg.publish_time)
            w.add_message(ids[ch.id], log_time=lt, publish_time=pt, data=data)
        f.seek(0)
        for m in make_reader(f).iter_metadata():
            if m.name not in (metadata or {}):
                w.add_metadata(m.name, dict(m.metadata))
        for name, values in (metadata or {}).items():
            w.add_metadata(name, values)
        if attachment:
            w.add_attachment(0, 0, attachment[0], "application/yaml", attachment[1])
        w.finish()
    return dst


def dio_mcap(path, *, channels: int = 1, messages: int = 3, **writer_options):
    """A small MCAP of another writer (the `mcap` library's, with `writer_options`):
    `messages` DI1 levels on the first of `channels` channels of topic /dio/io/DI1."""
    from mcap.writer import Writer

    with open(path, "wb") as f:
        w = Writer(f, **writer_options)
        w.start(profile="", library="test")
        sid = w.register_schema("hil.DioLevel", "jsonschema", b"{}")
        ids = [w.register_channel("/dio/io/DI1", "json", sid) for _ in range(channels)]
        for k in range(messages):
            w.add_message(ids[0], log_time=k, publish_time=k, data=b'{"level": true}')
        w.finish()
    return path


def plan_recording(out, name: str):
    """A shipped plan run on the built-in virtual bench (virtual time) into `out`: its
    recording's path (the run must pass)."""
    from pathlib import Path

    from hil.bench.bench import load_bench
    from hil.paths import plans_dir
    from hil.plan.plan import load_plan
    from hil.plan.runner import run_plan

    res = run_plan(load_plan(plans_dir() / f"{name}.yaml"), load_bench(None), out, reports=False)
    assert res.passed, [(s.label, s.message) for s in res.steps if s.status != "pass"]
    return Path(res.recording)
