"""Which compiled kernels this install has, said after `make` installs: silent when all built.

The kernels are optional at build time (no C compiler: the numpy twin runs, same results, slower), and
pip hides a failed optional build, so the user hears it here. The slow-downs are the measured ones of
docs/measurements.md.
"""
from __future__ import annotations

import importlib
import sys

# label (courtloc doctor), module, what runs instead, how much slower (docs/measurements.md: bench preprocess /
# bench localize)
KERNELS: tuple[tuple[str, str, str, str], ...] = (
    ("radial scan", "courtloc.scan._scan_kernel",
     "the numpy radial scan (scan/radial_scan.py)", "~1.8x slower per frame"),
    ("pose fit", "courtloc.localizer._fit_kernel",
     "the numpy pose fit (localizer/fit.py) with onnxruntime's floor lookup", "~10x slower per tracked frame"),
    ("global search", "courtloc.localizer._search_kernel",
     "the numpy global search (localizer/search.py)", "~2.5x slower per searching frame"),
)


def missing_kernels() -> list[tuple[str, str, str]]:
    missing = []
    for _, module, fallback, cost in KERNELS:
        try:
            importlib.import_module(module)
        except ImportError:
            missing.append((module, fallback, cost))
    return missing


def main() -> int:
    for module, fallback, cost in missing_kernels():
        print(f"warning: the C kernel {module} did not compile (no C compiler or Python headers?): "
              f"{fallback} runs instead, {cost} (docs/measurements.md); results are the same",
              file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
