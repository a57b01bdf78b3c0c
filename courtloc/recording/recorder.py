"""`courtloc record`: selected topics of one robot, from the bus into MCAP files.

The zenoh callback only stamps the arrival time and queues the payload; decoding (for the JSON view)
and writing happen on the recorder's own loop. The queue is bounded in messages and in bytes (raw
frames are ~1 MB each): if the disk cannot keep up, samples are dropped and counted rather than
growing memory without limit.
"""
from __future__ import annotations

import logging
import queue
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import zenoh

from courtloc.common import codec
from courtloc.common.bus import ZenohConfig, open_session
from courtloc.common.messages import SCHEMA_VERSION, Health
from courtloc.common.services_table import TOPICS
from courtloc.common.stats import RateLimitedLog
from courtloc.recording.foxview import FoxgloveViews
from courtloc.recording.jsonview import json_view
from courtloc.recording.mcapfile import EXACT_SUFFIX, McapSeries, RecordItem

log = logging.getLogger("courtloc.record")

# Raw frames are ~1 MB each at 30 Hz: recorded only when asked for by name.
HEAVY_TOPICS = frozenset({"camera/frame"})


def default_topics() -> list[str]:
    return [path for path in TOPICS if path not in HEAVY_TOPICS]


def resolve_topics(requested: list[str] | None) -> list[str]:
    """Topic paths to record; 'all' means every topic. Unknown names are an error naming the known ones."""
    if not requested:
        return default_topics()
    if requested == ["all"]:
        return list(TOPICS)
    unknown = [p for p in requested if p not in TOPICS]
    if unknown:
        raise ValueError(f"unknown topic(s) {unknown}; known: {sorted(TOPICS)} or 'all'")
    return list(dict.fromkeys(requested))


@dataclass
class RecordStats:
    messages: dict[str, int] = field(default_factory=dict)
    undecodable: dict[str, int] = field(default_factory=dict)
    overflow: int = 0

    @property
    def total(self) -> int:
        return sum(self.messages.values())

    def as_dict(self) -> dict[str, Any]:
        return {"messages": dict(self.messages), "undecodable": dict(self.undecodable), "overflow": self.overflow}


def publish_time_of(message: Any, fallback: int) -> int:
    """When the producer published: its own stamp (the last one on the header), or its clock for health."""
    if isinstance(message, Health):
        return message.wall_ns
    header = getattr(message, "header", None)
    if header is None:
        return fallback
    return header.stamps[-1].wall_ns if header.stamps else header.capture_wall_ns


class Recorder:
    def __init__(self, robot_id: str, zenoh_config: ZenohConfig, paths: list[str], series: McapSeries,
                 queue_size: int = 4096, queue_bytes: int = 256 << 20) -> None:
        self.robot_id = robot_id
        self.zenoh_config = zenoh_config
        self.paths = paths
        self.series = series
        self.stats = RecordStats()
        self._queue: queue.Queue[tuple[str, Any, int]] = queue.Queue(maxsize=queue_size)
        self._rate_log = RateLimitedLog(log)
        self._queue_bytes_max = queue_bytes
        self._queued_bytes = 0
        self._queued_lock = threading.Lock()

    def _callback(self, path: str):  # noqa: ANN202 - zenoh callback
        q, stats, lock = self._queue, self.stats, self._queued_lock

        def on_sample(sample: zenoh.Sample) -> None:
            size = len(sample.payload)
            with lock:
                if self._queued_bytes + size > self._queue_bytes_max or q.full():
                    stats.overflow += 1
                    return
                self._queued_bytes += size
                q.put_nowait((path, sample.payload, time.time_ns()))
        return on_sample

    def run(self, stop: threading.Event, duration_s: float | None = None, on_ready: Any = None,
            max_messages: int | None = None, on_progress: Any = None, progress_s: float = 10.0) -> RecordStats:
        """Record until `stop`, the duration or the message count; `on_progress(stats)` every `progress_s`."""
        zsession = open_session(self.zenoh_config, stop)
        if zsession is None:
            return self.stats
        subscribers = []
        try:
            for path in self.paths:
                subscribers.append(zsession.declare_subscriber(TOPICS[path].key(self.robot_id), self._callback(path)))
            if on_ready is not None:
                on_ready()
            deadline = None if duration_s is None else time.monotonic() + duration_s
            next_progress = time.monotonic() + progress_s
            while not stop.is_set() and (deadline is None or time.monotonic() < deadline):
                if max_messages is not None and self.stats.total >= max_messages:
                    break
                if on_progress is not None and time.monotonic() >= next_progress:
                    on_progress(self.stats)
                    next_progress += progress_s
                try:
                    item = self._queue.get(timeout=0.2)
                except queue.Empty:
                    self.series.tick()
                    continue
                self._write(*item)
            for sub in subscribers:
                sub.undeclare()
            subscribers.clear()
            while max_messages is None or self.stats.total < max_messages:
                # what arrived before the subscribers went is part of the recording
                try:
                    item = self._queue.get_nowait()
                except queue.Empty:
                    break
                self._write(*item)
        finally:
            for sub in subscribers:
                sub.undeclare()
            self.series.close()
            zsession.close()
        return self.stats

    def _write(self, path: str, payload: Any, log_time: int) -> None:
        raw = bytes(payload)
        with self._queued_lock:
            self._queued_bytes -= len(raw)
        try:
            item = record_item(path, self.robot_id, raw, log_time, self.series.foxglove)
        except codec.DecodeError as exc:
            self.stats.undecodable[path] = self.stats.undecodable.get(path, 0) + 1
            self._rate_log.warning(f"undecodable:{path}", f"{path}: payload kept raw only ({exc.reason}: {exc.detail})")
            item = RecordItem(path=path, robot_id=self.robot_id, log_time=log_time, publish_time=log_time,
                              sequence=0, raw=raw, json=None)
        self.series.write(item)
        self.stats.messages[path] = self.stats.messages.get(path, 0) + 1


def record_item(path: str, robot_id: str, raw: bytes, log_time: int,
                foxglove: FoxgloveViews | None = None) -> RecordItem:
    """One bus payload as the recorder stores it: exact bytes, JSON view, Foxglove channels.

    Raises codec.DecodeError when the payload does not decode (the caller keeps it raw only).
    """
    message = codec.decode(raw, TOPICS[path].message)
    header = getattr(message, "header", None)
    return RecordItem(
        path=path, robot_id=robot_id, log_time=log_time, publish_time=publish_time_of(message, log_time),
        sequence=(header.seq & 0xFFFFFFFF) if header is not None else 0, raw=raw,
        json=json_view(message, TOPICS[path].service),
        extras=tuple(foxglove.of(path, robot_id, message)) if foxglove is not None else ())


def recording_metadata(robot_id: str, paths: list[str]) -> dict[str, str]:
    return {"robot_id": robot_id, "schema_version": str(SCHEMA_VERSION), "topics": ",".join(paths),
            "exact_payloads": f"<file stem>{EXACT_SUFFIX}, message_encoding msgpack: the exact bus payloads"}
