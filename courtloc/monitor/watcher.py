"""The monitor's view of one robot: the launcher's BusWatcher plus trails, shadow model and raw frames.

Frames, edges and previews are not decoded here: their zenoh callbacks only keep the newest few
payloads (a frame is ~1 MB); the thumbnail thread decodes what it needs at its own pace. Raw frames
are subscribed to only while the preprocess stage publishes no preview: across Wi-Fi, a frame
subscription pulls every frame over the air.
"""
from __future__ import annotations

import threading
import time
from collections import deque
from contextlib import contextmanager
from typing import Any, Iterator

import zenoh

from courtloc.common import codec
from courtloc.common.messages import GroundTruth, Pose
from courtloc.common.services_table import TOPICS
from courtloc.services.deployment import DeploymentConfig
from courtloc.watch import BusWatcher, WatchState

TRAIL_LENGTH = 600  # poses kept (20 s at 30 Hz)
IMAGE_PATHS = ("camera/frame", "preprocess/edges", "preprocess/preview")


class RawRing:
    """The newest `size` payloads of one topic, with their arrival time; safe to fill from a callback."""

    def __init__(self, size: int) -> None:
        self._items: deque[tuple[float, Any]] = deque(maxlen=size)
        self._lock = threading.Lock()
        self.received = 0

    def put(self, payload: Any) -> None:
        with self._lock:
            self._items.append((time.monotonic(), payload))
            self.received += 1

    def newest_first(self) -> list[tuple[float, Any]]:
        with self._lock:
            return list(reversed(self._items))


class MonitorWatcher(BusWatcher):
    def __init__(self, config: DeploymentConfig) -> None:
        super().__init__(config)
        self.trail: deque[tuple[float, float]] = deque(maxlen=TRAIL_LENGTH)
        self.truth_trail: deque[tuple[float, float]] = deque(maxlen=TRAIL_LENGTH)
        self.last_truth: GroundTruth | None = None
        self.shadow_pose: Pose | None = None
        self.received_at: dict[str, float] = {}  # topic path -> monotonic time of the last sample
        self.health_at: dict[str, float] = {}
        self.rings = {"camera/frame": RawRing(8), "preprocess/edges": RawRing(8), "preprocess/preview": RawRing(1)}
        self._frame_sub: Any = None
        self._frame_sub_lock = threading.Lock()

    # ---- subscriptions ---------------------------------------------------------------------------
    def watched_paths(self) -> set[str]:
        return super().watched_paths() | {"infer/shadow_pose"}

    def extra_subscribers(self, zsession: zenoh.Session) -> list[Any]:
        robot = self.config.robot_id
        self.want_frames(True, zsession)
        return [zsession.declare_subscriber(TOPICS[path].key(robot), self._ring_callback(path))
                for path in IMAGE_PATHS if path != "camera/frame"]

    def want_frames(self, wanted: bool, zsession: zenoh.Session | None = None) -> None:
        """Subscribe to raw frames, or drop that subscription (called by the thumbnail thread)."""
        zsession = zsession or self._session
        with self._frame_sub_lock:
            if wanted and self._frame_sub is None and zsession is not None:
                self._frame_sub = zsession.declare_subscriber(
                    TOPICS["camera/frame"].key(self.config.robot_id), self._ring_callback("camera/frame"))
            elif not wanted and self._frame_sub is not None:
                self._frame_sub.undeclare()
                self._frame_sub = None

    @property
    def frames_subscribed(self) -> bool:
        return self._frame_sub is not None

    def close(self) -> None:
        self.want_frames(False)
        super().close()

    def _ring_callback(self, path: str):  # noqa: ANN202 - zenoh callback
        ring, received_at = self.rings[path], self.received_at

        def on_sample(sample: zenoh.Sample) -> None:
            ring.put(sample.payload)
            received_at[path] = time.monotonic()
        return on_sample

    # ---- decoding (watcher thread) -------------------------------------------------------------
    def _handle(self, path: str, payload: Any) -> None:
        now = time.monotonic()
        self.received_at[path] = now
        if path == "infer/shadow_pose":
            try:
                shadow = codec.decode(bytes(payload), Pose)
            except codec.DecodeError:
                self.state.undecodable += 1
                return
            with self._lock:
                self.shadow_pose = shadow
            return
        with self._lock:
            before_pose = self.state.last_pose
        super()._handle(path, payload)
        with self._lock:
            state = self.state
            if path.endswith("/health"):
                self.health_at[path.split("/")[0]] = now
            pose = state.last_pose
            if pose is not None and pose is not before_pose and pose.header.valid:
                self.trail.append((pose.x, pose.y))
            if path == "camera/ground_truth" and state.truths:
                truth = next(reversed(state.truths.values()))  # the one just decoded (insertion order)
                if truth is not self.last_truth:
                    self.last_truth = truth
                    self.truth_trail.append((truth.x, truth.y))

    # ---- reading ---------------------------------------------------------------------------------
    def connected(self) -> bool:
        """True while our zenoh session has a router (it reconnects by itself when one comes back)."""
        session = self._session
        if session is None:
            return False
        try:
            return any(True for _ in session.info.routers_zid())
        except Exception:  # a session closing under us: not connected
            return False

    @contextmanager
    def locked(self) -> Iterator[WatchState]:
        """The watch state, held still while the caller copies from it."""
        with self._lock:
            yield self.state

    def truth_for(self, seq: int) -> GroundTruth | None:
        with self._lock:
            return self.state.truths.get(seq)
