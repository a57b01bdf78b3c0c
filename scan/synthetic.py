"""Synthetic test frames for the scan: white lines and arcs on a grey floor at random poses, plus noise.

Used by the tests (fast == reference on many frames) and by `courtloc bench preprocess`, so both measure
on the same kind of picture. Not a renderer of the court: `courtloc.sim` is.
"""
from __future__ import annotations

import cv2
import numpy as np


def line_frame(rng: np.random.Generator, height: int = 480, width: int = 640, n_lines: int = 6,
               n_arcs: int = 2, noise: int = 12) -> np.ndarray:
    """A BGR frame: a grey floor with white straight lines and ellipse arcs of random width and pose."""
    floor = rng.integers(60, 150)
    frame = np.full((height, width, 3), floor, np.uint8)
    span = max(height, width)
    for _ in range(n_lines):
        p1 = tuple(int(v) for v in rng.integers(-span // 2, span + span // 2, 2))
        p2 = tuple(int(v) for v in rng.integers(-span // 2, span + span // 2, 2))
        cv2.line(frame, p1, p2, _white(rng), int(rng.integers(1, 9)), lineType=cv2.LINE_AA)
    for _ in range(n_arcs):
        centre = (int(rng.integers(0, width)), int(rng.integers(0, height)))
        axes = (int(rng.integers(1, span + 10)), int(rng.integers(1, span + 10)))
        start = int(rng.integers(0, 360))
        cv2.ellipse(frame, centre, axes, int(rng.integers(0, 180)), start, start + int(rng.integers(30, 300)),
                    _white(rng), int(rng.integers(1, 9)), lineType=cv2.LINE_AA)
    if noise:
        frame = cv2.add(frame, rng.integers(0, noise, frame.shape, dtype=np.uint8))
    return frame


def noise_frame(rng: np.random.Generator, height: int = 480, width: int = 640) -> np.ndarray:
    """Uniform random BGR pixels biased towards bright low-saturation, so roughly half are "white"."""
    value = rng.integers(140, 256, (height, width, 1))
    spread = rng.integers(0, 90, (height, width, 3))
    return np.clip(value - spread, 0, 255).astype(np.uint8)


def _white(rng: np.random.Generator) -> tuple[int, int, int]:
    base = int(rng.integers(185, 256))
    return tuple(int(min(255, base + rng.integers(-12, 12))) for _ in range(3))  # type: ignore[return-value]
