"""The last tracked pose on disk, so a restarted infer stage resumes from where the robot was.

Why: after a restart (a crash, kill -9, an update) the stage has no track, and on a point-symmetric court
a fresh view cannot tell the robot's pose from its mirror image; the configured start is the evidence of
a *fresh* run and would pick the wrong twin mid-run. The saved pose is that evidence instead: the
localizer's acquisition takes it as a prior whose uncertainty grows with its age (acquire.py).
Written at most twice a second from valid tracked frames (write to a temporary file, then rename: a
reader never sees half a file; no fsync: losing the last half second on a power cut costs nothing).
"""
from __future__ import annotations

import logging
import os
import time
from pathlib import Path

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from courtloc.localizer.acquire import Prior
from courtloc.localizer.odometry_buffer import OdometrySample

log = logging.getLogger(__name__)
SAVE_PERIOD_NS = 500_000_000


class SavedOdometry(BaseModel):
    """One buffered odometry sample (localizer.odometry_buffer.OdometrySample)."""

    model_config = ConfigDict(extra="forbid")
    t: float
    epoch: int
    pose: tuple[float, float, float]
    slip: bool
    source_ns: int
    seq: int
    cut: tuple[float, float] = (0.0, 0.0)

    @classmethod
    def of(cls, sample: OdometrySample) -> SavedOdometry:
        return cls(**sample.__dict__)

    def sample(self) -> OdometrySample:
        return OdometrySample(**self.model_dump())


class SavedPose(BaseModel):
    model_config = ConfigDict(extra="forbid")
    robot_id: str
    court: str
    x: float
    y: float
    yaw: float
    std_m: float = Field(ge=0)
    yaw_std_rad: float = Field(ge=0)
    wall_ns: int = Field(description="capture wall-clock time of the frame the pose is from")
    t_s: float | None = Field(default=None, description="the same frame's time on the frames' monotonic clock")
    odometry: list[SavedOdometry] = Field(default_factory=list, max_length=16, description="buffered odometry from "
                                          "the pose's time on (the fusion's snapshot), so a restarted stage carries "
                                          "the pose across the restart instead of growing its spread with its age")
    odometry_last: SavedOdometry | None = Field(default=None, description="the newest odometry sample as received")

    def age_s(self, now_ns: int | None = None) -> float:
        return ((now_ns or time.time_ns()) - self.wall_ns) * 1e-9

    def prior(self) -> Prior:
        """The pose as a prior. Its time `t_s` stays with it: the tracker keeps it only where the frames' clock
        agrees with the wall clock about the pose's age (`Tracker.state_for`), else the prior is aged by wall time."""
        return Prior(source="track", pose=np.array([self.x, self.y, self.yaw]), std_m=self.std_m,
                     yaw_std_rad=self.yaw_std_rad, t=self.t_s)

    def odometry_snapshot(self) -> tuple[list[OdometrySample], OdometrySample | None]:
        if not self.odometry or self.odometry_last is None:
            return [], None
        return [s.sample() for s in self.odometry], self.odometry_last.sample()


class ResumeFile:
    def __init__(self, path: Path, robot_id: str) -> None:
        self.path = Path(path)
        self.robot_id = robot_id
        self._last_ns = 0

    def load(self, court: str, max_age_s: float) -> SavedPose | None:
        """The saved pose when it is this robot's, on this court, and at most max_age_s old (a time stamp from
        the future is as unusable as a stale one)."""
        try:
            saved = SavedPose.model_validate_json(self.path.read_bytes())
        except FileNotFoundError:
            return None
        except (OSError, ValidationError, ValueError) as exc:
            log.warning("ignoring the saved pose %s: %s", self.path, str(exc).splitlines()[0])
            return None
        age = saved.age_s()
        if saved.robot_id != self.robot_id or saved.court != court or not 0.0 <= age <= max_age_s:
            log.info("not resuming from %s (robot %s, court %s, %.1f s old)", self.path, saved.robot_id, saved.court,
                     age)
            return None
        return saved

    def due(self, wall_ns: int) -> bool:
        """Whether a pose of this time would be saved (the last save is at least SAVE_PERIOD_NS old)."""
        return wall_ns - self._last_ns >= SAVE_PERIOD_NS

    def offer(self, prior: Prior | None, court: str, wall_ns: int,
              odometry: tuple[list[OdometrySample], OdometrySample | None] = ([], None)) -> None:
        """Save a tracked pose (and the odometry snapshot from its time on) when `due`."""
        if prior is None or prior.pose is None or not self.due(wall_ns):
            return
        self._last_ns = wall_ns
        samples, last = odometry
        saved = SavedPose(robot_id=self.robot_id, court=court, x=float(prior.pose[0]), y=float(prior.pose[1]),
                          yaw=float(prior.pose[2]), std_m=float(prior.std_m), yaw_std_rad=float(prior.yaw_std_rad or 0.0),
                          wall_ns=wall_ns, t_s=prior.t, odometry=[SavedOdometry.of(s) for s in samples] if last else [],
                          odometry_last=SavedOdometry.of(last) if last else None)
        tmp = self.path.with_name(self.path.name + ".tmp")
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            tmp.write_text(saved.model_dump_json())
            os.replace(tmp, self.path)
        except OSError as exc:  # a full or read-only disk must not stop inference
            log.warning("cannot save the pose to %s: %s", self.path, exc)
