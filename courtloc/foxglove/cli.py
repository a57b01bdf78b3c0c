"""`courtloc foxglove`: the robot live in Foxglove (the `foxglove` extra: foxglove-sdk)."""
from __future__ import annotations

import argparse
import json
import sys

from courtloc.common.config_loader import ConfigError
from courtloc.common.signals import stop_on_signals
from courtloc.foxglove.live import FoxgloveLive
from courtloc.recording.busargs import add_client_arguments, client_deployment
from courtloc.recording.foxview import FoxgloveViews


def register(sub: argparse._SubParsersAction) -> None:
    fox = sub.add_parser("foxglove", help="a live Foxglove WebSocket server: 3D court, pose, TF, camera, hits, "
                                          "shot solution, stage health")
    fox.add_argument("--port", type=int, default=8765, help="WebSocket port (default 8765; 0 picks a free one)")
    fox.add_argument("--host", default="127.0.0.1", help="listen address (0.0.0.0: the whole pit network)")
    fox.add_argument("--court", default=None, help="court drawn in 3D (default: the config's)")
    fox.add_argument("--camera", default=None, help="camera model placing the camera in TF (default: the config's)")
    fox.add_argument("--image-hz", type=float, default=15.0, help="most camera images per second forwarded")
    fox.add_argument("--duration", type=float, default=None, help="stop after S seconds (default: Ctrl-C)")
    add_client_arguments(fox)
    fox.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    try:
        import foxglove  # noqa: F401 - optional extra
    except ImportError:
        print("foxglove: needs the foxglove extra: pip install 'courtloc[foxglove]' (foxglove-sdk)", file=sys.stderr)
        return 2

    if not 0 <= args.port <= 65535 or args.image_hz <= 0:
        print(f"--port must be 0..65535 and --image-hz > 0 (got {args.port}, {args.image_hz})", file=sys.stderr)
        return 2
    try:
        config = client_deployment(args)
        views = FoxgloveViews.load(args.court or config.camera.sim.get("court", config.court), args.camera or config.camera.sim.get("camera"))
    except (ConfigError, ValueError) as exc:
        print(" ".join(str(exc).split()), file=sys.stderr)
        return 2
    live = FoxgloveLive(config.robot_id, config.zenoh, views, args.host, args.port, args.image_hz)
    stop = stop_on_signals()
    try:
        stats = live.run(stop, args.duration, on_ready=lambda url: print(f"foxglove server on {url} for "
                                                                         f"{config.robot_id}", flush=True))
    except RuntimeError as exc:  # the port is taken
        print(f"foxglove: {exc}", file=sys.stderr)
        return 1
    print(json.dumps(stats.as_dict()), flush=True)
    return 0
