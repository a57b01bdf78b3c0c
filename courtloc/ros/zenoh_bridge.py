"""`courtloc ros bridge` (EXPERIMENTAL, see rmw_zenoh.py): the robot's pose to ROS 2 nodes running rmw_zenoh
on the same Zenoh network, and their nav_msgs/Odometry into `shooter_bridge/odometry`.

Out: `<ns>/pose` (geometry_msgs/PoseWithCovarianceStamped, frame `court`, the pose's covariance) and
`/tf` (court -> base_link -> camera) for every pose its producer marked valid. In: `--odometry-topic`.
The Zenoh callbacks only keep the newest sample; conversion and publishing run on the bridge's thread.
"""
from __future__ import annotations

import logging
import os
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Callable

from pydantic import BaseModel, ConfigDict, Field, field_validator

from courtloc.common import codec
from courtloc.common.bus import ZenohConfig, open_session
from courtloc.common.messages import Pose
from courtloc.common.services_table import TOPICS
from courtloc.common.stats import RateLimitedLog
from courtloc.foxglove import scene
from courtloc.ros import convert, rmw_zenoh, types
from courtloc.ros.odometry_in import OdometryInput

log = logging.getLogger("courtloc.ros.bridge")


class BridgeOptions(BaseModel):
    model_config = ConfigDict(extra="forbid")
    domain_id: int = Field(0, ge=0, le=232)
    namespace: str = "/courtloc"
    odometry_topic: str = "/odom"
    node_name: str = Field("courtloc_bridge", pattern=r"^[A-Za-z][A-Za-z0-9_]*$")
    distro: rmw_zenoh.Distro = "humble"
    odometry_max_age_s: float = Field(0.2, gt=0)

    @field_validator("namespace", "odometry_topic")
    @classmethod
    def _ros_name(cls, value: str) -> str:
        if value and not all(part and (part[0].isalpha() or part[0] == "_") and part.replace("_", "a").isalnum()
                             for part in value.strip("/").split("/")):
            raise ValueError(f"{value!r} is not a ROS topic name")
        return value


@dataclass
class BridgeStats:
    poses_in: int = 0
    poses_out: int = 0
    poses_not_valid: int = 0
    odometry_in: int = 0
    odometry_rejected: dict[str, int] = field(default_factory=dict)
    errors: dict[str, int] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


class _Latest:
    """The newest payload of one input; the callback stores, the bridge thread takes."""

    def __init__(self, wake: threading.Event) -> None:
        self._lock = threading.Lock()
        self._value: Any = None
        self._wake = wake

    def put(self, value: Any) -> None:
        with self._lock:
            self._value = value
        self._wake.set()

    def take(self) -> Any:
        with self._lock:
            value, self._value = self._value, None
        return value


class RosZenohBridge:
    def __init__(self, robot_id: str, zenoh_config: ZenohConfig, options: BridgeOptions,
                 camera: scene.CameraPlacement | None = None) -> None:
        self.robot_id = robot_id
        self.zenoh_config = zenoh_config
        self.options = options
        self.camera = camera
        self.stats = BridgeStats()
        self._odometry = OdometryInput(robot_id, options.odometry_max_age_s)
        self._rate_log = RateLimitedLog(log)
        self._gid = os.urandom(16)
        self._sequence = 0

    def _pose_topic(self) -> str:
        return "/" + "/".join(p for p in (self.options.namespace.strip("/"), "pose") if p)

    def run(self, stop: threading.Event, duration_s: float | None = None,
            on_ready: Callable[[], None] | None = None) -> BridgeStats:
        session = open_session(self.zenoh_config, stop)
        if session is None:
            return self.stats
        wake = threading.Event()
        pose_in, odom_in = _Latest(wake), _Latest(wake)
        opts = self.options
        zid = str(session.info.zid())
        node = rmw_zenoh.Node(opts.domain_id, zid, node_id=0, name=opts.node_name)
        qos = rmw_zenoh.qos_string()
        pose_key = rmw_zenoh.data_key(opts.domain_id, self._pose_topic(), types.POSE_COV, opts.distro)
        tf_key = rmw_zenoh.data_key(opts.domain_id, "/tf", types.TF, opts.distro)
        declared: list[Any] = [
            session.liveliness().declare_token(node.token()),
            session.liveliness().declare_token(node.endpoint_token(1, "MP", self._pose_topic(), types.POSE_COV,
                                                                   opts.distro, qos)),
            session.liveliness().declare_token(node.endpoint_token(2, "MP", "/tf", types.TF, opts.distro,
                                                                   rmw_zenoh.qos_string(depth=100))),
            session.declare_subscriber(TOPICS["infer/pose"].key(self.robot_id),
                                       lambda sample: pose_in.put(bytes(sample.payload))),
        ]
        publishers = {pose_key: session.declare_publisher(pose_key), tf_key: session.declare_publisher(tf_key)}
        odometry_out = None
        if opts.odometry_topic:
            declared.append(session.liveliness().declare_token(node.endpoint_token(
                3, "MS", opts.odometry_topic, types.ODOMETRY, opts.distro, qos)))
            declared.append(session.declare_subscriber(
                rmw_zenoh.data_key_any_hash(opts.domain_id, opts.odometry_topic, types.ODOMETRY),
                lambda sample: odom_in.put(bytes(sample.payload))))
            odometry_out = session.declare_publisher(TOPICS["shooter_bridge/odometry"].key(self.robot_id))
        try:
            if on_ready is not None:
                on_ready()
            deadline = None if duration_s is None else time.monotonic() + duration_s
            while not stop.is_set() and (deadline is None or time.monotonic() < deadline):
                if not wake.wait(0.5):
                    continue
                wake.clear()
                payload = pose_in.take()
                if payload is not None:
                    self._on_pose(payload, publishers[pose_key], publishers[tf_key])
                payload = odom_in.take()
                if payload is not None and odometry_out is not None:
                    self._on_odometry(payload, odometry_out)
        finally:
            for entity in declared:
                entity.undeclare()
            for publisher in publishers.values():
                publisher.undeclare()
            if odometry_out is not None:
                odometry_out.undeclare()
            session.close()
        return self.stats

    def _count_error(self, reason: str, detail: str) -> None:
        self.stats.errors[reason] = self.stats.errors.get(reason, 0) + 1
        self._rate_log.warning(reason, f"{reason}: {detail}")

    def _put(self, publisher: Any, data: bytes, stamp_ns: int) -> None:
        self._sequence += 1
        publisher.put(data, attachment=rmw_zenoh.attachment(self._sequence, stamp_ns, self._gid))

    def _on_pose(self, payload: bytes, pose_publisher: Any, tf_publisher: Any) -> None:
        self.stats.poses_in += 1
        try:
            pose = codec.decode(payload, Pose)
        except codec.DecodeError as exc:
            self._count_error("pose_undecodable", exc.reason)
            return
        ros_pose = convert.pose_with_covariance(pose)
        robot = scene.robot_transform(pose)
        if ros_pose is None or robot is None:
            self.stats.poses_not_valid += 1  # never hand ROS a pose its producer did not trust
            return
        store = types.typestore()
        now = time.time_ns()
        self._put(pose_publisher, bytes(store.serialize_cdr(ros_pose, types.POSE_COV)), now)
        transforms = [robot] + ([scene.camera_transform(self.camera, pose.header.capture_wall_ns)]
                                if self.camera is not None else [])
        self._put(tf_publisher, bytes(store.serialize_cdr(convert.tf_message(transforms), types.TF)), now)
        self.stats.poses_out += 1

    def _on_odometry(self, payload: bytes, publisher: Any) -> None:
        self.stats.odometry_in += 1
        try:
            ros = types.typestore().deserialize_cdr(payload, types.ODOMETRY)
        except Exception as exc:  # noqa: BLE001 - rosbags raises several types on malformed CDR
            self._count_error("odometry_undecodable", str(exc))
            return
        message = self._odometry.convert(ros)
        self.stats.odometry_rejected = dict(self._odometry.rejected)
        publisher.put(codec.encode(message))
