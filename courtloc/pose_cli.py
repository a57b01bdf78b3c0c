"""`courtloc pose set X Y YAW`: tell a running robot where it is, from the pit (like an initial-pose tool).

The infer stage takes it as evidence for its localizer, which still confirms it against the view: a pose
the view contradicts is not reported valid (docs/localizer.md, "Acquisition").
"""
from __future__ import annotations

import argparse
import json
import math

from courtloc.cli_errors import RUN_EXIT, UsageError
from courtloc.cliargs import add_json_argument, json_to_stdout
from courtloc.common import codec
from courtloc.common.bus import open_session, wait_for_router
from courtloc.common.control import PoseReply, PoseRequest, SetPose
from courtloc.common.services_table import CONTROLS
from courtloc.recording.busargs import add_client_arguments, client_deployment

ROUTER_TIMEOUT_S = 10.0  # a one-shot request: give up on an absent router (as `courtloc model`)


def register(sub: argparse._SubParsersAction) -> None:
    pose = sub.add_parser("pose", help="set the robot's pose on a running robot")
    ops = pose.add_subparsers(dest="pose_op", metavar="OP", required=True)
    put = ops.add_parser("set", help="the robot is at X Y (court metres) facing YAW (degrees CCW from +x)")
    add_client_arguments(put, timeout_s=ROUTER_TIMEOUT_S)
    put.add_argument("x", type=float)
    put.add_argument("y", type=float)
    put.add_argument("yaw_deg", type=float, metavar="YAW")
    put.add_argument("--std", type=float, default=0.3, help="position uncertainty, metres (default 0.3)")
    put.add_argument("--yaw-std", type=float, default=10.0, help="heading uncertainty, degrees (default 10)")
    add_json_argument(put, "the robot's reply")
    put.set_defaults(func=_set)


def _set(args: argparse.Namespace) -> int:
    # a value out of range, a bad file or a missing credential raises, named (courtloc.cli: one line)
    body = SetPose(x=args.x, y=args.y, yaw=math.radians(args.yaw_deg), std_m=args.std,
                   yaw_std_rad=math.radians(args.yaw_std))
    config = client_deployment(args)
    wait_for_router(config.zenoh, args.timeout)  # names the endpoint; gives up after --timeout S
    control = CONTROLS["infer/set_pose"]
    session = open_session(config.zenoh)
    assert session is not None
    try:
        reply = None
        for answer in session.get(control.key(config.robot_id), payload=codec.encode(PoseRequest(body=body)),
                                  timeout=control.timeout_s):
            if answer.ok is None:
                raise UsageError(f"the robot answered with an error: {answer.err.payload.to_string()}", RUN_EXIT)
            reply = codec.decode(bytes(answer.ok.payload), PoseReply)
            break
    finally:
        session.close()
    if reply is None:
        raise UsageError(f"no answer from robot {config.robot_id!r}'s infer service within {control.timeout_s:g} s "
                         "(is it running, and is this the right robot?)", RUN_EXIT)
    if args.json is not None:
        args.json.write_text(json.dumps(reply.model_dump(), indent=2))
    if not json_to_stdout(args.json):
        print(("ok: " if reply.ok else "refused: ") + reply.reason)
    return 0 if reply.ok else 1
