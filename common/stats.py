"""Small counters and latency windows for health messages and benchmarks."""
from __future__ import annotations

import logging
import threading
import time
from collections import deque
from typing import Iterable

import numpy as np


def percentiles_ms(samples_ns: Iterable[int], qs: tuple[float, ...] = (50.0, 99.0)) -> list[float]:
    values = np.fromiter(samples_ns, dtype=np.float64)
    if values.size == 0:
        return [0.0 for _ in qs]
    return [float(v) / 1e6 for v in np.percentile(values, qs)]


class LatencyWindow:
    """The last `size` durations in ns; thread-safe appends, percentiles on demand."""

    def __init__(self, size: int = 512) -> None:
        self._values: deque[int] = deque(maxlen=size)
        self._lock = threading.Lock()

    def add(self, duration_ns: int) -> None:
        with self._lock:
            self._values.append(duration_ns)

    def percentiles_ms(self, qs: tuple[float, ...] = (50.0, 99.0)) -> list[float]:
        with self._lock:
            snapshot = list(self._values)
        return percentiles_ms(snapshot, qs)


class RateMeter:
    """Events per second between two reads of a monotonically growing counter."""

    def __init__(self) -> None:
        self._last_count = 0
        self._last_time = time.monotonic()

    def rate(self, count: int) -> float:
        now = time.monotonic()
        elapsed = max(now - self._last_time, 1e-9)
        hz = (count - self._last_count) / elapsed
        self._last_count, self._last_time = count, now
        return hz


class RateLimitedLog:
    """Logs the first event of a kind at once, then at most one line per `period_s` with the count since."""

    def __init__(self, logger: logging.Logger, period_s: float = 5.0) -> None:
        self._logger = logger
        self._period_s = period_s
        self._last: dict[str, float] = {}
        self._suppressed: dict[str, int] = {}
        self._lock = threading.Lock()

    def warning(self, kind: str, message: str, exc_info: bool = False) -> None:
        """`exc_info`: add the current exception's traceback to the first line of this kind (later
        reports of the same kind repeat the message, not the stack)."""
        now = time.monotonic()
        with self._lock:
            last = self._last.get(kind)
            if last is not None and now - last < self._period_s:
                self._suppressed[kind] = self._suppressed.get(kind, 0) + 1
                return
            suppressed = self._suppressed.pop(kind, 0)
            first = last is None
            self._last[kind] = now
        extra = f" ({suppressed} more since last report)" if suppressed else ""
        self._logger.warning("%s%s", message, extra, exc_info=exc_info and first)
