"""Inputs of the paper network, built the same way for training, eval and the runtime predictor.

The paper feeds its MLP the bottom 280x640 of the 640x480 edge image, scaled to [0, 1]. Ours is the
0/1 dot image (filled discs of radius `DOT_RADIUS` at each radial-scan hit). Two encodings of one input:

- dense:  float32 [1, H - crop_top, W]              (the graph the paper ships)
- sparse: int64 indices [K] into the flattened crop, float32 values [K]  (our exact sparse graph)

Both give the same network output (tested). A sparse input with K = 0 is valid (an empty image).
"""
from __future__ import annotations

import numpy as np

from courtloc.scan.seed_dots import draw_hits

FRAME_HEIGHT = 480
FRAME_WIDTH = 640
CROP_TOP = 200
DOT_RADIUS = 2
INPUT_HEIGHT = FRAME_HEIGHT - CROP_TOP  # 280
INPUT_WIDTH = FRAME_WIDTH  # 640


def hits_to_dot_image(hits: np.ndarray, height: int = FRAME_HEIGHT, width: int = FRAME_WIDTH,
                      radius: int = DOT_RADIUS) -> np.ndarray:
    """Full-frame 0/1 uint8 image with a filled disc (cv2.circle shape, 13 px at radius 2) at every hit.

    `hits` is N x >=2 with (row, col) first — the `Edges` message's int16 (row, col, ray, d) rows fit.
    Drawn by the preprocess stage's own `draw_hits`, so live hits and seed images give the same pixels.
    """

    hits = np.asarray(hits)
    if hits.size == 0:
        hits = hits.reshape(0, 2)
    return (draw_hits(hits, height, width, radius) > 0).astype(np.uint8)


def dense_input(dot_image: np.ndarray, crop_top: int = CROP_TOP) -> np.ndarray:
    """float32 [1, H - crop_top, W] in [0, 1] from a full-frame dot image (0/1 or 0/255)."""
    crop = np.asarray(dot_image)[crop_top:]
    scale = 255.0 if crop.dtype == np.uint8 and crop.max(initial=0) > 1 else 1.0
    return (crop.astype(np.float32) / np.float32(scale))[None]


def sparse_input(dot_image: np.ndarray, crop_top: int = CROP_TOP) -> tuple[np.ndarray, np.ndarray]:
    """(indices int64 [K], values float32 [K]): the non-zero pixels of the crop, row-major flat index."""
    dense = dense_input(dot_image, crop_top)[0]
    flat = dense.ravel()
    indices = np.flatnonzero(flat).astype(np.int64)
    return indices, flat[indices].astype(np.float32)


def hits_to_sparse_input(hits: np.ndarray, height: int = FRAME_HEIGHT, width: int = FRAME_WIDTH,
                         crop_top: int = CROP_TOP, radius: int = DOT_RADIUS) -> tuple[np.ndarray, np.ndarray]:
    """Sparse paper input straight from radial-scan hits (what the infer service gets on the bus)."""
    return sparse_input(hits_to_dot_image(hits, height, width, radius), crop_top)


def hits_to_dense_input(hits: np.ndarray, height: int = FRAME_HEIGHT, width: int = FRAME_WIDTH,
                        crop_top: int = CROP_TOP, radius: int = DOT_RADIUS) -> np.ndarray:
    return dense_input(hits_to_dot_image(hits, height, width, radius), crop_top)
