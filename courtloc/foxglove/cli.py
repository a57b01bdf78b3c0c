"""`courtloc foxglove`: the robot live in Foxglove (the `foxglove` extra: foxglove-sdk)."""
from __future__ import annotations

import argparse
import json

from courtloc.cli_errors import RUN_EXIT, UsageError
from courtloc.cliargs import port_number, positive_float
from courtloc.common.bus import wait_for_router
from courtloc.common.signals import stop_on_signals
from courtloc.foxglove.live import FoxgloveLive
from courtloc.recording.busargs import add_client_arguments, client_deployment
from courtloc.recording.foxview import FoxgloveViews


def register(sub: argparse._SubParsersAction) -> None:
    fox = sub.add_parser("foxglove", help="a live Foxglove WebSocket server: 3D court, pose, TF, camera, hits, "
                                          "shot solution, stage health")
    fox.add_argument("--port", type=port_number, default=8765, help="WebSocket port (default 8765; 0 picks a free one)")
    fox.add_argument("--host", default="127.0.0.1", help="listen address (0.0.0.0: the whole pit network)")
    fox.add_argument("--court", default=None, help="court drawn in 3D (default: the config's)")
    fox.add_argument("--camera", default=None, help="camera model placing the camera in TF (default: the config's)")
    fox.add_argument("--image-hz", type=positive_float, default=15.0, help="most camera images per second forwarded")
    fox.add_argument("--duration", type=positive_float, default=None, help="stop after S seconds (default: Ctrl-C)")
    add_client_arguments(fox)
    fox.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    try:
        import foxglove  # noqa: F401 - optional extra
    except ImportError:
        raise UsageError("needs the foxglove extra: pip install 'courtloc[foxglove]' (foxglove-sdk)") from None

    # a bad file, field, court or camera raises, named (courtloc.cli prints it as one line)
    config = client_deployment(args)
    views = FoxgloveViews.load(args.court or config.camera.sim.get("court", config.court),
                               args.camera or config.camera.sim.get("camera"))
    if args.timeout is not None:  # without it the server starts at once and serves once a router answers
        wait_for_router(config.zenoh, args.timeout)
    live = FoxgloveLive(config.robot_id, config.zenoh, views, args.host, args.port, args.image_hz)
    stop = stop_on_signals()
    try:
        stats = live.run(stop, args.duration, on_ready=lambda url: print(f"foxglove server on {url} for "
                                                                         f"{config.robot_id}", flush=True))
    except RuntimeError as exc:  # the port is taken
        raise UsageError(str(exc), RUN_EXIT) from None
    print(json.dumps(stats.as_dict()), flush=True)
    return 0
