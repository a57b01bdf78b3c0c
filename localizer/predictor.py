"""The runtime predictor: a model file or package in, `predict(hits, width, height, previous)` out.

What the infer service calls. The manifest's input kind decides how hits are fed:
- 'scan_hits' (a geometric localizer package folder): the package's ONNX turns hits into floor points,
  then the fit (courtloc.localizer.geometric) gives x, y, yaw, quality. `previous` enables tracking.
  With the compiled kernel built (fit_kernel.c), hits -> floor points is a lookup into the ONNX file's
  own floor table, fused with the per-hit geometry in one C call (an onnxruntime run alone costs more
  than the whole compiled fit); without it, onnxruntime and numpy as before.
- 'dense_image' / 'sparse_hits' (the paper network, an .onnx file): hits are drawn as the dot image
  (courtloc.localizer.paper_input) and the network gives x, y; no yaw; quality 1 (it has no self-check).
Stateless: the caller keeps the previous pose (e.g. the last valid Prediction).
"""
from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import Optional, Protocol, Sequence

import numpy as np
from pydantic import BaseModel, Field

from courtloc.localizer.manifest import Manifest, ManifestError, read_manifest

log = logging.getLogger(__name__)
PAPER_KINDS = ("dense_image", "sparse_hits")


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
    reason: str = ""  # why not valid beyond the fit's quality: "ambiguous", "searching", "confirming"


class Predictor(Protocol):
    manifest: Manifest

    def predict(self, hits: np.ndarray, width: int, height: int,
                previous: Optional[Prediction | Sequence[float]] = None) -> Prediction: ...


def _session(path: Path, providers: Sequence[str] | None, threads: int):
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    return ort.InferenceSession(str(path), options, providers=list(providers or ["CPUExecutionProvider"]))


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


def _floor_table(model_path: Path, shape: tuple[int, int]) -> np.ndarray:
    """The package ONNX's floor table (the initializer onnx_graph.build_graph stores), (H * W, 2) float32."""
    import onnx
    from onnx import numpy_helper

    for init in onnx.load(str(model_path)).graph.initializer:
        if init.name == "floor_table":
            table = np.ascontiguousarray(numpy_helper.to_array(init), np.float32)
            if table.shape != (shape[0] * shape[1], 2):
                raise ManifestError(f"{model_path}: floor table {table.shape} does not match {shape[1]}x{shape[0]}")
            return table
    raise ManifestError(f"{model_path}: no floor_table initializer")


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
    def __init__(self, folder: Path, providers: Sequence[str] | None = None, threads: int = 1,
                 config=None) -> None:
        from courtloc.localizer.fit import kernel_active
        from courtloc.localizer.geometric import GeometricLocalizer
        from courtloc.localizer.package import load_package

        self._kernel_active = kernel_active
        self.package = load_package(folder, config)
        self.manifest = self.package.manifest
        self.session = _session(self.package.model_path, providers, threads)
        self.localizer = GeometricLocalizer(self.package.court, self.package.camera, self.package.config)
        self.width, self.height = self.package.camera.width, self.package.camera.height
        self.floor_table = _floor_table(self.package.model_path, (self.height, self.width))

    def floor_points(self, hits: np.ndarray) -> np.ndarray:
        """The ONNX graph's answer: (N, 2) float32 floor points, NaN where a hit sees no floor."""
        return self.session.run(None, {"hits": _as_hits(hits)})[0]

    def projected_hits(self, hits: np.ndarray):  # -> projection.ProjectedHits
        """The fit's per-hit geometry: compiled table lookup when the kernel runs, else onnxruntime + numpy."""
        if self._kernel_active():
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

    def track(self, hits: np.ndarray, width: int, height: int, state, t: float | None = None):  # noqa: ANN001
        """One frame of a motion-filtered track (`GeometricLocalizer.track`): (Prediction, next state).

        `state` is what the previous call returned (None to start: the frame is a global search); t is the
        frame's capture time in seconds on one clock (None: frames a nominal period apart)."""
        self._check_size(width, height)
        step = self.localizer.track(self.projected_hits(hits), state, t)
        return _prediction(step.result), step.state


def _prediction(res) -> Prediction:  # noqa: ANN001 - geometric.LocalizeResult
    x, y, yaw = (float(v) for v in res.pose)
    return Prediction(x=x, y=y, yaw=yaw, quality=res.quality, valid=res.valid, mode=res.mode,
                      n_hits=res.fit.n_hits, n_inliers=res.fit.n_inliers,
                      position_std_m=res.fit.position_std_m if math.isfinite(res.fit.position_std_m) else None,
                      alternatives=[tuple(float(v) for v in a) for a in res.alternatives],
                      trackable=res.trackable, reason=res.status)


class PaperPredictor:
    """The paper network (dense or sparse graph): x, y only."""

    def __init__(self, path: Path, providers: Sequence[str] | None = None, threads: int = 1) -> None:
        self.manifest = read_manifest(path)
        if self.manifest.input.kind not in PAPER_KINDS:
            raise ManifestError(f"{path}: input kind {self.manifest.input.kind!r} is not a paper-network input")
        self.session = _session(path, providers, threads)
        self.names = [t.name for t in self.manifest.input.tensors]
        self.shape = self.manifest.input.tensors[0].shape
        self.crop_top = self.manifest.preprocessing.crop_top

    def predict(self, hits: np.ndarray, width: int, height: int,
                previous: Optional[Prediction | Sequence[float]] = None) -> Prediction:
        from courtloc.localizer import paper_input

        pre = self.manifest.preprocessing
        if (width, height) != (pre.frame_width, pre.frame_height):
            raise ValueError(f"frame {width}x{height} does not match the model's {pre.frame_width}x{pre.frame_height}")
        h = _as_hits(hits)
        if self.manifest.input.kind == "dense_image":
            dense = paper_input.hits_to_dense_input(h, height, width, self.crop_top, pre.dot_radius)
            feed = {self.names[0]: dense.reshape([d if isinstance(d, int) else -1 for d in self.shape])}
        else:
            idx, val = paper_input.hits_to_sparse_input(h, height, width, self.crop_top, pre.dot_radius)
            feed = {self.names[0]: idx, self.names[1]: val}
        out = self.session.run(None, feed)[0].reshape(-1)
        return Prediction(x=float(out[0]), y=float(out[1]), yaw=None, quality=1.0, valid=True, mode="network",
                          n_hits=len(h))


def load_predictor(path: Path | str, providers: Sequence[str] | None = None, threads: int = 1,
                   config=None) -> Predictor:
    """A predictor for a package folder (or its model.onnx) or a paper-network .onnx file.

    Raises ManifestError for a file without a usable manifest, so a service can refuse it and keep the
    model it has.
    """
    path = Path(path)
    onnx_path = path / "model.onnx" if path.is_dir() else path
    if not onnx_path.is_file():
        raise ManifestError(f"no model at {path} (a package folder or an .onnx file)")
    manifest = read_manifest(onnx_path)
    if manifest.input.kind == "scan_hits":
        return GeometricPredictor(onnx_path.parent, providers, threads, config)
    if manifest.input.kind in PAPER_KINDS:
        return PaperPredictor(onnx_path, providers, threads)
    raise ManifestError(f"{onnx_path}: no predictor for input kind {manifest.input.kind!r}")
