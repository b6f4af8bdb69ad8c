"""What callers put on the recorder's queue: one named tuple per kind of item.

The caller side only builds one of these and appends it (the hot path); the writer thread
dispatches on its type (`Recorder._run`). A CAN frame, the busiest item, goes as a plain tuple
in `CanItem`'s field order: a named tuple's constructor is a Python call per frame.
"""

from __future__ import annotations

import threading
from typing import Any, NamedTuple


class CanItem(NamedTuple):
    """A python-can `Message` seen on `bus` ("rx"/"tx" as seen by the harness)."""

    bus: str
    frame: Any
    direction: str
    t: int
    source_t: int | None


class SerialItem(NamedTuple):
    """One RS-485 chunk on `port`, with the inter-byte gaps where known."""

    port: str
    data: bytes
    direction: str
    t: int
    source_t: int | None
    gaps_us: list[int] | None


class BytesItem(NamedTuple):
    """An already encoded message on `topic` (JSON payloads of the harness topics); `obj`:
    the payload itself where it is exactly what decoding `data` gives (`Recorder.mirror`)."""

    topic: str
    schema: str
    source: str | None
    data: bytes
    t: int
    source_t: int | None
    obj: Any = None


class AttachItem(NamedTuple):
    name: str
    data: bytes
    media_type: str
    t: int


class MetadataItem(NamedTuple):
    name: str
    data: dict[str, str]


class BarrierItem(NamedTuple):
    """Set `done` once everything queued before it is written and flushed."""

    done: threading.Event
