"""ROS 2 out and in, without a ROS install: rosbag2 export of recordings, and an experimental live bridge
speaking rmw_zenoh's conventions on the same Zenoh network (needs the `ros` extra: rosbags)."""
