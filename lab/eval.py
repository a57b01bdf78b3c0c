"""Evaluating a localization model on a labelled dataset, on the runtime stack (onnxruntime, no torch).

Two kinds of model path:
- an ONNX file whose manifest input kind is 'dense_image' or 'sparse_hits' (the paper network): fed the
  dataset's 0/1 dot images directly, through `courtloc.localizer.paper_input`;
- a model folder (a localizer package, e.g. models/default): loaded with
  `courtloc.localizer.predictor.load_predictor` and fed the hits of each frame — for dot-image datasets
  the dot centres (`courtloc.scan.seed_dots.image_to_hits`), for raw frames the
  preprocessor's hits.

Plots need matplotlib (the `train` extra); without it `evaluate` still gives every number.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional, Protocol

import numpy as np

from courtloc.lab.datasets import Dataset
from courtloc.lab.metrics import PoseMetrics, compute_metrics, position_errors
from courtloc.lab.seed_frames import frame_time
from courtloc.localizer.manifest import PAPER_KINDS, Manifest, read_manifest
from courtloc.localizer.model_file import ModelFile
from courtloc.localizer.predictor import PaperPredictor, load_predictor
from courtloc.localizer.tracking import Tracker  # the robot's own tracking rule
from courtloc.models import bundled_package
from courtloc.world.court import load_court

log = logging.getLogger(__name__)


def default_model_path() -> Path:
    """The bundled package: what eval uses when no --model is given."""
    return bundled_package()


class FrameModel(Protocol):
    manifest: Manifest

    def predict_frame(self, dataset: Dataset, i: int) -> tuple[float, float, Optional[float]]:
        """(x, y, yaw or None) for frame i of `dataset`."""


class PaperOnnxModel:
    """The paper network's dense or sparse ONNX graph, fed the dataset's own dot images."""

    def __init__(self, path: Path, threads: int = 1) -> None:
        self.predictor = PaperPredictor(ModelFile.read(path), ["CPUExecutionProvider"], threads)
        self.manifest = self.predictor.manifest

    def predict_dots(self, dots: np.ndarray) -> np.ndarray:
        return self.predictor.run(self.predictor.dots_feed(dots))

    def predict_frame(self, dataset: Dataset, i: int) -> tuple[float, float, Optional[float]]:
        x, y = self.predict_dots(dataset.dot_image(i))
        return float(x), float(y), None


class HitsPredictorModel:
    """A localizer package driven through the runtime predictor, fed radial-scan hits.

    With `tracking` each frame starts from the infer stage's tracker (the same rule as on the robot: the
    model's motion filter, `predictor.track`, when it has one, timed by the file names' time stamps) while
    frames come from the same recording in order; without it every frame is localised on its own.
    """

    def __init__(self, path: Path, threads: int = 1, tracking: bool = True) -> None:
        self.predictor = load_predictor(path, providers=["CPUExecutionProvider"], threads=threads)
        self.manifest = self.predictor.manifest
        self.tracking = tracking
        self.tracker = Tracker()
        self._last: tuple[str, int] | None = None  # (recording, frame index) of the previous call

    def predict_frame(self, dataset: Dataset, i: int) -> tuple[float, float, Optional[float]]:
        hits, height, width = dataset.hits(i)
        recording = str(dataset.recordings[i])
        if not self.tracking or self._last != (recording, i - 1):
            self.tracker.reset()
        if self.tracking:
            pose = self.tracker.step(self.predictor, hits, width, height, t=frame_time(dataset.filenames[i]))
        else:
            pose = self.predictor.predict(hits, width, height)
        self._last = (recording, i)
        return float(pose.x), float(pose.y), None if pose.yaw is None else float(pose.yaw)


def open_model(path: Path | None, threads: int = 1, tracking: bool = True) -> FrameModel:
    """An ONNX file of the paper network, or a model folder for the runtime predictor (default models/default)."""
    path = Path(path) if path is not None else default_model_path()
    if path.is_file() and path.suffix == ".onnx":
        if read_manifest(path).input.kind in PAPER_KINDS:
            return PaperOnnxModel(path, threads)
        return HitsPredictorModel(path, threads, tracking)
    if path.is_dir():
        return HitsPredictorModel(path, threads, tracking)
    raise FileNotFoundError(f"no model at {path} (an .onnx file or a model folder)")


@dataclass
class EvalResult:
    metrics: PoseMetrics
    filenames: list[str]
    true_xy: np.ndarray
    pred_xy: np.ndarray
    true_yaw: np.ndarray
    pred_yaw: Optional[np.ndarray]
    court: str = ""
    extra: dict = field(default_factory=dict)


def evaluate(model: FrameModel, dataset: Dataset, indices: np.ndarray | None = None,
             progress: bool = False) -> EvalResult:
    chosen = np.arange(len(dataset)) if indices is None else np.asarray(indices, dtype=np.int64)
    preds = [model.predict_frame(dataset, int(i)) for i in _progress(chosen, progress)]
    pred_xy = np.array([(p[0], p[1]) for p in preds], dtype=np.float64).reshape(-1, 2)
    yaws = [p[2] for p in preds]
    pred_yaw = None if any(y is None for y in yaws) else np.array(yaws, dtype=np.float64)
    true_xy, true_yaw = dataset.xy[chosen], dataset.yaw[chosen]
    metrics = compute_metrics(pred_xy, true_xy, pred_yaw, true_yaw if pred_yaw is not None else None)
    return EvalResult(metrics, [dataset.filenames[i] for i in chosen], true_xy, pred_xy, true_yaw, pred_yaw,
                      court=model.manifest.court)


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
        handle.write("image_filename,x,y,yaw,pred_x,pred_y,pred_yaw,err_m\n")
        for k, name in enumerate(result.filenames):
            pred_yaw = "" if result.pred_yaw is None else f"{result.pred_yaw[k]:.6f}"
            handle.write(f"{name},{result.true_xy[k, 0]:.6f},{result.true_xy[k, 1]:.6f},{result.true_yaw[k]:.6f},"
                         f"{result.pred_xy[k, 0]:.6f},{result.pred_xy[k, 1]:.6f},{pred_yaw},{errors[k]:.6f}\n")


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
