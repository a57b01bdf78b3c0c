"""One deployment file (TOML) configures every process of a robot or a pit laptop.

With no file, the defaults below are the built-in deployment: everything on one machine, the
simulated camera, the bundled model.
"""
from __future__ import annotations

import importlib
import math
from pathlib import Path
from typing import Callable, Optional

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from courtloc.common.bus import ZenohConfig
from courtloc.common.config_loader import load_model, resolve_relative_paths
from courtloc.common.runtime import Service
from courtloc.common.security import with_identity
from courtloc.common.services_table import SERVICES, check_robot_id
from courtloc.services.camera.config import CameraConfig
from courtloc.services.infer.config import InferConfig, StartConfig
from courtloc.services.preprocess.config import PreprocessConfig
from courtloc.services.shooter_bridge.config import ShooterConfig
from courtloc.sim.source import SimSourceConfig

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
    restart_backoff_s: float = Field(default=0.5, gt=0)
    restart_backoff_max_s: float = Field(default=5.0, gt=0)

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

    @model_validator(mode="after")
    def _one_court_by_default(self) -> "DeploymentConfig":
        court_name, camera_name = _court_and_camera(self.court, self.camera_model)
        infer_update = {k: v for k, v in (("court", court_name), ("camera", camera_name))
                        if k not in self.infer.model_fields_set}
        if self.camera.source == "sim" and "start" not in self.infer.model_fields_set:
            # The simulated robot starts where its trajectory does: the start a team would configure.
            infer_update["start"] = sim_start(self.camera.sim)
        self.infer = self.infer.model_copy(update=infer_update)
        if "court" not in self.camera.sim.model_fields_set:
            self.camera.sim = self.camera.sim.model_copy(update={"court": self.court})
        if self.camera_model is not None and "camera" not in self.camera.sim.model_fields_set:
            self.camera.sim = self.camera.sim.model_copy(update={"camera": self.camera_model})
        target = self.shooter_bridge.target
        if "court" not in target.model_fields_set and target.ring is None:
            self.shooter_bridge = self.shooter_bridge.model_copy(
                update={"target": target.model_copy(update={"court": self.court})})
        return self

    @field_validator("robot_id")
    @classmethod
    def _robot_id_is_a_key_chunk(cls, value: str) -> str:
        return check_robot_id(value)


def _court_and_camera(court: str, camera: str | None) -> tuple[str, str]:
    """Names of the deployment's court and camera, as packages' manifests carry them (files are read once)."""
    from courtloc.sim.camera import load_camera
    from courtloc.sim.court import load_court

    model = load_court(court)
    return model.name, load_camera(camera or model.default_camera).name


def sim_start(sim: SimSourceConfig) -> StartConfig | None:
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


# Stage classes are imported only when that stage runs: a camera process never loads onnxruntime.
_STAGE_CLASSES: dict[str, str] = {
    "camera": "courtloc.services.camera.service:CameraService",
    "preprocess": "courtloc.services.preprocess.service:PreprocessService",
    "infer": "courtloc.services.infer.service:InferService",
    "shooter_bridge": "courtloc.services.shooter_bridge.service:ShooterBridgeService",
}


def available_stages() -> list[str]:
    return [name for name in SERVICES if name in _STAGE_CLASSES]


def build_stage(name: str, config: DeploymentConfig) -> Service:
    if name not in _STAGE_CLASSES:
        raise ValueError(f"no stage {name!r}; available: {available_stages()}")
    module_name, class_name = _STAGE_CLASSES[name].split(":")
    stage_class: Callable[..., Service] = getattr(importlib.import_module(module_name), class_name)
    # Each stage presents its own certificate and password (the ACL grants per identity).
    zenoh_config = config.zenoh.model_copy(update={"security": with_identity(config.zenoh.security, name)})
    return stage_class(config.robot_id, zenoh_config, getattr(config, name))
