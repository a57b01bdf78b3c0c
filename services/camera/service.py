"""Camera stage: publishes frames (and ground truth when the source knows it) at the configured rate."""
from __future__ import annotations

import time
from typing import ClassVar, Mapping

import cv2
import numpy as np

from courtloc.common.bus import ZenohConfig
from courtloc.common.messages import Frame, GroundTruth, Header
from courtloc.common.runtime import Service
from courtloc.common.shm_frames import PixelStaging, ShmFramePublisher
from courtloc.services.camera.config import CameraConfig
from courtloc.services.camera.sources import (
    ROBOT_SOURCES,
    Capture,
    FrameSource,
    SourceError,
    SourceFactory,
    make_source,
)


def encode_frame(frame: np.ndarray, header: Header, encoding: str, jpeg_quality: int,
                 staging: PixelStaging) -> tuple[Frame, bytes | bytearray]:
    """The frame message without its bytes, and the bytes (raw pixels in `staging`, or a JPEG)."""
    height, width = frame.shape[:2]
    if encoding == "jpeg":
        ok, buf = cv2.imencode(".jpg", frame, [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality])
        if not ok:
            raise SourceError("JPEG encoding failed")
        data: bytes | bytearray = buf.tobytes()
    else:
        data = staging.fill(frame)
    return Frame(header=header, width=width, height=height, encoding=encoding, data=b""), data


def capture_header(robot_id: str, seq: int, stage: str, taken_mono_ns: int | None) -> Header:
    """The frame's header, stamped now or, when the source knows it, at the instant the frame shows (the
    twin renders the robot's pose of that instant); a claimed instant from the future is ignored."""
    header = Header.now(robot_id, seq, stage)
    if taken_mono_ns is not None and taken_mono_ns <= header.capture_mono_ns:
        earlier = header.capture_mono_ns - taken_mono_ns
        header.capture_mono_ns -= earlier
        header.capture_wall_ns -= earlier
    return header


class CameraService(Service):
    name = "camera"
    # The source kinds this stage can open, by [camera] source; the twin's camera stage adds "sim".
    sources: ClassVar[Mapping[str, SourceFactory]] = ROBOT_SOURCES

    def __init__(self, robot_id: str, zenoh_config: ZenohConfig, config: CameraConfig) -> None:
        super().__init__(robot_id, zenoh_config)
        self.config = config
        self.source: FrameSource = make_source(config, self.sources)  # a bad source table stops the start here
        self._open = False
        self._backoff = config.reopen_backoff_s
        self._seq = 0
        self.source_errors = 0
        self._staging = PixelStaging()
        self._frames: ShmFramePublisher | None = None

    def on_start(self) -> None:
        self._frames = ShmFramePublisher(self.publisher("camera/frame"), int(self.config.shm_pool_mb * 2**20),
                                         enabled=self.zenoh_config.shared_memory)

    def produce(self) -> None:
        period = 1.0 / self.config.fps
        deadline = time.monotonic()
        while not self.stop_event.is_set():
            was_open = self._open
            capture = self._next_capture()
            if not was_open:
                deadline = time.monotonic()  # opening a source is not a missed frame slot
            if capture is not None:
                self._publish_capture(capture)
            deadline += period
            late = time.monotonic() - deadline
            if late > period:
                # We could not keep the rate: the slots we missed are drops, and we do not try to catch up.
                missed = int(late // period)
                self.extra_dropped += missed
                deadline += missed * period
            self.stop_event.wait(max(0.0, deadline - time.monotonic()))

    def _next_capture(self) -> Capture | None:
        try:
            if not self._open:
                self.source.open()
                self._open = True
                self._backoff = self.config.reopen_backoff_s
                self.log.info("camera source %s open", self.config.source)
            # After the first frame a decoding source writes into the staging buffer itself: no copy.
            capture = self.source.read(self._staging.view if self._staging.view.size else None)
        except SourceError as exc:
            self.source_errors += 1
            self.record_error("source", f"camera source: {exc}; reopening in {self._backoff:.1f} s")
            self._close_source()
            self.stop_event.wait(self._backoff)
            self._backoff = min(self._backoff * 2, self.config.reopen_backoff_max_s)
            return None
        frame = capture.frame
        if frame.ndim != 3 or frame.shape[2] != 3 or frame.dtype != np.uint8:
            self.record_error("source", f"source gave a {frame.shape} {frame.dtype} frame, not BGR uint8")
            return None
        return capture

    def _publish_capture(self, capture: Capture) -> None:
        header = capture_header(self.robot_id, self._seq, self.name, capture.taken_mono_ns)
        header.valid = True
        self._seq += 1
        start = time.perf_counter_ns()
        meta, data = encode_frame(capture.frame, header, self.config.encoding, self.config.jpeg_quality,
                                  self._staging)
        assert self._frames is not None
        if not self._frames.put(meta, data) and self._frames.enabled:
            self.record_error("shm_pool", f"shared-memory pool ({self.config.shm_pool_mb:g} MB) held by subscribers: "
                                          "frame sent as bytes")
        self.count_published("camera/frame", meta)
        if capture.truth is not None:
            x, y, yaw = capture.truth
            self.publish("camera/ground_truth",
                         GroundTruth(header=header, x=x, y=y, yaw=yaw, source=self.config.source))
        self.record_latency(time.perf_counter_ns() - start)

    def _close_source(self) -> None:
        if self._open:
            self.source.close()
            self._open = False

    def on_stop(self) -> None:
        self._close_source()

    def health_detail(self) -> dict[str, float | int | str]:
        shm = self._frames.stats if self._frames is not None else None
        return {"source": self.config.source, "source_errors": self.source_errors, "seq": self._seq,
                "frames_in_shm": shm.in_shm if shm else 0, "frames_as_bytes": shm.fallback_bytes if shm else 0}
