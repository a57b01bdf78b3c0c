"""The colour-marks candidates of the global search (localizer/marks_search.py) on the robocon2025 court: where a
frame's strip marks lie on their own colour, never on the other strip, and none beside a pose already proposed."""
from __future__ import annotations

import math

import numpy as np
import pytest

from courtloc.localizer.marks import MarkPoints
from courtloc.localizer.package import bundled_package
from courtloc.localizer.predictor import load_predictor

RED = 0  # the court's first mark: the red strip along +y (y 4.125-5.075 m)
TRUTH = np.array([2.0, 3.0, math.pi / 2])  # facing the red strip, 1.1 m from it


@pytest.fixture(scope="module")
def localizer():  # noqa: ANN201
    return load_predictor(bundled_package("robocon2025", "robocon2025")).localizer


def _strip_marks(pose: np.ndarray) -> MarkPoints:
    """Points of the red strip ahead of `pose` (court x 1-3 m, y 4.2-5.0 m), in the robot's frame."""
    gx, gy = np.meshgrid(np.linspace(1.0, 3.0, 9), np.linspace(4.2, 5.0, 5))
    dx, dy = gx.ravel() - pose[0], gy.ravel() - pose[1]
    c, s = math.cos(pose[2]), math.sin(pose[2])
    points = np.column_stack([c * dx + s * dy, -s * dx + c * dy])
    return MarkPoints(points, np.full(len(points), RED, np.int64))


def test_candidates_put_the_marks_on_their_own_strip_and_never_on_the_other(localizer) -> None:  # noqa: ANN001
    search, marks = localizer.search, _strip_marks(TRUTH)
    flat = np.zeros((len(search.yaws), len(search.ty), len(search.tx)), np.float32)  # lines tie everywhere
    cfg = localizer.config.search
    found = localizer.marks_search.candidates(flat, marks, [], cfg)
    assert len(found) == cfg.marks_candidates
    for pose in found:
        own, other = localizer.mark_map.evidence(pose, marks)
        assert own >= 0.9 * len(marks) and other == 0
        # Along the strip the marks cannot tell where; across it and in heading they do.
        assert abs(pose[1] - TRUTH[1]) < 0.3 and abs(math.remainder(pose[2] - TRUTH[2], 2 * math.pi)) < math.radians(10)


def test_no_candidate_beside_one_the_line_search_proposed_or_its_twin(localizer) -> None:  # noqa: ANN001
    search, marks = localizer.search, _strip_marks(TRUTH)
    flat = np.zeros((len(search.yaws), len(search.ty), len(search.tx)), np.float32)
    twin = np.array([-TRUTH[0], -TRUTH[1], TRUTH[2] + math.pi])
    found = localizer.marks_search.candidates(flat, marks, [TRUTH], localizer.config.search)
    assert found
    for pose in found:
        for taken in (TRUTH, twin):
            assert (math.hypot(*(pose[:2] - taken[:2])) >= 0.5
                    or abs(math.remainder(pose[2] - taken[2], 2 * math.pi)) >= math.radians(10))


def test_too_few_marks_or_none_asked_add_no_candidate(localizer) -> None:  # noqa: ANN001
    search, marks = localizer.search, _strip_marks(TRUTH)
    flat = np.zeros((len(search.yaws), len(search.ty), len(search.tx)), np.float32)
    cfg = localizer.config.search
    few = MarkPoints(marks.points[:cfg.marks_min - 1], marks.index[:cfg.marks_min - 1])
    assert localizer.marks_search.candidates(flat, few, [], cfg) == []
    none_asked = cfg.model_copy(update={"marks_candidates": 0})
    assert localizer.marks_search.candidates(flat, marks, [], none_asked) == []


def test_a_court_without_marks_has_no_marks_search() -> None:
    assert load_predictor(bundled_package("seed-gazebo", "seed-gazebo")).localizer.marks_search is None


def test_the_marks_search_sums_at_most_its_own_number_of_marks_spread_over_those_in_range(localizer) -> None:  # noqa: ANN001
    """45 strip marks in range, `marks_max_points` 15: every third is summed, whatever the line search's `max_points`
    (the strip is an area: fewer of its marks place it as well, at a fraction of the search's sums)."""
    search, marks = localizer.search, _strip_marks(TRUTH)
    assert len(marks.points) == 45
    shape = (len(search.yaws), len(search.ty), len(search.tx))
    cfg = localizer.config.search.model_copy(update={"marks_max_points": 15, "max_points": 60})
    capped = localizer.marks_search._off_colour_share(marks, shape, cfg)
    spread = np.linspace(0, 44, 15).round().astype(int)
    chosen = MarkPoints(marks.points[spread], marks.index[spread])
    alone = localizer.marks_search._off_colour_share(chosen, shape, cfg)
    every = localizer.marks_search._off_colour_share(marks, shape, cfg.model_copy(update={"marks_max_points": 45}))
    for half in range(2):
        np.testing.assert_array_equal(capped[half], alone[half])
        assert not np.array_equal(capped[half], every[half])
