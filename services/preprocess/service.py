"""Preprocess stage: frame -> white mask -> radial-scan hits, published as a few hundred points."""
from __future__ import annotations

import time

import cv2
import numpy as np

from courtloc.common.inbox import Delivery
from courtloc.common.messages import Edges, Frame
from courtloc.common.runtime import Service
from courtloc.common.services_table import Topic
from courtloc.services.preprocess.config import PreprocessConfig
from courtloc.services.preprocess.pipeline import FrameError, Preprocessor
from courtloc.services.preprocess.seed_dots import draw_hits


def frame_pixels(frame: Frame) -> np.ndarray:
    """The BGR image of a Frame message; FrameError when the bytes do not make one."""
    if frame.encoding == "jpeg":
        if not frame.data:
            raise FrameError("empty JPEG")
        image = cv2.imdecode(np.frombuffer(frame.data, np.uint8), cv2.IMREAD_COLOR)
        if image is None:
            raise FrameError("undecodable JPEG")
        if image.shape[:2] != (frame.height, frame.width):
            raise FrameError(f"JPEG is {image.shape[1]}x{image.shape[0]}, header says {frame.width}x{frame.height}")
        return image
    expected = frame.width * frame.height * 3
    if len(frame.data) != expected:
        raise FrameError(f"bgr8 payload has {len(frame.data)} bytes, {frame.width}x{frame.height}x3 needs {expected}")
    return np.frombuffer(frame.data, np.uint8).reshape(frame.height, frame.width, 3)


class PreprocessService(Service):
    name = "preprocess"

    def __init__(self, robot_id: str, zenoh_config, config: PreprocessConfig) -> None:  # noqa: ANN001
        super().__init__(robot_id, zenoh_config)
        self.config = config
        self.preprocessor = Preprocessor(config)
        self._last_preview = 0.0
        self.hits_last = 0

    def on_message(self, topic: Topic, message: Frame, delivery: Delivery) -> None:
        fresh = self.is_fresh(message.header, topic)
        try:
            image = frame_pixels(message)
            hits = self.preprocessor.process(image)
        except FrameError as exc:
            self.reject(topic.path, "bad_frame", str(exc))
            return
        self.hits_last = len(hits)
        header = message.header.forwarded(self.name, valid=message.header.valid and fresh)
        self.publish("preprocess/edges", Edges(
            header=header, width=message.width, height=message.height, crop_top=self.config.crop_top,
            n_hits=len(hits), hits=hits.astype("<i2", copy=False).tobytes()))
        self._maybe_preview(message, image, hits)

    def _maybe_preview(self, message: Frame, image: np.ndarray, hits: np.ndarray) -> None:
        preview = self.config.debug_preview
        now = time.monotonic()
        if not preview.enabled or now - self._last_preview < 1.0 / preview.max_rate_hz:
            return
        self._last_preview = now
        dots = draw_hits(hits, image.shape[0], image.shape[1], radius=self.config.dot_radius)
        shown = image.copy()
        shown[dots > 0] = (0, 0, 255)
        ok, buf = cv2.imencode(".jpg", shown, [cv2.IMWRITE_JPEG_QUALITY, preview.jpeg_quality])
        if ok:
            header = message.header.forwarded(self.name, valid=False)
            self.publish("preprocess/preview", Frame(header=header, width=image.shape[1], height=image.shape[0],
                                                      encoding="jpeg", data=buf.tobytes()))

    def health_detail(self) -> dict[str, float | int | str]:
        return {"hits_last": self.hits_last}
