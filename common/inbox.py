"""Latest-only hand-off from Zenoh's callback thread to a service's worker thread.

The callback only stores the newest payload per topic and notifies; decoding and work happen on the
worker. A payload replaced before the worker took it is counted as dropped: a slow stage skips
frames instead of building a backlog.
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Any


@dataclass
class Delivery:
    topic_path: str
    payload: Any  # zenoh.ZBytes or bytes; converted on the worker, not in the callback
    received_ns: int


class LatestInbox:
    def __init__(self) -> None:
        self._slots: dict[str, Delivery] = {}
        self._order: list[str] = []
        self._cond = threading.Condition()
        self.dropped = 0
        self.received = 0

    def put(self, topic_path: str, payload: Any) -> None:
        delivery = Delivery(topic_path, payload, time.monotonic_ns())
        with self._cond:
            self.received += 1
            if topic_path in self._slots:
                self.dropped += 1
            else:
                self._order.append(topic_path)
            self._slots[topic_path] = delivery
            self._cond.notify()

    def take(self, timeout: float) -> Delivery | None:
        """The oldest topic's newest payload, or None after `timeout` seconds without one."""
        with self._cond:
            if not self._order and not self._cond.wait(timeout):
                return None
            if not self._order:
                return None
            topic_path = self._order.pop(0)
            return self._slots.pop(topic_path)

    def wake(self) -> None:
        with self._cond:
            self._cond.notify_all()
