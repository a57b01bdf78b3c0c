"""courtloc messages <-> ROS 2 messages (rosbags objects). Frames: `court` is the fixed frame (REP 105's
`map` role), `base_link` the robot, `camera` the optical frame, as in courtloc.foxglove.scene."""
from __future__ import annotations

import math
from typing import Any

import cv2
import numpy as np

from courtloc.common.messages import Frame, Pose, ShotSolution
from courtloc.common.payloads import frame_pixels
from courtloc.foxglove import scene
from courtloc.ros import types

# Where the pose gives no covariance, or for z / roll / pitch (the robot is on the floor): a variance
# so large that robot_localization and Nav2 treat the component as unmeasured.
UNKNOWN_VARIANCE = 1e6


def _time(ns: int) -> Any:
    Time = types.typestore().types["builtin_interfaces/msg/Time"]
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def header(ns: int, frame_id: str) -> Any:
    return types.typestore().types["std_msgs/msg/Header"](stamp=_time(ns), frame_id=frame_id)


def _quaternion(q: dict[str, float]) -> Any:
    return types.typestore().types["geometry_msgs/msg/Quaternion"](x=q["x"], y=q["y"], z=q["z"], w=q["w"])


def pose_covariance(pose: Pose) -> np.ndarray:
    """The 6x6 (x, y, z, roll, pitch, yaw) covariance of ROS from the pose's 3x3 (x, y, yaw) one."""
    cov = np.diag([UNKNOWN_VARIANCE] * 6)
    if len(pose.covariance) == 9 and all(math.isfinite(v) for v in pose.covariance):
        small = np.asarray(pose.covariance, float).reshape(3, 3)
        index = [0, 1, 5]
        for i, a in enumerate(index):
            for j, b in enumerate(index):
                cov[a, b] = small[i, j]
        if pose.yaw is None:  # a position-only model: its yaw is not a measurement
            cov[5, :] = cov[:, 5] = 0.0
            cov[5, 5] = UNKNOWN_VARIANCE
    return cov


def pose_with_covariance(pose: Pose) -> Any | None:
    """geometry_msgs/PoseWithCovarianceStamped in `court`; None when x, y or yaw is not a number.

    Only send a pose on when `pose.header.valid` (the caller decides: the bag keeps all, the live bridge
    publishes valid ones only)."""
    if not all(math.isfinite(v) for v in (pose.x, pose.y, pose.yaw if pose.yaw is not None else 0.0)):
        return None
    ts = types.typestore().types
    point = ts["geometry_msgs/msg/Point"](x=pose.x, y=pose.y, z=0.0)
    ros_pose = ts["geometry_msgs/msg/Pose"](position=point,
                                             orientation=_quaternion(scene.yaw_quaternion(pose.yaw or 0.0)))
    with_cov = ts["geometry_msgs/msg/PoseWithCovariance"](pose=ros_pose,
                                                          covariance=pose_covariance(pose).reshape(-1))
    return ts[types.POSE_COV](header=header(pose.header.capture_wall_ns, scene.COURT_FRAME), pose=with_cov)


def transform_stamped(transform: dict[str, Any]) -> Any:
    """geometry_msgs/TransformStamped from a foxglove.FrameTransform dict (courtloc.foxglove.scene)."""
    ts = types.typestore().types
    t = transform["translation"]
    ns = transform["timestamp"]["sec"] * 1_000_000_000 + transform["timestamp"]["nsec"]
    return ts["geometry_msgs/msg/TransformStamped"](
        header=header(ns, transform["parent_frame_id"]), child_frame_id=transform["child_frame_id"],
        transform=ts["geometry_msgs/msg/Transform"](
            translation=ts["geometry_msgs/msg/Vector3"](x=t["x"], y=t["y"], z=t["z"]),
            rotation=_quaternion(transform["rotation"])))


def tf_message(transforms: list[dict[str, Any]]) -> Any:
    return types.typestore().types[types.TF](transforms=[transform_stamped(t) for t in transforms])


def compressed_image(frame: Frame, frame_id: str = scene.CAMERA_FRAME) -> Any:
    """sensor_msgs/CompressedImage: JPEG as is; a raw BGR frame is JPEG-encoded (ROS has no raw
    'compressed' format; use --raw-images for sensor_msgs/Image-sized bags elsewhere)."""
    data = frame.data
    if frame.encoding != "jpeg":
        ok, encoded = cv2.imencode(".jpg", frame_pixels(frame), [cv2.IMWRITE_JPEG_QUALITY, 95])
        if not ok:
            raise ValueError("JPEG encoding failed")
        data = encoded.tobytes()
    return types.typestore().types[types.IMAGE](header=header(frame.header.capture_wall_ns, frame_id), format="jpeg",
                                                data=np.frombuffer(data, np.uint8))


def shot_solution(solution: ShotSolution) -> Any:
    nan = float("nan")
    return types.typestore().types[types.SHOT](
        header=header(solution.header.capture_wall_ns, scene.ROBOT_FRAME), valid=solution.header.valid,
        command=solution.command, reason=solution.reason, distance_m=solution.distance_m,
        bearing_rad=nan if solution.bearing_rad is None else solution.bearing_rad, rpm=solution.rpm)
