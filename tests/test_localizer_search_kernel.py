"""The global search's compiled sums (localizer/search_kernel.c) against their numpy reference (search.py), and the
selection of the lowest-cost poses it hands to the non-maximum suppression.

Equality is exact: both add the same float32 values into each cell in the same order (the kernel vectorises
across cells, never within one cell's sum) and round to float32 at every add, whatever the CPU.
"""
from __future__ import annotations

import shutil

import numpy as np
import pytest
from localizer_kit import twin_setup

from courtloc.localizer import search
from courtloc.localizer.fit import kernel_enabled

POSES = [(2.0, 1.0, 0.3), (4.5, -2.0, 2.0), (-1.0, -2.0, 0.5), (1.0, 3.0, -1.2), (-5.0, 0.5, 3.0)]
compiled = pytest.mark.skipif(not search.kernel_available(), reason="compiled search kernel not built (no C compiler)")


@pytest.fixture(scope="module")
def setup():
    return twin_setup(POSES)


def test_compiled_search_is_built_where_a_compiler_is() -> None:
    # Without this the tests below would skip, not fail, where the C stopped compiling.
    if shutil.which("cc") is None and shutil.which("gcc") is None:
        pytest.skip("no C compiler on this machine: the numpy search is the one in use")
    assert search.kernel_available(), "pip install -e . should have compiled localizer/search_kernel.c"


@compiled
def test_compiled_search_sums_equal_the_numpy_sums_bit_for_bit(setup):
    _, _, localizer, projector, raw = setup
    coarse = localizer.search
    rows, cols = (coarse.i0, coarse.i1), (coarse.j0, coarse.j1)
    for pose in POSES:
        hits = projector.project(raw[pose][:, 0], raw[pose][:, 1])
        dx, dy = coarse.offsets(hits)
        assert dx.shape == (len(coarse.yaws), coarse.cfg.max_points), pose  # a frame with lines to sum
        shape = (len(coarse.yaws), rows[1] - rows[0], cols[1] - cols[0])
        compiled_sums, numpy_sums = np.zeros(shape, np.float32), np.zeros(shape, np.float32)
        search.accumulate(coarse.values, dx, dy, rows, cols, compiled_sums)
        search.accumulate_numpy(coarse.values, dx, dy, rows, cols, numpy_sums)
        assert np.array_equal(compiled_sums, numpy_sums), pose
        # The search as the localizer runs it, compiled and with the kernels switched off: the same candidates.
        compiled_candidates = coarse.candidates(hits)
        with kernel_enabled(False):
            numpy_candidates = coarse.candidates(hits)
        assert [c.tolist() for c in compiled_candidates] == [c.tolist() for c in numpy_candidates], pose


@compiled
def test_a_window_outside_the_field_is_refused_not_read():
    values = np.arange(20 * 30, dtype=np.float32).reshape(20, 30)
    out = np.zeros((1, 4, 5), np.float32)
    inside = np.array([[25]], np.int32), np.array([[16]], np.int32)  # one yaw, one hit
    search.accumulate(values, *inside, (0, 4), (0, 5), out)
    assert np.array_equal(out[0], values[16:20, 25:30])
    for dx, dy in (([[26]], [[0]]), ([[0]], [[17]]), ([[-1]], [[0]]), ([[0]], [[-1]])):
        with pytest.raises(ValueError, match="outside the padded field"):
            search.accumulate(values, np.array(dx, np.int32), np.array(dy, np.int32), (0, 4), (0, 5), out)


@pytest.mark.parametrize("size,n,levels", [(720_000, 320, 50), (50_000, 320, 3), (1000, 320, 1000), (300, 320, 7),
                                           (16, 1, 2)])
def test_lowest_is_the_n_smallest_by_value_then_index(size, n, levels):
    # Few levels: ties everywhere, as on a degenerate view whose costs are equal all along its lines.
    values = np.random.default_rng(size).integers(0, levels, size).astype(np.float32) / levels
    order = np.lexsort((np.arange(size), values))
    assert np.array_equal(search.lowest(values, n), order[:n])
