"""Golden inputs: radial-scan hits of frames at known poses, shipped inside a model package.

Made when the package is built (twin frames rendered at `golden_build.GOLDEN_POSES`, see
golden_build.py), written as `golden.npz` beside model.onnx and named with its sha256 by the
manifest (`Manifest.golden`), so the robot validates a candidate by comparing its answers with the
true poses without rendering anything.

File format (numpy .npz, no pickles):
    hits     int16 [N, 4]  every frame's hits, concatenated (row, col, ray, d), as on an Edges message
    offsets  int64 [F + 1] frame f's hits are hits[offsets[f]:offsets[f + 1]]
    poses    float64 [F, 3] true (x m, y m, yaw rad) of each frame, court frame
    size     int64 [2]     (width, height) of the frames
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from courtloc.world.angles import wrap_angle

GOLDEN_FILE = "golden.npz"
MAX_FRAMES = 64
MAX_HITS = 200_000  # all frames together; a frame has a few thousand


def sidecar_path(model_path: Path) -> Path:
    """Where a lone ONNX file keeps its golden inputs: NAME.onnx -> NAME.golden.npz (pushed as golden.npz)."""
    return Path(model_path).with_suffix(".golden.npz")


class GoldenError(ValueError):
    """A golden file that is not what this module writes."""


@dataclass(frozen=True)
class GoldenFrame:
    hits: np.ndarray
    width: int
    height: int
    pose: tuple[float, float, float]


def save_golden(path: Path, frames: list[GoldenFrame]) -> Path:
    if not frames or len({(f.width, f.height) for f in frames}) != 1:
        raise GoldenError("golden frames must be at least one, all of one size")
    offsets = np.cumsum([0] + [len(f.hits) for f in frames]).astype(np.int64)
    hits = np.concatenate([np.asarray(f.hits, np.int16).reshape(-1, 4) for f in frames])
    path = Path(path)
    with path.open("wb") as handle:
        np.savez(handle, hits=hits, offsets=offsets, poses=np.array([f.pose for f in frames], np.float64),
                 size=np.array([frames[0].width, frames[0].height], np.int64))
    return path


def load_golden(path: Path) -> list[GoldenFrame]:
    """The frames of a golden file; GoldenError for anything malformed or beyond the limits above."""
    try:
        with np.load(Path(path), allow_pickle=False) as data:
            arrays = {k: data[k] for k in ("hits", "offsets", "poses", "size")}
    except (OSError, ValueError, KeyError, EOFError) as exc:
        raise GoldenError(f"unreadable golden file: {type(exc).__name__}: {exc}") from None
    hits, offsets, poses, size = arrays["hits"], arrays["offsets"], arrays["poses"], arrays["size"]
    n = len(poses)
    if not (hits.dtype == np.int16 and hits.ndim == 2 and hits.shape[1] == 4 and len(hits) <= MAX_HITS):
        raise GoldenError(f"golden hits must be int16 [N <= {MAX_HITS}, 4], got {hits.dtype}{list(hits.shape)}")
    if not (poses.ndim == 2 and poses.shape[1] == 3 and 1 <= n <= MAX_FRAMES and np.isfinite(poses).all()):
        raise GoldenError(f"golden poses must be 1..{MAX_FRAMES} finite (x, y, yaw), got shape {list(poses.shape)}")
    if not (offsets.shape == (n + 1,) and offsets[0] == 0 and offsets[-1] == len(hits)
            and (np.diff(offsets) >= 0).all()):
        raise GoldenError("golden offsets do not cut the hits into one run per pose")
    if not (size.shape == (2,) and 0 < size[0] <= 8192 and 0 < size[1] <= 8192):
        raise GoldenError(f"golden frame size {size.tolist()} is not a frame size")
    width, height = int(size[0]), int(size[1])
    return [GoldenFrame(np.ascontiguousarray(hits[offsets[i]:offsets[i + 1]]), width, height,
                        (float(poses[i, 0]), float(poses[i, 1]), float(poses[i, 2]))) for i in range(n)]


def _wrapped_deg(a: float, b: float) -> float:
    return abs(math.degrees(wrap_angle(a - b)))


@dataclass
class GoldenRun:
    """A predictor's answers on golden frames, compared with their true poses."""

    position_error_m: list[float] = field(default_factory=list)
    yaw_error_deg: list[float | None] = field(default_factory=list)  # None: the model gives no yaw
    valid: list[bool] = field(default_factory=list)
    answers: list[tuple[float, float, float | None]] = field(default_factory=list)
    seconds: list[float] = field(default_factory=list)

    @property
    def worst(self) -> int:
        """Index of the frame with the largest position error (non-finite counts as largest)."""
        return max(range(len(self.position_error_m)),
                   key=lambda i: math.inf if not math.isfinite(self.position_error_m[i]) else self.position_error_m[i])

    def max_yaw_error_deg(self) -> float | None:
        known = [e for e in self.yaw_error_deg if e is not None]
        return max(known) if known else None


def run_golden(predictor, frames: list[GoldenFrame]) -> GoldenRun:  # noqa: ANN001 - localizer.predictor.Predictor
    """Each frame once, tracking from its true pose as a served frame tracks from the previous one.

    A first, untimed call on frame 0 without a previous pose warms the session up (a cold start's
    global search happens once, not per frame)."""
    predictor.predict(frames[0].hits, frames[0].width, frames[0].height, previous=None)
    run = GoldenRun()
    for frame in frames:
        start = time.perf_counter()
        pred = predictor.predict(frame.hits, frame.width, frame.height, previous=frame.pose)
        run.seconds.append(time.perf_counter() - start)
        x, y, yaw = float(pred.x), float(pred.y), None if pred.yaw is None else float(pred.yaw)
        error = math.hypot(x - frame.pose[0], y - frame.pose[1])
        run.position_error_m.append(error if math.isfinite(error) else math.inf)
        run.yaw_error_deg.append(None if yaw is None else
                                 (_wrapped_deg(yaw, frame.pose[2]) if math.isfinite(yaw) else math.inf))
        run.valid.append(bool(pred.valid))
        run.answers.append((x, y, yaw))
    return run
