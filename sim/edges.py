"""The twin's link to the preprocess stage: edge hits of rendered frames and dot centres of seed images.

Both come from `courtloc.scan` (the pipeline's own code), so the twin is checked against
exactly what the robot runs.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np

from courtloc.scan.config import PreprocessConfig, ScanConfig
from courtloc.scan.preprocessor import Preprocessor
from courtloc.scan.seed_dots import dots_to_hits, draw_hits


@lru_cache(maxsize=2)
def _preprocessor(paper: bool = False) -> Preprocessor:
    return Preprocessor(PreprocessConfig(scan=ScanConfig(min_edge_drop=0)) if paper else PreprocessConfig())


def scan_hits(bgr: np.ndarray) -> np.ndarray:
    """int16 (N, 4) hits (row, col, ray, d) of a BGR frame with the default preprocess configuration."""
    return _preprocessor().process(bgr)


def paper_scan_hits(bgr: np.ndarray) -> np.ndarray:
    """The hits the paper's Algorithm 1 gives (no edge drop): what the seed recordings' dots are, so what
    a dataset in their format holds."""
    return _preprocessor(paper=True).process(bgr)


def dot_centres(image: np.ndarray) -> np.ndarray:
    """(N, 2) float (u, v) = (column, row) centres of the white dots of a seed-style edge image."""

    rows_cols = dots_to_hits(image)
    return rows_cols[:, ::-1].astype(float)


def hits_image(hits: np.ndarray, height: int, width: int) -> np.ndarray:
    """The seed-style dot image (white radius-2 dots on black) of hits."""

    return draw_hits(hits, height, width)
