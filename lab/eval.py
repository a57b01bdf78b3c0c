"""Evaluating a localization model on a labelled dataset, on the runtime stack (onnxruntime, no torch).

Two kinds of model path:
- an ONNX file whose manifest input kind is 'dense_image' or 'sparse_hits' (the paper network): fed the
  dataset's 0/1 dot images directly, through `courtloc.localizer.paper_input`;
- a model folder (a localizer package, e.g. models/default): loaded with
  `courtloc.localizer.predictor.load_predictor` and fed the hits of each frame — for dot-image datasets
  the dot centres (`courtloc.scan.seed_dots.image_to_hits`), for raw frames the
  preprocessor's hits.

Every frame's answer carries the model's valid flag (the paper network has none: all its answers count
as valid), so the metrics come twice: over all frames, and over the valid ones (`valid_*`, with
`valid_wrong`: valid and more than 0.5 m off).

A start (`StartHint`: the robot's half and/or its start pose) is given to the model as the infer stage's
tracker gives its configured start: as the evidence of the first frame of each recording (of each frame
when frames are independent poses, e.g. `courtloc dataset synth` output, or without tracking).

Plots need matplotlib (the `train` extra); without it `evaluate` still gives every number.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal, Optional, Protocol

import numpy as np

from courtloc.lab.datasets import Dataset
from courtloc.lab.metrics import PoseMetrics, compute_metrics, position_errors
from courtloc.lab.seed_frames import frame_time
from courtloc.localizer.acquire import Prior
from courtloc.localizer.manifest import PAPER_KINDS, Manifest, read_manifest
from courtloc.localizer.model_file import ModelFile
from courtloc.localizer.predictor import PaperPredictor, load_predictor
from courtloc.localizer.tracking import Tracker  # the robot's own tracking rule
from courtloc.models import bundled_package
from courtloc.world.court import load_court

log = logging.getLogger(__name__)
STILL_FRAMES = 10  # an independent pose is a robot standing still for up to this many frames


def default_model_path() -> Path:
    """The bundled package: what eval uses when no --model is given."""
    return bundled_package()


@dataclass(frozen=True)
class FramePrediction:
    x: float
    y: float
    yaw: Optional[float]
    valid: bool


@dataclass(frozen=True)
class StartHint:
    """Where the robot starts: its half ("+x" / "-x") and/or a pose (x, y, yaw), the pose known to `std_m`
    and the heading to `yaw_std_deg` (the defaults of the infer stage's `[infer] start`)."""

    side: Optional[Literal["+x", "-x"]] = None
    pose: Optional[tuple[float, float, float]] = None
    std_m: float = 0.5
    yaw_std_deg: float = 20.0

    def __post_init__(self) -> None:
        if self.pose is not None and self.side is not None and abs(self.pose[0]) > 1e-9 \
                and (self.pose[0] > 0) != (self.side == "+x"):
            raise ValueError(f"start pose x = {self.pose[0]} is not in the start side {self.side}")

    def prior(self):  # noqa: ANN201 - acquire.Prior
        """The start as the localizer's evidence, as the infer stage hands it over (`[infer] start`)."""

        if self.pose is None:
            return Prior(source="start", half=self.side)
        return Prior(source="start", pose=np.array(self.pose, dtype=np.float64), std_m=self.std_m, half=self.side,
                     yaw_std_rad=math.radians(self.yaw_std_deg))


class FrameModel(Protocol):
    manifest: Manifest

    def predict_frame(self, dataset: Dataset, i: int) -> FramePrediction:
        """x, y, yaw (or None) and the valid flag for frame i of `dataset`."""


class PaperOnnxModel:
    """The paper network's dense or sparse ONNX graph, fed the dataset's own dot images."""

    def __init__(self, path: Path, threads: int = 1) -> None:
        self.predictor = PaperPredictor(ModelFile.read(path), ["CPUExecutionProvider"], threads)
        self.manifest = self.predictor.manifest

    def predict_dots(self, dots: np.ndarray) -> np.ndarray:
        return self.predictor.run(self.predictor.dots_feed(dots))

    def predict_frame(self, dataset: Dataset, i: int) -> FramePrediction:
        x, y = self.predict_dots(dataset.dot_image(i))
        return FramePrediction(float(x), float(y), None, valid=True)  # the network never says it does not know


class HitsPredictorModel:
    """A localizer package driven through the runtime predictor, fed radial-scan hits.

    With `tracking` each frame starts from the infer stage's tracker (the same rule as on the robot: the
    model's motion filter, `predictor.track`, when it has one, timed by the file names' time stamps) while
    frames come from the same recording in order; without it every frame is localised on its own.
    A start hint is the tracker's start (`Tracker.start`, as the infer stage's `[infer] start`): the
    evidence of every sequence's first frame.

    Frames that are independent poses (`Dataset.sequential` False, e.g. `dataset synth`) are each a robot
    standing still there: the frame is given to a fresh tracker up to `still_frames` times, 1/30 s apart,
    until its answer is valid, and the last answer counts (acquisition needs a few frames of agreement
    before it answers valid: docs/localizer.md).
    """

    def __init__(self, path: Path, threads: int = 1, tracking: bool = True, start: StartHint | None = None,
                 still_frames: int = STILL_FRAMES) -> None:
        self.predictor = load_predictor(path, providers=["CPUExecutionProvider"], threads=threads)
        self.manifest = self.predictor.manifest
        self.tracking = tracking
        self.still_frames = still_frames
        self.tracker = Tracker(start=None if start is None else start.prior())
        self._last: tuple[str, int] | None = None  # (recording, frame index) of the previous call

    def predict_frame(self, dataset: Dataset, i: int) -> FramePrediction:
        hits, height, width = dataset.hits(i)
        recording = str(dataset.recordings[i])
        if not self.tracking or not dataset.sequential or self._last != (recording, i - 1):
            self.tracker.reset()
        if not self.tracking:
            pose = self.predictor.predict(hits, width, height)
        elif dataset.sequential:
            pose = self.tracker.step(self.predictor, hits, width, height, t=frame_time(dataset.filenames[i]))
        else:
            for k in range(self.still_frames):
                pose = self.tracker.step(self.predictor, hits, width, height, t=k / 30.0)
                if pose.valid:
                    break
        self._last = (recording, i)
        yaw = None if pose.yaw is None else float(pose.yaw)
        finite = all(math.isfinite(v) for v in (pose.x, pose.y, *(() if yaw is None else (yaw,))))
        return FramePrediction(float(pose.x), float(pose.y), yaw, valid=bool(pose.valid) and finite)


def open_model(path: Path | None, threads: int = 1, tracking: bool = True,
               start: StartHint | None = None) -> FrameModel:
    """An ONNX file of the paper network, or a model folder for the runtime predictor (default models/default)."""
    path = Path(path) if path is not None else default_model_path()
    if path.is_file() and path.suffix == ".onnx":
        if read_manifest(path).input.kind in PAPER_KINDS:
            if start is not None:
                raise ValueError(f"{path}: the paper network takes no start side or pose")
            return PaperOnnxModel(path, threads)
        return HitsPredictorModel(path, threads, tracking, start)
    if path.is_dir():
        return HitsPredictorModel(path, threads, tracking, start)
    raise FileNotFoundError(f"no model at {path} (an .onnx file or a model folder)")


@dataclass
class EvalResult:
    metrics: PoseMetrics
    filenames: list[str]
    true_xy: np.ndarray
    pred_xy: np.ndarray
    true_yaw: np.ndarray
    pred_yaw: Optional[np.ndarray]
    valid: Optional[np.ndarray] = None
    court: str = ""
    extra: dict = field(default_factory=dict)


def evaluate(model: FrameModel, dataset: Dataset, indices: np.ndarray | None = None,
             progress: bool = False) -> EvalResult:
    chosen = np.arange(len(dataset)) if indices is None else np.asarray(indices, dtype=np.int64)
    preds = [model.predict_frame(dataset, int(i)) for i in _progress(chosen, progress)]
    pred_xy = np.array([(p.x, p.y) for p in preds], dtype=np.float64).reshape(-1, 2)
    yaws = [p.yaw for p in preds]
    pred_yaw = None if any(y is None for y in yaws) else np.array(yaws, dtype=np.float64)
    valid = np.array([p.valid for p in preds], dtype=bool)
    true_xy, true_yaw = dataset.xy[chosen], dataset.yaw[chosen]
    metrics = compute_metrics(pred_xy, true_xy, pred_yaw, true_yaw if pred_yaw is not None else None, valid=valid)
    return EvalResult(metrics, [dataset.filenames[i] for i in chosen], true_xy, pred_xy, true_yaw, pred_yaw,
                      valid=valid, court=model.manifest.court)


def _progress(items: np.ndarray, enabled: bool):  # noqa: ANN202
    """A tqdm bar when asked for and installed (tqdm is not a runtime dependency)."""
    if enabled:
        try:
            from tqdm import tqdm  # progress bars: tqdm comes with the train extra

            return tqdm(items, unit="frame")
        except ImportError:
            pass
    return items


def write_predictions_csv(result: EvalResult, path: Path) -> None:
    errors = position_errors(result.pred_xy, result.true_xy)
    with Path(path).open("w") as handle:
        handle.write("image_filename,x,y,yaw,pred_x,pred_y,pred_yaw,err_m,valid\n")
        for k, name in enumerate(result.filenames):
            pred_yaw = "" if result.pred_yaw is None else f"{result.pred_yaw[k]:.6f}"
            valid = "" if result.valid is None else int(result.valid[k])
            handle.write(f"{name},{result.true_xy[k, 0]:.6f},{result.true_xy[k, 1]:.6f},{result.true_yaw[k]:.6f},"
                         f"{result.pred_xy[k, 0]:.6f},{result.pred_xy[k, 1]:.6f},{pred_yaw},{errors[k]:.6f},{valid}\n")


def write_plots(result: EvalResult, out_dir: Path, title: str = "") -> list[Path]:
    """Truth vs prediction on the court, error CDF, mean error by court region. [] without matplotlib."""
    try:
        import matplotlib  # plots: matplotlib comes with the train extra

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt  # plots: matplotlib comes with the train extra
    except ImportError:
        log.warning("matplotlib not installed: no plots (numbers are unaffected)")
        return []
    out_dir.mkdir(parents=True, exist_ok=True)
    errors = position_errors(result.pred_xy, result.true_xy)
    half_l, half_w = _court_half_extent(result)
    written = []

    fig, ax = plt.subplots(figsize=(9, 6.5))
    _draw_court(ax, result.court)
    step = max(1, len(errors) // 600)  # keep the drawing readable
    t, p = result.true_xy[::step], result.pred_xy[::step]
    ax.plot(np.stack([t[:, 0], p[:, 0]]), np.stack([t[:, 1], p[:, 1]]), color="0.6", lw=0.5)
    ax.scatter(t[:, 0], t[:, 1], s=6, c="tab:blue", label="truth")
    ax.scatter(p[:, 0], p[:, 1], s=6, c="tab:red", label="prediction")
    ax.set_xlim(-half_l - 0.5, half_l + 0.5)
    ax.set_ylim(-half_w - 0.5, half_w + 0.5)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"{title} truth vs prediction (every {step}th frame)".strip())
    ax.legend(loc="upper right")
    written.append(_save(fig, out_dir / "truth_vs_prediction.png", plt))

    fig, ax = plt.subplots(figsize=(6, 4))
    ordered = np.sort(errors)
    ax.plot(ordered, np.arange(1, len(ordered) + 1) / len(ordered))
    for q, style in ((0.5, ":"), (0.95, "--")):
        ax.axvline(np.quantile(errors, q), color="k", ls=style, lw=0.8, label=f"p{int(q * 100)} {np.quantile(errors, q):.3f} m")
    ax.set_xscale("log")
    ax.set_xlabel("position error (m)")
    ax.set_ylabel("fraction of frames")
    ax.set_title(f"{title} error CDF (n={len(errors)})".strip())
    ax.grid(True, alpha=0.3)
    ax.legend()
    written.append(_save(fig, out_dir / "error_cdf.png", plt))

    fig, ax = plt.subplots(figsize=(9, 6))
    cell = 1.0
    xe = np.arange(-half_l, half_l + cell, cell)
    ye = np.arange(-half_w, half_w + cell, cell)
    sums, _, _ = np.histogram2d(result.true_xy[:, 0], result.true_xy[:, 1], bins=[xe, ye], weights=errors)
    counts, _, _ = np.histogram2d(result.true_xy[:, 0], result.true_xy[:, 1], bins=[xe, ye])
    mean = np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)
    image = ax.pcolormesh(xe, ye, mean.T, cmap="viridis", shading="flat")
    fig.colorbar(image, ax=ax, label="mean position error (m)")
    _draw_court(ax, result.court, colour="white")
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"{title} mean error by 1 m cell of the true position".strip())
    written.append(_save(fig, out_dir / "error_by_region.png", plt))
    return written


def _save(fig, path: Path, plt) -> Path:  # noqa: ANN001
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def _court_half_extent(result: EvalResult) -> tuple[float, float]:
    try:
        court = load_court(result.court)
        return court.length_m / 2, court.width_m / 2
    except Exception:  # unknown court: frame the data instead
        extent = np.abs(np.concatenate([result.true_xy, result.pred_xy])).max(axis=0)
        return float(np.ceil(extent[0])), float(np.ceil(extent[1]))


def _draw_court(ax, court_name: str, colour: str = "0.75") -> None:  # noqa: ANN001
    try:
        points, _ = load_court(court_name).white_edges(0.03)
    except Exception as exc:
        log.info("no court drawing for %r: %s", court_name, exc)
        return
    ax.scatter(points[:, 0], points[:, 1], s=0.3, c=colour, zorder=0)
