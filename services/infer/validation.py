"""Every check a candidate model must pass before it may serve (run in the validation child,
services/infer/sandbox.py): its manifest and weights, its graph against the manifest, its signature
(when required), and its own golden inputs answered within the accuracy it states and the deployment's
limits, on the court, valid and in time. A refusal carries the reason with its numbers.
"""
from __future__ import annotations

import logging
import math
from pathlib import Path

import numpy as np
import onnxruntime
from onnx.helper import tensor_dtype_to_np_dtype

from courtloc.common.signing import ModelSignatureError, signature_path, verify_model
from courtloc.localizer.golden import run_golden
from courtloc.localizer.manifest import MODEL_FILE, Manifest, ManifestError
from courtloc.localizer.model_file import ModelFile
from courtloc.localizer.predictor import Predictor, load_predictor
from courtloc.services.infer.config import InferConfig, providers_for
from courtloc.services.infer.golden import GoldenUnavailable, accuracy_limits, package_golden
from courtloc.world.court import Court

log = logging.getLogger(__name__)

_PROVIDER_NAMES = {"tensorrt": "TensorrtExecutionProvider", "cuda": "CUDAExecutionProvider",
                   "cpu": "CPUExecutionProvider"}


class ModelRefused(RuntimeError):
    """A candidate that failed validation; the message is the reason given back to the pusher."""


def available_providers(preferred: list[str]) -> list[str]:
    installed = set(onnxruntime.get_available_providers())
    chosen = [_PROVIDER_NAMES[p] for p in preferred if _PROVIDER_NAMES[p] in installed]
    return chosen or ["CPUExecutionProvider"]


def is_on_court(court: Court, x: float, y: float, margin: float) -> bool:
    return bool(court.contains(x, y, margin=margin))


def read_model_file(path: Path) -> ModelFile:
    """The model file read and parsed once; ModelRefused when it has no usable manifest."""
    try:
        return ModelFile.read(path)
    except ManifestError as exc:
        raise ModelRefused(f"manifest: {exc}") from None


def deployment_mismatch(manifest: Manifest, config: InferConfig) -> str:
    """Why a model does not fit this deployment's court or camera ('' when it does, or nothing is set)."""
    for what, want, have in (("court", config.court, manifest.court), ("camera", config.camera, manifest.camera)):
        if want is not None and have != want:
            return f"model is for {what} {have!r}, this deployment's {what} is {want!r}"
    return ""


def predictor_for(model_file: ModelFile, config: InferConfig) -> Predictor:
    try:
        return load_predictor(model_file, providers=available_providers(providers_for(config, model_file.manifest.input.kind)),
                              threads=config.threads)
    except Exception as exc:  # onnxruntime raises its own types for bad graphs and wrong shapes
        raise ModelRefused(f"cannot load: {type(exc).__name__}: {exc}") from None


def validate_candidate(folder: Path, config: InferConfig, pushed: bool) -> str:
    """Every check on the model in `folder` (run in the validation child); ModelRefused with the reason,
    else a one-line summary of its golden numbers."""
    model_file = read_model_file(folder / MODEL_FILE)
    mismatch = deployment_mismatch(model_file.manifest, config)
    if mismatch:
        raise ModelRefused(mismatch)
    if pushed:
        _check_signature_file(folder, config)
    check_graph_signature(model_file)
    try:
        model_file.verify_weights()
    except ManifestError as exc:
        raise ModelRefused(f"sha256: {exc}") from None
    return _run_golden(predictor_for(model_file, config), folder, config)


def check_graph_signature(model: ModelFile) -> None:
    """The graph's inputs are exactly the manifest's tensors: names, element types and fixed dimensions."""
    manifest = model.manifest
    graph = model.proto.graph
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
    if config.signing_public_key is None:
        raise ModelRefused("signature required but no signing_public_key is configured")
    model = folder / MODEL_FILE
    try:
        verify_model(model, signature_path(model), config.signing_public_key)
    except ModelSignatureError as exc:
        raise ModelRefused(f"signature: {exc}") from None


def _run_golden(predictor: Predictor, folder: Path, config: InferConfig) -> str:
    """The package's golden inputs against their true poses: refused with the numbers past the accuracy
    the manifest states or the deployment's limit, off the court, not valid, or too slow."""
    manifest = predictor.manifest
    try:
        frames = package_golden(folder, manifest)
    except GoldenUnavailable as exc:
        raise ModelRefused(f"golden inputs: {exc}") from None
    if len(frames) < config.golden_min_frames:
        raise ModelRefused(f"golden inputs: {len(frames)} frames, the deployment requires at least "
                           f"{config.golden_min_frames}")
    try:
        run = run_golden(predictor, frames)
    except Exception as exc:
        raise ModelRefused(f"golden input failed: {type(exc).__name__}: {exc}") from None
    (position_limit, position_source), (yaw_limit, yaw_source) = accuracy_limits(manifest, config)
    for i, frame in enumerate(frames):
        x, y, yaw = run.answers[i]
        truth = ", ".join(f"{v:.2f}" for v in frame.pose)
        values = [x, y] + ([] if yaw is None else [yaw])
        if not all(math.isfinite(v) for v in values):
            raise ModelRefused(f"golden frame {i} at ({truth}) gave a non-finite pose {values}")
        if not is_on_court(predictor.court, x, y, config.on_court_margin_m):
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
