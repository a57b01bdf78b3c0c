"""Integrated Gradients saliency of the paper network (as in the paper), written as PNGs.

IG(x)_i = (x_i - x'_i) * mean over alpha in (0, 1] of d f(x' + alpha (x - x')) / d x_i, with the black
image as baseline x' and a right Riemann sum of `steps` points. Each output (x and y) is attributed
separately; the PNG shows |IG_x| + |IG_y|, the pixels that moved the position estimate. The
completeness gap (sum of IG_k minus (f_k(x) - f_k(x'))) is logged so a too-coarse path is visible.
Needs torch: a training-side tool, run on OUT/model.pt.
"""
from __future__ import annotations

import logging
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np
import torch

from courtloc.lab.datasets import threshold_dots
from courtloc.localizer.paper_input import dense_input
from courtloc.training.paper_model import DensePaperNet

log = logging.getLogger(__name__)


def integrated_gradients(model: DensePaperNet, image: np.ndarray, steps: int = 32) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(attributions [2, H, W] for outputs x and y, prediction [2], completeness gap [2]) for image [1, H, W]."""
    x = torch.from_numpy(image)
    alphas = torch.arange(1, steps + 1, dtype=torch.float32) / steps
    path = (alphas[:, None, None, None] * x[None]).requires_grad_()  # baseline = zeros
    out = model(path)  # [steps, 2]
    grads = []
    for k in range(2):
        (g,) = torch.autograd.grad(out[:, k].sum(), path, retain_graph=k == 0)
        grads.append(g.mean(dim=0)[0])
    attributions = (torch.stack(grads) * x[0]).detach().numpy()
    with torch.no_grad():
        pred = model(x[None])[0].numpy()
        base = model(torch.zeros_like(x)[None])[0].numpy()
    gap = attributions.reshape(2, -1).sum(axis=1) - (pred - base)
    return attributions, pred, gap


def saliency_png(dots: np.ndarray, attributions: np.ndarray, crop_top: int, pred: np.ndarray) -> np.ndarray:
    """BGR picture: the full frame's dots in grey, |IG_x| + |IG_y| as a heat map over the crop."""
    height, width = dots.shape
    canvas = cv2.cvtColor((dots * 90).astype(np.uint8), cv2.COLOR_GRAY2BGR)
    magnitude = np.abs(attributions).sum(axis=0)
    peak = float(magnitude.max()) or 1.0
    heat = cv2.applyColorMap((255 * np.sqrt(magnitude / peak)).astype(np.uint8), cv2.COLORMAP_INFERNO)
    lit = magnitude > 0
    crop = canvas[crop_top:]
    crop[lit] = heat[lit]
    cv2.line(canvas, (0, crop_top), (width - 1, crop_top), (255, 128, 0), 1)
    cv2.putText(canvas, f"pred x={pred[0]:+.2f} m y={pred[1]:+.2f} m  (IG, black baseline)", (8, 24),
                cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 1, cv2.LINE_AA)
    return canvas


def explain_images(weights_file: Path, images: Sequence[Path], out_dir: Path, steps: int = 32) -> list[Path]:
    from courtloc.training.export import load_weights  # needs torch: the train extra

    state = load_weights(weights_file)
    crop_top = int(state["crop_top"])
    model = DensePaperNet.from_weights({k: np.asarray(v, np.float32) for k, v in state["weights"].items()})
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for path in images:
        gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if gray is None:
            raise FileNotFoundError(f"cannot read image {path}")
        dots = threshold_dots(gray)
        attributions, pred, gap = integrated_gradients(model, dense_input(dots, crop_top), steps)
        log.info("%s: pred %s, IG completeness gap %s", path.name, pred, gap)
        target = out_dir / f"{Path(path).stem}_ig.png"
        cv2.imwrite(str(target), saliency_png(dots, attributions, crop_top, pred))
        written.append(target)
    return written
