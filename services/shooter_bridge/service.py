"""Shooter bridge stage: pose -> shot solution -> MCU over serial.

Every pose is decided on at once. A ticker also re-decides every `decide_period_s` on the newest
pose it has, with that pose's age growing: when poses stop arriving the MCU gets HOLD (stale) within
one period, never the last RPM forever. Decisions from both threads go through one lock, so the
policy's slew state sees them in order.
"""
from __future__ import annotations

import math
import threading
import time
from collections import Counter
from typing import Optional

from courtloc.common.bus import ZenohConfig
from courtloc.common.inbox import Delivery
from courtloc.common.limits import clip_text
from courtloc.common.messages import Header, Pose, ShotSolution
from courtloc.common.runtime import Service
from courtloc.common.services_table import Topic
from courtloc.services.shooter_bridge.config import ShooterConfig, make_rpm_source
from courtloc.services.shooter_bridge.link import McuLink
from courtloc.services.shooter_bridge.odometry import OdometryIntake
from courtloc.services.shooter_bridge.policy import ShotDecision, build_policy
from courtloc.services.shooter_bridge.protocol import Command, OdometrySample
from courtloc.shot.geometry import Pose2D


class ShooterBridgeService(Service):
    name = "shooter_bridge"

    def __init__(self, robot_id: str, zenoh_config: ZenohConfig, config: ShooterConfig) -> None:
        super().__init__(robot_id, zenoh_config)
        self.config = config
        # Built here, not in on_start: a bad ring, table or area stops the process before it joins the bus.
        ring = config.target.ring_centre()
        self.rpm_source = make_rpm_source(config, ring_height_m=ring[2])
        self.policy = build_policy(config, self.rpm_source.lookup, ring=ring)
        self.odometry = OdometryIntake(robot_id, config.odometry, stage=self.name)
        self.link = McuLink(config.link, on_odometry=self._on_odometry if config.odometry.enabled else None)
        self._lock = threading.Lock()
        self._latest: Optional[Pose] = None
        self._last_decided = -math.inf
        self._last_published: Optional[tuple[Command, str, int]] = None
        self._seq = 0
        self._ticker: Optional[threading.Thread] = None
        self.holds: Counter[str] = Counter()
        self.log.info("ring at %s, rpm from %s", ring, self.rpm_source.describe())

    def on_start(self) -> None:
        self.link.start()
        self._ticker = threading.Thread(target=self._tick, name="shooter-ticker", daemon=True)
        self._ticker.start()

    def on_message(self, topic: Topic, message: Pose, delivery: Delivery) -> None:
        self.is_fresh(message.header, topic)  # counts stale input for health; the policy decides on HOLD
        with self._lock:
            self._latest = message
            self._decide(publish_always=True)

    def _on_odometry(self, sample: OdometrySample, received_ns: int) -> None:
        """On the link thread: check, time-align and publish one MCU odometry frame (microseconds of work)."""
        message = self.odometry.accept(sample, received_ns)
        if message is not None and self.session is not None:
            self.publish("shooter_bridge/odometry", message)

    def _tick(self) -> None:
        period = self.config.decide_period_s
        while not self.stop_event.wait(period / 2):
            with self._lock:
                if time.monotonic() - self._last_decided >= period:
                    self._decide(publish_always=False)

    def _decide(self, publish_always: bool) -> None:
        """One decision on the newest pose, sent to the MCU; published for a new pose, or when the
        command, reason or RPM changed (a ramp or a pose going stale shows on the bus)."""
        now = time.monotonic()
        self._last_decided = now
        if self.rpm_source.poll(now):
            self.log.info("rpm now from %s", self.rpm_source.describe())
        pose = self._latest
        if pose is None:
            decision = self.policy.decide(None, math.inf, False, now)
        else:
            decision = self.policy.decide(Pose2D(pose.x, pose.y, pose.yaw), pose.header.age_ns() / 1e9,
                                          pose.header.valid, now, pose.header.future_tolerance_ns() / 1e9)
        self.link.send(*decision.frame_fields())
        if not decision.valid:
            self.holds[decision.reason] += 1
        key = (decision.command, decision.reason, int(round(decision.rpm)))
        if publish_always or key != self._last_published:
            self._last_published = key
            self.publish("shooter_bridge/solution", self._solution(decision, pose))

    def _solution(self, decision: ShotDecision, pose: Optional[Pose]) -> ShotSolution:
        if pose is not None:
            header = pose.header.forwarded(self.name, valid=decision.valid)
        else:
            header = Header.now(self.robot_id, self._seq, self.name)
            self._seq += 1
        reason = decision.reason
        if reason == "invalid" and pose is not None and pose.reason:
            reason = clip_text(f"invalid:{pose.reason}")  # keep the upstream cause for the operator
        return ShotSolution(header=header,
                            distance_m=decision.distance_m if decision.distance_m is not None else math.nan,
                            bearing_rad=decision.bearing_rad, rpm=decision.rpm,
                            command=decision.command.name, reason=reason)

    def on_stop(self) -> None:
        if self._ticker is not None:
            self._ticker.join(timeout=2.0)
        self.link.stop()  # sends a final HOLD

    def health_detail(self) -> dict[str, float | int | str]:
        stats = self.link.stats
        detail: dict[str, float | int | str] = {
            "mcu_connected": int(self.link.connected), "mcu_frames_sent": stats.frames_sent,
            "mcu_heartbeats": stats.heartbeats_sent, "mcu_connects": stats.connects,
            "mcu_write_errors": stats.write_errors + stats.read_errors, "mcu_error": stats.last_error,
            "rpm_source": self.rpm_source.describe(),
        }
        status = self.link.last_status
        if status is not None:
            detail["mcu_rpm"] = status.rpm
            detail["mcu_flags"] = status.flags
        reloads = getattr(self.rpm_source, "reloads", None)
        if reloads is not None:
            detail["table_reloads"] = reloads
            detail["table_errors"] = getattr(self.rpm_source, "errors", 0)
        detail.update({f"hold.{reason}": count for reason, count in self.holds.items()})
        if stats.odometry_frames or stats.bad_odometry:
            detail["mcu_odometry_frames"] = stats.odometry_frames
            detail["mcu_bad_odometry"] = stats.bad_odometry
            detail.update(self.odometry.health())
        return detail
