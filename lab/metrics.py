"""Pose-error metrics shared by `courtloc eval`, training reports and model manifests.

Definitions (all over the n evaluated frames):
- mse: mean over frames AND both axes of the squared error, m^2 — the paper's (and torch's
  MSELoss) convention, i.e. ((dx^2 + dy^2) / 2).mean().
- mae_x, mae_y: mean absolute error per axis, m.
- mean/median/p95_err_m: of the Euclidean position error sqrt(dx^2 + dy^2), m; p95 by linear
  interpolation between order statistics (numpy's default).
- yaw_median_deg: median absolute yaw error, the difference wrapped to [-180, 180) degrees; only when
  yaw is both predicted and known.
"""
from __future__ import annotations

from typing import Optional

import numpy as np
from pydantic import BaseModel

from courtloc.world.angles import wrap_angle


class PoseMetrics(BaseModel):
    n: int
    mse: float
    mae_x: float
    mae_y: float
    mean_err_m: float
    median_err_m: float
    p95_err_m: float
    yaw_median_deg: Optional[float] = None

    def as_dict(self) -> dict[str, float | int]:
        """JSON-ready dict; yaw_median_deg only when yaw was evaluated."""
        return self.model_dump(exclude_none=True)


def position_errors(pred_xy: np.ndarray, true_xy: np.ndarray) -> np.ndarray:
    """Euclidean error per frame, m."""
    pred, true = _pair(pred_xy, true_xy)
    return np.hypot(pred[:, 0] - true[:, 0], pred[:, 1] - true[:, 1])


def _pair(pred_xy: np.ndarray, true_xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    pred = np.asarray(pred_xy, dtype=np.float64).reshape(-1, 2)
    true = np.asarray(true_xy, dtype=np.float64).reshape(-1, 2)
    if pred.shape != true.shape:
        raise ValueError(f"predictions {pred.shape} and truth {true.shape} differ in shape")
    if len(pred) == 0:
        raise ValueError("no frames to evaluate")
    return pred, true


def compute_metrics(pred_xy: np.ndarray, true_xy: np.ndarray, pred_yaw: np.ndarray | None = None,
                    true_yaw: np.ndarray | None = None) -> PoseMetrics:
    pred, true = _pair(pred_xy, true_xy)
    diff = pred - true
    err = np.hypot(diff[:, 0], diff[:, 1])
    yaw_median = None
    if pred_yaw is not None and true_yaw is not None:
        dyaw = wrap_angle(np.asarray(pred_yaw, dtype=np.float64) - np.asarray(true_yaw, dtype=np.float64))
        if dyaw.shape != (len(pred),):
            raise ValueError(f"yaw arrays must have shape ({len(pred)},), got {dyaw.shape}")
        yaw_median = float(np.degrees(np.median(np.abs(dyaw))))
    return PoseMetrics(
        n=len(pred),
        mse=float(np.mean(diff ** 2)),
        mae_x=float(np.mean(np.abs(diff[:, 0]))),
        mae_y=float(np.mean(np.abs(diff[:, 1]))),
        mean_err_m=float(err.mean()),
        median_err_m=float(np.median(err)),
        p95_err_m=float(np.percentile(err, 95)),
        yaw_median_deg=yaw_median,
    )
