"""One frame's answer of the geometric localizer: a pose with its fit, how it was found, and why it is invalid."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from courtloc.localizer.fit import FitResult


@dataclass(frozen=True)
class LocalizeResult:
    pose: np.ndarray  # (3,) x, y metres, yaw rad
    fit: FitResult
    mode: str  # "track" or "global"
    alternatives: list[np.ndarray] = field(default_factory=list)  # the mirror twin in "both" mode; the other
    # hypotheses while acquiring
    status: str = ""  # why an answer is invalid beyond its fit: "ambiguous", "searching", "confirming", "jump"

    @property
    def valid(self) -> bool:
        return self.fit.valid

    @property
    def quality(self) -> float:
        return self.fit.quality

    @property
    def trackable(self) -> bool:
        """Good enough to start the next frame from, even if not valid: a degenerate frame (only parallel
        lines) still pins yaw and one direction. With the motion filter (`track`) such a frame is fused:
        its covariance leaves the free direction to the prediction."""
        return self.fit.valid or (self.mode == "track" and self.fit.n_inliers >= 12 and self.fit.inlier_ratio >= 0.5)
