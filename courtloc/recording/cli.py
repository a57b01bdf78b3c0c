"""`courtloc record`, `courtloc replay` and the `capture` sub-command of `courtloc dataset`."""
from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
from pathlib import Path

from courtloc.recording.busargs import add_client_arguments, client_deployment


def register(sub: argparse._SubParsersAction) -> None:
    record = sub.add_parser("record", help="record a robot's topics to MCAP (JSON view + exact msgpack)")
    record.add_argument("out", type=Path, help="OUT.mcap (OUT-000.mcap, OUT-001.mcap... with a limit)")
    record.add_argument("--topics", nargs="+", default=None, metavar="TOPIC",
                        help="topic paths such as infer/pose camera/frame, or 'all' "
                             "(default: every topic except raw camera frames)")
    record.add_argument("--max-mb", type=float, default=None, help="start a new file at this size")
    record.add_argument("--max-seconds", type=float, default=None, help="start a new file after this long")
    record.add_argument("--duration", type=float, default=None, help="stop after S seconds (default: Ctrl-C)")
    record.add_argument("--max-messages", type=int, default=None, metavar="N", help="stop after N messages")
    record.add_argument("--court", default=None, help="court drawn in Foxglove's 3D panel (default: the config's)")
    record.add_argument("--camera", default=None,
                        help="camera model placing the camera on the robot in TF (default: the config's)")
    add_client_arguments(record)
    record.set_defaults(func=run_record)

    replay = sub.add_parser("replay", help="publish a recording with its original timing")
    replay.add_argument("input", type=Path, help="IN.mcap (or the series IN-000.mcap, IN-001.mcap...)")
    replay.add_argument("--speed", type=float, default=1.0, help="time scale: 2 plays twice as fast")
    replay.add_argument("--loop", action="store_true", help="start again at the end, until Ctrl-C")
    replay.add_argument("--only", nargs="+", default=None, metavar="TOPIC", help="replay these topic paths only")
    replay.add_argument("--restamp", action="store_true",
                        help="move capture times to now so stages treat the frames as fresh (changes bytes)")
    replay.add_argument("--wait-subscribers", type=float, default=0.0, metavar="S",
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
    capture.add_argument("--tolerance-ms", type=float, default=20.0, help="largest frame-to-pose time gap")
    capture.add_argument("--offset-ms", type=float, default=0.0,
                         help="the pose source's lag: a frame at t matches the pose stamped t + offset")
    capture.add_argument("--n", type=int, default=None, help="stop after N pairs")
    capture.add_argument("--duration", type=float, default=None, help="stop after S seconds")
    capture.add_argument("--truth-topic", default="camera/ground_truth",
                         help="pose topic that holds the truth (default: the sim's ground truth)")
    capture.add_argument("--truth-robot", default=None, metavar="ID",
                         help="robot id the truth is published under (an external tracker), default --robot")
    add_client_arguments(capture)
    capture.set_defaults(func=run_capture)


def _stop_on_signals() -> threading.Event:
    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    return stop


def _deployment(args: argparse.Namespace):  # noqa: ANN202
    from courtloc.common.config_loader import ConfigError

    try:
        return client_deployment(args)
    except (ConfigError, ValueError) as exc:
        print(exc, file=sys.stderr)
        return None


def run_record(args: argparse.Namespace) -> int:
    from courtloc.recording.foxview import FoxgloveViews
    from courtloc.recording.mcapfile import Limits, McapSeries, exact_path
    from courtloc.recording.recorder import Recorder, recording_metadata, resolve_topics

    config = _deployment(args)
    if config is None:
        return 2
    try:
        paths = resolve_topics(args.topics)
    except ValueError as exc:
        print(f"--topics: {exc}", file=sys.stderr)
        return 2
    for name in ("max_mb", "max_seconds", "duration", "max_messages"):
        value = getattr(args, name)
        if value is not None and value <= 0:
            print(f"--{name.replace('_', '-')} must be > 0, got {value}", file=sys.stderr)
            return 2
    limits = Limits(max_bytes=int(args.max_mb * 1e6) if args.max_mb else None, max_seconds=args.max_seconds)
    try:
        foxglove = FoxgloveViews.load(args.court or config.camera.sim.court, args.camera or config.camera.sim.camera)
    except (ValueError, OSError) as exc:
        print(f"--court/--camera: {exc}", file=sys.stderr)
        return 2
    args.out.parent.mkdir(parents=True, exist_ok=True)
    series = McapSeries(args.out, limits, recording_metadata(config.robot_id, paths), foxglove)
    stop = _stop_on_signals()
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
    from courtloc.common.services_table import TOPICS
    from courtloc.recording.mcapfile import dumps_summary, exact_path, recorded_channels, series_files
    from courtloc.recording.replay import Replayer, ReplayOptions

    from mcap.exceptions import McapError

    try:
        files = series_files(args.input)
        summary = dumps_summary(files)  # reads every file's summary: a broken file is named before replay
        exact = recorded_channels(files)
    except (FileNotFoundError, McapError, OSError) as exc:
        print(f"replay: {exc}", file=sys.stderr)
        return 2
    if args.info:
        print(summary)
        return 0
    if not exact and not any(exact_path(f).exists() for f in files):
        print(f"replay: {files[0]} holds no exact payloads: keep {exact_path(files[0]).name} beside it",
              file=sys.stderr)
        return 2
    if args.speed <= 0:
        print(f"--speed must be > 0, got {args.speed}", file=sys.stderr)
        return 2
    unknown = [p for p in args.only or [] if p not in TOPICS]
    if unknown:
        print(f"--only: unknown topic(s) {unknown}; known: {sorted(TOPICS)}", file=sys.stderr)
        return 2
    config = _deployment(args)
    if config is None:
        return 2
    options = ReplayOptions(speed=args.speed, loop=args.loop, only=set(args.only) if args.only else None,
                            robot_id=args.robot, restamp=args.restamp, wait_subscribers_s=args.wait_subscribers)
    stop = _stop_on_signals()
    print(f"replaying {', '.join(str(f) for f in files)}", flush=True)
    try:
        stats = Replayer(files, config.zenoh, options).run(stop)
    except (McapError, OSError) as exc:  # a file cut short mid-way (a recorder killed hard)
        print(f"replay: {exc}", file=sys.stderr)
        return 1
    print(json.dumps(stats.as_dict()), flush=True)
    return 0


def run_capture(args: argparse.Namespace) -> int:
    from courtloc.recording.capture import Capture, CaptureOptions

    config = _deployment(args)
    if config is None:
        return 2
    options = CaptureOptions(out=args.out, tolerance_ms=args.tolerance_ms, offset_ms=args.offset_ms, n=args.n,
                             duration_s=args.duration, truth_path=args.truth_topic, truth_robot=args.truth_robot)
    stop = _stop_on_signals()
    try:
        capture = Capture(config.robot_id, config.zenoh, options)
        ready = lambda: print(f"capturing {config.robot_id} frames + {options.truth_path} to {args.out}", flush=True)  # noqa: E731
        stats = capture.run(stop, on_ready=ready)
    except (ValueError, FileExistsError) as exc:
        print(exc, file=sys.stderr)
        return 2
    print(json.dumps({"out": str(args.out), **stats.as_dict()}), flush=True)
    return 0
