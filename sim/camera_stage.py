"""`python -m courtloc.sim.camera_stage [--config FILE]`: the camera stage with the twin as its camera.

The robot side never imports the twin, so the camera stage (courtloc.services.camera) opens only real
sources. This entry point runs that very service class with the twin's simulated camera added to its source
kinds as "sim": same loop, pacing, encoding, shared memory, health and ground truth. `courtloc up` (the
launcher), `courtloc run camera` and the tests' buskit start it when the deployment's [camera] source is
"sim" (courtloc/stage_cli.py: stage_module).
"""
from __future__ import annotations

import sys
import time
from typing import Any, Callable, ClassVar, Mapping

import numpy as np
from pydantic import ValidationError

from courtloc.common.config_loader import ConfigError, describe_validation_error
from courtloc.services.camera.config import CameraConfig
from courtloc.services.camera.service import CameraService
from courtloc.services.camera.sources import Capture, SourceFactory
from courtloc.services.deployment import stage_main
from courtloc.sim.source import SimSource, SimSourceConfig


def sim_source_config(camera: CameraConfig) -> SimSourceConfig:
    """The deployment's [camera.sim] table as the twin's config, paced at the camera's rate. A bad table is a
    ConfigError naming each bad field by its place in the deployment file (camera.sim.<field>)."""
    try:
        return SimSourceConfig.model_validate({**camera.sim, "fps": camera.fps})
    except ValidationError as exc:
        moved: list[Any] = [{**e, "loc": ("camera", "sim", *e["loc"])} for e in exc.errors()]
        relocated = ValidationError.from_exception_data("DeploymentConfig", moved)
        raise ConfigError(describe_validation_error("the deployment's [camera.sim] table", relocated)) from None


class SimFrameSource:
    """The camera stage's source over the twin's (its own trajectory and renderer; with [camera.sim.mcu] also
    the robot's MCU on a pty): each frame with the true pose it shows and, with the MCU, the instant it shows."""

    def __init__(self, config: CameraConfig, clock: Callable[[], int] = time.monotonic_ns) -> None:
        self._sim = SimSource(sim_source_config(config))
        self._fps = config.fps
        self._clock = clock
        self._t0_ns: int | None = None

    def open(self) -> None:
        self._sim.open()
        self._sim.warm_up()  # before the clock starts: the first frames come at the camera's rate
        self._t0_ns = None

    def read(self, out: np.ndarray | None = None) -> Capture:
        # A real camera's frame shows the moment it was taken: a slot the stage missed (a slow render, a busy
        # host) is time the robot kept moving through, not a pause of the world. Frame i used to show i/fps
        # whatever the clock said, so after a missed slot the stamps ran 33 ms ahead of the motion shown and
        # the tracker's filter saw the robot move at half its speed for a frame.
        now = self._clock()
        if self._t0_ns is None:
            self._t0_ns = now
        self._sim.frame_index = max(self._sim.frame_index, round((now - self._t0_ns) * self._fps / 1e9))
        frame, pose = self._sim.read()
        return Capture(frame, pose, self._sim.taken_mono_ns)

    def close(self) -> None:
        self._sim.close()


class SimCameraService(CameraService):
    """The camera stage, able to open the twin's simulated camera too."""

    sources: ClassVar[Mapping[str, SourceFactory]] = {**CameraService.sources, "sim": SimFrameSource}


if __name__ == "__main__":
    sys.exit(stage_main(SimCameraService))
