"""`courtloc foxglove`: a live Foxglove WebSocket server on the pit laptop, fed from one robot's bus.

Channels: JSON with a JSON Schema, the same topic names and messages as a recording's view (see
courtloc.recording.foxview and jsonview), so deploy/foxglove/courtloc.json shows both. Robot id `r`:

| topic | schema | from |
|---|---|---|
| `courtloc/r/infer/pose/in_frame` (+ `shadow_pose`, `camera/ground_truth`) | foxglove.PoseInFrame | the pose topics |
| `courtloc/r/tf` | foxglove.FrameTransform | court -> base_link (valid poses), base_link -> camera (every second) |
| `courtloc/r/scene` | foxglove.SceneUpdate | the court and the robot's footprint (every second, for late joiners) |
| `courtloc/r/camera/frame` | foxglove.CompressedImage | camera/frame (raw frames JPEG-encoded, at most `--image-hz`) |
| `courtloc/r/preprocess/edges/annotations` | foxglove.ImageAnnotations | the hits, drawn on the image |
| `courtloc/r/shooter_bridge/solution` | courtloc.ShotSolution | shooter_bridge/solution |
| `courtloc/r/<service>/health` | courtloc.Health | every stage's health |

The Zenoh callbacks only keep the newest payload of each topic; decoding, conversion and logging run on
the server's own thread (a slow pit laptop skips frames, it never queues them).
"""
from __future__ import annotations

import json
import logging
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Callable

import cv2

from courtloc.common import codec
from courtloc.common.bus import ZenohConfig, open_session
from courtloc.common.messages import Edges, Frame, GroundTruth, Health, Pose, ShotSolution
from courtloc.common.payloads import frame_pixels
from courtloc.common.services_table import TOPICS
from courtloc.common.stats import RateLimitedLog
from courtloc.foxglove import scene
from courtloc.recording.foxview import FoxgloveViews, hits_topic, pose_topic, scene_topic, tf_topic
from courtloc.recording.jsonview import json_view, schema_data, schema_name

log = logging.getLogger("courtloc.foxglove")

POSE_PATHS = ("infer/pose", "infer/shadow_pose", "camera/ground_truth")
STATIC_PERIOD_S = 1.0


@dataclass
class LiveStats:
    received: dict[str, int] = field(default_factory=dict)
    logged: dict[str, int] = field(default_factory=dict)
    undecodable: dict[str, int] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        return {"received": dict(self.received), "logged": dict(self.logged), "undecodable": dict(self.undecodable)}


class _Newest:
    """Newest payload per topic path; callbacks store, the server thread takes them all."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._items: dict[str, bytes] = {}
        self.wake = threading.Event()

    def put(self, path: str, payload: bytes) -> None:
        with self._lock:
            self._items[path] = payload
        self.wake.set()

    def take_all(self) -> dict[str, bytes]:
        with self._lock:
            items, self._items = self._items, {}
        return items


class FoxgloveLive:
    def __init__(self, robot_id: str, zenoh_config: ZenohConfig, views: FoxgloveViews, host: str = "127.0.0.1",
                 port: int = 8765, image_hz: float = 15.0) -> None:
        self.robot_id = robot_id
        self.zenoh_config = zenoh_config
        self.views = views
        self.host, self.port = host, port
        self.image_period_s = 1.0 / image_hz
        self.stats = LiveStats()
        self._rate_log = RateLimitedLog(log)
        self._channels: dict[str, Any] = {}
        self._last_image = 0.0
        self.tf_topic, self.scene_topic = tf_topic(robot_id), scene_topic(robot_id)
        self.image_topic, self.hits_topic = TOPICS["camera/frame"].key(robot_id), hits_topic(robot_id)

    # ---- channels ---------------------------------------------------------------------------------
    def _open_channels(self, context: Any) -> None:
        import foxglove  # optional extra: only the live server needs it

        def channel(topic: str, schema: str) -> None:
            self._channels[topic] = foxglove.Channel(
                topic, schema=foxglove.Schema(name=schema, encoding="jsonschema", data=schema_data(schema)),
                message_encoding="json", context=context)

        for path in POSE_PATHS:
            channel(pose_topic(path, self.robot_id), "foxglove.PoseInFrame")
        channel(self.tf_topic, "foxglove.FrameTransform")
        channel(self.scene_topic, "foxglove.SceneUpdate")
        channel(self.image_topic, "foxglove.CompressedImage")
        channel(self.hits_topic, "foxglove.ImageAnnotations")
        for path, topic in TOPICS.items():
            if topic.message in (Health, ShotSolution):
                channel(topic.key(self.robot_id), schema_name(topic.message))

    def _log(self, topic: str, body: bytes | dict[str, Any], log_time: int) -> None:
        data = body if isinstance(body, bytes) else json.dumps(body, separators=(",", ":"), allow_nan=False).encode()
        self._channels[topic].log(data, log_time=log_time)
        self.stats.logged[topic] = self.stats.logged.get(topic, 0) + 1

    # ---- conversion (the server thread) -----------------------------------------------------------
    def _static(self, now_ns: int) -> None:
        self._log(self.scene_topic, scene.court_scene(self.views.court_drawing, self.views.rings, now_ns), now_ns)
        self._log(self.tf_topic, scene.camera_transform(self.views.camera, now_ns), now_ns)

    def _handle(self, path: str, payload: bytes, now_ns: int) -> None:
        self.stats.received[path] = self.stats.received.get(path, 0) + 1
        try:
            message = codec.decode(payload, TOPICS[path].message)
        except codec.DecodeError as exc:
            self.stats.undecodable[path] = self.stats.undecodable.get(path, 0) + 1
            self._rate_log.warning(f"undecodable:{path}", f"{path}: {exc.reason}")
            return
        if path in POSE_PATHS and isinstance(message, (Pose, GroundTruth)):
            in_frame = scene.pose_in_frame(message)
            if in_frame is not None:
                self._log(pose_topic(path, self.robot_id), in_frame, now_ns)
            if path == "infer/pose" and isinstance(message, Pose):
                transform = scene.robot_transform(message)
                if transform is not None:
                    self._log(self.tf_topic, transform, now_ns)
        elif path == "camera/frame" and isinstance(message, Frame):
            if time.monotonic() - self._last_image >= self.image_period_s:
                self._last_image = time.monotonic()
                self._log(self.image_topic, _jpeg_view(message), now_ns)
        elif path == "preprocess/edges" and isinstance(message, Edges):
            self._log(self.hits_topic, scene.hit_annotations(message), now_ns)
        elif isinstance(message, (ShotSolution, Health)):
            self._log(TOPICS[path].key(self.robot_id), json_view(message).data, now_ns)

    def paths(self) -> list[str]:
        wanted = set(POSE_PATHS) | {"camera/frame", "preprocess/edges", "shooter_bridge/solution"}
        return [p for p, t in TOPICS.items() if p in wanted or t.message is Health]

    def run(self, stop: threading.Event, duration_s: float | None = None,
            on_ready: Callable[[str], None] | None = None) -> LiveStats:
        import foxglove  # optional extra

        context = foxglove.Context()
        self._open_channels(context)
        # the server first: a taken port fails at once, before waiting for the robot's router
        server = foxglove.start_server(name=f"courtloc {self.robot_id}", host=self.host, port=self.port,
                                       context=context)
        session = open_session(self.zenoh_config, stop)
        if session is None:
            server.stop()
            return self.stats
        newest = _Newest()
        subscribers = [session.declare_subscriber(TOPICS[p].key(self.robot_id),
                                                  lambda sample, p=p: newest.put(p, bytes(sample.payload)))
                       for p in self.paths()]
        try:
            if on_ready is not None:
                on_ready(f"ws://{self.host}:{server.port}")
            deadline = None if duration_s is None else time.monotonic() + duration_s
            next_static = 0.0
            while not stop.is_set() and (deadline is None or time.monotonic() < deadline):
                now = time.monotonic()
                if now >= next_static:
                    self._static(time.time_ns())
                    next_static = now + STATIC_PERIOD_S
                if newest.wake.wait(min(0.2, max(0.0, next_static - time.monotonic()))):
                    newest.wake.clear()
                    for path, payload in newest.take_all().items():
                        self._handle(path, payload, time.time_ns())
        finally:
            for sub in subscribers:
                sub.undeclare()
            server.stop()
            session.close()
        return self.stats


def _jpeg_view(frame: Frame) -> bytes:
    """foxglove.CompressedImage JSON of a frame; raw BGR frames are JPEG-encoded first (Wi-Fi to the pit)."""
    if frame.encoding != "jpeg":
        ok, encoded = cv2.imencode(".jpg", frame_pixels(frame), [cv2.IMWRITE_JPEG_QUALITY, 80])
        if not ok:
            raise ValueError("JPEG encoding failed")
        frame = frame.model_copy(update={"encoding": "jpeg", "data": encoded.tobytes()})
    return json_view(frame, scene.CAMERA_FRAME).data
