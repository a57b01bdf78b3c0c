"""`courtloc dataset capture`: frames paired with the pose nearest in time, written in the seed format.

Like the paper's synchronizer: each frame takes the truth pose whose capture stamp is nearest to its
own (plus an optional offset for a tracker with a known lag), if within the tolerance; frames with
no pose close enough are counted and left out. The seed format is `images/*.jpg` plus
`pose_data.csv` (image_filename, x, y, orientation_z) where orientation_z is the z of a yaw-only
quaternion with w >= 0: z = sin(yaw/2) with yaw wrapped to (-pi, pi], so yaw = 2*asin(z).
"""
from __future__ import annotations

import bisect
import csv
import logging
import math
import queue
import threading
import time
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Generic, TypeVar

import cv2
import zenoh

from courtloc.common import codec
from courtloc.common.bus import ZenohConfig, open_session
from courtloc.common.messages import Frame
from courtloc.common.payloads import frame_pixels
from courtloc.common.services_table import TOPICS
from courtloc.common.stats import RateLimitedLog

log = logging.getLogger("courtloc.capture")

CSV_NAME = "pose_data.csv"
CSV_FIELDS = ("image_filename", "x", "y", "orientation_z")
# A frame whose pose has not arrived this long after the frame itself is decided with what is there.
LATE_TRUTH_S = 1.0

T = TypeVar("T")
F = TypeVar("F")


def orientation_z(yaw: float) -> float:
    """z of the yaw-only quaternion with w >= 0 (yaw wrapped to (-pi, pi])."""
    wrapped = math.remainder(yaw, 2 * math.pi)
    if wrapped <= -math.pi:
        wrapped = math.pi
    return math.sin(wrapped / 2)


class NearestMatcher(Generic[F, T]):
    """Pairs each frame stamp with the nearest truth stamp within `tolerance_ns`.

    A frame is decided once a truth at least `tolerance_ns` newer than it has arrived (no later truth
    can then be nearer, truths arriving in stamp order) or when `flush` says it has waited long enough.
    """

    def __init__(self, tolerance_ns: int, keep_ns: int = 5_000_000_000) -> None:
        self.tolerance_ns = tolerance_ns
        self.keep_ns = keep_ns
        self._truth_stamps: list[int] = []
        self._truths: list[T] = []
        self._pending: list[tuple[int, float, F]] = []  # (stamp, arrival monotonic s, frame)

    def add_truth(self, stamp_ns: int, truth: T) -> None:
        index = bisect.bisect_right(self._truth_stamps, stamp_ns)
        self._truth_stamps.insert(index, stamp_ns)
        self._truths.insert(index, truth)

    def add_frame(self, stamp_ns: int, frame: F, arrival_s: float) -> None:
        self._pending.append((stamp_ns, arrival_s, frame))

    def ready(self, now_s: float, late_s: float = LATE_TRUTH_S) -> list[tuple[F, T | None]]:
        """Frames that can be decided now, each with its truth or None."""
        newest = self._truth_stamps[-1] if self._truth_stamps else None
        decided, still = [], []
        for stamp, arrival, frame in self._pending:
            if (newest is not None and newest >= stamp + self.tolerance_ns) or now_s - arrival >= late_s:
                decided.append((frame, self._nearest(stamp)))
            else:
                still.append((stamp, arrival, frame))
        self._pending = still
        self._prune()
        return decided

    def _nearest(self, stamp: int) -> T | None:
        index = bisect.bisect_left(self._truth_stamps, stamp)
        best: tuple[int, T] | None = None
        for i in (index - 1, index):
            if 0 <= i < len(self._truth_stamps):
                gap = abs(self._truth_stamps[i] - stamp)
                if gap <= self.tolerance_ns and (best is None or gap < best[0]):
                    best = (gap, self._truths[i])
        return None if best is None else best[1]

    def _prune(self) -> None:
        if not self._truth_stamps:
            return
        oldest_needed = min((s for s, _, _ in self._pending), default=self._truth_stamps[-1])
        cut = bisect.bisect_left(self._truth_stamps, oldest_needed - self.tolerance_ns - self.keep_ns)
        del self._truth_stamps[:cut], self._truths[:cut]


@dataclass
class CaptureOptions:
    out: Path
    tolerance_ms: float = 20.0
    offset_ms: float = 0.0  # truth stamp ~ frame stamp + offset (a tracker's known lag)
    n: int | None = None
    duration_s: float | None = None
    truth_path: str = "camera/ground_truth"
    truth_robot: str | None = None  # truth published under another robot id (an external tracker)
    jpeg_quality: int = 95


@dataclass
class CaptureStats:
    captured: int = 0
    unmatched: int = 0
    no_yaw: int = 0
    rejected: dict[str, int] = field(default_factory=dict)
    overflow: int = 0

    def as_dict(self) -> dict[str, Any]:
        return {"captured": self.captured, "unmatched": self.unmatched, "no_yaw": self.no_yaw,
                "rejected": dict(self.rejected), "overflow": self.overflow}


class SeedWriter:
    """images/ + pose_data.csv; refuses a folder that already holds a dataset (never overwrites one)."""

    def __init__(self, out: Path, jpeg_quality: int) -> None:
        if (out / CSV_NAME).exists():
            raise FileExistsError(f"{out / CSV_NAME} exists; choose an empty --out folder")
        self.images = out / "images"
        self.images.mkdir(parents=True, exist_ok=True)
        self.jpeg_quality = jpeg_quality
        self._csv_file = (out / CSV_NAME).open("w", newline="", encoding="utf-8")
        self._csv = csv.writer(self._csv_file)
        self._csv.writerow(CSV_FIELDS)

    def write(self, frame: Frame, x: float, y: float, yaw: float) -> str:
        stamp = datetime.fromtimestamp(frame.header.capture_wall_ns / 1e9, tz=timezone.utc)
        name = f"img_{stamp:%Y%m%d_%H%M%S_%f}.jpg"
        if (self.images / name).exists():
            name = f"img_{stamp:%Y%m%d_%H%M%S_%f}_{frame.header.seq}.jpg"
        (self.images / name).write_bytes(self._jpeg(frame))
        self._csv.writerow([name, repr(float(x)), repr(float(y)), repr(orientation_z(yaw))])
        self._csv_file.flush()
        return name

    def _jpeg(self, frame: Frame) -> bytes:
        if frame.encoding == "jpeg":
            return frame.data  # already compressed by the camera: stored as received
        ok, buf = cv2.imencode(".jpg", frame_pixels(frame), [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality])
        if not ok:
            raise ValueError("JPEG encoding failed")
        return buf.tobytes()

    def close(self) -> None:
        self._csv_file.close()


class Capture:
    def __init__(self, robot_id: str, zenoh_config: ZenohConfig, options: CaptureOptions) -> None:
        truth_topic = TOPICS.get(options.truth_path)
        if truth_topic is None or not {"x", "y", "yaw"} <= set(truth_topic.message.model_fields):
            poses = [p for p, t in TOPICS.items() if {"x", "y", "yaw"} <= set(t.message.model_fields)]
            raise ValueError(f"--truth-topic {options.truth_path!r} is not a pose topic; use one of {poses}")
        self.robot_id = robot_id
        self.zenoh_config = zenoh_config
        self.options = options
        self.stats = CaptureStats()
        self._queue: queue.Queue[tuple[str, Any, float]] = queue.Queue(maxsize=256)
        self._rate_log = RateLimitedLog(log)
        self._matcher: NearestMatcher[Frame, Any] = NearestMatcher(int(options.tolerance_ms * 1e6))

    def _callback(self, kind: str):  # noqa: ANN202 - zenoh callback
        q, stats = self._queue, self.stats

        def on_sample(sample: zenoh.Sample) -> None:
            try:
                q.put_nowait((kind, sample.payload, time.monotonic()))
            except queue.Full:
                stats.overflow += 1
        return on_sample

    def run(self, stop: threading.Event, on_ready: Any = None) -> CaptureStats:
        writer = SeedWriter(self.options.out, self.options.jpeg_quality)
        zsession = open_session(self.zenoh_config, stop)
        if zsession is None:
            writer.close()
            return self.stats
        opts = self.options
        subs = [
            zsession.declare_subscriber(TOPICS["camera/frame"].key(self.robot_id), self._callback("frame")),
            zsession.declare_subscriber(TOPICS[opts.truth_path].key(opts.truth_robot or self.robot_id),
                                        self._callback("truth")),
        ]
        try:
            if on_ready is not None:
                on_ready()
            deadline = None if opts.duration_s is None else time.monotonic() + opts.duration_s
            while not stop.is_set() and not self._done() and (deadline is None or time.monotonic() < deadline):
                try:
                    item = self._queue.get(timeout=0.1)
                except queue.Empty:
                    item = None
                if item is not None:
                    self._take(*item)
                for frame, truth in self._matcher.ready(time.monotonic()):
                    self._save(writer, frame, truth)
        finally:
            for sub in subs:
                sub.undeclare()
            writer.close()
            zsession.close()
        return self.stats

    def _done(self) -> bool:
        return self.options.n is not None and self.stats.captured >= self.options.n

    def _take(self, kind: str, payload: Any, arrival: float) -> None:
        path = "camera/frame" if kind == "frame" else self.options.truth_path
        try:
            message = codec.decode(bytes(payload), TOPICS[path].message)
        except codec.DecodeError as exc:
            self.stats.rejected[path] = self.stats.rejected.get(path, 0) + 1
            self._rate_log.warning(f"reject:{path}", f"rejected {path}: {exc}")
            return
        stamp = message.header.capture_wall_ns
        if kind == "frame":
            self._matcher.add_frame(stamp + int(self.options.offset_ms * 1e6), message, arrival)
        else:
            self._matcher.add_truth(stamp, message)

    def _save(self, writer: SeedWriter, frame: Frame, truth: Any) -> None:
        if self._done():
            return
        if truth is None:
            self.stats.unmatched += 1
            return
        if truth.yaw is None:
            self.stats.no_yaw += 1
            return
        try:
            writer.write(frame, truth.x, truth.y, truth.yaw)
        except ValueError as exc:
            self.stats.rejected["camera/frame"] = self.stats.rejected.get("camera/frame", 0) + 1
            self._rate_log.warning("bad_frame", f"frame {frame.header.seq} not saved: {exc}")
            return
        self.stats.captured += 1
