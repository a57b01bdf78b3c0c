"""The ROS 2 message types we exchange, from the `rosbags` type store (ROS 2 Humble definitions: JetPack 6
is Ubuntu 22.04), plus our one custom type, courtloc_msgs/msg/ShotSolution."""
from __future__ import annotations

from functools import lru_cache
from typing import Any

POSE_COV = "geometry_msgs/msg/PoseWithCovarianceStamped"
TF = "tf2_msgs/msg/TFMessage"
IMAGE = "sensor_msgs/msg/CompressedImage"
ODOMETRY = "nav_msgs/msg/Odometry"
SHOT = "courtloc_msgs/msg/ShotSolution"

SHOT_MSGDEF = """\
# courtloc shooter bridge decision for one pose (courtloc.ShotSolution)
std_msgs/Header header
bool valid                # true for SET_RPM
string command            # SET_RPM or HOLD
string reason             # why HOLD; empty for SET_RPM
float64 distance_m        # shot distance; NaN when unknown
float64 bearing_rad       # turn to face the ring, CCW positive; NaN when the pose had no yaw
float64 rpm               # commanded wheel RPM; 0 on HOLD
"""


@lru_cache(maxsize=1)
def typestore() -> Any:
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore  # rosbags: the ros extra

    store = get_typestore(Stores.ROS2_HUMBLE)
    store.register(get_types_from_msg(SHOT_MSGDEF, SHOT))
    return store


def dds_type_name(msgtype: str) -> str:
    """geometry_msgs/msg/Pose -> geometry_msgs::msg::dds_::Pose_ (the name rmw implementations announce)."""
    package, kind, name = msgtype.split("/")
    return f"{package}::{kind}::dds_::{name}_"
