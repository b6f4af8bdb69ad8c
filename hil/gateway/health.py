"""Per-bus health as a gateway reports it on `<lab>/<bench>/health`.

CAN error frames are read as SocketCAN encodes them (linux/can/error.h): class bits in the
identifier (CAN_ERR_BUSOFF 0x40, CAN_ERR_CRTL 0x04, CAN_ERR_RESTARTED 0x100), controller
status in data[1], TX/RX error counters in data[6]/data[7] (CAN_ERR_CNT).
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field

CAN_ERR_CRTL = 0x004
CAN_ERR_BUSOFF = 0x040
CAN_ERR_RESTARTED = 0x100
CAN_ERR_CNT = 0x200
CAN_ERR_CRTL_RX_PASSIVE = 0x10
CAN_ERR_CRTL_TX_PASSIVE = 0x20


@dataclass
class BusHealth:
    """Counters and state of one exported bus (thread-safe through `lock`)."""

    kind: str  # "can" | "rs485" | "dio"
    name: str
    url: str
    key: str
    link: str = "down"  # "up" | "down"
    state: str = "unknown"  # CAN: active | passive | bus-off (error frames / bus.state)
    bus_off: bool = False
    tx_error_counter: int | None = None
    rx_error_counter: int | None = None
    error_frames: int = 0
    rx: int = 0  # from the bench to the network
    tx: int = 0  # from the holder onto the bench
    refused: int = 0  # samples without the current holder's lease token (dropped)
    bad: int = 0  # the holder's samples no device could send (a bad frame, chunk or level)
    errors: int = 0  # adapter / port errors (OSError, CanError, serial errors)
    reopens: int = 0
    last_error: str = ""
    since_ns: int = field(default_factory=time.time_ns)  # last link change
    lock: threading.Lock = field(default_factory=threading.Lock, repr=False, compare=False)

    def up(self) -> bool:
        """Mark the link up; True if it changed."""
        with self.lock:
            if self.link == "up":
                return False
            self.link, self.since_ns = "up", time.time_ns()
            if self.state == "unknown" or self.bus_off:
                self.state, self.bus_off = "active", False
            return True

    def down(self, error: BaseException | str) -> bool:
        """Count an error and mark the link down; True if it changed."""
        with self.lock:
            self.errors += 1
            self.last_error = (error if isinstance(error, str)
                               else f"{type(error).__name__}: {error}")
            if self.link == "down":
                return False
            self.link, self.since_ns = "down", time.time_ns()
            return True

    def error_frame(self, can_id: int, data: bytes) -> None:
        with self.lock:
            self.error_frames += 1
            if can_id & CAN_ERR_BUSOFF:
                self.bus_off, self.state = True, "bus-off"
            elif can_id & CAN_ERR_RESTARTED:
                self.bus_off, self.state = False, "active"
            elif can_id & CAN_ERR_CRTL and len(data) > 1:
                ctrl = data[1]
                if ctrl & (CAN_ERR_CRTL_RX_PASSIVE | CAN_ERR_CRTL_TX_PASSIVE):
                    self.state = "passive"
            if can_id & (CAN_ERR_CRTL | CAN_ERR_CNT) and len(data) >= 8:
                self.tx_error_counter, self.rx_error_counter = data[6], data[7]

    def snapshot(self) -> dict:
        """A JSON-ready copy of the fields."""
        with self.lock:
            return {k: v for k, v in self.__dict__.items() if k != "lock"}
