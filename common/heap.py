"""Giving the C heap's free pages back to the OS after a one-off burst of allocations.

Building a localizer (the court's distance field on a 1 cm grid, the coarse-search tables) allocates
~100 MB of numpy temporaries that are freed at once, but glibc keeps freed heap pages mapped for reuse,
so the infer stage's resident memory (PSS) stayed ~90 MB above what it holds (measured: 230 -> 139 MB
after one malloc_trim on the bundled package). The robot's memory budget counts those pages.
"""
from __future__ import annotations

import ctypes
import logging

log = logging.getLogger(__name__)


def return_free_heap() -> bool:
    """Ask the C library to release free heap memory (glibc's malloc_trim); False where it has none (musl)."""
    try:
        trim = ctypes.CDLL(None).malloc_trim
    except (AttributeError, OSError):
        return False
    trim.argtypes = [ctypes.c_size_t]
    trim.restype = ctypes.c_int
    return bool(trim(0))
