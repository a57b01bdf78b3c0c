"""Infer service settings."""
from __future__ import annotations

import os
from pathlib import Path
from typing import Literal, Optional

from pydantic import BaseModel, ConfigDict, Field, model_validator

from courtloc.localizer.odometry_fusion import FusionConfig


def default_store_path() -> Path:
    base = os.environ.get("XDG_DATA_HOME") or str(Path.home() / ".local" / "share")
    return Path(base) / "courtloc" / "model-store"


Provider = Literal["tensorrt", "cuda", "cpu"]


def providers_for(config: "InferConfig", input_kind: str) -> list[str]:
    """The provider preference for a model of this input kind (short names, as in the config)."""
    return list(config.accelerator_providers if input_kind in config.accelerate_kinds else config.providers)
class StartConfig(BaseModel):
    """Where the robot starts a run: a pose (x, y and optionally the heading, each with its uncertainty)
    or only the half it starts in. The localizer's acquisition takes it as evidence between hypotheses
    that the view alone cannot tell apart (docs/localizer.md, "Acquisition")."""

    model_config = ConfigDict(extra="forbid")
    half: Optional[Literal["+x", "-x"]] = Field(None, description="the half the robot starts in")
    x: Optional[float] = Field(None, description="start position, court metres")
    y: Optional[float] = None
    yaw_deg: Optional[float] = Field(None, description="start heading, degrees CCW from +x (None: unknown)")
    std_m: float = Field(0.5, gt=0, description="how well the start position is known")
    yaw_std_deg: float = Field(20.0, gt=0, description="how well the start heading is known")

    @model_validator(mode="after")
    def _a_pose_or_a_half(self) -> "StartConfig":
        if (self.x is None) != (self.y is None):
            raise ValueError("start: give both x and y (or neither)")
        if self.x is None and self.yaw_deg is not None:
            raise ValueError("start: yaw_deg needs x and y")
        if self.x is None and self.half is None:
            raise ValueError("start: give x and y (a pose) or half (\"+x\" or \"-x\")")
        if self.x is not None and self.half is not None and (self.x > 0) != (self.half == "+x"):
            raise ValueError(f"start: x = {self.x} is not in half {self.half!r}")
        return self


class InferConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")

    store: Path = Field(default_factory=default_store_path,
                        description="model repository: <store>/<name>/<version>/model.onnx")
    # The bundled localizer's graph is a small int16 table lookup: TensorRT cannot take it and CUDA only
    # adds copies, so models run on the CPU unless their input kind is listed in `accelerate_kinds`.
    providers: list[Provider] = Field(
        default_factory=lambda: ["cpu"],
        description="onnxruntime execution providers, in order of preference, for every model whose input kind "
                    "is not in accelerate_kinds; those not installed are skipped")
    accelerator_providers: list[Provider] = Field(
        default_factory=lambda: ["tensorrt", "cuda", "cpu"],
        description="providers, in order of preference, for models whose input kind is in accelerate_kinds")
    accelerate_kinds: list[Literal["dense_image", "sparse_hits", "scan_hits"]] = Field(
        default_factory=lambda: ["dense_image"],
        description="model input kinds that benefit from a GPU (the paper's dense image network)")
    threads: int = Field(default=1, ge=1, le=64, description="onnxruntime intra-op threads")
    # 200 ms admits the paper's dense graph (~70 ms per frame on a 2-core x86 here) so it stays servable
    # for comparison; its exact sparse graph (~4 ms) is the one to serve. Tighten it on the robot.
    golden_latency_budget_ms: float = Field(default=200.0, gt=0,
                                            description="a candidate slower than this on golden inputs is refused")
    # A pose reported valid and wrong is the worst failure: whatever accuracy a manifest states, a candidate
    # further off than this on its golden inputs is refused (the paper network needs these raised to serve).
    max_golden_position_error_m: float = Field(default=0.25, gt=0,
                                               description="refuse a candidate whose golden position error exceeds this")
    max_golden_yaw_error_deg: float = Field(default=5.0, gt=0,
                                            description="refuse a candidate whose golden yaw error exceeds this")
    golden_min_frames: int = Field(default=3, ge=1, description="a package must ship at least this many golden frames")
    # Validation runs in a child process: its address space may grow this much over the child's own
    # (python + onnxruntime) before allocations fail, and it is killed after validation_timeout_s.
    validation_memory_mb: float = Field(default=1024.0, gt=0,
                                        description="memory a candidate may take while it is validated")
    validation_timeout_s: float = Field(default=60.0, gt=0, description="a candidate validating longer is refused")
    # Measured inwards: a robot's centre stays about half its width from the area's edge, and a pose nearer the
    # edge than that is more often a wrong fit than a robot (the twin's fast walk, vision only: tracks snapped
    # to the far end line there, metres from the truth).
    on_court_margin_m: float = Field(default=0.5, ge=0, description="a pose nearer than this to the edge of the "
                                     "robot's area (Court.area_half_extent_m), or beyond it, is not valid (off_court)")
    require_signature: bool = Field(default=False, description="refuse pushed models without a valid signature")
    signing_public_key: Path | None = None
    max_upload_mb: float = Field(default=2048.0, gt=0)
    fusion: FusionConfig = Field(default_factory=FusionConfig,
                                 description="odometry fusion in the tracker (off: shooter_bridge/odometry is ignored)")
    max_open_uploads: int = Field(default=2, ge=1, description="a new push evicts the least recently written beyond this")
    upload_ttl_h: float = Field(default=24.0, gt=0, description="an upload without a new byte for this long is removed")
    start: Optional[StartConfig] = Field(default=None, description="where the robot starts a run (None: the "
                                         "localizer waits for a pose the view decides, or `courtloc pose set`)")
    drift_mps: Optional[float] = Field(default=None, gt=0, description="how fast the robot may move while it has no "
                                       "valid pose (the spread of a lost or saved pose grows at this rate; default: "
                                       "the package's acquire.motion_sigma_mps). A robot that stops without a pose "
                                       "can set it low, and then resumes on the right side after any outage")
    resume_file: Optional[Path] = Field(default=None, description="the last tracked pose, saved twice a second so a "
                                        "restarted stage resumes from it (default: beside the store)")
    resume_max_age_s: float = Field(default=60.0, ge=0, description="a saved pose older than this is a previous run's "
                                    "(the configured start applies instead)")
    court: Optional[str] = Field(default=None, description="the deployment's court (set from the top-level `court`)")
    camera: Optional[str] = Field(default=None, description="the deployment's camera (set from the top-level "
                                  "`camera`, default the court's own)")

    @property
    def resume_path(self) -> Path:
        return self.resume_file or self.store.parent / f"{self.store.name}.last-pose.json"
