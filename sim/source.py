"""The simulated camera: drives the twin robot along a trajectory and renders what its camera sees.

The camera service paces it; here time is simply frame_index / fps, so a run is reproducible frame for
frame, and each read returns the frame together with the TRUE pose it was rendered at.
"""
from __future__ import annotations

import logging
import math
import time
from pathlib import Path
from typing import Literal, Optional

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator

from courtloc.services.camera.config import DEFAULT_SIM_WAYPOINTS
from courtloc.sim.render import Renderer, RenderOptions
from courtloc.sim.trajectory import CsvTrajectory, KidnapTrajectory, RandomWalkTrajectory, WaypointTrajectory
from courtloc.sim.twin_mcu import TwinMcu, TwinMcuConfig
from courtloc.world.camera import Pose, load_camera
from courtloc.world.court import load_court

log = logging.getLogger(__name__)

# The default route is the deployment's too (it tells the infer stage where the simulated robot starts):
# it lives with the camera config, which the robot side reads without importing the twin.
DEFAULT_WAYPOINTS: list[list[float]] = DEFAULT_SIM_WAYPOINTS


class SimSourceConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")
    court: str = Field("seed-gazebo", description="court name (world/courts) or JSON path")
    camera: Optional[str] = Field(None, description="camera name or JSON path; default: the court's camera")
    trajectory: Literal["waypoints", "random_walk", "csv"] = "waypoints"
    waypoints: list[list[float]] = Field(default_factory=lambda: [list(w) for w in DEFAULT_WAYPOINTS])
    speed_mps: float = Field(1.0, gt=0, le=10)
    yaw_rate_rps: float = Field(1.5, gt=0, le=20)
    margin_m: float = Field(0.3, ge=0, description="random walk: distance kept from the area's edge")
    csv_path: Optional[str] = None
    seed: int = 0
    render: RenderOptions = RenderOptions()
    fps: float = Field(30.0, gt=0, le=1000)
    start: Optional[list[float]] = Field(None, description="random walk: start pose [x, y, yaw] (default the centre, "
                                         "facing +x)")
    kidnaps_s: list[float] = Field(default_factory=list, description="times (s) the robot is teleported; after each it "
                                   "random-walks from the new pose")
    kidnap_same_half: bool = Field(True, description="teleport within the half the robot is in (see KidnapTrajectory)")
    outages_s: list[tuple[float, float]] = Field(default_factory=list, description="[start, end) times (s) the camera "
                                                 "shows nothing usable; the robot keeps moving")
    outage: Literal["dark", "blocked"] = Field("dark", description="dark: lens capped (black + sensor noise); "
                                               "blocked: something right in front of the lens")
    mcu: Optional[TwinMcuConfig] = Field(None, description="run the robot's MCU too: wheel odometry and gyro of "
                                         "this trajectory on a pty at `mcu.link` (see twin_mcu.py)")

    @field_validator("start")
    @classmethod
    def _start_is_a_pose(cls, value: Optional[list[float]]) -> Optional[list[float]]:
        if value is not None and len(value) != 3:
            raise ValueError(f"start must be [x, y, yaw], got {value}")
        return value

    @field_validator("outages_s")
    @classmethod
    def _outages_are_intervals(cls, value: list[tuple[float, float]]) -> list[tuple[float, float]]:
        for start, end in value:
            if not 0 <= start < end:
                raise ValueError(f"outage [{start}, {end}) must satisfy 0 <= start < end")
        return value

    def in_outage(self, t: float) -> bool:
        return any(start <= t < end for start, end in self.outages_s)


class SimSource:
    """open() -> read() -> (BGR frame, true pose) ... -> close(); also a context manager."""

    def __init__(self, config: SimSourceConfig) -> None:
        self.config = config
        self.frame_index = 0
        self._renderer = None
        self._trajectory = None
        self._mcu: TwinMcu | None = None
        self._t0_ns: int | None = None  # with the MCU: the host time of sim time 0 (the first read)
        self.taken_mono_ns: int | None = None  # with the MCU: the instant the last frame shows

    # ---- lifecycle ------------------------------------------------------------------------------
    def open(self) -> "SimSource":
        cfg = self.config
        court = load_court(cfg.court)
        camera = load_camera(cfg.camera or court.default_camera)
        self.court = court
        self._trajectory = self._build_trajectory(court)
        self._renderer = Renderer(court, camera)
        self.frame_index = 0
        self._t0_ns = self.taken_mono_ns = None
        if cfg.mcu is not None:
            self._mcu = TwinMcu(cfg.mcu, self._trajectory, cfg.kidnaps_s, seed=cfg.seed)
            self._mcu.start()
        log.info("sim source: court %s, camera %s, %s trajectory at %.1f fps", court.name, camera.name, cfg.trajectory,
                 cfg.fps)
        return self

    def warm_up(self) -> None:
        """Build the renderer's randomisation assets now, not on the frames that first draw them (a source read
        in real time would miss slots there)."""
        if self._renderer is None:
            raise RuntimeError("SimSource is not open: call open() first")
        self._renderer.warm_up(self.config.render)

    def close(self) -> None:
        if self._mcu is not None:
            self._mcu.stop()
            self._mcu = None
        self._renderer = None
        self._trajectory = None

    def __enter__(self) -> "SimSource":
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def camera(self):
        if self._renderer is None:
            raise RuntimeError("SimSource is not open")
        return self._renderer.camera

    @property
    def trajectory(self):
        """The robot's path (with `kidnaps_s`, the teleports too): what a simulated wheel odometry follows."""
        if self._trajectory is None:
            raise RuntimeError("SimSource is not open")
        return self._trajectory

    # ---- frames ---------------------------------------------------------------------------------
    def pose_at_index(self, index: int) -> Pose:
        if self._trajectory is None:
            raise RuntimeError("SimSource is not open: call open() first")
        return self._trajectory.pose_at(index / self.config.fps)

    def _shutter_open_pose(self, t: float, pose: Pose) -> Pose | None:
        """Where the robot was when the shutter opened (None: no motion blur, or a teleport in between)."""
        exposure = self.config.render.motion_blur_s
        if exposure <= 0:
            return None
        assert self._trajectory is not None
        start = self._trajectory.pose_at(max(t - exposure, 0.0))
        # A teleport inside the exposure is not motion: the frame shows where the robot is now.
        return start if math.hypot(start[0] - pose[0], start[1] - pose[1]) < 0.5 else None

    def read(self) -> tuple[np.ndarray, tuple[float, float, float]]:
        """The next frame (BGR uint8) and the true pose (x, y, yaw) it shows; time advances 1/fps, or
        with the MCU runs in real time (the frame shows the instant of the read, `taken_mono_ns`)."""
        if self._renderer is None:
            raise RuntimeError("SimSource is not open: call open() first")
        index = self.frame_index
        t = index / self.config.fps
        if self._mcu is not None:
            # The wheels drive in host time, so the frames must too: a frame shows the robot where it is
            # at the read, and a camera that cannot keep its rate misses moments instead of slowing it.
            self.taken_mono_ns = time.monotonic_ns()
            if self._t0_ns is None:
                self._t0_ns = self.taken_mono_ns
                self._mcu.clock.start(self._t0_ns)
            t = (self.taken_mono_ns - self._t0_ns) / 1e9
        assert self._trajectory is not None
        pose = self._trajectory.pose_at(t)
        if not self.court.contains(pose[0], pose[1]):
            raise ValueError(f"frame {index}: pose {pose} lies outside court {self.court.name!r}")
        # Each frame's randomisation depends only on (seed, frame index): reproducible from any start.
        rng = np.random.default_rng([self.config.seed, index])
        if self.config.in_outage(t):
            frame = self._outage_frame(rng)
        else:
            frame = self._renderer.render(pose, self.config.render, rng, self._shutter_open_pose(t, pose))
        self.frame_index += 1
        return frame, (float(pose[0]), float(pose[1]), float(pose[2]))

    def _outage_frame(self, rng: np.random.Generator) -> np.ndarray:
        cam = self.camera
        level = 6.0 if self.config.outage == "dark" else 60.0 + 40.0 * float(rng.random())
        noise = rng.normal(level, 3.0, (cam.height, cam.width, 1))
        return np.clip(np.repeat(noise, 3, axis=2), 0, 255).astype(np.uint8)

    @property
    def timestamp(self) -> float:
        """Simulated time of the next frame, seconds."""
        return self.frame_index / self.config.fps

    # ---- setup ----------------------------------------------------------------------------------
    def _build_trajectory(self, court):
        cfg = self.config
        hx, hy = court.area_half_extent_m
        where = f"court {court.name!r} (|x| <= {hx}, |y| <= {hy})"
        first = self._first_trajectory(court, where)
        if not cfg.kidnaps_s:
            return first
        return KidnapTrajectory(first, court, cfg.kidnaps_s, cfg.speed_mps, cfg.yaw_rate_rps, cfg.seed,
                                cfg.margin_m, cfg.kidnap_same_half)

    def _first_trajectory(self, court, where: str):
        cfg = self.config
        if cfg.start is not None and cfg.trajectory != "random_walk":
            raise ValueError(f"start applies to the random walk only, not trajectory {cfg.trajectory!r}")
        if cfg.trajectory == "waypoints":
            for i, w in enumerate(cfg.waypoints):
                if len(w) < 2 or not court.contains(w[0], w[1]):
                    raise ValueError(f"waypoints[{i}] = {w} lies outside {where}")
            return WaypointTrajectory(cfg.waypoints, cfg.speed_mps, cfg.yaw_rate_rps)
        if cfg.trajectory == "random_walk":
            start = None
            if cfg.start is not None:
                if not court.contains(cfg.start[0], cfg.start[1]):
                    raise ValueError(f"start {cfg.start} lies outside {where}")
                start = (float(cfg.start[0]), float(cfg.start[1]), float(cfg.start[2]))
            return RandomWalkTrajectory(court, cfg.speed_mps, cfg.yaw_rate_rps, cfg.seed, cfg.margin_m, start=start)
        if not cfg.csv_path:
            raise ValueError("csv_path is required for trajectory 'csv'")
        traj = CsvTrajectory(Path(cfg.csv_path), cfg.fps)
        outside = np.flatnonzero(~court.contains(traj.poses[:, 0], traj.poses[:, 1]))
        if len(outside):
            i = int(outside[0])
            raise ValueError(f"{cfg.csv_path} row {i + 1}: pose {tuple(traj.poses[i])} lies outside {where} "
                             f"({len(outside)} rows outside)")
        return traj
