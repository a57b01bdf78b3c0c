"""What the next frame starts from: the previous pose, kept while it is still worth tracking from.

A valid pose is kept. A pose that is not valid but still trackable (a degenerate view: only parallel
lines, the position along them unknown) is kept too, so the tracker rides through it. After too many
frames without either, the previous pose is dropped and the model searches the court again, so a robot
that lost track recovers instead of fitting to a stale guess forever.

A model that tracks with a motion filter (the geometric localizer's `track`) keeps its own state in
`motion`: opaque here, handed back to the model with the next frame, with its own loss rules
(`localizer/motion.py`). `previous` is still kept, so a swap to a model without a filter tracks on.

`step` is the one predictor-plus-tracker step: the infer stage, its shadow runner and `courtloc eval`
all localise a frame through it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from courtloc.localizer.odometry_fusion import OdometryFusion, fused_track
from courtloc.localizer.predictor import Prediction, Predictor


@dataclass
class Tracker:
    max_lost_frames: int = 10
    previous: tuple[float, float, float] | None = None
    lost_frames: int = 0
    motion: object | None = None
    odometry_reason: str = ""

    def update(self, x: float, y: float, yaw: float | None, valid: bool, trackable: bool) -> None:
        if yaw is not None and (valid or trackable):
            self.previous = (x, y, yaw)
            self.lost_frames = 0
            return
        self.lost_frames += 1
        if self.lost_frames > self.max_lost_frames:
            self.previous = None

    def step(self, predictor: Predictor, hits: np.ndarray, width: int, height: int,
             t: float | None, fusion: OdometryFusion | None = None) -> Prediction:
        """Localise one frame from what this tracker knows, and learn from the answer.

        `t` is the frame's capture time in seconds on one clock (the filter predicts over the real interval).
        With `fusion` (a geometric model's serving tracker) odometry predicts between the frames; why
        odometry made a frame invalid is left in `odometry_reason`.
        """
        prediction, self.motion, self.odometry_reason = fused_track(predictor, fusion, hits, width, height,
                                                                    self.motion, t)
        self.update(prediction.x, prediction.y, prediction.yaw, prediction.valid, prediction.trackable)
        return prediction

    def reset(self) -> None:
        self.previous = None
        self.lost_frames = 0
        self.motion = None
