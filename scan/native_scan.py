"""The compiled radial scan (`scan_kernel.c`), when it was built; None otherwise.

`pip install -e .` compiles the kernel when a C compiler and Python's headers are there (they are on a
JetPack image and on CI); without them the install still succeeds and `RadialScanner` uses the numpy
path, which gives the same hits, ~2x slower (`courtloc bench preprocess` prints both).
"""
from __future__ import annotations

import logging
from types import ModuleType

import numpy as np

log = logging.getLogger(__name__)

try:
    from courtloc.scan import _scan_kernel
    _MISSING = ""
except ImportError as exc:  # no C compiler at install time: the numpy scan serves
    _scan_kernel = None
    _MISSING = str(exc)


def load_kernel() -> ModuleType | None:
    if _scan_kernel is None:
        log.info("compiled radial scan not built (%s); using the numpy scan", _MISSING)
    return _scan_kernel


def kernel_hit_samples(kernel: ModuleType, bgr: np.ndarray, pixel_offsets: np.ndarray, sample_pixel: np.ndarray,
                       has_predecessor: np.ndarray, bit_table: np.ndarray, min_edge_drop: int = 0,
                       edge_drop_samples: int = 1) -> np.ndarray:
    """Indices of the hit samples of one contiguous BGR frame (see scan_kernel.c for the arguments)."""
    # Fresh scratch per call: three small allocations, and nothing shared between threads.
    is_white = np.empty(pixel_offsets.shape[0], np.uint8)
    bright = np.empty(pixel_offsets.shape[0], np.uint8)
    out = np.empty(sample_pixel.shape[0], np.int32)
    n = kernel.scan_hits(bgr, pixel_offsets, sample_pixel, has_predecessor, bit_table, is_white, bright, out,
                         min_edge_drop, edge_drop_samples)
    return out[:n]
