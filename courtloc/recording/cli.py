"""`courtloc record`, `courtloc replay` and the `capture` sub-command of `courtloc dataset`."""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from mcap.exceptions import McapError

from courtloc.cli_errors import UsageError
from courtloc.cliargs import nonnegative_float, positive_float, positive_int
from courtloc.common.bus import wait_for_router
from courtloc.common.services_table import TOPICS
from courtloc.common.signals import stop_on_signals
from courtloc.recording.busargs import add_client_arguments, client_deployment
from courtloc.recording.capture import CSV_NAME, Capture, CaptureOptions
from courtloc.recording.foxview import FoxgloveViews
from courtloc.recording.mcapfile import Limits, McapSeries, dumps_summary, exact_path, recorded_channels, series_files
from courtloc.recording.recorder import Recorder, recording_metadata, resolve_topics
from courtloc.recording.replay import Replayer, ReplayOptions

MCAP_MAGIC = b"\x89MCAP0\r\n"  # the first bytes of every MCAP file (the spec's magic)


def register(sub: argparse._SubParsersAction) -> None:
    record = sub.add_parser("record", help="record a robot's topics to MCAP (JSON view + exact msgpack)")
    record.add_argument("out", type=Path, help="OUT.mcap (OUT-000.mcap, OUT-001.mcap... with a limit)")
    record.add_argument("--topics", nargs="+", default=None, metavar="TOPIC",
                        help="topic paths such as infer/pose camera/frame, or 'all' "
                             "(default: every topic except raw camera frames)")
    record.add_argument("--max-mb", type=positive_float, default=None, help="start a new file at this size")
    record.add_argument("--max-seconds", type=positive_float, default=None, help="start a new file after this long")
    record.add_argument("--duration", type=positive_float, default=None,
                        help="stop after S seconds (default: Ctrl-C)")
    record.add_argument("--max-messages", type=positive_int, default=None, metavar="N", help="stop after N messages")
    record.add_argument("--court", default=None, help="court drawn in Foxglove's 3D panel (default: the config's)")
    record.add_argument("--camera", default=None,
                        help="camera model placing the camera on the robot in TF (default: the config's)")
    add_client_arguments(record)
    record.set_defaults(func=run_record)

    replay = sub.add_parser("replay", help="publish a recording with its original timing")
    replay.add_argument("input", type=Path, help="IN.mcap (or the series IN-000.mcap, IN-001.mcap...)")
    replay.add_argument("--speed", type=positive_float, default=1.0, help="time scale: 2 plays twice as fast")
    replay.add_argument("--loop", action="store_true", help="start again at the end, until Ctrl-C")
    replay.add_argument("--only", nargs="+", default=None, metavar="TOPIC", help="replay these topic paths only")
    replay.add_argument("--restamp", action="store_true",
                        help="move capture times to now so stages treat the frames as fresh (changes bytes); at "
                        "the recorded speed all by one shift, keeping their spacing")
    replay.add_argument("--wait-subscribers", type=nonnegative_float, default=0.0, metavar="S",
                        help="wait up to S seconds for a subscriber before the first message")
    replay.add_argument("--info", action="store_true", help="print the recording's channels and exit")
    add_client_arguments(replay, robot_help="publish as this robot id (default: the recorded one; changes bytes)")
    replay.set_defaults(func=run_replay)


def register_dataset(dataset_sub: argparse._SubParsersAction) -> None:
    """The hook of `courtloc dataset` (sim/cli.py DATASET_COMMAND_MODULES)."""
    add_capture_parser(dataset_sub)


def add_capture_parser(dataset_sub: argparse._SubParsersAction) -> None:
    """Adds `capture` to the `courtloc dataset` group (the group itself lives with the sim's CLI)."""
    capture = dataset_sub.add_parser("capture", help="record frames with time-matched poses in the seed format")
    capture.add_argument("--out", type=Path, required=True, help="folder for images/ and pose_data.csv")
    capture.add_argument("--tolerance-ms", type=positive_float, default=20.0, help="largest frame-to-pose time gap")
    capture.add_argument("--offset-ms", type=float, default=0.0,
                         help="the pose source's lag: a frame at t matches the pose stamped t + offset")
    capture.add_argument("--n", type=positive_int, default=None, help="stop after N pairs")
    capture.add_argument("--duration", type=positive_float, default=None, help="stop after S seconds")
    capture.add_argument("--truth-topic", default="camera/ground_truth",
                         help="pose topic that holds the truth (default: the sim's ground truth)")
    capture.add_argument("--truth-robot", default=None, metavar="ID",
                         help="robot id the truth is published under (an external tracker), default --robot")
    add_client_arguments(capture)
    capture.set_defaults(func=run_capture)


def _deployment(args: argparse.Namespace):  # noqa: ANN202
    """The deployment (a bad file or field raises, named), once its router answers (or --timeout)."""
    config = client_deployment(args)
    wait_for_router(config.zenoh, args.timeout)
    return config


def _recording_files(path: Path) -> list[Path]:
    """The recording's files, each checked to be MCAP by its first bytes (a text file is no recording)."""

    files = series_files(path)
    for file in files:
        with file.open("rb") as handle:
            if handle.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
                raise UsageError(f"{file} is not an MCAP recording (it does not start with the MCAP magic)")
    return files


def run_record(args: argparse.Namespace) -> int:
    try:
        paths = resolve_topics(args.topics)
    except ValueError as exc:
        raise UsageError(f"--topics: {exc}") from exc
    config = _deployment(args)
    limits = Limits(max_bytes=int(args.max_mb * 1e6) if args.max_mb else None, max_seconds=args.max_seconds)
    try:
        foxglove = FoxgloveViews.load(args.court or config.camera.sim.get("court", config.court),
                                      args.camera or config.camera.sim.get("camera"))
    except (ValueError, OSError) as exc:
        raise UsageError(f"--court/--camera: {exc}") from exc
    args.out.parent.mkdir(parents=True, exist_ok=True)
    series = McapSeries(args.out, limits, recording_metadata(config.robot_id, paths), foxglove)
    stop = stop_on_signals()
    recorder = Recorder(config.robot_id, config.zenoh, paths, series)
    ready = lambda: print(f"recording {len(paths)} topic(s) of {config.robot_id} to {args.out}", flush=True)  # noqa: E731

    def progress(stats) -> None:  # noqa: ANN001
        size = sum(f.stat().st_size for view in series.files for f in (view, exact_path(view)) if f.exists()) / 1e6
        print(f"recorded {stats.total} messages, {size:.1f} MB on disk, {len(series.files)} file(s), "
              f"{stats.overflow} dropped", flush=True)

    try:
        stats = recorder.run(stop, args.duration, on_ready=ready, max_messages=args.max_messages,
                             on_progress=progress)
    except OSError as exc:  # the disk: full, gone, not writable
        print(f"record: cannot write {args.out}: {exc}", file=sys.stderr)
        return 1
    print(json.dumps({"files": [str(f) for f in series.files], **stats.as_dict()}), flush=True)
    return 0


def run_replay(args: argparse.Namespace) -> int:
    files = _recording_files(args.input)
    try:
        summary = dumps_summary(files)  # reads every file's summary: a broken file is named before replay
        exact = recorded_channels(files)
    except (McapError, OSError, EOFError, ValueError) as exc:
        raise UsageError(f"{args.input}: not a readable MCAP recording ({type(exc).__name__}: {exc})") from exc
    if args.info:
        print(summary)
        return 0
    if not exact and not any(exact_path(f).exists() for f in files):
        raise UsageError(f"{files[0]} holds no exact payloads: keep {exact_path(files[0]).name} beside it")
    unknown = [p for p in args.only or [] if p not in TOPICS]
    if unknown:
        raise UsageError(f"--only: unknown topic(s) {unknown}; known: {sorted(TOPICS)}")
    config = _deployment(args)
    options = ReplayOptions(speed=args.speed, loop=args.loop, only=set(args.only) if args.only else None,
                            robot_id=args.robot, restamp=args.restamp, wait_subscribers_s=args.wait_subscribers)
    stop = stop_on_signals()
    print(f"replaying {', '.join(str(f) for f in files)}", flush=True)
    try:
        stats = Replayer(files, config.zenoh, options).run(stop)
    except (McapError, OSError) as exc:  # a file cut short mid-way (a recorder killed hard)
        print(f"replay: {exc}", file=sys.stderr)
        return 1
    print(json.dumps(stats.as_dict()), flush=True)
    return 0


def run_capture(args: argparse.Namespace) -> int:
    if (args.out / CSV_NAME).exists():  # said before waiting for a router (SeedWriter refuses it too)
        raise UsageError(f"{args.out / CSV_NAME} exists; choose an empty --out folder")
    config = client_deployment(args)
    options = CaptureOptions(out=args.out, tolerance_ms=args.tolerance_ms, offset_ms=args.offset_ms, n=args.n,
                             duration_s=args.duration, truth_path=args.truth_topic, truth_robot=args.truth_robot)
    stop = stop_on_signals()
    try:
        capture = Capture(config.robot_id, config.zenoh, options)
        wait_for_router(config.zenoh, args.timeout)
        ready = lambda: print(f"capturing {config.robot_id} frames + {options.truth_path} to {args.out}", flush=True)  # noqa: E731
        stats = capture.run(stop, on_ready=ready)
    except (ValueError, FileExistsError) as exc:
        print(exc, file=sys.stderr)
        return 2
    print(json.dumps({"out": str(args.out), **stats.as_dict()}), flush=True)
    return 0
