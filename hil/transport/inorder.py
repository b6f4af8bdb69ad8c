"""Deliver what two threads report in the order it was stored.

A port hears the other side on more than one thread (a zenoh subscriber, and the answer to
a query for current levels). Each stores a level under the port's lock and then calls the
listeners without it, so a second thread could store later and still be heard first: a CI
run heard STO_A, DI4, STO_B. `InOrder` is queued in the same critical section as the store;
whichever thread finds nobody delivering delivers everything queued, oldest first, with no
lock held while a listener runs. On one thread it delivers at once, as a plain call would.
"""

from __future__ import annotations

import collections
import threading
from collections.abc import Callable


class InOrder:
    """A queue of deliveries run one at a time, in the order they were queued."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._queued: collections.deque[Callable[[], None]] = collections.deque()
        self._busy = False

    def queue(self, deliver: Callable[[], None]) -> None:
        """Queue `deliver`; call it inside the critical section that stored what it tells."""
        with self._lock:
            self._queued.append(deliver)

    def run(self) -> None:
        """Deliver everything queued, unless another thread is at it (it will deliver ours).

        A delivery that raises leaves the rest queued for the next `run`."""
        with self._lock:
            if self._busy:
                return
            self._busy = True
        try:
            while True:
                with self._lock:
                    if not self._queued:
                        self._busy = False
                        return
                    deliver = self._queued.popleft()
                deliver()
        except BaseException:
            with self._lock:
                self._busy = False
            raise
