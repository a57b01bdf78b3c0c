"""Colour marks as evidence: does a pose put the marks a frame saw where the court paints that colour?

The scan reports pixels of the court's asymmetric colours (`courtloc.scan.marks`: robocon2025's red strip
along +y, blue along -y); the package's floor table turns them into robot-frame floor points. A pose
places them on the court: a mark on a texel painted its own colour counts for the pose, on another
mark's colour against it, anywhere else nothing (a red robot, a blue ball, the mark beyond the modelled
floor). The 180-degree twin of a pose puts every red mark on the blue strip, so a few frames that see a
strip tell the twins apart. Acquisition (acquire.py) accumulates the counts per hypothesis.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from courtloc.world.court import Court

# Coarse on purpose: the strips are a metre wide, and a mark's floor point is uncertain by tens of
# centimetres far away; a 5 cm grid of a 19 x 13 m floor is 0.1 MB.
MARK_MAP_RESOLUTION_M = 0.05


@dataclass(frozen=True)
class MarkPoints:
    """A frame's colour marks on the floor, robot frame: (M, 2) metres and (M,) mark indices."""

    points: np.ndarray
    index: np.ndarray

    def __len__(self) -> int:
        return int(self.points.shape[0])


def mark_points(floor_table: np.ndarray, width: int, marks: np.ndarray) -> MarkPoints:
    """Marks (int16 rows of (row, col, mark index)) -> their floor points through a package's (H * W, 2)
    floor table; marks outside the image or above the horizon (no floor) are left out."""
    rows, cols = marks[:, 0].astype(np.int64), marks[:, 1].astype(np.int64)
    inside = (rows >= 0) & (cols >= 0) & (cols < width) & (rows * width + cols < floor_table.shape[0])
    points = floor_table[rows[inside] * width + cols[inside]].astype(np.float64)
    seen = np.all(np.isfinite(points), axis=1)
    return MarkPoints(points[seen], marks[inside, 2][seen].astype(np.int64))


def off_their_colour(own: int, seen: int, min_marks: int, share: float) -> bool:
    """Whether a frame's colour marks speak against a pose: at least `min_marks` of them on the floor (`seen`), under
    `share` of them on their own colour there (`own`, `MarkMap.evidence`). The search-again rule, a decision being
    confirmed and odometry's pose are all judged by it."""
    return seen >= min_marks and own < share * seen


def places(own: int, seen: int, min_marks: int) -> bool:
    """Whether a frame's colour marks leave a pose possible: under `min_marks` of them on the floor (`seen`) say
    nothing, else at least half lie on their own colour there (`own`). Acquisition judges its hypotheses by it: the
    search-again rule (none is placed) and newcomers beside a tracked hypothesis (`hypotheses.py`)."""
    return not off_their_colour(own, seen, min_marks, 0.5)


class MarkMap:
    """Which of the court's marks is painted where, on a top-down grid."""

    def __init__(self, court: Court) -> None:
        labels, texel_to_court = court.mark_map(MARK_MAP_RESOLUTION_M)
        self.labels = labels
        self.court_to_texel = np.linalg.inv(texel_to_court)
        self.n_marks = len(court.marks)

    def evidence(self, pose: np.ndarray, marks: MarkPoints) -> tuple[int, int]:
        """(marks on their own colour, marks on another mark's colour) when the robot stands at `pose`."""
        if len(marks) == 0:
            return 0, 0
        cx, cy = self._on_court(pose, marks)
        own, other = self._painted(np.stack([cx, cy, np.ones_like(cx)]), marks.index)
        return int(np.count_nonzero(own)), int(np.count_nonzero(other))

    def evidence_along(self, pose: np.ndarray, direction: np.ndarray, offsets: np.ndarray,
                       marks: MarkPoints) -> tuple[np.ndarray, np.ndarray]:
        """`evidence` at `pose` moved by each of `offsets` (m) along the unit `direction` (x, y), heading kept:
        (own, other) count arrays, one entry per offset."""
        if len(marks) == 0 or len(offsets) == 0:
            return np.zeros(len(offsets), np.int64), np.zeros(len(offsets), np.int64)
        cx, cy = self._on_court(pose, marks)
        cx = cx[None, :] + offsets[:, None] * float(direction[0])
        cy = cy[None, :] + offsets[:, None] * float(direction[1])
        court_xy = np.stack([cx.ravel(), cy.ravel(), np.ones(cx.size)])
        own, other = self._painted(court_xy, np.tile(marks.index, len(offsets)))
        return own.reshape(len(offsets), -1).sum(axis=1), other.reshape(len(offsets), -1).sum(axis=1)

    @staticmethod
    def _on_court(pose: np.ndarray, marks: MarkPoints) -> tuple[np.ndarray, np.ndarray]:
        """The marks' court x and y with the robot at `pose`."""
        x, y, yaw = (float(v) for v in pose)
        c, s = np.cos(yaw), np.sin(yaw)
        px, py = marks.points[:, 0], marks.points[:, 1]
        return x + c * px - s * py, y + s * px + c * py

    def _painted(self, court_xy: np.ndarray, index: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For (3, N) homogeneous court points of marks `index`: on their own colour, on another mark's."""
        col, row = np.rint(self.court_to_texel[:2] @ court_xy).astype(np.int64)
        h, w = self.labels.shape
        on_map = (row >= 0) & (row < h) & (col >= 0) & (col < w)
        painted = np.zeros(court_xy.shape[1], np.int64)
        painted[on_map] = self.labels[row[on_map], col[on_map]]
        own = painted == index + 1
        return own, (painted > 0) & ~own
