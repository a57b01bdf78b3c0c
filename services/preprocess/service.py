"""Preprocess stage: frame -> white mask -> radial-scan hits, published as a few hundred points."""
from __future__ import annotations

import time
from typing import Any

import numpy as np

from courtloc.common.bus import ZenohConfig
from courtloc.common.inbox import Delivery
from courtloc.common.messages import Edges, Frame
from courtloc.common.payloads import FrameError, decode_frame, hits_to_bytes, marks_to_bytes
from courtloc.common.runtime import Service
from courtloc.common.services_table import Topic
from courtloc.common.shm_frames import ReceivedFrame, decode_frame_payload
from courtloc.scan.config import PreprocessConfig
from courtloc.scan.preprocessor import Preprocessor


class PreprocessService(Service):
    name = "preprocess"

    def __init__(self, robot_id: str, zenoh_config: ZenohConfig, config: PreprocessConfig) -> None:
        super().__init__(robot_id, zenoh_config)
        self.config = config
        self.preprocessor = Preprocessor(config)
        self._last_preview = 0.0
        self.hits_last = 0
        self.frames_via_shm = 0
        self.frames_via_bytes = 0

    def on_start(self) -> None:
        # Ray tables and the colour bit table take ~0.2 s to build: pay it before the first frame arrives.
        self.preprocessor.warm_up()

    def decode_input(self, topic: Topic, payload: Any) -> Any:
        if topic.message is Frame:  # the pixels are copied out of the payload once, never re-encoded
            return decode_frame_payload(payload)
        return super().decode_input(topic, payload)

    def on_message(self, topic: Topic, received: ReceivedFrame, delivery: Delivery) -> None:
        message = received.message
        if received.via_shm:
            self.frames_via_shm += 1
        else:
            self.frames_via_bytes += 1
        fresh = self.is_fresh(message.header, topic)
        try:
            image = decode_frame(message.encoding, received.pixels, message.width, message.height)
            hits = self.preprocessor.process(image)
            marks = self.preprocessor.marks(image)
        except FrameError as exc:
            self.reject(topic.path, exc.reason, str(exc))
            return
        self.hits_last = len(hits)
        header = message.header.forwarded(self.name, valid=message.header.valid and fresh)
        self.publish("preprocess/edges", Edges(
            header=header, width=message.width, height=message.height, crop_top=self.config.crop_top,
            n_hits=len(hits), hits=hits_to_bytes(hits), n_marks=len(marks), marks=marks_to_bytes(marks)))
        self._maybe_preview(message, image, hits)

    def _maybe_preview(self, message: Frame, image: np.ndarray, hits: np.ndarray) -> None:
        preview = self.config.debug_preview
        now = time.monotonic()
        if not preview.enabled or now - self._last_preview < 1.0 / preview.max_rate_hz:
            return
        self._last_preview = now
        header = message.header.forwarded(self.name, valid=False)  # a picture for people, not an input
        self.publish("preprocess/preview", Frame(header=header, width=image.shape[1], height=image.shape[0],
                                                  encoding="jpeg",
                                                  data=self.preprocessor.debug_preview_jpeg(image, hits)))

    def health_detail(self) -> dict[str, float | int | str]:
        return {"hits_last": self.hits_last, "scan": "compiled" if self.preprocessor.native else "numpy",
                "frames_via_shm": self.frames_via_shm, "frames_via_bytes": self.frames_via_bytes}
