"""The twin's wheel odometry and gyro: what the robot's MCU would send while driving a trajectory.

Each ODOMETRY frame covers the window since the previous one: the body-frame velocity the wheels saw
(the true mean velocity times a wheel scale error, plus noise, plus slip bursts in which the wheels
over-read), the wheel yaw rate (noisier) and the gyro rate (bias plus noise, clipped at full scale).
The MCU stamps frames with its own microsecond clock (an offset and a drift from the host's) and they
reach the host after a latency with jitter. `OdometryIntake` (the bridge's own code) then turns them
into the `Odometry` messages the infer stage receives.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterator, Sequence

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from courtloc.common.messages import Odometry
from courtloc.services.shooter_bridge.odometry import OdometryConfig, OdometryIntake
from courtloc.services.shooter_bridge.protocol import OdometrySample, OdomFlag
from courtloc.sim.trajectory import Trajectory
from courtloc.world.angles import wrap_angle


class OdometrySimConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")
    rate_hz: float = Field(100.0, gt=0)
    wheel_scale: float = Field(1.03, gt=0, description="wheels read this times the true distance")
    speed_noise_m_s: float = Field(0.02, ge=0)
    wheel_yaw_noise_rad_s: float = Field(0.05, ge=0)
    slip_rate_hz: float = Field(0.2, ge=0, description="slip bursts per second")
    slip_duration_s: float = Field(0.15, ge=0)
    slip_over_read: float = Field(0.3, ge=0, description="wheels over-read by this fraction during a burst")
    gyro_bias_rad_s: float = Field(0.01, description="constant gyro bias")
    gyro_noise_rad_s: float = Field(0.003, ge=0)
    gyro_full_scale_rad_s: float = Field(8.7, gt=0, description="500 deg/s")
    latency_s: float = Field(0.004, ge=0, description="serial + scheduling delay, least value")
    latency_jitter_s: float = Field(0.003, ge=0, description="mean of the extra, exponential delay")
    clock_offset_s: float = Field(1234.5, description="MCU clock minus host clock at t = 0")
    clock_drift_ppm: float = Field(40.0, description="MCU crystal error")


@dataclass(frozen=True)
class Delivered:
    """One `Odometry` message and the host time it reaches the consumer."""

    at_s: float
    message: Odometry


class OdometrySimulator:
    def __init__(self, trajectory: Trajectory, config: OdometrySimConfig, seed: int = 0,
                 robot_id: str = "robot1", kidnaps_s: Sequence[float] = ()) -> None:
        self.trajectory = trajectory
        self.kidnaps_s = [float(t) for t in kidnaps_s]  # teleports the wheels do not feel
        self.config = config
        self.rng = np.random.default_rng(seed)
        self.intake = OdometryIntake(robot_id, OdometryConfig())
        self._slip_until = -math.inf

    def _sample(self, i: int, t0: float, t1: float) -> OdometrySample:
        # Windows without a teleport keep the one-piece velocity: the same stream, to the last bit, as before kidnaps
        # were known here (the sweeps' committed results replay exactly).
        if any(t0 < t <= t1 for t in self.kidnaps_s):
            forward, left, turn = felt_motion(self.trajectory, self.kidnaps_s, t0, t1)
            vx, vy, wz = forward / (t1 - t0), left / (t1 - t0), turn / (t1 - t0)
        else:
            vx, vy, wz = body_velocity(self.trajectory.pose_at(t0), self.trajectory.pose_at(t1), t1 - t0)
        return self.measure(i, vx, vy, wz, t1 - t0, t1)

    def measure(self, seq: int, vx: float, vy: float, wz: float, dt: float, t_end_s: float) -> OdometrySample:
        """The frame the MCU sends for a window of `dt` seconds ending at host time `t_end_s` in which the
        robot truly moved at body velocity (vx, vy) and yaw rate wz: the wheels' and the gyro's errors added."""
        cfg = self.config
        if cfg.slip_rate_hz > 0 and self.rng.random() < cfg.slip_rate_hz * dt:
            self._slip_until = t_end_s + cfg.slip_duration_s
        slipping = t_end_s < self._slip_until
        scale = cfg.wheel_scale * (1 + (cfg.slip_over_read if slipping else 0.0))
        gyro = wz + cfg.gyro_bias_rad_s + self.rng.normal(0, cfg.gyro_noise_rad_s)
        saturated = abs(gyro) > cfg.gyro_full_scale_rad_s
        flags = OdomFlag.WHEELS_VALID | OdomFlag.GYRO_VALID
        if saturated:
            flags |= OdomFlag.GYRO_SATURATED
            gyro = math.copysign(cfg.gyro_full_scale_rad_s, gyro)
        mcu_s = cfg.clock_offset_s + t_end_s * (1 + cfg.clock_drift_ppm * 1e-6)
        return OdometrySample(
            seq=seq & 0xFFFF, mcu_time_us=int(round(mcu_s * 1e6)) & 0xFFFFFFFF,
            vx_m_s=round(vx * scale + self.rng.normal(0, cfg.speed_noise_m_s), 3),
            vy_m_s=round(vy * scale + self.rng.normal(0, cfg.speed_noise_m_s), 3),
            wz_wheels_rad_s=round(wz * scale + self.rng.normal(0, cfg.wheel_yaw_noise_rad_s), 3),
            wz_gyro_rad_s=round(gyro, 6), flags=flags)

    def stream(self, duration_s: float) -> Iterator[Delivered]:
        """Messages in the order they reach the host, with their arrival times (seconds, host clock)."""
        cfg = self.config
        period = 1.0 / cfg.rate_hz
        pending: list[tuple[float, OdometrySample]] = []
        n = int(duration_s * cfg.rate_hz)
        for i in range(1, n + 1):
            t0, t1 = (i - 1) * period, i * period
            arrive = t1 + cfg.latency_s + float(self.rng.exponential(cfg.latency_jitter_s))
            pending.append((arrive, self._sample(i, t0, t1)))
        # The serial line delivers in order: a frame cannot overtake the one before it.
        arrive_prev = -math.inf
        for arrive, sample in pending:
            arrive = max(arrive, arrive_prev)
            arrive_prev = arrive
            ns = int(round(arrive * 1e9))
            message = self.intake.accept(sample, ns, ns)
            if message is not None:
                yield Delivered(at_s=arrive, message=message)


def body_velocity(a: tuple[float, float, float], b: tuple[float, float, float],
                  dt: float) -> tuple[float, float, float]:
    """The mean body-frame velocity (forward, left) and yaw rate that take pose `a` to pose `b` in `dt`."""
    c, s = math.cos(a[2]), math.sin(a[2])
    dx, dy = b[0] - a[0], b[1] - a[1]
    return (c * dx + s * dy) / dt, (-s * dx + c * dy) / dt, wrap_angle(b[2] - a[2]) / dt


def felt_motion(trajectory: Trajectory, kidnaps_s: Sequence[float], s0: float,
                s1: float) -> tuple[float, float, float]:
    """Body-frame displacement (forward, left) and turn from sim time s0 to s1 as the wheels feel it: a
    teleport in between is not motion, only the driving on either side of it is."""
    cuts = [s0, *sorted(t for t in kidnaps_s if s0 < t <= s1), s1]
    forward = left = turn = 0.0
    for a, b in zip(cuts, cuts[1:]):
        end = b - 1e-6 if b in kidnaps_s else b  # a kidnap piece ends just before the teleport
        if end <= a:
            continue
        vx, vy, wz = body_velocity(trajectory.pose_at(a), trajectory.pose_at(end), end - a)
        forward, left, turn = forward + vx * (end - a), left + vy * (end - a), turn + wz * (end - a)
    return forward, left, turn
