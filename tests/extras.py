"""Why a test of an optional extra skips: said once, in the words a developer can act on."""

TORCH_MISSING = ("torch is not installed: the paper network's tests need the training extra "
                 "(CPU build: see README, Development; .ci/run installs it)")


def float32_sum_tolerance(terms: int, scale: float) -> float:
    """How far two float32 computations of the same sums may differ when they add in different orders
    (another BLAS, CPU or kernel): up to `terms` * eps relative to the magnitudes summed (the bound of a
    recursive sum of `terms` terms), taken here as `scale` (the largest value involved, at least 1)."""
    import numpy as np

    return terms * float(np.finfo(np.float32).eps) * max(1.0, scale)
