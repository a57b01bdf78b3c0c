"""`courtloc calibrate intrinsics` and `courtloc calibrate mount`: a team's own camera, from a chessboard
and a few frames at a measured pose (see docs/bringup.md)."""
from __future__ import annotations

import argparse
import json
import logging
import sys
import tempfile
from pathlib import Path

from courtloc.cli_errors import UsageError
from courtloc.cliargs import add_json_argument, json_to_stdout, positive_int
from courtloc.common.bus import wait_for_router
from courtloc.lab.intrinsics import (
    Board,
    IntrinsicsOptions,
    calibrate_intrinsics,
    image_files,
    import_camera_info,
)
from courtloc.lab.mount import PoseFrames, fit_mount, hits_of_frames, mounted_camera
from courtloc.recording.busargs import add_client_arguments, client_deployment
from courtloc.sim.live_frames import grab_frames
from courtloc.world.camera import load_camera
from courtloc.world.court import load_court

log = logging.getLogger(__name__)


def register_calibrate_verbs(verbs: argparse._SubParsersAction) -> None:
    p = verbs.add_parser("intrinsics", help="focal length, principal point and lens distortion from chessboard "
                                            "images (or import an OpenCV / ROS camera_info YAML)")
    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument("--images", help="folder of chessboard images taken with the robot's camera")
    source.add_argument("--camera-info", help="import an OpenCV calibration or a ROS camera_info YAML instead")
    p.add_argument("--board", help="COLSxROWS inner corners, e.g. 9x6 for a board of 10x7 squares")
    p.add_argument("--square", type=float, help="side of one square, metres (measure it on the print)")
    p.add_argument("--out", required=True, help="camera JSON to write (the input of `calibrate mount`)")
    p.add_argument("--name", default=None, help="camera name in the JSON (default: the output file's stem)")
    p.add_argument("--min-views", type=int, default=8, help="usable views needed (default 8)")
    p.add_argument("--max-blur", type=float, default=3.5,
                   help="refuse a view whose board edges are wider than this many pixels (default 3.5)")
    p.add_argument("--fit-k3", action="store_true", help="also fit k3 (wide-angle lenses, many views)")
    p.set_defaults(func=_intrinsics)

    m = verbs.add_parser("mount", help="height, pitch, roll and offset of the camera on the robot, from frames "
                                       "taken at measured poses on the court")
    m.add_argument("--court", dest="mount_court", required=True, help="court name or JSON path")
    m.add_argument("--camera", dest="mount_camera", required=True,
                   help="camera JSON with the intrinsics (from `calibrate intrinsics`)")
    m.add_argument("--pose", dest="mount_pose", action="append", required=True, metavar="X,Y,YAW",
                   help="where the robot stood (court metres, yaw in radians); repeat with --frames for more poses")
    m.add_argument("--frames", dest="mount_frames", action="append", default=[], metavar="DIR",
                   help="folder of frames taken at the matching --pose")
    m.add_argument("--live", dest="mount_live", action="store_true",
                   help="take the frames of the (single) --pose from the running robot's camera/frame instead")
    m.add_argument("--live-frames", dest="mount_live_n", type=positive_int, default=5,
                   help="frames to take with --live")
    m.add_argument("--save", dest="mount_save", type=Path, default=None,
                   help="with --live: keep the frames in this folder (default: a new temporary folder)")

    add_client_arguments(m)
    m.add_argument("--height", dest="mount_height", type=float, default=None,
                   help="starting height, metres (default: searched)")
    m.add_argument("--pitch", dest="mount_pitch", type=float, default=None,
                   help="starting pitch down, radians (default: searched)")
    m.add_argument("--check", action="store_true", help="print the residual of every court line, pixels")
    m.add_argument("--out", dest="mount_out", default=None, help="write the mounted camera JSON here")
    add_json_argument(m, "the fitted mount")
    m.set_defaults(func=_mount)


def _write_camera(camera, path: str) -> None:
    Path(path).write_text(json.dumps(camera.model_dump(), indent=1) + "\n")


def _intrinsics(args: argparse.Namespace) -> int:
    name = args.name or Path(args.out).stem
    # A bad file, board, view or field raises (IntrinsicsError is a ValueError): one line from courtloc.cli.
    if args.camera_info:
        camera = import_camera_info(args.camera_info, name=name)
        _write_camera(camera, args.out)
        print(f"fx {camera.fx:.2f} fy {camera.fy:.2f} cx {camera.cx:.2f} cy {camera.cy:.2f} "
              f"({camera.width}x{camera.height}), k1 {camera.k1:.5f} k2 {camera.k2:.5f} p1 {camera.p1:.6f} "
              f"p2 {camera.p2:.6f} k3 {camera.k3:.5f}")
        print(f"camera written to {args.out} (mount still to fit: courtloc calibrate mount)")
        return 0
    if not args.board or args.square is None:
        raise UsageError("--images needs --board COLSxROWS and --square METRES")
    board = Board.parse(args.board, args.square)
    options = IntrinsicsOptions(min_views=args.min_views, max_sharpness_px=args.max_blur, fit_k3=args.fit_k3,
                                name=name)
    result = calibrate_intrinsics(image_files(args.images), board, options)
    print(result.report())
    _write_camera(result.camera, args.out)
    print(f"camera written to {args.out} (mount still to fit: courtloc calibrate mount)")
    return 0


def _mount(args: argparse.Namespace) -> int:
    # A bad file, name, pose or field raises (MountError is a ValueError), and no router raises
    # RouterUnreachable (exit 1: the command line was right): one line from courtloc.cli.
    if args.mount_live:
        if len(args.mount_pose) != 1 or args.mount_frames:
            raise UsageError("--live takes the frames of exactly one --pose (and no --frames)")
        args.mount_frames = [str(_live_frames(args))]
    if len(args.mount_pose) != len(args.mount_frames):
        raise UsageError(f"{len(args.mount_pose)} --pose and {len(args.mount_frames)} --frames: "
                         "give one --frames per --pose")
    court = load_court(args.mount_court)
    camera = load_camera(args.mount_camera)
    sets = [PoseFrames(pose=PoseFrames.parse_pose(p), frames=Path(f))
            for p, f in zip(args.mount_pose, args.mount_frames)]
    dots = hits_of_frames(sets)
    result = fit_mount(court, dots, camera, poses=len(sets), initial_height=args.mount_height,
                       initial_pitch=args.mount_pitch)
    if args.json is not None:
        args.json.write_text(result.model_dump_json(indent=1))
    quiet = json_to_stdout(args.json)  # stdout is the JSON's
    if not quiet:
        print(result.report())
        if args.check:
            print(result.check_report())
    if args.mount_out:
        _write_camera(mounted_camera(result, Path(args.mount_out).stem), args.mount_out)
        print(f"camera written to {args.mount_out}", file=sys.stderr if quiet else sys.stdout)
    return 0


def _live_frames(args: argparse.Namespace) -> Path:
    """Frames from the robot's running camera stage, saved where `calibrate mount` reads them."""

    deployment = client_deployment(args)
    wait_for_router(deployment.zenoh, args.timeout)  # names the endpoint; gives up after --timeout S
    folder = args.mount_save or Path(tempfile.mkdtemp(prefix="courtloc-mount-"))
    saved = grab_frames(deployment.robot_id, deployment.zenoh, args.mount_live_n, folder)
    print(f"{len(saved)} live frames saved in {folder}", file=sys.stderr)
    return folder
