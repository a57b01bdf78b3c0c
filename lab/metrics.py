"""Pose-error metrics shared by `courtloc eval`, training reports and model manifests.

Definitions (all over the n evaluated frames):
- mse: mean over frames AND both axes of the squared error, m^2 — the paper's (and torch's
  MSELoss) convention, i.e. ((dx^2 + dy^2) / 2).mean().
- mae_x, mae_y: mean absolute error per axis, m.
- mean/median/p95_err_m: of the Euclidean position error sqrt(dx^2 + dy^2), m; p95 by linear
  interpolation between order statistics (numpy's default).
- yaw_median_deg: median absolute yaw error, the difference wrapped to [-180, 180) degrees; only when
  yaw is both predicted and known.
- with the model's valid flags: valid_fraction (valid frames / n), valid_mean_err_m and valid_p95_err_m
  (over the valid frames only; None when none is valid), valid_wrong (valid frames more than `WRONG_M`
  off: the failure that matters, a pose the robot would act on).
"""
from __future__ import annotations

from typing import Optional

import numpy as np
from pydantic import BaseModel

from courtloc.world.angles import wrap_angle

WRONG_M = 0.5  # a valid pose further off than this is "valid and wrong"
_VALID_KEYS = ("valid_fraction", "valid_mean_err_m", "valid_p95_err_m", "valid_wrong")


class PoseMetrics(BaseModel):
    n: int
    mse: float
    mae_x: float
    mae_y: float
    mean_err_m: float
    median_err_m: float
    p95_err_m: float
    yaw_median_deg: Optional[float] = None
    valid_fraction: Optional[float] = None
    valid_mean_err_m: Optional[float] = None
    valid_p95_err_m: Optional[float] = None
    valid_wrong: Optional[int] = None

    def as_dict(self) -> dict[str, float | int | None]:
        """JSON-ready dict; yaw_median_deg only when yaw was evaluated, the valid_* keys only when validity was
        (then all four, null when no frame was valid)."""
        out = self.model_dump(exclude_none=True)
        if self.valid_fraction is not None:
            out.update({key: getattr(self, key) for key in _VALID_KEYS})
        return out


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


def valid_metrics(err: np.ndarray, valid: np.ndarray, wrong_m: float = WRONG_M) -> dict[str, float | int | None]:
    """The valid_* numbers from per-frame errors and valid flags (see the module docstring)."""
    err = np.asarray(err, dtype=np.float64)
    valid = np.asarray(valid, dtype=bool)
    if valid.shape != err.shape:
        raise ValueError(f"valid flags {valid.shape} and errors {err.shape} differ in shape")
    kept = err[valid]
    return {
        "valid_fraction": float(valid.mean()) if err.size else None,
        "valid_mean_err_m": float(kept.mean()) if kept.size else None,
        "valid_p95_err_m": float(np.percentile(kept, 95)) if kept.size else None,
        "valid_wrong": int(np.count_nonzero(kept > wrong_m)),
    }


def compute_metrics(pred_xy: np.ndarray, true_xy: np.ndarray, pred_yaw: np.ndarray | None = None,
                    true_yaw: np.ndarray | None = None, valid: np.ndarray | None = None) -> PoseMetrics:
    """Metrics over all frames; with `valid` (the model's per-frame flag) also the valid_* ones."""
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
        **(valid_metrics(err, valid) if valid is not None else {}),
    )
