"""`courtloc pose set X Y YAW`: tell a running robot where it is, from the pit (like an initial-pose tool).

The infer stage takes it as evidence for its localizer, which still confirms it against the view: a pose
the view contradicts is not reported valid (docs/localizer.md, "Acquisition").
"""
from __future__ import annotations

import argparse
import json
import math
import sys

from courtloc.recording.busargs import add_client_arguments, client_deployment


def register(sub: argparse._SubParsersAction) -> None:
    pose = sub.add_parser("pose", help="set the robot's pose on a running robot")
    ops = pose.add_subparsers(dest="pose_op", metavar="OP", required=True)
    put = ops.add_parser("set", help="the robot is at X Y (court metres) facing YAW (degrees CCW from +x)")
    add_client_arguments(put)
    put.add_argument("x", type=float)
    put.add_argument("y", type=float)
    put.add_argument("yaw_deg", type=float, metavar="YAW")
    put.add_argument("--std", type=float, default=0.3, help="position uncertainty, metres (default 0.3)")
    put.add_argument("--yaw-std", type=float, default=10.0, help="heading uncertainty, degrees (default 10)")
    put.add_argument("--json", action="store_true", help="print the robot's reply as JSON")
    put.set_defaults(func=_set)


def _set(args: argparse.Namespace) -> int:
    from pydantic import ValidationError

    from courtloc.common import codec
    from courtloc.common.bus import open_session
    from courtloc.common.control import PoseReply, PoseRequest, SetPose
    from courtloc.common.services_table import CONTROLS

    try:
        body = SetPose(x=args.x, y=args.y, yaw=math.radians(args.yaw_deg), std_m=args.std,
                       yaw_std_rad=math.radians(args.yaw_std))
        config = client_deployment(args)
    except ValidationError as exc:
        error = exc.errors()[0]
        print(f"error: {'.'.join(map(str, error['loc']))}: {error['msg']}", file=sys.stderr)
        return 2
    except ValueError as exc:  # ConfigError included: a bad file or a missing credential, named
        print(exc, file=sys.stderr)
        return 2
    control = CONTROLS["infer/set_pose"]
    session = open_session(config.zenoh)
    assert session is not None
    try:
        reply = None
        for answer in session.get(control.key(config.robot_id), payload=codec.encode(PoseRequest(body=body)),
                                  timeout=control.timeout_s):
            if answer.ok is None:
                print(f"error: {answer.err.payload.to_string()}", file=sys.stderr)
                return 1
            reply = codec.decode(bytes(answer.ok.payload), PoseReply)
            break
    finally:
        session.close()
    if reply is None:
        print("error: no answer from the robot's infer service (is it running, and is this the right robot?)",
              file=sys.stderr)
        return 1
    print(json.dumps(reply.model_dump(), indent=2) if args.json else ("ok: " if reply.ok else "refused: ") + reply.reason)
    return 0 if reply.ok else 1
