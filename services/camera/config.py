"""Camera service settings."""
from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

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
    # The simulated camera is the digital twin (courtloc.sim), which a robot with a real camera never loads:
    # its table stays raw here and the twin validates it when source = "sim" (see sim/source.py for fields).
    sim: dict[str, Any] = Field(default_factory=dict)

    @model_validator(mode="after")
    def _source_section_present(self) -> "CameraConfig":
        if self.source in ("file", "folder") and getattr(self, self.source) is None:
            raise ValueError(f"source = {self.source!r} needs a [camera.{self.source}] section")
        if self.source == "sim":
            sim_source_config(self)  # a bad [camera.sim] table fails here, at start, naming its field
        return self


def sim_source_config(config: CameraConfig) -> "SimSourceConfig":  # noqa: F821 - the twin's type
    """The [camera.sim] table as the twin's own config, paced at the camera's rate."""
    from courtloc.sim.source import SimSourceConfig  # the twin: loaded only when the camera is simulated

    return SimSourceConfig.model_validate({**config.sim, "fps": config.fps})
