"""nav_msgs/Odometry from ROS -> courtloc Odometry (common/messages.py) on `shooter_bridge/odometry`.

ROS stamps are wall-clock time (the robot's clocks are assumed synchronised, see `courtloc doctor`); a
stamp too far in the past or in the future is as untrustworthy as a bad value: the message is still
published with `header.valid = false` and counted, so the consumer sees the gap.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

from courtloc.common.messages import Header, Odometry

MAX_SPEED_M_S = 10.0  # a Robocon robot does not drive faster: beyond this the value is wrong
MAX_YAW_RATE_RAD_S = 20.0


@dataclass
class OdometryInput:
    robot_id: str
    max_age_s: float = 0.2
    seq: int = 0
    epoch: int = 0
    rejected: dict[str, int] = field(default_factory=dict)
    _last_stamp_ns: int | None = None
    _last_frame: str | None = None

    def _reject(self, reason: str) -> str:
        self.rejected[reason] = self.rejected.get(reason, 0) + 1
        return reason

    def convert(self, ros: Any, now_wall_ns: int | None = None, now_mono_ns: int | None = None) -> Odometry:
        wall = time.time_ns() if now_wall_ns is None else now_wall_ns
        mono = time.monotonic_ns() if now_mono_ns is None else now_mono_ns
        stamp = int(ros.header.stamp.sec) * 1_000_000_000 + int(ros.header.stamp.nanosec)
        twist, pose = ros.twist.twist, ros.pose.pose
        q = pose.orientation
        yaw = math.atan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y * q.y + q.z * q.z))
        values = (twist.linear.x, twist.linear.y, twist.angular.z, pose.position.x, pose.position.y, yaw)
        problem = ""
        if not all(math.isfinite(v) for v in values):
            problem = self._reject("non_finite")
        elif math.hypot(twist.linear.x, twist.linear.y) > MAX_SPEED_M_S or abs(twist.angular.z) > MAX_YAW_RATE_RAD_S:
            problem = self._reject("implausible")
        elif abs(wall - stamp) > self.max_age_s * 1e9:
            problem = self._reject("stale" if stamp < wall else "future")
        # continuity breaks when the odometry frame changes or time runs backwards
        if (self._last_frame is not None and ros.header.frame_id != self._last_frame) or \
                (self._last_stamp_ns is not None and stamp <= self._last_stamp_ns):
            self.epoch += 1
        self._last_frame, self._last_stamp_ns = ros.header.frame_id, stamp
        self.seq += 1
        header = Header(robot_id=self.robot_id, seq=self.seq, capture_wall_ns=stamp,
                        capture_mono_ns=mono - (wall - stamp), valid=not problem)
        ok = not problem
        return Odometry(header=header, source="ros", source_seq=self.seq, source_time_ns=stamp,
                        received_mono_ns=mono, window_s=0.0,
                        vx_m_s=twist.linear.x if ok else 0.0, vy_m_s=twist.linear.y if ok else 0.0,
                        wz_wheels_rad_s=twist.angular.z if ok else 0.0, wheels_valid=ok, epoch=self.epoch,
                        odom_x_m=pose.position.x if ok else 0.0, odom_y_m=pose.position.y if ok else 0.0,
                        odom_yaw_rad=yaw if ok else 0.0)
