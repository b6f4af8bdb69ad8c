"""python-can io plugin: `.mcap` for `can.Logger` / `can.LogReader` / `can.logger` / `can.player`.

Registered in pyproject.toml under the entry point groups `can.io.message_writer` and
`can.io.message_reader` with the key ".mcap" (python-can 4.6 looks them up by suffix in
`can.io.logger._update_writer_plugins` and `can.io.player._update_reader_plugins`).
Files are ordinary hil recordings: frames go to `/can/<bus>/raw` (+ decoded CANopen).
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import can
from can.io.generic import MessageReader, MessageWriter

from hil.record.reader import Recording, decode
from hil.record.recorder import Recorder


def frame_from_json(obj: dict, timestamp: float, channel: Any) -> can.Message:
    """A `can.Message` from a `hil.CanFrame` JSON object; ValueError for one no CAN bus
    carries (an identifier past 11/29 bits or negative, more data than the DLC or the frame
    type allows), which a reader skips and counts as a message of the wrong shape: a
    candump line `-01#00`, say, or a BLF writer's struct.error."""
    data = bytes.fromhex(obj.get("data", ""))
    fd = _flag(obj, "fd")
    dlc = _int(obj, "dlc", len(data))
    if not fd and dlc > 8 and len(data) == 8:  # a classic frame's raw DLC 9-15 (SocketCAN's
        dlc = 8  # CC_LEN8_DLC) carries 8 bytes: kept as such
    return can.Message(
        timestamp=timestamp,
        arbitration_id=_int(obj, "id"),
        is_extended_id=_flag(obj, "ext"),
        is_remote_frame=_flag(obj, "rtr"),
        is_error_frame=_flag(obj, "err"),
        is_fd=fd,
        bitrate_switch=_flag(obj, "brs"),
        error_state_indicator=_flag(obj, "esi"),
        dlc=dlc,
        data=data,
        channel=channel,
        is_rx=obj.get("dir", "rx") != "tx",
        check=True,
    )


def _flag(obj: dict, key: str) -> bool:
    """A frame's flag as the recorder writes it, true or false (absent: false). A text or a
    number is refused: "false" would read as true, and the frame as another kind of frame."""
    v = obj.get(key, False)
    if type(v) is not bool:
        raise ValueError(f"{key} {v!r}: not true or false")
    return v


def _int(obj: dict, key: str, default: int | None = None) -> int:
    """A frame's identifier or DLC: an integer (not 1.5, not true)."""
    v = obj[key] if default is None else obj.get(key, default)
    if type(v) is not int:
        raise ValueError(f"{key} {v!r}: not an integer")
    return v


def can_buses(rec: Recording) -> list[str]:
    """Bus names with a `/can/<bus>/raw` channel."""
    return sorted(t[5:-4] for t in rec.topics() if t.startswith("/can/") and t.endswith("/raw"))


def _check_time(time: str) -> None:
    if time not in ("log", "publish"):
        raise ValueError(f"time {time!r}: must be 'log' or 'publish'")


def bus_topics(rec: Recording, bus: str | None) -> dict[str, str]:
    """{raw topic: bus} of `bus` (None: every bus) in `rec`; ValueError naming the buses."""
    buses = can_buses(rec)
    if bus is not None:
        if bus not in buses:
            raise ValueError(
                f"bus {bus!r}: not in {rec.path} (buses: {', '.join(buses) or 'none'})"
            )
        buses = [bus]
    return {f"/can/{b}/raw": b for b in buses}


def can_messages(
    rec: Recording, bus: str | None = None, *, time: str = "log"
) -> Iterator[tuple[str, can.Message]]:
    """(bus, can.Message) for every recorded frame (of `bus`), timestamps from log_time or
    publish_time, in file order."""
    _check_time(time)
    names = bus_topics(rec, bus)
    for topic, lt, pt, obj in rec.messages(list(names)):
        b = names[topic]
        try:
            yield b, frame_from_json(obj, (lt if time == "log" else pt) / 1e9, b)
        except (ValueError, TypeError, KeyError):  # no frame a CAN bus carries: skipped
            continue


def stream_can(path: str | Path, bus: str | None, on_frame: Callable[[str, can.Message], None],
               *, time: str = "log", head: Recording | None = None) -> Recording:
    """`can_messages` a frame at a time without holding the recording: a first read learns
    the buses (`head`: that reading, done already), the second hands each frame of `bus`
    (None: every bus) to `on_frame(bus, message)`, in file order."""
    _check_time(time)
    if head is None:
        head = Recording.survey(path)  # channels and state, no message
    names = bus_topics(head, bus)

    def take(topic: str, lt: int, pt: int, data: bytes) -> None:
        b = names[topic]
        on_frame(b, frame_from_json(decode(data), (lt if time == "log" else pt) / 1e9, b))

    return Recording.stream(path, list(names), take)


class McapCanWriter(MessageWriter):
    """`can.Logger("x.mcap")`: frames to `/can/<channel>/raw`; log_time = message timestamp.

    `channel` (keyword) names the bus when a message carries none (default "can0").
    """

    def __init__(self, file: Any, channel: str = "can0", **kwargs: Any) -> None:
        if kwargs.get("append"):
            raise ValueError(f"{file}: MCAP recordings cannot be appended to")
        self.channel = str(channel)
        self.recorder = Recorder(
            file if hasattr(file, "write") else Path(file), metadata={"source": "python-can logger"}
        )

    def on_message_received(self, msg: can.Message) -> None:
        bus = msg.channel if isinstance(msg.channel, str) and msg.channel else self.channel
        t = round(msg.timestamp * 1e9)  # 0.0 is a time (a converted log's start), not "now"
        self.recorder.can(bus, msg, "rx" if msg.is_rx else "tx", t, None)

    def file_size(self) -> int:
        return self.recorder.path.stat().st_size if self.recorder.path else 0

    def stop(self) -> None:
        self.recorder.close()


class McapCanReader(MessageReader):
    """`can.LogReader("x.mcap")`: every recorded CAN frame as a `can.Message`.

    Keywords: `bus` (only that bus), `time` ("log" default, or "publish").
    """

    def __init__(self, file: Any, bus: str | None = None, time: str = "log", **kwargs: Any):
        self.file = file
        self.bus = bus
        self.time = time
        _check_time(time)
        # its buses and state now (a bad bus is said at once); its frames as they are read
        self.recording = Recording.survey(file)
        bus_topics(self.recording, bus)
        self._stop = threading.Event()

    def __iter__(self) -> Iterator[can.Message]:
        """The frames, read a record at a time on a thread of its own (a long recording is
        never held whole; at most `_AHEAD` frames wait to be taken)."""
        q: queue.Queue = queue.Queue(maxsize=_AHEAD)
        stop = threading.Event()
        self._stop = stop

        def on_frame(_bus: str, msg: can.Message) -> None:
            while not stop.is_set():
                try:
                    q.put(msg, timeout=0.1)
                    return
                except queue.Full:
                    continue
            raise _Stopped

        def read() -> None:
            try:
                stream_can(self.file, self.bus, on_frame, time=self.time, head=self.recording)
            except _Stopped:
                return
            except BaseException as exc:  # handed to the iterating thread
                q.put(_Failed(exc))
                return
            q.put(_END)

        thread = threading.Thread(target=read, daemon=True, name="mcap-can-reader")
        thread.start()
        try:
            while True:
                try:
                    item = q.get(timeout=0.1)
                except queue.Empty:
                    if thread.is_alive():
                        continue
                    return  # `stop()` ended the read: nothing more comes
                if item is _END:
                    return
                if isinstance(item, _Failed):
                    raise item.exc
                yield item
        finally:  # the caller stopped early (or is done): the reading thread ends too
            stop.set()
            thread.join(timeout=5)

    def stop(self) -> None:
        self._stop.set()


_AHEAD = 4096  # frames read ahead of the caller


class _Stopped(Exception):
    """The iterating caller stopped: the reading thread ends its read."""


class _Failed:
    __slots__ = ("exc",)

    def __init__(self, exc: BaseException) -> None:
        self.exc = exc


_END = object()
