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

from pydantic import BaseModel, ConfigDict, Field, model_validator

from courtloc.common.limits import (
    MAX_DETAIL_ENTRIES,
    MAX_HITS,
    MAX_HITS_BYTES,
    MAX_IMAGE_BYTES,
    MAX_IMAGE_PIXELS,
    MAX_IMAGE_SIDE,
    MAX_MARKS,
    MAX_MARKS_BYTES,
    MAX_STAMPS,
    HostName,
    Name,
    Text,
)

SCHEMA_VERSION = 1
HOST = socket.gethostname()

# Time is data: an age below zero means a stamp from the future, which is as untrustworthy as an old one.
# On one host both stamps come from the same monotonic clock, so nothing legitimate is in the future.
# Across hosts ages are wall-clock differences: the hosts' clocks must agree within this bound
# (chrony, the robot serving time; docs/deployment.md "Clocks"), and a stamp further ahead is stale.
CLOCK_OFFSET_TOLERANCE_NS = 20_000_000


class Strict(BaseModel):
    """Base for bus messages: unknown fields are an error, not silently dropped."""

    model_config = ConfigDict(extra="forbid", frozen=False)


class StageStamp(Strict):
    stage: Name
    mono_ns: int
    wall_ns: int
    host: HostName = HOST


class Header(Strict):
    schema_version: int = SCHEMA_VERSION
    robot_id: Name
    seq: int = Field(ge=0)
    capture_mono_ns: int
    capture_wall_ns: int
    capture_host: HostName = HOST
    valid: bool = False
    stamps: list[StageStamp] = Field(default_factory=list, max_length=MAX_STAMPS)

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
        """Time since capture: monotonic clock on the capturing host, wall clock across hosts.

        Negative for a stamp from the future; use `is_fresh` to judge it."""
        if self.capture_host == HOST:
            return time.monotonic_ns() - self.capture_mono_ns
        return time.time_ns() - self.capture_wall_ns

    def future_tolerance_ns(self) -> int:
        """How far ahead of our clock this header's capture stamp may be (clock offset between hosts)."""
        return 0 if self.capture_host == HOST else CLOCK_OFFSET_TOLERANCE_NS

    def is_fresh(self, budget_ns: float) -> bool:
        """Captured at most `budget_ns` ago and not from the future (beyond the clocks' tolerance)."""
        return age_is_fresh(self.age_ns(), budget_ns, self.future_tolerance_ns())

    def span_ns(self) -> int:
        """Capture to the latest stamp (end-to-end latency when read by the last stage)."""
        if not self.stamps:
            return 0
        last = self.stamps[-1]
        if last.host == self.capture_host:
            return last.mono_ns - self.capture_mono_ns
        return last.wall_ns - self.capture_wall_ns


def age_is_fresh(age_ns: float, budget_ns: float, future_tolerance_ns: float) -> bool:
    """The one freshness rule: -tolerance <= age <= budget (NaN is never fresh)."""
    return -future_tolerance_ns <= age_ns <= budget_ns


class _Image(Strict):
    """A declared image size, bounded by the contract before any pixel is looked at."""

    width: int = Field(gt=0, le=MAX_IMAGE_SIDE)
    height: int = Field(gt=0, le=MAX_IMAGE_SIDE)

    @model_validator(mode="after")
    def _bounded_area(self) -> "_Image":
        if self.width * self.height > MAX_IMAGE_PIXELS:
            raise ValueError(f"{self.width}x{self.height} is more than {MAX_IMAGE_PIXELS} pixels")
        return self


class Frame(_Image):
    """A camera image. `encoding` is 'bgr8' (raw, shape height x width x 3) or 'jpeg'."""

    header: Header
    encoding: Literal["bgr8", "jpeg"]
    data: bytes = Field(max_length=MAX_IMAGE_BYTES)


class GroundTruth(Strict):
    """The true pose of a frame (simulation, or labels of a replayed recording)."""

    header: Header
    x: float
    y: float
    yaw: float
    source: Name


class Edges(_Image):
    """Radial-scan hits: int16 rows of (row, col, ray, d) in full-frame pixels, packed little-endian; and
    the court's colour marks seen in the frame: int16 rows of (row, col, mark index), the same packing
    (none unless the deployment's court has marks: `Court.marks`)."""

    header: Header
    crop_top: int = Field(ge=0, le=MAX_IMAGE_SIDE)
    n_hits: int = Field(ge=0, le=MAX_HITS)
    hits: bytes = Field(max_length=MAX_HITS_BYTES)
    n_marks: int = Field(0, ge=0, le=MAX_MARKS)
    marks: bytes = Field(b"", max_length=MAX_MARKS_BYTES)


ODOMETRY_SEQS_MAX = 512  # 100 Hz odometry through a 5 s camera outage


class Pose(Strict):
    header: Header
    x: float
    y: float
    yaw: Optional[float] = None
    quality: float = 0.0
    model_name: Name
    model_version: int
    infer_ms: float
    reason: Text = ""
    covariance: list[float] = Field(default_factory=list, max_length=9,
                                    description="row-major 3x3 covariance of (x, y, yaw) when the model tracks; [] else")
    # Which odometry the answer was fused with, so a logged run replays exactly (openpilot's process replay): the
    # stage's inbox keeps only the newest odometry message, so the messages published are not all the ones taken in.
    odometry_seqs: list[int] = Field(default_factory=list, max_length=ODOMETRY_SEQS_MAX,
                                     description="source_seq of each odometry message the stage took in since its "
                                     "previous answer, in order (fusion on; the newest ODOMETRY_SEQS_MAX)")


class ShotSolution(Strict):
    header: Header
    distance_m: float
    bearing_rad: Optional[float] = None
    rpm: float
    command: Literal["SET_RPM", "HOLD"]
    reason: Text = ""


class Health(Strict):
    """Published once a second by every service."""

    schema_version: int = SCHEMA_VERSION
    robot_id: Name
    service: Name
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
    last_error: Text = ""
    detail: dict[Name, float | int | Text] = Field(default_factory=dict, max_length=MAX_DETAIL_ENTRIES)


class Odometry(Strict):
    """Body-frame motion over a short window, from any source with its own clock.

    The shooter bridge publishes the MCU's wheel odometry and gyro; a ROS bridge or a tracking camera
    may publish the same message. Body frame: x forward, y left, yaw counter-clockwise.
    `header.capture_*_ns` is the END of the window on the publishing host's clocks (the source's
    clock mapped onto them); `header.valid` is the publisher's verdict that the source's clock and
    values passed its checks. A half whose `*_valid` is false carries 0, never a number to use.

    `odom_*` is the pose dead-reckoned by the publisher since the start of `epoch` (translation from
    the wheels, heading from the gyro, or from the wheels without one), so a consumer that reads only
    the newest message loses nothing: the motion between two times is the difference of two messages
    of the same epoch. The epoch changes whenever continuity broke (start, a clock jump, a window
    that could not be integrated); a difference across epochs means nothing.
    """

    header: Header
    source: Name = Field(min_length=1, description="e.g. 'mcu', 'ros', 't265'")
    source_seq: int = Field(ge=0)
    source_time_ns: int = Field(description="the source's own clock at the end of the window, unwrapped")
    received_mono_ns: int = Field(description="when the publisher read it (its monotonic clock)")
    window_s: float = Field(ge=0.0, le=1.0, description="the velocities are means over this window")
    vx_m_s: float = 0.0
    vy_m_s: float = 0.0
    wz_wheels_rad_s: float = 0.0
    wz_gyro_rad_s: float = 0.0
    wheels_valid: bool = False
    gyro_valid: bool = False
    gyro_saturated: bool = Field(False, description="the gyro hit full scale: its rate is a lower bound")
    wheel_slip: bool = Field(False, description="the source's own traction check tripped")
    epoch: int = Field(0, ge=0)
    odom_x_m: float = 0.0
    odom_y_m: float = 0.0
    odom_yaw_rad: float = 0.0
    heading_from_gyro: bool = Field(False, description="odom_yaw_rad integrates the gyro (else the wheels)")
