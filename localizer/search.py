"""Global (cold-start) pose search: every yaw step x every coarse translation, then top-k refined.

Cost of a pose = sum over hits of the clipped |distance to paint| on a coarse grid. For one yaw the
rotated hits are fixed offsets, so the cost of *all* translations on the grid is a sum of shifted copies
of the coarse field: one array add per hit and yaw, no per-pose work. Yaw runs over [0, 180) only: the
court is point-symmetric, so (x, y, yaw + 180) is the mirror (-x, -y) of a pose already searched; the
caller picks between the two (symmetry.py).

The sums run in C when the optional extension was built (search_kernel.c, bit-identical to `accumulate_numpy`,
which runs otherwise, or within `fit.kernel_enabled(False)`): the numpy loop is ~3,600 array adds a frame,
10-14 ms on the development machine, and a searching frame then outlasted a 30 fps frame interval (the infer
stage dropped frames while acquiring).
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from courtloc.localizer.config import SearchConfig
from courtloc.localizer.court_field import CourtField
from courtloc.localizer.fit import kernels_wanted
from courtloc.localizer.projection import ProjectedHits

try:
    from courtloc.localizer import _search_kernel
except ImportError:  # built without a C compiler: the numpy loop below, same sums, slower
    _search_kernel = None

# The pool of lowest-cost grid poses the non-maximum suppression walks, per candidate asked for.
POOL_PER_CANDIDATE = 40
# Candidates this near (and this near in heading) to a better one are one basin: only the better is refined.
NEAR_M = 0.5
NEAR_YAW_RAD = math.radians(10)


def kernel_available() -> bool:
    return _search_kernel is not None


def accumulate_numpy(values: np.ndarray, dx: np.ndarray, dy: np.ndarray, rows: tuple[int, int],
                     cols: tuple[int, int], out: np.ndarray) -> None:
    """out[k] += the window of `values` at each hit's offset (dx[k, p], dy[k, p]), hit by hit, for every yaw k:
    the reference the compiled `accumulate` follows."""
    (i0, i1), (j0, j1) = rows, cols
    for k in range(len(dx)):
        acc = out[k]
        for ox, oy in zip(dx[k], dy[k]):
            acc += values[i0 + oy:i1 + oy, j0 + ox:j1 + ox]


def accumulate(values: np.ndarray, dx: np.ndarray, dy: np.ndarray, rows: tuple[int, int], cols: tuple[int, int],
               out: np.ndarray) -> None:
    """`accumulate_numpy`, compiled when the extension was built (and `fit.kernel_enabled` does not say no)."""
    if _search_kernel is None or not kernels_wanted():
        accumulate_numpy(values, dx, dy, rows, cols, out)
        return
    ny, nx = values.shape
    _search_kernel.accumulate(values, ny, nx, np.ascontiguousarray(dx, np.int32), np.ascontiguousarray(dy, np.int32),
                              dx.shape[0], dx.shape[1], rows[0], rows[1], cols[0], cols[1], out)


def lowest(values: np.ndarray, n: int) -> np.ndarray:
    """Indices of the n smallest of a flat array, ordered by (value, index).

    The n-th smallest of any subset is at least the n-th smallest of all, so the values at or below a strided
    sample's n-th smallest hold all n: a partition of the sample and a sort of those few instead of a selection
    over the whole search volume (7 ms for 720,000 costs on the development machine)."""
    if n >= len(values):
        idx = np.arange(len(values))
    else:
        stride = max(1, min(16, len(values) // max(n, 1)))
        sample = values[::stride]
        bound = np.partition(sample, n - 1)[n - 1]
        idx = np.flatnonzero(values <= bound)
    return idx[np.lexsort((idx, values[idx]))][:n]


def distinct(poses: np.ndarray, limit: int, yaw_period: float, taken: Sequence[np.ndarray] = ()) -> list[np.ndarray]:
    """The first `limit` of `poses` (x, y, yaw rows, best first) none of which is near a better one or a pose of
    `taken` (`NEAR_M`, and `NEAR_YAW_RAD` with headings compared modulo `yaw_period`): non-maximum suppression."""
    picked: list[np.ndarray] = []
    for pose in poses:
        if any(math.hypot(*(pose[:2] - p[:2])) < NEAR_M
               and abs(math.remainder(pose[2] - p[2], yaw_period)) < NEAR_YAW_RAD for p in (*taken, *picked)):
            continue
        picked.append(pose)
        if len(picked) >= limit:
            break
    return picked


class CoarseSearch:
    def __init__(self, field: CourtField, area_half_extent: tuple[float, float], cfg: SearchConfig) -> None:
        self.cfg = cfg
        coarse = field.coarse(cfg.coarse_factor, cfg.clip_m)
        self.res = coarse.resolution
        pad = int(math.ceil(cfg.max_range_m / self.res)) + 2
        self.pad = pad
        self.values = np.pad(coarse.values, pad, constant_values=cfg.clip_m)
        ny, nx = coarse.values.shape
        hx = area_half_extent[0] + cfg.area_margin_m
        hy = area_half_extent[1] + cfg.area_margin_m
        xs = coarse.x0 + self.res * np.arange(nx)
        ys = coarse.y0 + self.res * np.arange(ny)
        jx = np.nonzero(np.abs(xs) <= hx)[0]
        iy = np.nonzero(np.abs(ys) <= hy)[0]
        self.j0, self.j1 = int(jx[0]), int(jx[-1]) + 1
        self.i0, self.i1 = int(iy[0]), int(iy[-1]) + 1
        self.tx = xs[self.j0:self.j1]
        self.ty = ys[self.i0:self.i1]
        self.yaws = np.radians(np.arange(0.0, 180.0, cfg.yaw_step_deg))

    def _select(self, hits: ProjectedHits) -> np.ndarray:
        near = np.nonzero(hits.range_m < self.cfg.max_range_m)[0]
        if len(near) > self.cfg.max_points:
            # Spread the kept hits over the frame rather than taking a cluster.
            near = near[np.linspace(0, len(near) - 1, self.cfg.max_points).round().astype(int)]
        return hits.points[near]

    def offsets(self, hits: ProjectedHits) -> tuple[np.ndarray, np.ndarray]:
        """(n_yaw, n_selected) int32 column and row offsets of each selected hit, rotated by each yaw, into the
        padded field."""
        pts = self._select(hits)
        c, s = np.cos(self.yaws)[:, None], np.sin(self.yaws)[:, None]
        dx = np.rint((c * pts[:, 0] - s * pts[:, 1]) / self.res).astype(np.int32) + self.pad
        dy = np.rint((s * pts[:, 0] + c * pts[:, 1]) / self.res).astype(np.int32) + self.pad
        return dx, dy

    def costs(self, hits: ProjectedHits) -> np.ndarray:
        """(n_yaw, n_ty, n_tx) mean clipped distance of the selected hits for every grid pose."""
        dx, dy = self.offsets(hits)
        out = np.zeros((len(self.yaws), self.i1 - self.i0, self.j1 - self.j0), np.float32)
        if dx.shape[1] == 0:
            out[:] = self.cfg.clip_m
            return out
        accumulate(self.values, dx, dy, (self.i0, self.i1), (self.j0, self.j1), out)
        out /= dx.shape[1]
        return out

    def candidates(self, hits: ProjectedHits) -> list[np.ndarray]:
        """Up to cfg.candidates distinct low-cost poses (x, y, yaw), best first."""
        return self.pick(self.costs(hits))

    def pick(self, cost: np.ndarray) -> list[np.ndarray]:
        """Up to cfg.candidates distinct low-cost poses (x, y, yaw) of a `costs` array, best first."""
        best = lowest(cost.ravel(), POOL_PER_CANDIDATE * self.cfg.candidates)
        k, i, j = np.unravel_index(best, cost.shape)
        # Headings over half a turn: a pose and its turned-around self are one search pose (module docstring).
        return distinct(np.column_stack([self.tx[j], self.ty[i], self.yaws[k]]), self.cfg.candidates, math.pi)
