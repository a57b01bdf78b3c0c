"""Export a trained paper network (OUT/model.pt) to its dense and sparse ONNX graphs, each with a manifest
and its golden inputs beside it (NAME-KIND.golden.npz: twin frames of the court at known poses, pushed
with the model as golden.npz)."""
from __future__ import annotations

import logging
from pathlib import Path
from typing import Iterable

import numpy as np
import onnx
import torch

from courtloc.lab.golden_build import breaches, render_golden, write_golden
from courtloc.localizer.golden import run_golden, sidecar_path
from courtloc.localizer.manifest import (
    InputSpec,
    Manifest,
    OutputSpec,
    TensorSpec,
    TrainingData,
    attach_manifest,
    runtime_preprocessing,
)
from courtloc.localizer.model_file import ModelFile
from courtloc.localizer.predictor import PaperPredictor
from courtloc.training import paper_onnx
from courtloc.world.camera import load_camera
from courtloc.world.court import load_court

log = logging.getLogger(__name__)


def load_weights(weights_file: Path) -> dict:
    """{'weights', 'input_shape', 'crop_top', 'summary'} from OUT/model.pt, or from a training checkpoint
    (OUT/last.pt: the model after its last finished epoch; memory-mapped, the optimiser state is not read)."""
    state = torch.load(weights_file, weights_only=False, mmap=True)
    if "weights" in state:
        return state
    if "model" not in state:
        raise ValueError(f"{weights_file} is neither OUT/model.pt nor a training checkpoint OUT/last.pt")
    from courtloc.training.paper_model import SparsePaperNet  # needs torch: the train extra

    table = state["model"]["first.weight"]
    config = state.get("config", {})
    height, width = state.get("input_shape") or _shape_from_pixels(table.shape[0])
    model = SparsePaperNet.__new__(SparsePaperNet)
    torch.nn.Module.__init__(model)  # no random init of a 734 MB table only to overwrite it
    model.n_pixels = table.shape[0]
    model.first = torch.nn.EmbeddingBag(table.shape[0], table.shape[1], mode="sum", sparse=True, _weight=table)
    model.first_bias = torch.nn.Parameter(state["model"]["first_bias"])
    from courtloc.training.paper_model import _tail  # needs torch: the train extra

    model.tail = _tail()
    model.tail.load_state_dict({k[len("tail."):]: v for k, v in state["model"].items() if k.startswith("tail.")})
    history = state.get("history", [])
    summary = {"train_fingerprint": "", "train_recordings": config.get("train_recordings") or [],
               "n_train": 0, "metrics": {}, "history": history,
               "note": f"checkpoint after epoch {state.get('epoch')} of {config.get('epochs')}"}
    return {"weights": model.numpy_weights(), "input_shape": [height, width],
            "crop_top": int(config.get("crop_top", 200)), "summary": summary}


def _shape_from_pixels(n_pixels: int, width: int = 640) -> tuple[int, int]:
    """Checkpoints written before input_shape was stored: the paper's 640-wide crop."""
    if n_pixels % width:
        raise ValueError(f"cannot tell the input shape of a {n_pixels}-pixel checkpoint")
    return n_pixels // width, width


def paper_manifest(kind: str, summary: dict, height: int, width: int, crop_top: int, name: str,
                   version: int, court: str, camera: str) -> Manifest:
    if kind == "dense":
        inputs = InputSpec(kind="dense_image", description="bottom crop of the 0/1 edge-dot image, float32",
                           tensors=[TensorSpec(name=paper_onnx.DENSE_INPUT, dtype="float32", shape=[1, height, width])])
    else:
        inputs = InputSpec(kind="sparse_hits",
                           description="non-zero pixels of the crop: row-major flat index (row*W+col, row "
                                       "counted from crop_top) and value; see courtloc.localizer.paper_input",
                           tensors=[TensorSpec(name=paper_onnx.SPARSE_INDICES, dtype="int64", shape=["K"]),
                                    TensorSpec(name=paper_onnx.SPARSE_VALUES, dtype="float32", shape=["K"])])
    return Manifest(
        name=f"{name}-{kind}", version=version, input=inputs,
        preprocessing=runtime_preprocessing(width, height + crop_top, crop_top), court=court, camera=camera,
        outputs=[OutputSpec(name=paper_onnx.OUTPUT, components=["x", "y"], units=["m", "m"])],
        training_data=TrainingData(fingerprint=summary.get("train_fingerprint", ""),
                                   recordings=summary.get("train_recordings", []),
                                   n_frames=summary.get("n_train", 0),
                                   description="paper network, Adam 1e-4 (lazy Adam on layer 1), batch 8, MSE"),
        metrics={k: {m: float(v) for m, v in d.items()} for k, d in summary.get("metrics", {}).items()},
        extra={"architecture": "Flatten-Linear(N,1024)-ReLU-256-ReLU-64-ReLU-2", "graph": kind},
    )


def _golden_frames(court: str, camera: str, width: int, height: int):  # noqa: ANN202 - list[GoldenFrame] | None
    """Twin frames for the golden inputs, or None when the camera's frames are not the network's input size."""

    cam = load_camera(camera)
    if (cam.width, cam.height) != (width, height):
        log.warning("no golden inputs: camera %s gives %dx%d frames, the network takes %dx%d; a robot will "
                    "refuse this model", camera, cam.width, cam.height, width, height)
        return None
    return render_golden(load_court(court), cam)


def stated_accuracy(errors: list[float], step_m: float = 0.05) -> float:
    """What an export states when not told: its worst golden error plus a quarter, rounded up to 5 cm."""
    worst = max(errors)
    if not np.isfinite(worst):
        raise ValueError("the exported graph gives a non-finite pose on its golden inputs")
    return float(np.ceil(worst * 1.25 / step_m) * step_m) or step_m


def _attach_golden(model: onnx.ModelProto, manifest: Manifest, path: Path, frames, golden_error_m: float | None) -> Manifest:  # noqa: ANN001
    """Save the golden frames beside `path` and name them, with the accuracy stated on them, in `manifest`."""

    attach_manifest(model, manifest)
    onnx.save(model, str(path))
    run = run_golden(PaperPredictor(ModelFile.read(path)), frames)
    limit = golden_error_m if golden_error_m is not None else stated_accuracy(run.position_error_m)
    golden = write_golden(sidecar_path(path), frames, limit, None)
    problems = breaches(run, golden)
    if problems:
        raise ValueError(f"{path}: the exported graph misses the accuracy it states: " + "; ".join(problems))
    log.info("%s: golden position error max %.3f m, stated %.2f m", path.name, max(run.position_error_m), limit)
    return manifest.model_copy(update={"golden": golden})


def export_paper(weights_file: Path, out_dir: Path, kinds: Iterable[str] = ("dense", "sparse"),
                 name: str = "paper-mlp", version: int = 1, court: str = "seed-gazebo",
                 camera: str = "seed-gazebo", golden_error_m: float | None = None) -> dict[str, Path]:
    """golden_error_m: the accuracy the manifests state on the golden inputs (default: `stated_accuracy`
    of what the exported graph achieves on them)."""
    state = load_weights(weights_file)
    weights = {k: np.asarray(v, dtype=np.float32) for k, v in state["weights"].items()}
    height, width = state["input_shape"]
    out_dir.mkdir(parents=True, exist_ok=True)
    frames = _golden_frames(court, camera, width, height + state["crop_top"])
    written = {}
    for kind in kinds:
        if kind not in ("dense", "sparse"):
            raise ValueError(f"unknown graph kind {kind!r}")
        model = paper_onnx.build_dense(weights, height, width) if kind == "dense" else paper_onnx.build_sparse(weights)
        manifest = paper_manifest(kind, state["summary"], height, width, state["crop_top"], name, version, court,
                                  camera)
        path = out_dir / f"{name}-{kind}.onnx"
        if frames is not None:
            manifest = _attach_golden(model, manifest, path, frames, golden_error_m)
        attach_manifest(model, manifest)
        onnx.save(model, str(path))
        log.info("wrote %s", path)
        written[kind] = path
        del model
    return written
