"""`courtloc ros bridge` (experimental rmw_zenoh bridge): a real router, the bridge as its own process, and
a test client that plays the ROS 2 side with plain Zenoh: it finds the bridge's liveliness tokens,
decodes the CDR poses it publishes, and sends it nav_msgs/Odometry."""
from __future__ import annotations

import math
import threading
import time
from typing import Any

import numpy as np
import pytest
import zenoh
from buskit import PYTHON, BusClient, Proc, endpoint, free_port, start_router

from courtloc.common import codec
from courtloc.common.messages import Header, Pose

pytest.importorskip("rosbags", reason="the ros extra")
from courtloc.ros import rmw_zenoh, types  # noqa: E402

ROBOT = "robot1"
COV = [0.0004, 0.0001, 0.00002, 0.0001, 0.0009, 0.00003, 0.00002, 0.00003, 0.0001]
POSE_KEY = "0/courtloc/pose/geometry_msgs::msg::dds_::PoseWithCovarianceStamped_/TypeHashNotSupported"
ODOM_KEY = "0/odom/nav_msgs::msg::dds_::Odometry_/TypeHashNotSupported"


def _pose(seq: int, x: float, valid: bool) -> Pose:
    header = Header.now(ROBOT, seq, "infer")
    header.valid = valid
    return Pose(header=header, x=x, y=-1.0, yaw=0.25, model_name="m", model_version=1, infer_ms=1.0,
                covariance=COV, reason="" if valid else "low_quality")


def _odometry(stamp_ns: int, vx: float) -> bytes:
    store = types.typestore()
    t = store.types
    header = t["std_msgs/msg/Header"](stamp=t["builtin_interfaces/msg/Time"](sec=stamp_ns // 10**9,
                                                                             nanosec=stamp_ns % 10**9),
                                      frame_id="odom")
    pose = t["geometry_msgs/msg/PoseWithCovariance"](
        pose=t["geometry_msgs/msg/Pose"](position=t["geometry_msgs/msg/Point"](x=0.4, y=0.1, z=0.0),
                                         orientation=t["geometry_msgs/msg/Quaternion"](
                                             x=0.0, y=0.0, z=math.sin(0.1), w=math.cos(0.1))),
        covariance=np.zeros(36))
    twist = t["geometry_msgs/msg/TwistWithCovariance"](
        twist=t["geometry_msgs/msg/Twist"](linear=t["geometry_msgs/msg/Vector3"](x=vx, y=0.0, z=0.0),
                                           angular=t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.3)),
        covariance=np.zeros(36))
    message = t[types.ODOMETRY](header=header, child_frame_id="base_link", pose=pose, twist=twist)
    return bytes(store.serialize_cdr(message, types.ODOMETRY))


def _wait_matched(session: zenoh.Session, key: str, timeout: float = 20.0) -> Any:
    matched = threading.Event()
    publisher = session.declare_publisher(key)
    listener = publisher.declare_matching_listener(lambda status: matched.set() if status.matching else None)
    if not (publisher.matching_status.matching or matched.wait(timeout)):
        raise AssertionError(f"nobody subscribes {key}")
    listener.undeclare()
    return publisher


def _ros_tokens(session: zenoh.Session, count: int, timeout: float = 20.0) -> list[str]:
    """The bridge's discovery tokens as a ROS 2 graph sees them. They reach the router after the bridge says
    it is up, so a one-shot query can come back empty: listen (with history) until all have arrived."""
    alive: set[str] = set()
    arrived = threading.Condition()

    def on_token(sample: zenoh.Sample) -> None:
        with arrived:
            if sample.kind == zenoh.SampleKind.PUT:
                alive.add(str(sample.key_expr))
            arrived.notify_all()

    listener = session.liveliness().declare_subscriber("@ros2_lv/0/**", on_token, history=True)
    try:
        with arrived:
            arrived.wait_for(lambda: len(alive) >= count, timeout)
            return sorted(alive)
    finally:
        listener.undeclare()


@pytest.mark.integration
def test_bridge_speaks_rmw_zenoh_both_ways() -> None:
    port = free_port()
    router = start_router(port)
    bridge = Proc([*PYTHON, "ros", "bridge", "--connect", endpoint(port), "--robot", ROBOT]).start()
    client = BusClient(port, ROBOT)
    received: list[tuple[bytes, bytes | None]] = []
    got = threading.Condition()

    def on_ros_pose(sample: zenoh.Sample) -> None:
        with got:
            received.append((bytes(sample.payload), bytes(sample.attachment) if sample.attachment else None))
            got.notify_all()

    ros_sub = client.session.declare_subscriber(POSE_KEY, on_ros_pose)
    try:
        bridge.wait_line("ros bridge up")
        # discovery as a ROS 2 node sees it: a node, two publishers, one subscription
        tokens = _ros_tokens(client.session, count=4)
        kinds = sorted(token.split("/")[5] for token in tokens)
        assert kinds == ["MP", "MP", "MS", "NN"], tokens
        pose_token = next(t for t in tokens if "PoseWithCovarianceStamped" in t)
        assert pose_token.split("/")[6:] == ["%", "%", "courtloc_bridge", "courtloc%pose",
                                             "geometry_msgs::msg::dds_::PoseWithCovarianceStamped_",
                                             "TypeHashNotSupported", "1:2:1,10:,:,:,,"]
        client.wait_subscribed("infer/pose")
        client.put_raw("infer/pose", codec.encode(_pose(1, 9.0, valid=False)))  # never reaches ROS
        client.put_raw("infer/pose", codec.encode(_pose(2, 1.5, valid=True)))
        with got:
            assert got.wait_for(lambda: received, 20)
        payload, attachment = received[0]
        assert payload[:4] == b"\x00\x01\x00\x00", "CDR little-endian encapsulation header"
        ros = types.typestore().deserialize_cdr(payload, types.POSE_COV)
        assert (ros.header.frame_id, ros.pose.pose.position.x, ros.pose.pose.position.y) == ("court", 1.5, -1.0)
        cov = np.asarray(ros.pose.covariance).reshape(6, 6)
        np.testing.assert_array_equal(cov[np.ix_([0, 1, 5], [0, 1, 5])], np.array(COV).reshape(3, 3))
        assert attachment is not None
        sequence, stamp, gid = rmw_zenoh.parse_attachment(attachment)
        assert sequence >= 1 and len(gid) == 16 and abs(stamp - time.time_ns()) < 60e9

        # odometry from ROS into the courtloc topic, with the stamp checked
        client.subscribe("shooter_bridge/odometry")
        ros_odom = _wait_matched(client.session, ODOM_KEY)
        ros_odom.put(_odometry(time.time_ns(), 0.8))
        odom = client.wait_for("shooter_bridge/odometry")
        assert odom.header.valid and odom.source == "ros" and odom.wheels_valid
        assert (odom.vx_m_s, odom.wz_wheels_rad_s, odom.odom_x_m) == (0.8, 0.3, 0.4)
        assert odom.odom_yaw_rad == pytest.approx(0.2)
        ros_odom.put(_odometry(time.time_ns() - 5 * 10**9, 0.8))  # five seconds old: as bad as a wrong value
        stale = client.wait_for("shooter_bridge/odometry", lambda m: m.source_seq == 2)
        assert not stale.header.valid and not stale.wheels_valid and stale.vx_m_s == 0.0
        ros_odom.put(b"\x00\x01\x00\x00 not an odometry message")  # counted, and the bridge goes on
        ros_odom.put(_odometry(time.time_ns(), 0.5))
        assert client.wait_for("shooter_bridge/odometry", lambda m: m.source_seq == 3).vx_m_s == 0.5
        ros_odom.undeclare()
    finally:
        ros_sub.undeclare()
        client.close()
        bridge.stop()
        router.stop()
    assert len(received) == 1, "the pose its producer marked invalid was not published"
