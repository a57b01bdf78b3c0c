"""Usable views for `courtloc bench twin`: the frames whose lines alone place the robot.

Issue 20 times a recovery "within 1 s of a usable view". After a kidnap the twin robot may face no lines,
or only lines along one direction (a view that cannot pin the pose down): no localizer can be back before
the camera sees something it can place, so the clock starts at the first frame it could. A frame's view
is usable when the bundled localizer's fit started AT the frame's true pose has the inliers a valid fit
needs, pins the position to `USABLE_STD_M` in its worst direction, and stays within `NEAR_M` of the
truth (a fit that slides to another basin placed the robot elsewhere). The std bound is looser than a
lone fit's validity (0.08 m): the tracker combines frames, and a start view pinned to 0.1 m is valid
within a few of them; a degenerate view's std along its lines is metres or unbounded. It is judged with
the package built for the court and the camera the twin renders with, whatever model the infer stage
serves.

The side of a point-symmetric court is not part of it: no view tells the twins apart there, so a kidnap
on seed-gazebo can stay unrecovered however usable its views are.
"""
from __future__ import annotations

import logging
import math
from dataclasses import replace

import numpy as np

from courtloc.bench_twin_metrics import Event, TruthSample, in_windows
from courtloc.lab.metrics import WRONG_M
from courtloc.localizer.fit import fit_pose
from courtloc.localizer.manifest import ManifestError
from courtloc.localizer.package import bundled_package
from courtloc.localizer.predictor import GeometricPredictor, load_predictor

log = logging.getLogger("courtloc.bench_twin")
# Half the bench's "wrong" distance: a valid fit this close to the truth is the truth's basin (the twin's
# valid fits are a few cm off; the next basins, the court's parallel lines, are 0.5 m and more away).
NEAR_M = WRONG_M / 2
USABLE_STD_M = 0.15


class ViewJudge:
    """Whether a frame's hits place the robot at its true pose (module docstring)."""

    def __init__(self, predictor: GeometricPredictor) -> None:
        self.predictor = predictor
        self.quality = predictor.localizer.config.quality.model_copy(update={"max_position_std_m": USABLE_STD_M})

    def usable(self, hits: np.ndarray, truth: TruthSample) -> bool:
        if not len(hits):
            return False
        loc = self.predictor.localizer
        start = np.array([truth.x, truth.y, truth.yaw])
        fit = fit_pose(loc.field, self.predictor.projected_hits(hits), start, loc.config.fit, self.quality)
        return bool(fit.valid) and math.hypot(*(fit.pose[:2] - start[:2])) <= NEAR_M


def view_judge(court: str, camera: str) -> ViewJudge | None:
    """The judge for the twin's court and camera; None (recoveries timed from the event) when no package
    was built for them."""
    try:
        predictor = load_predictor(bundled_package(court, camera))
    except ManifestError as exc:
        log.warning("recoveries are timed from the event, not from a usable view: %s", exc)
        return None
    if not isinstance(predictor, GeometricPredictor):
        log.warning("recoveries are timed from the event: the bundled %s / %s package is no geometric localizer",
                    court, camera)
        return None
    return ViewJudge(predictor)


def with_views(events: list[Event], truths: list[TruthSample], hits_by_capture: dict[int, np.ndarray],
               judge: ViewJudge | None, end_ns: int) -> list[Event]:
    """Each event with `view_ns`: the capture of the first usable view at or after it and before the next
    event (or `end_ns`); None when there was none. Without a judge, the events as they are (timed from
    their own first frame)."""
    if judge is None:
        return list(events)
    frames = sorted((t for t in truths if t.capture_ns in hits_by_capture), key=lambda t: t.capture_ns)
    out = []
    for event, horizon in in_windows(events, end_ns):
        view = next((t.capture_ns for t in frames if event.start_ns <= t.capture_ns < horizon
                     and judge.usable(hits_by_capture[t.capture_ns], t)), None)
        out.append(replace(event, view_ns=view))
    return out
