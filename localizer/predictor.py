"""The runtime predictor: a model file or package in, `predict(hits, width, height, previous)` and
`track(hits, width, height, state, t)` out.

What the infer service calls. The manifest's input kind decides how hits are fed:
- 'scan_hits' (a geometric localizer package folder): the package's ONNX turns hits into floor points,
  then the fit (courtloc.localizer.geometric) gives x, y, yaw, quality. `previous` enables tracking.
  With the compiled kernel built (fit_kernel.c), hits -> floor points is a lookup into the ONNX file's
  own floor table, fused with the per-hit geometry in one C call (an onnxruntime run alone costs more
  than the whole compiled fit); without it, onnxruntime and numpy as before.
- 'dense_image' / 'sparse_hits' (the paper network, an .onnx file): hits are drawn as the dot image
  (courtloc.localizer.paper_input) and the network gives x, y; no yaw; quality 1 (it has no self-check).
Stateless: the caller keeps the previous pose or the tracking state (`courtloc.localizer.tracking`).
Every model file is read and parsed once (`ModelFile`); its court comes from its package (a geometric
package ships court.json) or, for a bare paper-network file, from the world model by the manifest's name.
"""
from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import Optional, Protocol, Sequence

import numpy as np
import onnxruntime as ort
from pydantic import BaseModel, Field

from courtloc.localizer.config import LocalizerConfig
from courtloc.localizer.fit import kernel_active
from courtloc.localizer.geometric import GeometricLocalizer
from courtloc.localizer.manifest import MODEL_FILE, PAPER_KINDS, Manifest, ManifestError
from courtloc.localizer.marks import MarkPoints, mark_points
from courtloc.localizer.model_file import ModelFile
from courtloc.localizer.package import load_package
from courtloc.localizer.paper_input import dense_input, hits_to_dense_input, hits_to_sparse_input, sparse_input
from courtloc.localizer.result import LocalizeResult
from courtloc.world.court import Court, load_court

log = logging.getLogger(__name__)


class Prediction(BaseModel):
    x: float
    y: float
    yaw: Optional[float] = None  # radians, court frame; None when the model does not estimate it
    quality: float = Field(ge=0.0, le=1.0)
    valid: bool
    mode: str = ""  # geometric: "track" or "global"
    n_hits: int = 0
    n_inliers: int = 0
    position_std_m: Optional[float] = None
    alternatives: list[tuple[float, float, float]] = Field(default_factory=list)  # symmetry "both"
    trackable: bool = False  # fine as the next frame's `previous` even when not valid (degenerate view)
    reason: str = ""  # why not valid beyond the fit's quality: "ambiguous", "searching", "confirming", "jump"


class Predictor(Protocol):
    manifest: Manifest
    court: Court

    def predict(self, hits: np.ndarray, width: int, height: int,
                previous: Optional[Prediction | Sequence[float]] = None) -> Prediction: ...

    def track(self, hits: np.ndarray, width: int, height: int, state: object,
              t: float | None = None, marks: np.ndarray | None = None) -> tuple[Prediction, object]:
        """One frame of a track: the prediction and the state to hand back with the next frame; `marks` the
        frame's colour marks (int16 rows of (row, col, mark index)), for a model that weighs them."""


def _session(model: ModelFile, providers: Sequence[str] | None, threads: int) -> ort.InferenceSession:
    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    return ort.InferenceSession(model.data, options, providers=list(providers or ["CPUExecutionProvider"]))


def _as_hits(hits: np.ndarray) -> np.ndarray:
    h = np.asarray(hits)
    if h.dtype == np.int16 and h.ndim == 2 and h.shape[1] == 4 and h.flags.c_contiguous:
        return h  # what the preprocess stage sends: nothing to convert
    if h.size == 0:
        return np.zeros((0, 4), np.int16)
    if h.ndim != 2 or h.shape[1] < 2:
        raise ValueError(f"hits must be N x 4 (row, col, ray, d), got shape {h.shape}")
    if h.shape[1] < 4:
        h = np.column_stack([h, np.zeros((len(h), 4 - h.shape[1]))])
    return np.rint(h[:, :4]).astype(np.int16)


def _floor_table(model: ModelFile, shape: tuple[int, int]) -> np.ndarray:
    """The package ONNX's floor table (the initializer the package builder stores), (H * W, 2) float32."""
    table = model.initializer("floor_table")
    if table is None:
        raise ManifestError(f"{model.path.name}: no floor_table initializer")
    table = np.ascontiguousarray(table, np.float32)
    if table.shape != (shape[0] * shape[1], 2):
        raise ManifestError(f"{model.path.name}: floor table {table.shape} does not match {shape[1]}x{shape[0]}")
    return table


def _previous_pose(previous) -> Optional[np.ndarray]:
    if previous is None:
        return None
    if isinstance(previous, Prediction):
        if not (previous.valid or previous.trackable) or previous.yaw is None:
            return None
        return np.array([previous.x, previous.y, previous.yaw])
    pose = np.asarray(previous, np.float64).reshape(-1)
    if pose.size != 3 or not all(map(math.isfinite, pose.tolist())):
        raise ValueError(f"previous pose must be (x, y, yaw), got {previous!r}")
    return pose


class GeometricPredictor:
    def __init__(self, model: ModelFile, providers: Sequence[str] | None = None, threads: int = 1,
                 config: LocalizerConfig | None = None) -> None:
        self.package = load_package(model, config)
        self.manifest = self.package.manifest
        self.court = self.package.court
        self.session = _session(model, providers, threads)
        self.localizer = GeometricLocalizer(self.package.court, self.package.camera, self.package.config)
        self.width, self.height = self.package.camera.width, self.package.camera.height
        self.floor_table = _floor_table(model, (self.height, self.width))

    def floor_points(self, hits: np.ndarray) -> np.ndarray:
        """The ONNX graph's answer: (N, 2) float32 floor points, NaN where a hit sees no floor."""
        return self.session.run(None, {"hits": _as_hits(hits)})[0]

    def projected_hits(self, hits: np.ndarray):  # -> projection.ProjectedHits
        """The fit's per-hit geometry: compiled table lookup when the kernel runs, else onnxruntime + numpy."""
        if kernel_active():
            return self.localizer.geometry.from_table(self.floor_table, _as_hits(hits))
        hits = _as_hits(hits)
        return self.localizer.geometry.from_points(self.floor_points(hits), hits[:, 0], hits[:, 1])

    def _check_size(self, width: int, height: int) -> None:
        if (width, height) != (self.width, self.height):
            raise ValueError(f"frame {width}x{height} does not match the package camera {self.width}x{self.height}")

    def predict(self, hits: np.ndarray, width: int, height: int,
                previous: Optional[Prediction | Sequence[float]] = None) -> Prediction:
        self._check_size(width, height)
        return _prediction(self.localizer.localize(self.projected_hits(hits), _previous_pose(previous)))

    def track(self, hits: np.ndarray, width: int, height: int, state, t: float | None = None,  # noqa: ANN001
              marks: np.ndarray | None = None):  # noqa: ANN201
        """One frame of a motion-filtered track (`GeometricLocalizer.track`): (Prediction, next state).

        `state` is what the previous call returned (None to start: the frame is a global search); t is the
        frame's capture time in seconds on one clock (None: frames a nominal period apart); `marks` the
        frame's colour marks, evidence when the package's court has marks."""
        self._check_size(width, height)
        points = None
        if marks is not None and len(marks) and self.localizer.mark_map is not None:
            def points() -> MarkPoints:  # on the floor only when acquisition asks (a tracked frame does not)
                return self._mark_points(marks)
        step = self.localizer.track(self.projected_hits(hits), state, t, points)
        return _prediction(step.result), step.state

    def mark_evidence(self, pose: np.ndarray, marks: np.ndarray | None) -> tuple[int, int]:
        """(marks on their own colour at `pose`, marks on the floor) of a frame's colour marks ((0, 0) without any, or
        on a court without marks)."""
        if marks is None or not len(marks) or self.localizer.mark_map is None:
            return 0, 0
        points = self._mark_points(marks)
        own, _ = self.localizer.mark_map.evidence(pose, points)
        return own, len(points)

    def _mark_points(self, marks: np.ndarray) -> MarkPoints:
        """A frame's colour marks (int16 rows of (row, col, mark index)) on the floor, robot frame."""
        return mark_points(self.floor_table, self.width, np.asarray(marks))


def _prediction(res: LocalizeResult) -> Prediction:
    x, y, yaw = (float(v) for v in res.pose)
    return Prediction(x=x, y=y, yaw=yaw, quality=res.quality, valid=res.valid, mode=res.mode,
                      n_hits=res.fit.n_hits, n_inliers=res.fit.n_inliers,
                      position_std_m=res.fit.position_std_m if math.isfinite(res.fit.position_std_m) else None,
                      alternatives=[tuple(float(v) for v in a) for a in res.alternatives],
                      trackable=res.trackable, reason=res.status)


class PaperPredictor:
    """The paper network (dense or sparse graph): x, y only."""

    def __init__(self, model: ModelFile, providers: Sequence[str] | None = None, threads: int = 1) -> None:
        self.manifest = model.manifest
        if self.manifest.input.kind not in PAPER_KINDS:
            raise ManifestError(f"{model.path.name}: input kind {self.manifest.input.kind!r} is not a "
                                "paper-network input")
        try:
            self.court = load_court(self.manifest.court)
        except (OSError, ValueError) as exc:
            raise ManifestError(f"unknown court {self.manifest.court!r}: {exc}") from None
        self.session = _session(model, providers, threads)
        self.names = [t.name for t in self.manifest.input.tensors]
        self.shape = self.manifest.input.tensors[0].shape
        self.crop_top = self.manifest.preprocessing.crop_top

    def predict(self, hits: np.ndarray, width: int, height: int,
                previous: Optional[Prediction | Sequence[float]] = None) -> Prediction:
        pre = self.manifest.preprocessing
        if (width, height) != (pre.frame_width, pre.frame_height):
            raise ValueError(f"frame {width}x{height} does not match the model's {pre.frame_width}x{pre.frame_height}")
        h = _as_hits(hits)
        if self.manifest.input.kind == "dense_image":
            feed = self._dense_feed(hits_to_dense_input(h, height, width, self.crop_top, pre.dot_radius))
        else:
            feed = self._sparse_feed(*hits_to_sparse_input(h, height, width, self.crop_top, pre.dot_radius))
        xy = self.run(feed)
        return Prediction(x=float(xy[0]), y=float(xy[1]), yaw=None, quality=1.0, valid=True, mode="network",
                          n_hits=len(h))

    def track(self, hits: np.ndarray, width: int, height: int, state: object,
              t: float | None = None, marks: np.ndarray | None = None) -> tuple[Prediction, object]:
        """The network sees each frame alone: tracking is predicting, and there is no state (nor marks)."""
        return self.predict(hits, width, height), None

    def dots_feed(self, dots: np.ndarray) -> dict[str, np.ndarray]:
        """The session inputs for one full-frame 0/1 dot image (the seed datasets' form of the input)."""
        if self.manifest.input.kind == "dense_image":
            return self._dense_feed(dense_input(dots, self.crop_top))
        return self._sparse_feed(*sparse_input(dots, self.crop_top))

    def run(self, feed: dict[str, np.ndarray]) -> np.ndarray:
        """(x, y) for one feed."""
        return self.session.run(None, feed)[0].reshape(-1)[:2]

    def _dense_feed(self, dense: np.ndarray) -> dict[str, np.ndarray]:
        # [1, H, W] for the MLP, [1, 1, H, W] for the CNN baselines
        return {self.names[0]: dense.reshape([d if isinstance(d, int) else -1 for d in self.shape])}

    def _sparse_feed(self, indices: np.ndarray, values: np.ndarray) -> dict[str, np.ndarray]:
        return {self.names[0]: indices, self.names[1]: values}


def load_predictor(path: Path | str | ModelFile, providers: Sequence[str] | None = None, threads: int = 1,
                   config: LocalizerConfig | None = None) -> Predictor:
    """A predictor for a package folder (or its model.onnx) or a paper-network .onnx file.

    Raises ManifestError for a file without a usable manifest, so a service can refuse it and keep the
    model it has.
    """
    if isinstance(path, ModelFile):
        model = path
    else:
        path = Path(path)
        onnx_path = path / MODEL_FILE if path.is_dir() else path
        if not onnx_path.is_file():
            raise ManifestError(f"no model at {path} (a package folder or an .onnx file)")
        model = ModelFile.read(onnx_path)
    kind = model.manifest.input.kind
    if kind == "scan_hits":
        return GeometricPredictor(model, providers, threads, config)
    if kind in PAPER_KINDS:
        return PaperPredictor(model, providers, threads)
    raise ManifestError(f"{model.path.name}: no predictor for input kind {kind!r}")
