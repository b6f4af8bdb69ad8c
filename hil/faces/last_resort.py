"""The faces' last-resort handler: an exception no protocol rule answers is a bug, not input.

A face turns every refusal the model raises into the protocol's answer (Modbus exception,
SDO abort). Anything else that escapes a handler (a model bug, a failing callback) is
caught here: counted, logged with its traceback once per (place, exception type), and the
face keeps serving. Tests assert `count == 0` ("zero drive exceptions").
"""

from __future__ import annotations

import logging


class LastResort:
    """Counts unexpected exceptions of one face and logs each kind once."""

    def __init__(self, log: logging.Logger, face: str) -> None:
        self.log = log
        self.face = face
        self.count = 0
        self.last: str | None = None  # "where: Type: message" of the latest one
        self._seen: set[tuple[str, type]] = set()

    def __call__(self, where: str, exc: BaseException) -> None:
        self.count += 1
        self.last = f"{where}: {type(exc).__name__}: {exc}"
        key = (where, type(exc))
        if key in self._seen:
            self.log.debug("%s face: %s (again)", self.face, self.last)
            return
        self._seen.add(key)
        self.log.error(
            "%s face: %s failed; answered and kept serving (further %s here are counted only)",
            self.face, where, type(exc).__name__, exc_info=exc,
        )  # fmt: skip
