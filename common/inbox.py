"""Hand-off from Zenoh's callback thread to a service's worker thread, bounded per topic.

The callback only stores the payload and notifies; decoding and work happen on the worker. Each topic keeps at most
`keep` payloads the worker has not taken (the services table's `Topic.inbox_depth`); one more pushes out the topic's
oldest, counted as dropped. So a slow stage skips frames instead of building a backlog, and a stream topic kept two
deep rides out a stall of about one frame interval (scheduler, a searching frame) without losing a frame: at 120 fps
latest-only inboxes dropped 1-3 frames in 2,200 that way (docs/measurements.md, thirtieth session). A topic whose
newest message carries all the older ones did (`superseding`, odometry) loses nothing when one replaces another: that
is counted as superseded, apart from the drops.
"""
from __future__ import annotations

import threading
import time
from collections import Counter, deque
from dataclasses import dataclass
from typing import Any, Iterable, Mapping


@dataclass
class Delivery:
    topic_path: str
    payload: Any  # zenoh.ZBytes or bytes; converted on the worker, not in the callback
    received_ns: int


class Inbox:
    """Payloads in arrival order, at most `keep[topic]` (default 1) of a topic waiting at a time."""

    def __init__(self, keep: Mapping[str, int] | None = None, superseding: Iterable[str] = ()) -> None:
        self._keep = dict(keep or {})
        if any(depth < 1 for depth in self._keep.values()):
            raise ValueError(f"inbox depths must be >= 1: {self._keep}")
        self._superseding = frozenset(superseding)
        deep = sorted(t for t in self._superseding if self._keep.get(t, 1) != 1)
        if deep:
            raise ValueError(f"a topic whose newest message supersedes the older ones is kept one deep: {deep}")
        self._queue: deque[Delivery] = deque()
        self._waiting: Counter[str] = Counter()
        self._cond = threading.Condition()
        self.dropped = 0
        self.superseded = 0
        self.received = 0

    def put(self, topic_path: str, payload: Any) -> None:
        delivery = Delivery(topic_path, payload, time.monotonic_ns())
        with self._cond:
            self.received += 1
            if self._waiting[topic_path] < self._keep.get(topic_path, 1):
                self._waiting[topic_path] += 1
                self._queue.append(delivery)
            else:
                if topic_path in self._superseding:
                    self.superseded += 1
                else:
                    self.dropped += 1
                self._replace_oldest(delivery)
            self._cond.notify()

    def _replace_oldest(self, delivery: Delivery) -> None:
        """The topic's oldest waiting payload goes. Kept one deep, the newest takes its place in the order (an
        odometry message that came before a frame is still taken before it: fusion needs the motion up to the
        frame); deeper, the newest joins the end."""
        depth = self._keep.get(delivery.topic_path, 1)
        for i, waiting in enumerate(self._queue):
            if waiting.topic_path == delivery.topic_path:
                if depth == 1:
                    self._queue[i] = delivery
                else:
                    del self._queue[i]
                    self._queue.append(delivery)
                return

    def take(self, timeout: float) -> Delivery | None:
        """The oldest waiting payload, or None after `timeout` seconds without one."""
        with self._cond:
            if not self._queue and not self._cond.wait(timeout):
                return None
            if not self._queue:
                return None
            delivery = self._queue.popleft()
            self._waiting[delivery.topic_path] -= 1
            return delivery

    def wake(self) -> None:
        with self._cond:
            self._cond.notify_all()
