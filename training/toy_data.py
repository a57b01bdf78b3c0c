"""A tiny synthetic seed-format dataset for tests and smoke runs (numpy + OpenCV, no torch).

Each frame shows a few dots whose image positions move with the pose, so a network can learn x, y
from it; two or more recordings are named seed-style (img_YYYYMMDD_...) to exercise the splits.
"""
from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np

from courtloc.localizer.paper_input import hits_to_dot_image


def write_toy_dataset(root: Path, recordings: Sequence[str] = ("20240101", "20240102"), frames_per_recording: int = 24,
                      height: int = 48, width: int = 64, crop_top: int = 16, seed: int = 0,
                      jpeg: bool = False) -> Path:
    """Write DIR/images/*.png (or .jpg) + DIR/pose_data.csv; returns DIR."""
    rng = np.random.default_rng(seed)
    images = Path(root) / "images"
    images.mkdir(parents=True, exist_ok=True)
    rows = []
    span = height - crop_top - 6
    for rec in recordings:
        for k in range(frames_per_recording):
            x, y = rng.uniform(-1.0, 1.0, size=2)
            yaw = float(rng.uniform(-math.pi, math.pi))
            # Dots whose pixel positions encode the pose: col ~ x, row ~ y, plus two fixed landmarks.
            col = int(round((x + 1.0) / 2.0 * (width - 7))) + 3
            row = crop_top + 3 + int(round((y + 1.0) / 2.0 * span))
            hits = np.array([[row, col], [crop_top + 3, 3], [height - 4, width - 4]], dtype=np.int16)
            dots = hits_to_dot_image(hits, height, width) * 255
            name = f"img_{rec}_{k:06d}_{k * 1000:06d}.{'jpg' if jpeg else 'png'}"
            cv2.imwrite(str(images / name), dots)
            rows.append((name, x, y, math.sin(yaw / 2.0)))
    with (Path(root) / "pose_data.csv").open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["image_filename", "x", "y", "orientation_z"])
        writer.writerows(rows)
    return Path(root)
