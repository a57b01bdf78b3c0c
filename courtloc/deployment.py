"""One deployment file (TOML) configures every process of a robot or a pit laptop.

With no file, the defaults below are the built-in deployment: everything on one machine, the
simulated camera, the bundled model.
"""
from __future__ import annotations

import importlib
from pathlib import Path
from typing import Callable

from pydantic import BaseModel, ConfigDict, Field, field_validator

from courtloc.common.bus import ZenohConfig
from courtloc.common.config_loader import load_model
from courtloc.common.runtime import Service
from courtloc.common.services_table import SERVICES, check_robot_id
from courtloc.services.camera.config import CameraConfig

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"


class RouterConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")
    listen: list[str] = Field(default_factory=lambda: [DEFAULT_ENDPOINT])


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
    zenoh: ZenohConfig = Field(default_factory=ZenohConfig)
    router: RouterConfig = Field(default_factory=RouterConfig)
    launcher: LauncherConfig = Field(default_factory=LauncherConfig)
    camera: CameraConfig = Field(default_factory=CameraConfig)

    @field_validator("robot_id")
    @classmethod
    def _robot_id_is_a_key_chunk(cls, value: str) -> str:
        return check_robot_id(value)


def load_deployment(path: Path | None) -> DeploymentConfig:
    return load_model(path, DeploymentConfig)


# Stage classes are imported only when that stage runs: a camera process never loads onnxruntime.
_STAGE_CLASSES: dict[str, str] = {
    "camera": "courtloc.services.camera.service:CameraService",
}


def available_stages() -> list[str]:
    return [name for name in SERVICES if name in _STAGE_CLASSES]


def build_stage(name: str, config: DeploymentConfig) -> Service:
    if name not in _STAGE_CLASSES:
        raise ValueError(f"no stage {name!r}; available: {available_stages()}")
    module_name, class_name = _STAGE_CLASSES[name].split(":")
    stage_class: Callable[..., Service] = getattr(importlib.import_module(module_name), class_name)
    return stage_class(config.robot_id, config.zenoh, getattr(config, name))
