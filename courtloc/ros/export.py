"""`courtloc export rosbag2 IN.mcap OUT/`: a recording as a ROS 2 bag (rosbags writer, no ROS install).

Reads the exact payloads (bit-exact bus messages, see courtloc.recording.mcapfile) and writes, stamped
with each message's receive time:

| topic (namespace `/courtloc`) | type | from |
|---|---|---|
| `<ns>/pose` | geometry_msgs/PoseWithCovarianceStamped (frame `court`) | valid `infer/pose` |
| `/tf` | tf2_msgs/TFMessage: court -> base_link, base_link -> camera | valid `infer/pose` |
| `/tf_static` | tf2_msgs/TFMessage: base_link -> camera (once) | the camera model |
| `<ns>/camera/image/compressed` | sensor_msgs/CompressedImage (JPEG) | `camera/frame` |
| `<ns>/shot_solution` | courtloc_msgs/ShotSolution (definition stored in the bag) | `shooter_bridge/solution` |

Invalid poses are left out: a bag is what robot_localization or Nav2 would fuse, and a pose its
producer did not trust must not reach them.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from courtloc.common import codec
from courtloc.common.messages import Frame, Pose, ShotSolution
from courtloc.common.services_table import TOPICS
from courtloc.foxglove import scene
from courtloc.recording.mcapfile import read_series, series_files
from courtloc.ros import convert, types

log = logging.getLogger("courtloc.ros.export")

EXPORTED = ("infer/pose", "camera/frame", "shooter_bridge/solution")


@dataclass
class ExportStats:
    written: dict[str, int] = field(default_factory=dict)
    skipped: dict[str, int] = field(default_factory=dict)  # reason -> count

    def count(self, topic: str) -> None:
        self.written[topic] = self.written.get(topic, 0) + 1

    def skip(self, reason: str) -> None:
        self.skipped[reason] = self.skipped.get(reason, 0) + 1


def export_rosbag2(recording: Path, out: Path, camera: scene.CameraPlacement, namespace: str = "/courtloc",
                   robot_id: str | None = None) -> ExportStats:
    """Writes the bag folder `out` (must not exist); returns what was written and skipped, by reason."""
    from rosbags.rosbag2 import Writer  # rosbags: the ros extra

    store = types.typestore()
    stats = ExportStats()
    files = series_files(recording)
    ns = "/" + namespace.strip("/") if namespace.strip("/") else ""
    with Writer(out, version=8) as writer:
        connections: dict[str, Any] = {}

        def write(topic: str, msgtype: str, message: Any, log_time: int) -> None:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=store)
            writer.write(connections[topic], log_time, bytes(store.serialize_cdr(message, msgtype)))
            stats.count(topic)

        static_written = False
        for record in read_series(files, only=set(EXPORTED)):
            if robot_id is not None and record.robot_id != robot_id:
                stats.skip("other_robot")
                continue
            try:
                message = codec.decode(record.data, TOPICS[record.path].message)
            except codec.DecodeError:
                stats.skip("undecodable")
                continue
            if not static_written:
                write("/tf_static", types.TF, convert.tf_message([scene.camera_transform(camera, record.log_time)]),
                      record.log_time)
                static_written = True
            if isinstance(message, Pose):
                ros_pose = convert.pose_with_covariance(message)
                robot = scene.robot_transform(message)
                if ros_pose is None or robot is None:
                    stats.skip("pose_not_valid")
                    continue
                write(f"{ns}/pose", types.POSE_COV, ros_pose, record.log_time)
                write("/tf", types.TF, convert.tf_message(
                    [robot, scene.camera_transform(camera, message.header.capture_wall_ns)]), record.log_time)
            elif isinstance(message, Frame):
                write(f"{ns}/camera/image/compressed", types.IMAGE, convert.compressed_image(message),
                      record.log_time)
            elif isinstance(message, ShotSolution):
                write(f"{ns}/shot_solution", types.SHOT, convert.shot_solution(message), record.log_time)
    log.info("wrote %s: %s", out, stats.written)
    return stats
