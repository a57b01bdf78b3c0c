"""Loading a stored model into a ready-to-serve predictor, and refusing the ones that must not serve.

Validation runs off the hot path, before a swap, in a child process with a memory limit and a
deadline (services/infer/sandbox.py runs services/infer/validation.py there). Only a model that passed
is loaded here (its file parsed once) and warmed up on the same golden inputs.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

from courtloc.common.heap import return_free_heap
from courtloc.localizer.golden import run_golden
from courtloc.localizer.manifest import Manifest
from courtloc.localizer.predictor import Predictor
from courtloc.services.infer.config import InferConfig
from courtloc.services.infer.golden import package_golden
from courtloc.services.infer.sandbox import validate_in_child
from courtloc.services.infer.store import ModelRef, StoredModel
from courtloc.services.infer.validation import ModelRefused, deployment_mismatch, predictor_for, read_model_file
from courtloc.world.court import Court

log = logging.getLogger(__name__)


@dataclass
class LoadedModel:
    ref: ModelRef
    predictor: Predictor
    input_kind: str

    @property
    def manifest(self) -> Manifest:
        return self.predictor.manifest

    @property
    def court(self) -> Court:
        """The court the model comes with (its package's court.json), for the on-court check."""
        return self.predictor.court


def load_model(stored: StoredModel, config: InferConfig, validate: bool = False,
               pushed: bool = False) -> LoadedModel:
    """Load, after validating it in a bounded child process when `validate`; raises ModelRefused with the reason.

    `pushed`: the model is entering the store, so its signature is checked (when required). Versions
    already in the store were checked when they came in, and the bundled default ships unsigned.
    """
    if validate:
        validate_in_child(stored.folder, config, pushed)
    model_file = read_model_file(stored.model_path)  # the one parse of the graph in this process
    mismatch = deployment_mismatch(model_file.manifest, config)
    if mismatch:
        raise ModelRefused(mismatch)
    predictor = predictor_for(model_file, config)
    localizer = getattr(predictor, "localizer", None)
    if config.drift_mps is not None and localizer is not None:
        localizer.config.acquire = localizer.config.acquire.model_copy(update={"motion_sigma_mps": config.drift_mps})
    loaded = LoadedModel(stored.ref, predictor, model_file.manifest.input.kind)
    if validate:
        _warm_up(loaded, stored.folder)
    return_free_heap()  # the field's build scratch: ~90 MB the stage would otherwise keep for good
    return loaded


def _warm_up(model: LoadedModel, folder: Path) -> None:
    """The golden inputs once through the session that will serve: its first runs are the slow ones."""
    try:
        run_golden(model.predictor, package_golden(folder, model.manifest))
    except Exception as exc:  # validated in the child a moment ago: only a changed file gets here
        raise ModelRefused(f"golden inputs failed after validation: {type(exc).__name__}: {exc}") from None
