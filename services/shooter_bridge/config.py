"""Settings of the shooter bridge (one TOML file; unknown keys are an error, named with their field)."""
from __future__ import annotations

from pathlib import Path
from typing import Literal, Optional, Union

from pydantic import BaseModel, ConfigDict, Field, model_validator

from courtloc.common.config_loader import load_model, resolve_relative_paths
from courtloc.services.shooter_bridge.odometry import OdometryConfig
from courtloc.shot.ballistics import ShotModel
from courtloc.shot.geometry import ShooterMount, ring_for
from courtloc.shot.rpm import PriorSource, RpmSource, TableWatcher


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class MountConfig(_Strict):
    """The release point in the robot frame."""

    forward_m: float = Field(0.0, description="ahead of the pose origin, along the robot's heading")
    left_m: float = Field(0.0, description="to the left of the pose origin")
    release_height_m: float = Field(0.9, gt=0, le=3.0, description="above the floor")

    def mount(self) -> ShooterMount:
        return ShooterMount(self.forward_m, self.left_m, self.release_height_m)


class TargetConfig(_Strict):
    court: str = Field("robocon2025", description="court model name (world/courts) or path to its JSON")
    basket: Union[Literal["positive_x", "negative_x"], int] = Field(
        "positive_x", description="the ring on that half of the court, or an index into the court's rings")
    ring: Optional[tuple[float, float, float]] = Field(None, description="ring centre (x, y, z); overrides the court")

    def ring_centre(self) -> tuple[float, float, float]:
        return self.ring if self.ring is not None else ring_for(self.court, self.basket)


class PhysicsConfig(_Strict):
    """The prior used when no calibration table is configured (and the base of `courtloc shooter fit`)."""

    launch_angle_deg: float = Field(60.0, gt=0, lt=90)
    drag_per_m: float = Field(0.0, ge=0, le=0.5, description="k in a = -k|v|v; ~0.02 for a size-7 basketball")
    wheel_radius_m: float = Field(0.05, gt=0, le=0.5)
    slip: float = Field(0.7, gt=0, le=1.0, description="ball exit speed / wheel surface speed")
    min_distance_m: float = Field(0.5, ge=0, description="range tabulated at start-up")
    max_distance_m: float = Field(10.0, gt=0)

    def model(self, release_height_m: float, ring_height_m: float = 2.43) -> ShotModel:
        return ShotModel(release_height_m=release_height_m, ring_height_m=ring_height_m,
                         launch_angle_deg=self.launch_angle_deg, drag_per_m=self.drag_per_m,
                         wheel_radius_m=self.wheel_radius_m, slip=self.slip)


class RpmConfig(_Strict):
    table: Optional[Path] = Field(None, description="CSV of measured distance_m,rpm; relative to the config file")
    reload_interval_s: float = Field(0.5, gt=0, description="how often the table file is checked for changes")
    physics: PhysicsConfig = Field(default_factory=PhysicsConfig)


class AreaConfig(_Strict):
    """Where the robot may shoot from. `court` = the court model's robot area; else a rectangle or polygon."""

    kind: Literal["court", "rectangle", "polygon"] = "court"
    x_min: float = -7.5
    x_max: float = 7.5
    y_min: float = -4.0
    y_max: float = 4.0
    polygon: list[tuple[float, float]] = Field(default_factory=list)

    @model_validator(mode="after")
    def _shape(self) -> "AreaConfig":
        if self.kind == "rectangle" and not (self.x_min < self.x_max and self.y_min < self.y_max):
            raise ValueError("area: x_min < x_max and y_min < y_max are required")
        if self.kind == "polygon" and len(self.polygon) < 3:
            raise ValueError("area.polygon needs at least 3 vertices")
        return self


class PolicyConfig(_Strict):
    freshness_s: float = Field(0.2, gt=0, description="a pose older than this gives HOLD")
    min_rpm: float = Field(500.0, ge=0)
    max_rpm: float = Field(5000.0, gt=0, le=65535)
    idle_rpm: float = Field(0.0, ge=0, description="where the slew reference decays to while holding")
    slew_rpm_per_s: float = Field(3000.0, gt=0)
    min_distance_m: float = Field(0.0, ge=0, description="closer than this gives HOLD (out_of_range)")
    max_distance_m: Optional[float] = Field(None, gt=0, description="farther than this gives HOLD (out_of_range)")
    hold_beyond_table: bool = Field(False, description="HOLD instead of clamping outside the table's distances")
    max_bearing_rad: Optional[float] = Field(None, gt=0, description="HOLD (not_facing) when yaw is known and the "
                                             "ring is more than this off the firing line")
    area: AreaConfig = Field(default_factory=AreaConfig)

    @model_validator(mode="after")
    def _limits(self) -> "PolicyConfig":
        if self.min_rpm > self.max_rpm:
            raise ValueError(f"min_rpm {self.min_rpm} > max_rpm {self.max_rpm}")
        if self.max_distance_m is not None and self.max_distance_m <= self.min_distance_m:
            raise ValueError("max_distance_m must exceed min_distance_m")
        return self


class LinkConfig(_Strict):
    port: str = Field("/dev/ttyACM0", description="serial device path (a stable /dev/serial/by-id link is best)")
    baud: int = Field(115200, gt=0)
    heartbeat_s: float = Field(0.1, gt=0, le=5.0, description="a HEARTBEAT goes out when nothing else did for this long")
    reconnect_initial_s: float = Field(0.1, gt=0)
    reconnect_max_s: float = Field(5.0, gt=0)
    write_timeout_s: float = Field(0.05, gt=0)

    @model_validator(mode="after")
    def _backoff(self) -> "LinkConfig":
        if self.reconnect_max_s < self.reconnect_initial_s:
            raise ValueError("reconnect_max_s must be >= reconnect_initial_s")
        return self


class ShooterConfig(_Strict):
    mount: MountConfig = Field(default_factory=MountConfig)
    target: TargetConfig = Field(default_factory=TargetConfig)
    rpm: RpmConfig = Field(default_factory=RpmConfig)
    policy: PolicyConfig = Field(default_factory=PolicyConfig)
    link: LinkConfig = Field(default_factory=LinkConfig)
    odometry: OdometryConfig = Field(default_factory=OdometryConfig)
    decide_period_s: float = Field(0.05, gt=0, le=1.0, description="re-decide at least this often, so a pose "
                                   "that stops arriving turns into HOLD")


def load_shooter_config(path: Optional[Path]) -> ShooterConfig:
    """The config file at `path` (TOML or JSON), or the defaults; raises ConfigError naming the field."""

    config = load_model(path, ShooterConfig)
    return config if path is None else resolve_relative_paths(config, Path(path).resolve().parent)


def make_rpm_source(config: ShooterConfig, ring_height_m: float) -> RpmSource:
    """The configured table (watched for changes) or, without one, the physics prior."""
    if config.rpm.table is not None:
        return TableWatcher(config.rpm.table, config.rpm.reload_interval_s)
    physics = config.rpm.physics
    return PriorSource(physics.model(config.mount.release_height_m, ring_height_m),
                       physics.min_distance_m, physics.max_distance_m)
