"""The one message contract: every payload on the bus is one of these pydantic models.

A frame's header travels down the chain: each stage copies it, appends its own stamp and sets
`valid` only when its output can be trusted. The last stage computes end-to-end latency from the
first and last stamps.
"""
from __future__ import annotations

import os
import socket
import time
from typing import Literal, Optional

from pydantic import BaseModel, ConfigDict, Field

SCHEMA_VERSION = 1
HOST = socket.gethostname()


class Strict(BaseModel):
    """Base for bus messages: unknown fields are an error, not silently dropped."""

    model_config = ConfigDict(extra="forbid", frozen=False)


class StageStamp(Strict):
    stage: str
    mono_ns: int
    wall_ns: int
    host: str = HOST


class Header(Strict):
    schema_version: int = SCHEMA_VERSION
    robot_id: str
    seq: int = Field(ge=0)
    capture_mono_ns: int
    capture_wall_ns: int
    capture_host: str = HOST
    valid: bool = False
    stamps: list[StageStamp] = Field(default_factory=list)

    @classmethod
    def now(cls, robot_id: str, seq: int, stage: str) -> "Header":
        mono, wall = time.monotonic_ns(), time.time_ns()
        return cls(robot_id=robot_id, seq=seq, capture_mono_ns=mono, capture_wall_ns=wall,
                   stamps=[StageStamp(stage=stage, mono_ns=mono, wall_ns=wall)])

    def forwarded(self, stage: str, valid: bool) -> "Header":
        """A copy for the next stage's output, stamped by `stage`; validity is the caller's verdict."""
        stamp = StageStamp(stage=stage, mono_ns=time.monotonic_ns(), wall_ns=time.time_ns())
        return self.model_copy(update={"valid": valid, "stamps": [*self.stamps, stamp]})

    def age_ns(self) -> int:
        """Time since capture: monotonic clock on the capturing host, wall clock across hosts."""
        if self.capture_host == HOST:
            return time.monotonic_ns() - self.capture_mono_ns
        return time.time_ns() - self.capture_wall_ns

    def span_ns(self) -> int:
        """Capture to the latest stamp (end-to-end latency when read by the last stage)."""
        if not self.stamps:
            return 0
        last = self.stamps[-1]
        if last.host == self.capture_host:
            return last.mono_ns - self.capture_mono_ns
        return last.wall_ns - self.capture_wall_ns


class Frame(Strict):
    """A camera image. `encoding` is 'bgr8' (raw, shape height x width x 3) or 'jpeg'."""

    header: Header
    width: int = Field(gt=0)
    height: int = Field(gt=0)
    encoding: Literal["bgr8", "jpeg"]
    data: bytes


class GroundTruth(Strict):
    """The true pose of a frame (simulation, or labels of a replayed recording)."""

    header: Header
    x: float
    y: float
    yaw: float
    source: str


class Edges(Strict):
    """Radial-scan hits: int16 rows of (row, col, ray, d) in full-frame pixels, packed little-endian."""

    header: Header
    width: int = Field(gt=0)
    height: int = Field(gt=0)
    crop_top: int = Field(ge=0)
    n_hits: int = Field(ge=0)
    hits: bytes


class Pose(Strict):
    header: Header
    x: float
    y: float
    yaw: Optional[float] = None
    quality: float = 0.0
    model_name: str
    model_version: int
    infer_ms: float
    reason: str = ""
    # Row-major 3x3 covariance of (x, y, yaw) in m^2, m rad, rad^2 (court frame), from the producer's fit;
    # None when the model gives none (then a consumer must not invent one). Without yaw, only the
    # x/y block means something.
    covariance: Optional[list[float]] = Field(default=None, min_length=9, max_length=9)


class ShotSolution(Strict):
    header: Header
    distance_m: float
    bearing_rad: Optional[float] = None
    rpm: float
    command: Literal["SET_RPM", "HOLD"]
    reason: str = ""


class Health(Strict):
    """Published once a second by every service."""

    schema_version: int = SCHEMA_VERSION
    robot_id: str
    service: str
    pid: int = Field(default_factory=os.getpid)
    wall_ns: int = Field(default_factory=time.time_ns)
    uptime_s: float
    rate_in_hz: float
    rate_out_hz: float
    frames_in: int
    frames_out: int
    dropped: int
    rejected: int
    stale: int
    latency_ms_p50: float
    latency_ms_p99: float
    e2e_ms_p50: float = 0.0
    e2e_ms_p99: float = 0.0
    last_error: str = ""
    detail: dict[str, float | int | str] = Field(default_factory=dict)
