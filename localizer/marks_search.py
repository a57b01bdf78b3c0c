"""Coarse poses where a frame's colour marks lie on their own colour: more candidates for the global search.

Facing a colour strip, a robot often sees one or two white lines beside it: views the lines alone fit in hundreds of
places about as well, and the line search's few candidates (search.py) may all be elsewhere (the robocon2025 twin's
kidnaps, fused: for 0.8 s the truth ranked 530th-790th of the coarse poses while 130-230 marks of the strip were in
view). The marks place it. The share of them that would land off their own colour is a cost, summed over the line
search's grid the way its line cost is (a shifted copy of each mark's "not my colour" map per mark and heading), and
`marks_weight` times it is added to the line cost. The marks tell a pose from its point-symmetric twin, so the heading
runs over the full turn; on a point-symmetric court the second half-turn's line cost is the first's at the mirrored
position (the grid is mirrored to a fraction of a cell). The poses found are only candidates: refined and judged as
the line search's are.
"""
from __future__ import annotations

import math

import numpy as np

from courtloc.localizer.config import SearchConfig
from courtloc.localizer.marks import MarkMap, MarkPoints
from courtloc.localizer.search import POOL_PER_CANDIDATE, CoarseSearch, accumulate, distinct, lowest
from courtloc.localizer.symmetry import mirror


class MarksSearch:
    def __init__(self, search: CoarseSearch, mark_map: MarkMap, point_symmetric: bool) -> None:
        self.search = search
        ny, nx = search.values.shape
        # The padded grid's cell centres: padded column c holds the coarse column c - pad (search.py).
        xs = search.tx[0] + search.res * (np.arange(nx) - search.pad - search.j0)
        ys = search.ty[0] + search.res * (np.arange(ny) - search.pad - search.i0)
        gx, gy = np.meshgrid(xs, ys)
        col, row = np.rint(mark_map.court_to_texel[:2] @ np.stack([gx.ravel(), gy.ravel(), np.ones(gx.size)])
                           ).astype(np.int64)
        h, w = mark_map.labels.shape
        inside = (row >= 0) & (row < h) & (col >= 0) & (col < w)
        labels = np.zeros(gx.size, np.int64)
        labels[inside] = mark_map.labels[row[inside], col[inside]]
        labels = labels.reshape(ny, nx)
        self.off_colour = [np.ascontiguousarray(labels != m + 1, np.float32) for m in range(mark_map.n_marks)]
        # The second half-turn's line cost is the first's mirrored on a point-symmetric court and a grid mirrored to a
        # fraction of a cell; else only the first half-turn is searched.
        tolerance = 0.25 * search.res
        self.both_halves = point_symmetric and bool(np.allclose(search.tx, -search.tx[::-1], atol=tolerance)
                                                    and np.allclose(search.ty, -search.ty[::-1], atol=tolerance))

    def candidates(self, line_cost: np.ndarray, marks: MarkPoints, taken: list[np.ndarray],
                   cfg: SearchConfig) -> list[np.ndarray]:
        """Up to `marks_candidates` poses (x, y, yaw) of least line cost (`CoarseSearch.costs`) plus `marks_weight` x
        the share of the marks off their colour, none near a better one nor near a pose of `taken` (the line search's
        candidates) or its twin; none with fewer than `marks_min` marks in range."""
        if cfg.marks_candidates == 0:
            return []
        shares = self._off_colour_share(marks, line_cost.shape, cfg)
        if shares is None:
            return []
        first, second = shares
        costs, yaws = [line_cost + cfg.marks_weight * first], [self.search.yaws]
        if self.both_halves:
            costs.append(line_cost[:, ::-1, ::-1] + cfg.marks_weight * second)
            yaws.append(self.search.yaws + math.pi)
        total, all_yaws = np.concatenate(costs), np.concatenate(yaws)
        best = lowest(total.ravel(), POOL_PER_CANDIDATE * cfg.marks_candidates)
        k, i, j = np.unravel_index(best, total.shape)
        near = [np.asarray(p, np.float64) for p in taken] + [mirror(np.asarray(p, np.float64)) for p in taken]
        return distinct(np.column_stack([self.search.tx[j], self.search.ty[i], all_yaws[k]]), cfg.marks_candidates,
                        2 * math.pi, near)

    def _off_colour_share(self, marks: MarkPoints, shape: tuple[int, ...], cfg: SearchConfig
                          ) -> tuple[np.ndarray, np.ndarray] | None:
        """The share of the marks (in range, spread over at most `marks_max_points`) off their own colour at every
        grid pose, for the search's headings and for them turned half a turn; None with fewer than `marks_min` in
        range."""
        search = self.search
        near = np.nonzero(np.hypot(marks.points[:, 0], marks.points[:, 1]) < cfg.max_range_m)[0]
        if len(near) < cfg.marks_min:
            return None
        if len(near) > cfg.marks_max_points:
            near = near[np.linspace(0, len(near) - 1, cfg.marks_max_points).round().astype(int)]
        points, index = marks.points[near], marks.index[near]
        c, s = np.cos(search.yaws)[:, None], np.sin(search.yaws)[:, None]
        rows, cols = (search.i0, search.i1), (search.j0, search.j1)
        first, second = np.zeros(shape, np.float32), np.zeros(shape, np.float32)
        for m in np.unique(index):
            pts = points[index == m]
            dx = np.rint((c * pts[:, 0] - s * pts[:, 1]) / search.res).astype(np.int32)
            dy = np.rint((s * pts[:, 0] + c * pts[:, 1]) / search.res).astype(np.int32)
            accumulate(self.off_colour[m], dx + search.pad, dy + search.pad, rows, cols, first)
            # Turned half a turn, a mark's offset is negated.
            accumulate(self.off_colour[m], search.pad - dx, search.pad - dy, rows, cols, second)
        return first / len(near), second / len(near)
