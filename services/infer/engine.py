"""Loading a stored model into a ready-to-serve predictor, and refusing the ones that must not serve.

Validation runs off the hot path, before a swap: the manifest is readable and its weights' sha256
matches, the graph's signature matches the manifest, a signature file verifies (when required), and
golden inputs give finite poses on the court within the latency budget. Only then is it warmed up.
"""
from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from courtloc.services.infer.config import InferConfig

if TYPE_CHECKING:
    from courtloc.localizer.manifest import Manifest
    from courtloc.sim.court import Court
from courtloc.services.infer.golden import GoldenSets
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


def load_model(stored: StoredModel, config: InferConfig, golden: GoldenSets | None,
               pushed: bool = False) -> LoadedModel:
    """Load and (when `golden` is given) validate; raises ModelRefused with the reason.

    `pushed`: the model is entering the store, so its signature is checked (when required). Versions
    already in the store were checked when they came in, and the bundled default ships unsigned.
    """
    from courtloc.localizer.manifest import ManifestError, read_manifest, verify_weights
    from courtloc.localizer.predictor import load_predictor
    from courtloc.sim.court import load_court

    path = stored.model_path
    try:
        manifest = read_manifest(path)
    except ManifestError as exc:
        raise ModelRefused(f"manifest: {exc}") from None
    except Exception as exc:  # a truncated or non-ONNX file fails inside onnx's parser
        raise ModelRefused(f"not a readable ONNX model: {type(exc).__name__}: {exc}") from None
    if golden is not None:
        if pushed:
            _check_signature_file(stored.folder, config)
        check_graph_signature(path, manifest)
        try:
            verify_weights(path)
        except ManifestError as exc:
            raise ModelRefused(f"sha256: {exc}") from None
        except Exception as exc:
            raise ModelRefused(f"weights unreadable: {type(exc).__name__}: {exc}") from None
    mismatch = deployment_mismatch(manifest, config)
    if mismatch:
        raise ModelRefused(mismatch)
    try:
        predictor = load_predictor(stored.folder, providers=available_providers(config.providers),
                                   threads=config.threads)
    except Exception as exc:  # onnxruntime raises its own types for bad graphs and wrong shapes
        raise ModelRefused(f"cannot load: {type(exc).__name__}: {exc}") from None
    localizer = getattr(predictor, "localizer", None)
    if config.drift_mps is not None and localizer is not None:
        localizer.config.acquire = localizer.config.acquire.model_copy(update={"motion_sigma_mps": config.drift_mps})
    try:
        court = load_court(manifest.court)
    except Exception as exc:
        raise ModelRefused(f"unknown court {manifest.court!r}: {exc}") from None
    loaded = LoadedModel(stored.ref, predictor, court, manifest.input.kind)
    if golden is not None:
        _run_golden(loaded, config, golden)
    return loaded


def deployment_mismatch(manifest: "Manifest", config: InferConfig) -> str:
    """Why a model does not fit this deployment's court or camera ('' when it does, or nothing is set)."""
    for what, want, have in (("court", config.court, manifest.court), ("camera", config.camera, manifest.camera)):
        if want is not None and have != want:
            return f"model is for {what} {have!r}, this deployment's {what} is {want!r}"
    return ""


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


def _run_golden(model: LoadedModel, config: InferConfig, golden: GoldenSets) -> None:
    manifest = model.manifest
    try:
        frames = golden.get(manifest.court, manifest.camera)
    except Exception as exc:
        raise ModelRefused(f"no golden inputs for court {manifest.court!r} / camera {manifest.camera!r}: {exc}") \
            from None
    timings = []
    # The first call warms the session up from a cold start (no previous pose) and is not timed. The
    # timed calls run as frames are served at frame rate, tracking from a previous pose (a tracking
    # model's cold-start search is many times slower and happens once, not per frame).
    for previous, frame in [(None, frames[0]), *((f.pose, f) for f in frames)]:
        start = time.perf_counter()
        try:
            pred = model.predictor.predict(frame.hits, frame.width, frame.height, previous=previous)
        except Exception as exc:
            raise ModelRefused(f"golden input failed: {type(exc).__name__}: {exc}") from None
        timings.append(time.perf_counter() - start)
        values = [pred.x, pred.y] + ([] if pred.yaw is None else [pred.yaw])
        if not all(math.isfinite(v) for v in values):
            raise ModelRefused(f"golden input gave a non-finite pose {values}")
        if not is_on_court(model.court, pred.x, pred.y, config.on_court_margin_m):
            raise ModelRefused(f"golden input gave a pose off the court ({pred.x:.2f}, {pred.y:.2f})")
    median_ms = float(np.median(timings[1:])) * 1e3
    if median_ms > config.golden_latency_budget_ms:
        raise ModelRefused(f"too slow: {median_ms:.1f} ms per frame > budget {config.golden_latency_budget_ms} ms")
    log.info("model %s validated: golden median %.2f ms", model.ref, median_ms)
