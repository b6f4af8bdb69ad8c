"""What a transport calls to have its traffic recorded. The recorder implements `Tap`;
a transport without a tap records nothing (`tap=None`).

Timestamps are integer ns. `t` is when the harness saw the traffic (`time.time_ns()` on
the wall clock the recorder uses); `source_t` is the source's own timestamp (hardware, model
or gateway capture time) when it has one, else None.
"""

from __future__ import annotations

from typing import Any, Protocol


class Tap(Protocol):
    def can(self, bus: str, frame: Any, direction: str, t: int, source_t: int | None) -> None:
        """A CAN frame (a `can.Message`), direction "rx" or "tx"."""

    def serial(
        self,
        port: str,
        data: bytes,
        direction: str,
        t: int,
        source_t: int | None,
        gaps_us: list[int] | None = None,
    ) -> None:
        """A chunk of RS-485 bytes, with the gaps between them where known."""

    def dio(self, name: str, line: str, level: bool, t: int, source_t: int | None) -> None:
        """A DI/DO/STO line level (electrical: True = closed/conducting)."""

    def pulse(self, name: str, kind: str, body: dict[str, Any], t: int,
              source_t: int | None) -> None:
        """A pulse-line message (`seg`, `oab`, `oz`: docs/pulse.md)."""
