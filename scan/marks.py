"""Colour marks: where a frame shows the court's asymmetric colours (robocon2025's red and blue strips).

The white paint of a court is point-symmetric, so a view of it fits the robot's pose and its 180-degree
twin equally well; a floor colour on one side only tells them apart. The scan reports the pixels of a
coarse grid that have a mark's colour; the localizer projects them onto the floor of each pose it
weighs (`courtloc.localizer.marks`). A grid is enough: the strips are metres long, and a few dozen
pixels decide.
"""
from __future__ import annotations

import numpy as np

from courtloc.common.payloads import HIT_DTYPE, MARK_FIELDS
from courtloc.scan.config import MarkClass
from courtloc.scan.hsv_mask import WhiteMask


def empty_marks() -> np.ndarray:
    return np.zeros((0, MARK_FIELDS), HIT_DTYPE)


class MarkFinder:
    """The colour marks of one configuration: BGR frame -> int16 (M, 3) rows (row, col, mark index)."""

    def __init__(self, marks: tuple[MarkClass, ...], grid_px: int, max_marks: int) -> None:
        # The HSV-box mask of the white test serves any colour: one instance per mark.
        self._masks = [WhiteMask(mark.hsv_ranges) for mark in marks]
        self.grid_px = grid_px
        self.max_marks = max_marks

    def find(self, bgr: np.ndarray) -> np.ndarray:
        if not self._masks:
            return empty_marks()
        step, first = self.grid_px, self.grid_px // 2
        grid = np.ascontiguousarray(bgr[first::step, first::step])
        found = []
        for index, mask in enumerate(self._masks):
            rows, cols = np.nonzero(mask.frame(grid))
            found.append(np.stack([rows * step + first, cols * step + first, np.full(rows.shape, index)], axis=1))
        marks = np.concatenate(found)
        if len(marks) > self.max_marks:  # evenly thinned, so every part of the frame keeps its share
            marks = marks[np.linspace(0, len(marks) - 1, self.max_marks).astype(np.int64)]
        return marks.astype(HIT_DTYPE)
