"""Training the paper network on a CPU through its exact sparse first layer.

Follows the paper: MSE on (x, y), Adam lr 1e-4, batch 8, 15 epochs, input the bottom crop of the 0/1
edge-dot image. One documented deviation: the first layer's weight is updated with lazy Adam
(courtloc.training.lazy_adam.LazyAdamRows), which only moves the rows (pixels) lit in the current batch, where dense Adam
would keep moving earlier-lit rows on their momentum. Everything else uses torch.optim.Adam.

Frames are held in memory as their non-zero pixels (about 1.5k of 179k per seed frame).
"""
from __future__ import annotations

import json
import logging
import shutil
from pathlib import Path
from typing import Literal, Optional

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field

from courtloc.lab.datasets import Dataset, split_by_recording
from courtloc.lab.metrics import compute_metrics
from courtloc.localizer.paper_input import CROP_TOP, sparse_input
from courtloc.training.lazy_adam import LazyAdamRows, RowBatch
from courtloc.training.paper_model import SparsePaperNet

log = logging.getLogger(__name__)
LAST_CHECKPOINT = "last.pt"
FINAL_WEIGHTS = "model.pt"
HISTORY = "history.json"
LOSS_CURVE = "loss_curve.png"


class TrainConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")

    data: Path
    csv: Optional[Path] = None
    kind: Literal["dots", "raw"] = "dots"
    out: Path
    train_recordings: Optional[list[str]] = None
    val_recordings: Optional[list[str]] = None
    crop_top: int = Field(default=CROP_TOP, ge=0)
    epochs: int = Field(default=15, ge=1)
    batch_size: int = Field(default=8, ge=1)
    lr: float = Field(default=1e-4, gt=0)
    seed: int = 0
    resume: bool = False
    progress: bool = True
    # Budget options (CPU-only runs of the CNN baselines): every k-th frame of the training recordings
    # (consecutive frames share most of their dots), every k-th held-out frame for the per-epoch validation,
    # and a k x k max-pool in front of a CNN baseline (inside the exported graph, so its input stays full size).
    frame_step: int = Field(default=1, ge=1)
    val_frame_step: int = Field(default=1, ge=1)
    downscale: int = Field(default=1, ge=1)


class SparseFrames:
    """The non-zero pixels of each frame's crop, concatenated, with per-frame offsets."""

    def __init__(self, dataset: Dataset, indices: np.ndarray, crop_top: int, progress: bool = False) -> None:
        from tqdm import tqdm  # progress bars: tqdm comes with the train extra

        parts_i, parts_v, lengths = [], [], []
        shape = None
        for i in tqdm(indices, desc="loading frames", disable=not progress, unit="frame"):
            dots = dataset.dot_image(int(i))
            shape = (dots.shape[0] - crop_top, dots.shape[1]) if shape is None else shape
            if (dots.shape[0] - crop_top, dots.shape[1]) != shape:
                raise ValueError(f"frame {dataset.filenames[int(i)]} has shape {dots.shape}, others {shape}")
            idx, val = sparse_input(dots, crop_top)
            parts_i.append(idx)
            parts_v.append(val)
            lengths.append(len(idx))
        if shape is None:
            raise ValueError("no frames selected")
        self.shape: tuple[int, int] = shape
        self.indices = np.concatenate(parts_i)
        self.values = np.concatenate(parts_v)
        self.starts = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)
        self.targets = dataset.xy[indices].astype(np.float32)

    def __len__(self) -> int:
        return len(self.targets)

    def frame(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        a, b = self.starts[k], self.starts[k + 1]
        return self.indices[a:b], self.values[a:b]

    def batch(self, which: np.ndarray) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        spans = [(self.starts[k], self.starts[k + 1]) for k in which]
        idx = np.concatenate([self.indices[a:b] for a, b in spans])
        val = np.concatenate([self.values[a:b] for a, b in spans])
        offsets = np.concatenate([[0], np.cumsum([b - a for a, b in spans])[:-1]]).astype(np.int64)
        return torch.from_numpy(idx), torch.from_numpy(val), torch.from_numpy(offsets)


def predict(model: SparsePaperNet, frames: SparseFrames, batch_size: int = 64) -> np.ndarray:
    model.eval()
    out = []
    with torch.no_grad():
        for start in range(0, len(frames), batch_size):
            which = np.arange(start, min(start + batch_size, len(frames)))
            out.append(model(*frames.batch(which)).numpy())
    model.train()
    return np.concatenate(out).astype(np.float64)


def plot_history(history: list[dict], path: Path) -> bool:
    """Loss curve PNG; False (and nothing written) when matplotlib is not installed."""
    try:
        import matplotlib  # plots: matplotlib comes with the train extra

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt  # plots: matplotlib comes with the train extra
    except ImportError:
        log.warning("matplotlib not installed: no loss curve")
        return False
    epochs = [h["epoch"] for h in history]
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.plot(epochs, [h["train_loss"] for h in history], marker="o", label="train loss (MSE, running)")
    if history and "val_mse" in history[0]:
        ax.plot(epochs, [h["val_mse"] for h in history], marker="o", label="validation MSE (held-out recordings)")
    ax.set_xlabel("epoch")
    ax.set_ylabel("MSE (m$^2$)")
    ax.set_yscale("log")
    ax.grid(True, alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return True


def _split(dataset: Dataset, cfg: TrainConfig) -> tuple[np.ndarray, np.ndarray]:
    """Recording split, then every frame_step-th training and val_frame_step-th held-out frame."""
    if cfg.train_recordings is None and cfg.val_recordings is None:
        train_idx, val_idx = split_by_recording(dataset.recordings)
    elif cfg.val_recordings == []:
        train_idx = dataset.indices_of(cfg.train_recordings or dataset.recording_ids())
        val_idx = np.array([], np.int64)
    else:
        train_idx, val_idx = split_by_recording(dataset.recordings, val=cfg.val_recordings, train=cfg.train_recordings)
    return train_idx[::cfg.frame_step], val_idx[::cfg.val_frame_step]


def train(cfg: TrainConfig) -> dict:
    """Train; returns the summary also written to OUT/history.json. Resumable from OUT/last.pt."""
    cfg.out.mkdir(parents=True, exist_ok=True)
    dataset = Dataset(cfg.data, csv_path=cfg.csv, kind=cfg.kind)
    train_idx, val_idx = _split(dataset, cfg)
    log.info("train frames %d (%s), validation frames %d (%s)", len(train_idx),
             sorted(set(dataset.recordings[train_idx])), len(val_idx), sorted(set(dataset.recordings[val_idx])))
    train_frames = SparseFrames(dataset, train_idx, cfg.crop_top, cfg.progress)
    val_frames = SparseFrames(dataset, val_idx, cfg.crop_top, cfg.progress) if len(val_idx) else None
    height, width = train_frames.shape

    torch.manual_seed(cfg.seed)
    model = SparsePaperNet(height * width)
    table = model.first.weight.data  # trained through LazyAdamRows, outside autograd
    opt_sparse = LazyAdamRows(table, lr=cfg.lr)
    opt_dense = torch.optim.Adam(model.dense_parameters(), lr=cfg.lr)
    history: list[dict] = []
    start_epoch = 1
    last = cfg.out / LAST_CHECKPOINT
    if cfg.resume and last.is_file():
        state = torch.load(last, weights_only=False)
        model.load_state_dict(state["model"])
        opt_sparse.load_state_dict(state["opt_sparse"])
        opt_dense.load_state_dict(state["opt_dense"])
        history = state["history"]
        start_epoch = state["epoch"] + 1
        log.info("resumed from %s after epoch %d", last, state["epoch"])

    from tqdm import tqdm  # progress bars: tqdm comes with the train extra

    loss_fn = torch.nn.MSELoss()
    targets = torch.from_numpy(train_frames.targets)
    for epoch in range(start_epoch, cfg.epochs + 1):
        order = np.random.default_rng([cfg.seed, epoch]).permutation(len(train_frames))  # resumable
        batches = [order[k:k + cfg.batch_size] for k in range(0, len(order), cfg.batch_size)]
        running, seen = 0.0, 0
        bar = tqdm(batches, desc=f"epoch {epoch}/{cfg.epochs}", disable=not cfg.progress, unit="batch")
        for which in bar:
            rows = RowBatch(*zip(*(train_frames.frame(k) for k in which)))
            gathered = table.index_select(0, rows.rows)
            first_out = (rows.matrix.T @ gathered).requires_grad_()  # == Linear(N, 1024) without bias
            pred = model.tail(first_out + model.first_bias)
            loss = loss_fn(pred, targets[which])
            opt_dense.zero_grad()
            loss.backward()
            opt_sparse.step(rows.rows, gathered, rows.matrix @ first_out.grad)
            opt_dense.step()
            running += float(loss.detach()) * len(which)
            seen += len(which)
            bar.set_postfix(loss=f"{running / seen:.4f}")
        entry: dict = {"epoch": epoch, "train_loss": running / seen}
        in_sample = compute_metrics(predict(model, train_frames), train_frames.targets)
        entry.update(train_mse=in_sample.mse, train_mean_err_m=in_sample.mean_err_m)
        if val_frames is not None:
            val_metrics = compute_metrics(predict(model, val_frames), val_frames.targets)
            entry.update(val_mse=val_metrics.mse, val_mean_err_m=val_metrics.mean_err_m)
        history.append(entry)
        log.info("epoch %s", entry)
        tmp = cfg.out / (LAST_CHECKPOINT + ".tmp")
        torch.save({"model": model.state_dict(), "opt_sparse": opt_sparse.state_dict(),
                    "opt_dense": opt_dense.state_dict(), "epoch": epoch, "history": history,
                    "config": cfg.model_dump(mode="json"), "input_shape": [height, width]}, tmp)
        shutil.move(tmp, last)  # atomic: a crash mid-save leaves the previous checkpoint intact
        plot_history(history, cfg.out / LOSS_CURVE)

    del opt_sparse, opt_dense  # 1.5 GB of first-layer moments; not needed for the final evaluation and save
    summary = {
        "config": cfg.model_dump(mode="json"),
        "input_shape": [height, width],
        "train_recordings": sorted(set(dataset.recordings[train_idx].tolist())),
        "val_recordings": sorted(set(dataset.recordings[val_idx].tolist())),
        "train_fingerprint": dataset.fingerprint(train_idx),
        "n_train": len(train_idx),
        "history": history,
        "metrics": {"train": compute_metrics(predict(model, train_frames), train_frames.targets).as_dict()},
    }
    if val_frames is not None:
        summary["metrics"]["val"] = compute_metrics(predict(model, val_frames), val_frames.targets).as_dict()
    torch.save({"weights": model.numpy_weights(), "input_shape": [height, width], "crop_top": cfg.crop_top,
                "summary": summary}, cfg.out / FINAL_WEIGHTS)
    (cfg.out / HISTORY).write_text(json.dumps(summary, indent=1))
    return summary
