"""Camera service settings."""
from __future__ import annotations

from pathlib import Path
from typing import Any, Literal, Optional

from pydantic import BaseModel, ConfigDict, Field, model_validator


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid")


class DeviceSourceConfig(_Section):
    device: str = Field(default="0", description="a V4L2 index ('0') or a GStreamer pipeline string")
    width: int = Field(default=640, gt=0)
    height: int = Field(default=480, gt=0)
    fps: float = Field(default=30.0, gt=0)


class FileSourceConfig(_Section):
    path: Path
    loop: bool = True


class FolderSourceConfig(_Section):
    path: Path
    csv: Path | None = Field(default=None, description="seed-format poses, published as ground truth")
    pattern: str = "*.jpg"
    loop: bool = True


# The simulated camera is the digital twin's (courtloc.sim), which nothing on the robot side imports. Its
# [camera.sim] table stays raw here: the twin's camera stage (sim/camera_stage.py) validates all of it, and
# `courtloc up` and `courtloc run camera` check it before anything starts. What the deployment itself reads of
# it is the route's start (SimRoute), the infer stage's start in a simulated deployment.
DEFAULT_SIM_WAYPOINTS: list[list[float]] = [[3.0, -2.0], [3.0, 2.0], [-3.0, 2.0], [-3.0, -2.0]]
"""A loop around the seed court that sees the key, the three-point line and the centre line. Starts in the +x
half, where the bundled localizer assumes a robot starts (its `half`), then tours both. The twin's default."""


class SimRoute(BaseModel):
    """Where the simulated robot starts, as far as the [camera.sim] table says (its other fields are the twin's
    to check). The defaults are the twin's own (sim/source.py: SimSourceConfig)."""

    model_config = ConfigDict(extra="ignore")
    trajectory: str = "waypoints"
    waypoints: list[list[float]] = Field(default_factory=lambda: [list(w) for w in DEFAULT_SIM_WAYPOINTS])
    start: Optional[tuple[float, float, float]] = Field(None, description="random walk: start pose [x, y, yaw]")


class CameraConfig(_Section):
    source: Literal["device", "file", "folder", "sim"] = "sim"
    fps: float = Field(default=30.0, gt=0, le=240)
    encoding: Literal["bgr8", "jpeg"] = Field(
        default="bgr8", description="bgr8 on the robot; jpeg when the next hop crosses Wi-Fi")
    jpeg_quality: int = Field(default=85, ge=10, le=100)
    shm_pool_mb: float = Field(
        default=16.0, ge=2.0, le=512.0, description="shared-memory pool for frames (a 640x480 BGR frame is 0.9 MB); "
        "when subscribers hold it all, frames go out as plain bytes and are counted")
    reopen_backoff_s: float = Field(default=0.5, gt=0)
    reopen_backoff_max_s: float = Field(default=5.0, gt=0)
    device: DeviceSourceConfig = Field(default_factory=DeviceSourceConfig)
    file: FileSourceConfig | None = None
    folder: FolderSourceConfig | None = None
    sim: dict[str, Any] = Field(default_factory=dict, description="the twin's simulated camera, raw (see above)")

    @model_validator(mode="after")
    def _source_section_present(self) -> "CameraConfig":
        if self.source in ("file", "folder") and getattr(self, self.source) is None:
            raise ValueError(f"source = {self.source!r} needs a [camera.{self.source}] section")
        if self.source == "sim":
            self.sim_route()  # a bad route fails here, at start, naming its field
        return self

    def sim_route(self) -> SimRoute:
        return SimRoute.model_validate(self.sim)
