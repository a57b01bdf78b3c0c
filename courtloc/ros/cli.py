"""`courtloc export rosbag2` and `courtloc ros bridge` (the `ros` extra: rosbags)."""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from courtloc.cli_errors import UsageError
from courtloc.cliargs import nonnegative_int, positive_float
from courtloc.common.bus import wait_for_router
from courtloc.common.signals import stop_on_signals
from courtloc.recording.busargs import add_client_arguments, client_deployment
from courtloc.recording.foxview import FoxgloveViews
from courtloc.ros.export import export_rosbag2
from courtloc.ros.zenoh_bridge import BridgeOptions, RosZenohBridge

ROS_EXTRA_HINT = "needs the ros extra: pip install 'courtloc[ros]' (rosbags)"


def register_export(export_sub: argparse._SubParsersAction) -> None:
    """The hook of `courtloc export` (courtloc/export_cli.py)."""
    bag = export_sub.add_parser("rosbag2", help="a recording as a ROS 2 bag: PoseWithCovarianceStamped, TF, "
                                                "CompressedImage, shot solution")
    bag.add_argument("input", type=Path, help="IN.mcap written by `courtloc record` (or the series IN-000.mcap...)")
    bag.add_argument("out", type=Path, help="bag folder to create (must not exist)")
    bag.add_argument("--namespace", default="/courtloc", help="prefix of the courtloc topics (default /courtloc)")
    bag.add_argument("--robot", default=None, metavar="ID", help="only this robot's messages (default: all)")
    bag.add_argument("--court", default="seed-gazebo", help="court whose default camera places the camera in TF")
    bag.add_argument("--camera", default=None, help="camera model for base_link -> camera (default: the court's)")
    bag.set_defaults(func=run_export)


def register(sub: argparse._SubParsersAction) -> None:
    ros = sub.add_parser("ros", help="ROS 2 on the same Zenoh network (experimental rmw_zenoh bridge)")
    ros_sub = ros.add_subparsers(dest="ros_command", metavar="SUBCOMMAND")
    ros.set_defaults(func=lambda args: (ros.print_help(), 2)[1])
    bridge = ros_sub.add_parser("bridge", help="publish PoseWithCovarianceStamped + TF the way rmw_zenoh does, "
                                               "and feed nav_msgs/Odometry into shooter_bridge/odometry")
    bridge.add_argument("--domain", type=nonnegative_int, default=0, help="ROS_DOMAIN_ID (default 0)")
    bridge.add_argument("--namespace", default="/courtloc", help="prefix of the published topics")
    bridge.add_argument("--odometry-topic", default="/odom", help="ROS topic read as odometry ('' for none)")
    bridge.add_argument("--duration", type=positive_float, default=None, help="stop after S seconds (default: Ctrl-C)")
    bridge.add_argument("--distro", choices=("humble", "jazzy"), default="humble",
                        help="rmw_zenoh's key format: humble (no type hash) or jazzy (RIHS01 hashes)")
    bridge.add_argument("--court", default=None, help="court whose camera places base_link -> camera "
                                                      "(default: the config's)")
    bridge.add_argument("--camera", default=None, help="camera model (default: the config's)")
    add_client_arguments(bridge)
    bridge.set_defaults(func=run_bridge)


def run_export(args: argparse.Namespace) -> int:
    try:
        import rosbags  # noqa: F401 - optional extra
    except ImportError:
        raise UsageError(ROS_EXTRA_HINT) from None

    if args.out.exists():
        raise UsageError(f"{args.out} exists; give a new folder")
    # a missing recording, a bad court or camera raises, named (courtloc.cli prints it as one line)
    camera = FoxgloveViews.load(args.court, args.camera).camera
    stats = export_rosbag2(args.input, args.out, camera, args.namespace, args.robot)
    print(json.dumps({"bag": str(args.out), "written": stats.written, "skipped": stats.skipped}))
    return 0


def run_bridge(args: argparse.Namespace) -> int:
    try:
        import rosbags  # noqa: F401 - optional extra
    except ImportError:
        raise UsageError(ROS_EXTRA_HINT) from None

    # a bad file, field, court or camera raises, named (courtloc.cli prints it as one line)
    config = client_deployment(args)
    options = BridgeOptions(domain_id=args.domain, namespace=args.namespace, odometry_topic=args.odometry_topic,
                            distro=args.distro)
    camera = FoxgloveViews.load(args.court or config.camera.sim.get("court", config.court),
                                args.camera or config.camera.sim.get("camera")).camera
    wait_for_router(config.zenoh, args.timeout)  # names the endpoint; gives up after --timeout S
    stop = stop_on_signals()
    bridge = RosZenohBridge(config.robot_id, config.zenoh, options, camera)
    stats = bridge.run(stop, args.duration,
                       on_ready=lambda: print(f"ros bridge up for {config.robot_id} (domain {args.domain})",
                                              flush=True))
    print(json.dumps(stats.as_dict()), flush=True)
    return 0
