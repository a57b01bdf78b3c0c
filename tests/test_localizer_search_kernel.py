"""The global search's compiled sums (localizer/search_kernel.c) against their numpy reference (search.py), and the
selection of the lowest-cost poses it hands to the non-maximum suppression.

Equality is exact: both add the same float32 values into each cell in the same order (the kernel vectorises
across cells, never within one cell's sum) and round to float32 at every add, whatever the CPU.
"""
from __future__ import annotations

import numpy as np
import pytest
from localizer_kit import twin_setup

from courtloc.localizer import search

POSES = [(2.0, 1.0, 0.3), (4.5, -2.0, 2.0), (-1.0, -2.0, 0.5), (1.0, 3.0, -1.2), (-5.0, 0.5, 3.0)]
compiled = pytest.mark.skipif(not search.kernel_available(), reason="compiled search kernel not built (no C compiler)")


@pytest.fixture(scope="module")
def setup():
    return twin_setup(POSES)


@compiled
def test_compiled_search_costs_equal_the_numpy_costs_bit_for_bit(setup, monkeypatch):
    _, _, localizer, projector, raw = setup
    coarse = localizer.search
    for pose in POSES:
        hits = projector.project(raw[pose][:, 0], raw[pose][:, 1])
        compiled_costs = coarse.costs(hits)
        compiled_candidates = coarse.candidates(hits)
        with monkeypatch.context() as m:
            m.setattr(search, "_search_kernel", None)
            numpy_costs = coarse.costs(hits)
            numpy_candidates = coarse.candidates(hits)
        assert len(coarse._select(hits)) >= 20, pose  # a frame with lines to sum
        assert np.array_equal(compiled_costs, numpy_costs), pose
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
