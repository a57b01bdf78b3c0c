"""MCU ODOMETRY frames -> `Odometry` messages on this host's clock, checked and dead-reckoned.

The MCU stamps each frame with its own free-running microsecond clock. That clock is mapped onto the
host's monotonic clock by the least-delayed frame of the last `offset_window_s` (the minimum of
`receive time - MCU time`): serial and scheduling delays only ever add, so the minimum is the
closest estimate of the true offset, and the window lets it follow the crystals' drift.

Every frame is checked before it is used; a frame that fails is counted by reason and, when it broke
continuity (the clock jumped, a window could not be integrated), a new epoch starts.
"""
from __future__ import annotations

import math
import time
from collections import Counter, deque
from dataclasses import dataclass
from typing import Optional

from pydantic import BaseModel, ConfigDict, Field, model_validator

from courtloc.common.messages import Header, Odometry, StageStamp
from courtloc.services.shooter_bridge.protocol import OdometrySample, OdomFlag

WRAP_US = 1 << 32


class OdometryConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")

    enabled: bool = Field(True, description="publish the MCU's ODOMETRY frames on shooter_bridge/odometry")
    source: str = Field("mcu", min_length=1)
    max_speed_m_s: float = Field(6.0, gt=0, description="a wheel velocity beyond this is a fault, not motion")
    max_yaw_rate_rad_s: float = Field(20.0, gt=0, description="a wheel yaw rate beyond this is a fault")
    max_window_s: float = Field(0.5, gt=0, le=1.0, description="a longer gap between frames starts a new epoch")
    clock_tolerance_s: float = Field(0.05, gt=0, description="MCU time may run ahead of host time by this much")
    offset_window_s: float = Field(5.0, gt=0, description="the clock offset is the best frame of this window")
    freshness_s: float = Field(0.1, gt=0, description="a frame later than this after its window ended is dropped")

    @model_validator(mode="after")
    def _windows(self) -> "OdometryConfig":
        if self.offset_window_s < self.max_window_s:
            raise ValueError("odometry.offset_window_s must be >= max_window_s")
        return self


class ClockMap:
    """The MCU's wrapping microsecond clock, unwrapped and mapped onto the host's monotonic clock."""

    def __init__(self, window_s: float) -> None:
        self.window_ns = int(window_s * 1e9)
        self._offsets: deque[tuple[int, int]] = deque()  # (receive ns, offset ns), offsets increasing
        self._last_raw: Optional[int] = None
        self._unwrapped_us = 0

    def reset(self) -> None:
        self._offsets.clear()
        self._last_raw = None
        self._unwrapped_us = 0

    @staticmethod
    def delta_us(previous_raw: int, raw: int) -> int:
        """Signed difference of two uint32 stamps (a negative one means the clock went back)."""
        delta = (raw - previous_raw) % WRAP_US
        return delta - WRAP_US if delta >= WRAP_US // 2 else delta

    def unwrap(self, raw: int) -> int:
        if self._last_raw is not None:
            self._unwrapped_us += self.delta_us(self._last_raw, raw)
        else:
            self._unwrapped_us = raw
        self._last_raw = raw
        return self._unwrapped_us * 1000

    def map(self, source_ns: int, received_ns: int) -> int:
        """The host monotonic time of `source_ns`, learning from this frame's delay."""
        offset = received_ns - source_ns
        while self._offsets and self._offsets[-1][1] >= offset:
            self._offsets.pop()  # a later frame with a smaller delay makes the older one useless
        self._offsets.append((received_ns, offset))
        while self._offsets[0][0] < received_ns - self.window_ns:
            self._offsets.popleft()
        return source_ns + self._offsets[0][1]


@dataclass
class _Previous:
    seq: int
    raw_us: int
    received_ns: int
    source_ns: int


class OdometryIntake:
    """Turns decoded ODOMETRY frames into `Odometry` messages; not thread-safe (the link thread owns it)."""

    def __init__(self, robot_id: str, config: OdometryConfig, stage: str = "shooter_bridge") -> None:
        self.robot_id = robot_id
        self.config = config
        self.stage = stage
        self.clock = ClockMap(config.offset_window_s)
        self.rejected: Counter[str] = Counter()  # frames not published, by reason
        self.degraded: Counter[str] = Counter()  # frames published with a half dropped or a new epoch, by reason
        self.lost = 0  # ODOMETRY frames the MCU sent that never arrived (SEQ gaps)
        self.epoch = -1
        self._previous: Optional[_Previous] = None
        self._pose = [0.0, 0.0, 0.0]
        self._heading_from_gyro: Optional[bool] = None
        self._seq = 0
        self._last_seq: Optional[int] = None  # of any frame that arrived, used or not

    def _new_epoch(self) -> None:
        self.epoch += 1
        self._pose = [0.0, 0.0, 0.0]
        self._heading_from_gyro = None

    def accept(self, sample: OdometrySample, received_ns: Optional[int] = None,
               received_wall_ns: Optional[int] = None) -> Optional[Odometry]:
        """The message for `sample` read at `received_ns` (host monotonic), or None (counted in `rejected`)."""
        received_ns = time.monotonic_ns() if received_ns is None else received_ns
        received_wall_ns = time.time_ns() if received_wall_ns is None else received_wall_ns
        previous = self._previous
        window_s = 0.0
        if self._last_seq is not None:
            self.lost += (sample.seq - self._last_seq - 1) % 0x10000 if sample.seq != self._last_seq else 0
        self._last_seq = sample.seq
        if previous is not None:
            delta_us = ClockMap.delta_us(previous.raw_us, sample.mcu_time_us)
            if sample.seq == previous.seq and delta_us == 0:
                self.rejected["duplicate"] += 1
                return None
            if delta_us == 0:
                self.rejected["clock_stalled"] += 1
                return None
            if delta_us < 0:
                self.rejected["clock_backwards"] += 1
                return None
            host_s = (received_ns - previous.received_ns) / 1e9
            window_s = delta_us / 1e6
            if window_s > max(self.config.max_window_s, host_s + self.config.clock_tolerance_s):
                # The MCU claims more time passed than the host saw (or a gap too long to integrate):
                # its clock jumped or it rebooted. Start again from this frame.
                self.degraded["clock_jump" if window_s > host_s + self.config.clock_tolerance_s else "gap"] += 1
                self.clock.reset()
                previous = None
                window_s = 0.0
        source_ns = self.clock.unwrap(sample.mcu_time_us)
        capture_ns = self.clock.map(source_ns, received_ns)
        self._previous = _Previous(sample.seq, sample.mcu_time_us, received_ns, source_ns)
        late_s = (received_ns - capture_ns) / 1e9
        wheels_ok, gyro_ok = self._usable_halves(sample)
        if previous is None or not wheels_ok:
            self._new_epoch()  # nothing to integrate across: this frame is the new origin
        else:
            self._integrate(sample, window_s, gyro_ok)
        if late_s > self.config.freshness_s:
            self.rejected["late"] += 1
            return None
        self._seq += 1
        capture_wall_ns = received_wall_ns - (received_ns - capture_ns)
        header = Header(robot_id=self.robot_id, seq=self._seq - 1, capture_mono_ns=capture_ns,
                        capture_wall_ns=capture_wall_ns, valid=wheels_ok or gyro_ok,
                        stamps=[StageStamp(stage=self.stage, mono_ns=received_ns, wall_ns=received_wall_ns)])
        return Odometry(
            header=header, source=self.config.source, source_seq=sample.seq, source_time_ns=source_ns,
            received_mono_ns=received_ns, window_s=min(window_s, 1.0),
            vx_m_s=sample.vx_m_s if wheels_ok else 0.0, vy_m_s=sample.vy_m_s if wheels_ok else 0.0,
            wz_wheels_rad_s=sample.wz_wheels_rad_s if wheels_ok else 0.0,
            wz_gyro_rad_s=sample.wz_gyro_rad_s if gyro_ok else 0.0,
            wheels_valid=wheels_ok, gyro_valid=gyro_ok,
            gyro_saturated=bool(sample.flags & OdomFlag.GYRO_SATURATED),
            wheel_slip=bool(sample.flags & OdomFlag.WHEEL_SLIP), epoch=self.epoch,
            odom_x_m=self._pose[0], odom_y_m=self._pose[1], odom_yaw_rad=self._pose[2],
            heading_from_gyro=bool(self._heading_from_gyro))

    def _usable_halves(self, sample: OdometrySample) -> tuple[bool, bool]:
        wheels = sample.wheels_valid and not sample.flags & OdomFlag.FAULT
        if wheels and (math.hypot(sample.vx_m_s, sample.vy_m_s) > self.config.max_speed_m_s
                       or abs(sample.wz_wheels_rad_s) > self.config.max_yaw_rate_rad_s):
            self.degraded["implausible_wheels"] += 1
            wheels = False
        gyro = sample.gyro_valid and not sample.flags & OdomFlag.FAULT
        if gyro and sample.flags & OdomFlag.GYRO_SATURATED:
            self.degraded["gyro_saturated"] += 1  # a lower bound is not a rate: steer by the wheels
            gyro = False
        return wheels, gyro

    def _integrate(self, sample: OdometrySample, window_s: float, gyro_ok: bool) -> None:
        if self._heading_from_gyro is not None and self._heading_from_gyro != gyro_ok:
            self.degraded["heading_source_changed"] += 1
            self._new_epoch()
            return
        self._heading_from_gyro = gyro_ok
        rate = sample.wz_gyro_rad_s if gyro_ok else sample.wz_wheels_rad_s
        x, y, yaw = self._pose
        mid = yaw + 0.5 * rate * window_s  # midpoint rule: exact for a constant-rate arc to 2nd order
        c, s = math.cos(mid), math.sin(mid)
        self._pose = [x + (c * sample.vx_m_s - s * sample.vy_m_s) * window_s,
                      y + (s * sample.vx_m_s + c * sample.vy_m_s) * window_s,
                      yaw + rate * window_s]

    def health(self) -> dict[str, int]:
        detail = {f"odom_rejected.{k}": v for k, v in self.rejected.items()}
        detail.update({f"odom_degraded.{k}": v for k, v in self.degraded.items()})
        detail["odom_lost"] = self.lost
        detail["odom_published"] = self._seq
        return detail
