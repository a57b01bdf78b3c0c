"""The paper's CNN baselines: MobileNetV2 and EfficientNet-B0 with a 1-channel stem, regressing (x, y).

torchvision is an optional extra (`vision`); without it `build_baseline` raises BaselineUnavailable
and the tests skip. Same data, split, loss, optimiser and batch as the paper network; input the same
0/1 crop, as float32 [1, 1, H, W]. Exported with a manifest (input kind 'dense_image').

`downscale` k > 1 puts a k x k max-pool in front of the CNN: it is trained and exported with the network,
so the ONNX input (and every caller) stays the full crop while the CNN sees 1/k^2 of the pixels. Max,
not mean, because the input is thin 0/1 dots and a mean would fade them.
"""
from __future__ import annotations

import json
import logging
import time
from pathlib import Path

import numpy as np
import onnx
import torch
from torch import nn

from courtloc.lab.datasets import Dataset
from courtloc.lab.metrics import compute_metrics
from courtloc.localizer.manifest import InputSpec, TensorSpec, attach_manifest
from courtloc.training import paper_onnx

log = logging.getLogger(__name__)
ARCHES = ("mobilenet_v2", "efficientnet_b0")


class BaselineUnavailable(RuntimeError):
    """torchvision is not installed."""


def _one_channel_stem(conv: nn.Conv2d) -> nn.Conv2d:
    """The stem conv rebuilt for 1 input channel (same kernel, stride, padding and width)."""
    return nn.Conv2d(1, conv.out_channels, conv.kernel_size, conv.stride, conv.padding, bias=conv.bias is not None)


def build_baseline(arch: str, downscale: int = 1) -> nn.Module:
    try:
        import torchvision  # torchvision: the vision extra
    except ImportError as exc:
        raise BaselineUnavailable("the CNN baselines need torchvision (pip install '.[vision]')") from exc
    if arch == "mobilenet_v2":
        model = torchvision.models.mobilenet_v2(weights=None, num_classes=2)
        model.features[0][0] = _one_channel_stem(model.features[0][0])
    elif arch == "efficientnet_b0":
        model = torchvision.models.efficientnet_b0(weights=None, num_classes=2)
        model.features[0][0] = _one_channel_stem(model.features[0][0])
    else:
        raise ValueError(f"unknown baseline {arch!r}; choose from {ARCHES}")
    if downscale > 1:
        return nn.Sequential(nn.MaxPool2d(downscale), model)
    return model


def dense_batch(frames, which: np.ndarray) -> torch.Tensor:  # noqa: ANN001 - trainer.SparseFrames
    """[B, 1, H, W] float32 images rebuilt from the frames' non-zero pixels."""
    height, width = frames.shape
    out = torch.zeros(len(which), height * width)
    for row, k in enumerate(which):
        idx, val = frames.frame(int(k))
        out[row, torch.from_numpy(idx)] = torch.from_numpy(val)
    return out.view(len(which), 1, height, width)


def export_cnn(model: nn.Module, height: int, width: int, path: Path, manifest) -> Path:  # noqa: ANN001
    """ONNX (legacy TorchScript exporter, IR 8, opset 17) with the manifest attached."""
    model.eval()
    torch.onnx.export(model, (torch.zeros(1, 1, height, width),), str(path), input_names=[paper_onnx.DENSE_INPUT],
                      output_names=[paper_onnx.OUTPUT], opset_version=paper_onnx.OPSET, dynamo=False)
    proto = onnx.load(str(path))
    proto.ir_version = min(proto.ir_version, paper_onnx.IR_VERSION)
    manifest = manifest.model_copy(update={"input": InputSpec(
        kind="dense_image", description="bottom crop of the 0/1 edge-dot image, float32, NCHW",
        tensors=[TensorSpec(name=paper_onnx.DENSE_INPUT, dtype="float32", shape=[1, 1, height, width])])})
    attach_manifest(proto, manifest)
    onnx.save(proto, str(path))
    return path


def _predict(model: nn.Module, frames, batch_size: int = 16) -> np.ndarray:  # noqa: ANN001
    model.eval()
    out = []
    with torch.no_grad():
        for start in range(0, len(frames), batch_size):
            out.append(model(dense_batch(frames, np.arange(start, min(start + batch_size, len(frames))))).numpy())
    model.train()
    return np.concatenate(out).astype(np.float64)


def train_baseline(cfg, arch: str) -> dict:  # noqa: ANN001 - trainer.TrainConfig
    """Train one CNN baseline like the paper network (Adam, MSE, batch, epochs from cfg); export OUT/ARCH.onnx.

    cfg.frame_step / val_frame_step / downscale are the budget options (see TrainConfig); the per-epoch
    and summary metrics are on the strided frames, the full held-out numbers come from `courtloc eval`.
    """

    from tqdm import tqdm  # progress bars: tqdm comes with the train extra

    from courtloc.training.export import paper_manifest  # needs torch: the train extra
    from courtloc.training.trainer import HISTORY, SparseFrames, _split, plot_history  # needs torch: the train extra

    build_baseline(arch)  # fails fast, before loading data, when torchvision is absent
    cfg.out.mkdir(parents=True, exist_ok=True)
    dataset = Dataset(cfg.data, csv_path=cfg.csv, kind=cfg.kind)
    train_idx, val_idx = _split(dataset, cfg)
    log.info("%s: train frames %d (%s, every %d), validation frames %d (%s, every %d), downscale %d", arch,
             len(train_idx), sorted(set(dataset.recordings[train_idx])), cfg.frame_step, len(val_idx),
             sorted(set(dataset.recordings[val_idx])), cfg.val_frame_step, cfg.downscale)
    train_frames = SparseFrames(dataset, train_idx, cfg.crop_top, cfg.progress)
    val_frames = SparseFrames(dataset, val_idx, cfg.crop_top, cfg.progress) if len(val_idx) else None
    torch.manual_seed(cfg.seed)
    model = build_baseline(arch, cfg.downscale)
    optimiser = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    targets = torch.from_numpy(train_frames.targets)
    history = []
    for epoch in range(1, cfg.epochs + 1):
        order = np.random.default_rng([cfg.seed, epoch]).permutation(len(train_frames))
        running = 0.0
        started = time.perf_counter()
        starts = range(0, len(order), cfg.batch_size)
        for start in tqdm(starts, desc=f"{arch} epoch {epoch}/{cfg.epochs}", disable=not cfg.progress, unit="batch"):
            which = order[start:start + cfg.batch_size]
            loss = nn.functional.mse_loss(model(dense_batch(train_frames, which)), targets[which])
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
            running += float(loss.detach()) * len(which)
        entry = {"epoch": epoch, "train_loss": running / len(order), "train_seconds": time.perf_counter() - started}
        if val_frames is not None:
            val_metrics = compute_metrics(_predict(model, val_frames), val_frames.targets)
            entry.update(val_mse=val_metrics.mse, val_mean_err_m=val_metrics.mean_err_m)
        history.append(entry)
        log.info("%s epoch %s", arch, entry)
        plot_history(history, cfg.out / f"{arch}_loss_curve.png")
    height, width = train_frames.shape
    summary = {"arch": arch, "config": cfg.model_dump(mode="json"), "input_shape": [height, width],
               "history": history, "train_recordings": sorted(set(dataset.recordings[train_idx].tolist())),
               "val_recordings": sorted(set(dataset.recordings[val_idx].tolist())),
               "train_fingerprint": dataset.fingerprint(train_idx), "n_train": len(train_idx),
               "metrics": {"train": compute_metrics(_predict(model, train_frames), train_frames.targets).as_dict()}}
    if val_frames is not None:
        summary["metrics"]["val"] = compute_metrics(_predict(model, val_frames), val_frames.targets).as_dict()
    manifest = paper_manifest("dense", summary, height, width, cfg.crop_top, arch, 1, "seed-gazebo", "seed-gazebo")
    stem = f"{cfg.downscale}x{cfg.downscale} max-pool, " if cfg.downscale > 1 else ""
    training_data = manifest.training_data.model_copy(update={"description": (
        f"{arch} baseline, Adam {cfg.lr:g}, batch {cfg.batch_size}, {cfg.epochs} epochs, MSE, "
        f"every {cfg.frame_step} frame(s)")})
    export_cnn(model, height, width, cfg.out / f"{arch}.onnx", manifest.model_copy(update={
        "name": arch, "training_data": training_data,
        "extra": {"architecture": f"{stem}{arch}, 1-channel stem", "downscale": str(cfg.downscale)}}))
    (cfg.out / f"{arch}_{HISTORY}").write_text(json.dumps(summary, indent=1, default=str))
    return summary
