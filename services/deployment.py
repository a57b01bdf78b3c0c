"""One deployment file (TOML) configures every process of a robot or a pit laptop.

With no file, the defaults below are the built-in deployment: everything on one machine, the
simulated camera, the bundled model.
"""
from __future__ import annotations

import argparse
import logging
import math
import sys
from pathlib import Path
from typing import Optional, Sequence

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from courtloc.common.bus import RouterUnreachable, ZenohConfig, check_zenoh_id, wait_for_router
from courtloc.common.config_loader import ConfigError, load_model, resolve_relative_paths
from courtloc.common.exposure import insecure_exposure, is_loopback, warn_while_insecure
from courtloc.common.realtime import RealtimeConfig, RealtimeError, apply_realtime
from courtloc.common.runtime import HEALTH_PERIOD_S, Service
from courtloc.common.security import with_identity
from courtloc.common.services_table import SERVICES, check_robot_id
from courtloc.scan.config import HsvRange, MarkClass, PreprocessConfig
from courtloc.services.camera.config import CameraConfig, SimRoute
from courtloc.services.infer.config import InferConfig, StartConfig
from courtloc.services.shooter_bridge.config import ShooterConfig
from courtloc.world.camera import load_camera
from courtloc.world.court import load_court

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"


class RouterConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")
    listen: list[str] = Field(default_factory=lambda: [DEFAULT_ENDPOINT])
    connect: list[str] = Field(default_factory=list, description="other routers to join (a split deployment)")
    secure_dir: Path | None = Field(
        default=None, description="robot bundle of `courtloc secure init`: require mTLS + password, enforce the ACL")


class LauncherConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")
    services: list[str] = Field(default_factory=lambda: list(SERVICES))
    run_router: bool = Field(default=True, description="start an in-process router before the stages")
    restart_backoff_s: float = Field(default=0.5, gt=0, description="a stage's first restart delay; doubles")
    restart_backoff_max_s: float = Field(default=5.0, gt=0)
    restart_healthy_s: float = Field(default=10.0, gt=0, description="a stage up this long is healthy: its "
                                     "next restart starts from the first delay again")
    router_restart_backoff_s: float = Field(default=0.1, ge=0, description="the router's first restart delay "
                                            "(every stage waits on it); doubles up to restart_backoff_s")

    @field_validator("services")
    @classmethod
    def _known_services(cls, names: list[str]) -> list[str]:
        unknown = [n for n in names if n not in SERVICES]
        if unknown:
            raise ValueError(f"unknown service(s) {unknown}; known: {sorted(SERVICES)}")
        return names


class DeploymentConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")

    robot_id: str = "robot1"
    court: str = Field(default="seed-gazebo", description="the court every stage assumes unless its own "
                       "section names one (sim camera, shooter target, the localizer package the infer stage serves)")
    camera_model: Optional[str] = Field(default=None, description="the robot's camera model (name or JSON path) "
                                        "when it is not the court's own (`default_camera` of the court file)")
    zenoh: ZenohConfig = Field(default_factory=ZenohConfig)
    router: RouterConfig = Field(default_factory=RouterConfig)
    launcher: LauncherConfig = Field(default_factory=LauncherConfig)
    camera: CameraConfig = Field(default_factory=CameraConfig)
    preprocess: PreprocessConfig = Field(default_factory=PreprocessConfig)
    infer: InferConfig = Field(default_factory=InferConfig)
    shooter_bridge: ShooterConfig = Field(default_factory=ShooterConfig)
    realtime: RealtimeConfig = Field(default_factory=RealtimeConfig,
                                     description="optional CPU affinity / SCHED_FIFO per stage, off by default")
    health_period_s: float = Field(default=HEALTH_PERIOD_S, gt=0.0, le=60.0,
                                   description="seconds between two health reports of each stage")
    insecure: bool = Field(default=False, description="allow listening beyond loopback without the security "
                           "bundle (a warning is logged every minute while it does)")

    @model_validator(mode="after")
    def _one_court_by_default(self) -> "DeploymentConfig":
        court_name, camera_name = _court_and_camera(self.court, self.camera_model)
        infer_update = {k: v for k, v in (("court", court_name), ("camera", camera_name))
                        if k not in self.infer.model_fields_set}
        if "court" not in self.camera.sim:
            self.camera.sim = {**self.camera.sim, "court": self.court}
        if self.camera_model is not None and "camera" not in self.camera.sim:
            self.camera.sim = {**self.camera.sim, "camera": self.camera_model}
        if self.camera.source == "sim" and "start" not in self.infer.model_fields_set:
            # The simulated robot starts where its trajectory does: the start a team would configure.
            infer_update["start"] = sim_start(self.camera.sim_route())
        self.infer = self.infer.model_copy(update=infer_update)
        if "marks" not in self.preprocess.model_fields_set:
            # The court's asymmetric colours, in the court's order: the infer stage reads a mark's index so.
            self.preprocess = self.preprocess.model_copy(update={"marks": court_marks(self.court)})
        target = self.shooter_bridge.target
        if "court" not in target.model_fields_set and target.ring is None:
            self.shooter_bridge = self.shooter_bridge.model_copy(
                update={"target": target.model_copy(update={"court": self.court})})
        return self

    @field_validator("robot_id")
    @classmethod
    def _robot_id_is_a_key_chunk(cls, value: str) -> str:
        return check_robot_id(value)

    @model_validator(mode="after")
    def _secure_beyond_loopback(self) -> "DeploymentConfig":
        """Other teams share the arena network: whatever listens beyond loopback requires mTLS, unless
        the file says `insecure = true` in so many words."""
        if self.insecure:
            return self
        if any(not is_loopback(ep) for ep in self.router.listen) and self.router.secure_dir is None:
            raise ValueError(f"router.listen {self.router.listen} is reachable beyond this machine without "
                             "router.secure_dir (run `courtloc secure init`), or set insecure = true")
        if any(not is_loopback(ep) for ep in self.zenoh.listen) and self.zenoh.security is None:
            raise ValueError(f"zenoh.listen {self.zenoh.listen} is reachable beyond this machine without "
                             "[zenoh.security], or set insecure = true")
        return self

    def as_fresh_run(self) -> "DeploymentConfig":
        """The deployment for the first start of a run: the infer stage does not resume a pose an earlier run
        saved (its configured start is this run's evidence; a saved pose seconds old from the previous run,
        grown by its age, explained both mirror twins and left the localizer ambiguous for good)."""
        return self.model_copy(update={"infer": self.infer.model_copy(update={"resume_max_age_s": 0.0})})


def _court_and_camera(court: str, camera: str | None) -> tuple[str, str]:
    """Names of the deployment's court and camera, as packages' manifests carry them (files are read once)."""
    model = load_court(court)
    return model.name, load_camera(camera or model.default_camera).name


def court_marks(court: str) -> tuple[MarkClass, ...]:
    """The preprocess stage's colour marks for a court (`Court.marks`)."""
    return tuple(MarkClass(name=m.name, hsv_ranges=tuple(HsvRange(lower=lo, upper=hi) for lo, hi in m.hsv_ranges))
                 for m in load_court(court).marks)


def sim_start(sim: SimRoute) -> StartConfig | None:
    """Where the simulated robot starts, as a start with a generous spread (the stages come up while it
    already drives: the infer stage's first frame can be seconds into the run)."""
    if sim.trajectory == "waypoints" and len(sim.waypoints) >= 2:
        first, second = sim.waypoints[0], sim.waypoints[1]
        yaw = first[2] if len(first) > 2 else math.atan2(second[1] - first[1], second[0] - first[0])
        return StartConfig(x=first[0], y=first[1], yaw_deg=math.degrees(yaw), std_m=1.5, yaw_std_deg=60.0)
    if sim.trajectory == "random_walk":  # at `start`, else RandomWalkTrajectory's centre facing +x
        x, y, yaw = sim.start or (0.0, 0.0, 0.0)
        return StartConfig(x=x, y=y, yaw_deg=math.degrees(yaw), std_m=1.5, yaw_std_deg=60.0)
    return None


def load_deployment(path: Path | None) -> DeploymentConfig:
    config = load_model(path, DeploymentConfig)
    return config if path is None else resolve_relative_paths(config, Path(path).resolve().parent)


def stage_main(stage_class: type[Service], argv: Sequence[str] | None = None) -> int:
    """The entry point of one stage process (`python -m courtloc.services.<stage> --config FILE`).

    A stage process loads its own stage and nothing else: a camera never loads onnxruntime.
    """
    parser = argparse.ArgumentParser(prog=f"python -m courtloc.services.{stage_class.name}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")
    parser.add_argument("--config", type=Path, default=None, help="deployment TOML (default: built-in)")
    parser.add_argument("--timeout", type=float, default=None, help="give up when no router answers within S s")
    parser.add_argument("--fresh-run", action="store_true",
                        help="a new run (the launcher's first start): a pose saved by an earlier run is not resumed")
    parser.add_argument("--expect-router", type=_zenoh_id_argument, default=None, metavar="ZID",
                        help="the zenoh id of the router `courtloc up` started: connected to any other router "
                             "(another pipeline's, on the port after ours died) the stage exits non-zero")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING - 10 * min(args.verbose, 2),
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        config = load_deployment(args.config)
    except ConfigError as exc:
        print(exc, file=sys.stderr)
        return 2
    if args.fresh_run:
        config = config.as_fresh_run()
    name = stage_class.name
    try:
        # Each stage presents its own certificate and password (the ACL grants per identity).
        zenoh_config = config.zenoh.model_copy(update={"security": with_identity(config.zenoh.security, name)})
        stage = stage_class(config.robot_id, zenoh_config, getattr(config, name))  # a bad input file stops it here
        stage.health_period_s = config.health_period_s
        stage.expected_router_id = args.expect_router
        applied = apply_realtime(name, config.realtime)
        if zenoh_config.mode == "client":  # a peer opens without a router; a client waits for one
            wait_for_router(zenoh_config, args.timeout)
    except (ValueError, OSError, RealtimeError) as exc:  # ConfigError, a table or credential file, no router
        print(f"{name}: {exc}", file=sys.stderr)
        return 1 if isinstance(exc, RouterUnreachable) else 2
    if applied:
        logging.getLogger(f"courtloc.{name}").info("real-time settings: %s", ", ".join(applied))
    warn_while_insecure(insecure_exposure(config.zenoh.listen, config.zenoh.security is not None),
                        stage.stop_event, logging.getLogger(f"courtloc.{name}"))
    return stage.run()


def _zenoh_id_argument(value: str) -> str:
    try:
        return check_zenoh_id(value)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
