"""Loading a stored model into a ready-to-serve predictor, and refusing the ones that must not serve.

Validation runs off the hot path, before a swap, in a child process with a memory limit and a
deadline (services/infer/sandbox.py): the manifest is readable and its weights' sha256 matches, the
graph's signature matches the manifest, a signature file verifies (when required), and the package's
own golden inputs give, within the latency budget, poses within the accuracy the manifest states
and the deployment's limits. Only then is it loaded here and warmed up on the same golden inputs.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from courtloc.services.infer.config import InferConfig

if TYPE_CHECKING:
    from courtloc.localizer.manifest import Manifest
    from courtloc.sim.court import Court
from courtloc.services.infer.store import ModelRef, StoredModel

log = logging.getLogger(__name__)

_PROVIDER_NAMES = {"tensorrt": "TensorrtExecutionProvider", "cuda": "CUDAExecutionProvider",
                   "cpu": "CPUExecutionProvider"}


class ModelRefused(RuntimeError):
    """A candidate that failed validation; the message is the reason given back to the pusher."""


@dataclass
class LoadedModel:
    ref: ModelRef
    predictor: object  # courtloc.localizer.predictor.Predictor
    court: object  # courtloc.sim.court.Court, for the on-court check
    input_kind: str

    @property
    def manifest(self) -> "Manifest":
        return self.predictor.manifest


def available_providers(preferred: list[str]) -> list[str]:
    import onnxruntime

    installed = set(onnxruntime.get_available_providers())
    chosen = [_PROVIDER_NAMES[p] for p in preferred if _PROVIDER_NAMES[p] in installed]
    return chosen or ["CPUExecutionProvider"]


def is_on_court(court: "Court", x: float, y: float, margin: float) -> bool:
    return bool(court.contains(x, y, margin=margin))


def load_model(stored: StoredModel, config: InferConfig, validate: bool = False,
               pushed: bool = False) -> LoadedModel:
    """Load, after validating it in a bounded child process when `validate`; raises ModelRefused with the reason.

    `pushed`: the model is entering the store, so its signature is checked (when required). Versions
    already in the store were checked when they came in, and the bundled default ships unsigned.
    """
    from courtloc.localizer.manifest import ManifestError, read_manifest
    from courtloc.localizer.predictor import load_predictor
    from courtloc.sim.court import load_court

    if validate:
        from courtloc.services.infer.sandbox import validate_in_child

        validate_in_child(stored.folder, config, pushed)
    path = stored.model_path
    try:
        manifest = read_manifest(path)
    except ManifestError as exc:
        raise ModelRefused(f"manifest: {exc}") from None
    except Exception as exc:  # a truncated or non-ONNX file fails inside onnx's parser
        raise ModelRefused(f"not a readable ONNX model: {type(exc).__name__}: {exc}") from None
    try:
        predictor = load_predictor(stored.folder, providers=available_providers(config.providers),
                                   threads=config.threads)
    except Exception as exc:  # onnxruntime raises its own types for bad graphs and wrong shapes
        raise ModelRefused(f"cannot load: {type(exc).__name__}: {exc}") from None
    try:
        court = load_court(manifest.court)
    except Exception as exc:
        raise ModelRefused(f"unknown court {manifest.court!r}: {exc}") from None
    loaded = LoadedModel(stored.ref, predictor, court, manifest.input.kind)
    if validate:
        _warm_up(loaded, stored.folder)
    return loaded


def _warm_up(model: LoadedModel, folder: Path) -> None:
    """The golden inputs once through the session that will serve: its first runs are the slow ones."""
    from courtloc.localizer.golden import run_golden
    from courtloc.services.infer.golden import package_golden

    try:
        run_golden(model.predictor, package_golden(folder, model.manifest))
    except Exception as exc:  # validated in the child a moment ago: only a changed file gets here
        raise ModelRefused(f"golden inputs failed after validation: {type(exc).__name__}: {exc}") from None


def validate_candidate(folder: Path, config: InferConfig, pushed: bool) -> str:
    """Every check on the model in `folder` (run in the validation child); ModelRefused with the reason,
    else a one-line summary of its golden numbers."""
    from courtloc.localizer.manifest import ManifestError, read_manifest, verify_weights
    from courtloc.localizer.predictor import load_predictor
    from courtloc.sim.court import load_court

    path = folder / "model.onnx"
    try:
        manifest = read_manifest(path)
    except ManifestError as exc:
        raise ModelRefused(f"manifest: {exc}") from None
    except Exception as exc:  # a truncated or non-ONNX file fails inside onnx's parser
        raise ModelRefused(f"not a readable ONNX model: {type(exc).__name__}: {exc}") from None
    if pushed:
        _check_signature_file(folder, config)
    check_graph_signature(path, manifest)
    try:
        verify_weights(path)
    except ManifestError as exc:
        raise ModelRefused(f"sha256: {exc}") from None
    except Exception as exc:
        raise ModelRefused(f"weights unreadable: {type(exc).__name__}: {exc}") from None
    try:
        predictor = load_predictor(folder, providers=available_providers(config.providers), threads=config.threads)
    except Exception as exc:  # onnxruntime raises its own types for bad graphs and wrong shapes
        raise ModelRefused(f"cannot load: {type(exc).__name__}: {exc}") from None
    try:
        court = load_court(manifest.court)
    except Exception as exc:
        raise ModelRefused(f"unknown court {manifest.court!r}: {exc}") from None
    return _run_golden(LoadedModel(ModelRef(name="candidate", version=1), predictor, court, manifest.input.kind),
                       folder, config)


def check_graph_signature(path: Path, manifest: "Manifest") -> None:
    """The graph's inputs are exactly the manifest's tensors: names, element types and fixed dimensions."""
    import onnx
    from onnx.helper import tensor_dtype_to_np_dtype

    graph = onnx.load(str(path), load_external_data=False).graph
    weights = {t.name for t in graph.initializer}
    inputs = {i.name: i for i in graph.input if i.name not in weights}
    wanted = {t.name: t for t in manifest.input.tensors}
    if set(inputs) != set(wanted):
        raise ModelRefused(f"graph inputs {sorted(inputs)} do not match the manifest's {sorted(wanted)}")
    for name, spec in wanted.items():
        tensor_type = inputs[name].type.tensor_type
        dtype = tensor_dtype_to_np_dtype(tensor_type.elem_type).name
        dims = [d.dim_value if d.HasField("dim_value") else d.dim_param for d in tensor_type.shape.dim]
        fixed_mismatch = any(isinstance(want, int) and isinstance(have, int) and want != have
                             for want, have in zip(spec.shape, dims))
        if dtype != spec.dtype or len(dims) != len(spec.shape) or fixed_mismatch:
            raise ModelRefused(f"input {name!r} is {dtype}{dims}, the manifest says {spec.dtype}{spec.shape}")


def _check_signature_file(folder: Path, config: InferConfig) -> None:
    if not config.require_signature:
        return
    from courtloc.security.signing import ModelSignatureError, signature_path, verify_model

    if config.signing_public_key is None:
        raise ModelRefused("signature required but no signing_public_key is configured")
    model = folder / "model.onnx"
    try:
        verify_model(model, signature_path(model), config.signing_public_key)
    except ModelSignatureError as exc:
        raise ModelRefused(f"signature: {exc}") from None


def _run_golden(model: LoadedModel, folder: Path, config: InferConfig) -> str:
    """The package's golden inputs against their true poses: refused with the numbers past the accuracy
    the manifest states or the deployment's limit, off the court, not valid, or too slow."""
    from courtloc.localizer.golden import run_golden
    from courtloc.services.infer.golden import GoldenUnavailable, accuracy_limits, package_golden

    manifest = model.manifest
    try:
        frames = package_golden(folder, manifest)
    except GoldenUnavailable as exc:
        raise ModelRefused(f"golden inputs: {exc}") from None
    if len(frames) < config.golden_min_frames:
        raise ModelRefused(f"golden inputs: {len(frames)} frames, the deployment requires at least "
                           f"{config.golden_min_frames}")
    try:
        run = run_golden(model.predictor, frames)
    except Exception as exc:
        raise ModelRefused(f"golden input failed: {type(exc).__name__}: {exc}") from None
    (position_limit, position_source), (yaw_limit, yaw_source) = accuracy_limits(manifest, config)
    for i, frame in enumerate(frames):
        x, y, yaw = run.answers[i]
        truth = ", ".join(f"{v:.2f}" for v in frame.pose)
        values = [x, y] + ([] if yaw is None else [yaw])
        if not all(math.isfinite(v) for v in values):
            raise ModelRefused(f"golden frame {i} at ({truth}) gave a non-finite pose {values}")
        if not is_on_court(model.court, x, y, config.on_court_margin_m):
            raise ModelRefused(f"golden frame {i} at ({truth}) gave a pose off the court ({x:.2f}, {y:.2f})")
        error = run.position_error_m[i]
        if error > position_limit:
            raise ModelRefused(f"golden frame {i} at ({truth}) answered ({x:.2f}, {y:.2f}): position error "
                               f"{error:.3f} m > {position_limit:g} m ({position_source})")
        yaw_error = run.yaw_error_deg[i]
        if yaw_error is not None and yaw_limit is not None and yaw_error > yaw_limit:
            raise ModelRefused(f"golden frame {i} at ({truth}) answered yaw {yaw:.3f} rad: yaw error "
                               f"{yaw_error:.2f} deg > {yaw_limit:g} deg ({yaw_source})")
        if not run.valid[i]:
            raise ModelRefused(f"golden frame {i} at ({truth}): the model calls its own pose not valid")
    median_ms = float(np.median(run.seconds)) * 1e3
    if median_ms > config.golden_latency_budget_ms:
        raise ModelRefused(f"too slow: {median_ms:.1f} ms per frame > budget {config.golden_latency_budget_ms} ms")
    yaw_max = run.max_yaw_error_deg()
    summary = (f"golden: {len(frames)} frames, position error max {max(run.position_error_m):.4f} m "
               f"(limit {position_limit:g} m)" + ("" if yaw_max is None else f", yaw max {yaw_max:.3f} deg")
               + f", median {median_ms:.2f} ms")
    log.info("candidate validated: %s", summary)
    return summary
