"""CLI of the digital twin: `courtloc calibrate` (+ `intrinsics`, `mount`) and the `courtloc dataset` group.

Extending `courtloc dataset`: add the module to DATASET_COMMAND_MODULES; the module exposes
`register_dataset(dataset_subparsers)` and adds its sub-command there with `set_defaults(func=handler)`,
exactly like a top-level command module (handler(args) -> exit code; import heavy libraries inside it).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from types import ModuleType

import numpy as np

from courtloc.cli_errors import UsageError
from courtloc.cliargs import nonnegative_int, positive_int
from courtloc.lab.calibrate import (
    SEED_LAG_S,
    CalibrationOptions,
    calibrate,
    dot_reproduction,
    load_dot_frames,
    nominal_camera,
)
from courtloc.lab.calibrate_cli import register_calibrate_verbs
from courtloc.recording import cli as recording_cli
from courtloc.sim.labels import lag_corrected, read_pose_csv
from courtloc.sim.render import RenderOptions
from courtloc.sim.synth import SynthConfig, synth
from courtloc.world.camera import load_camera
from courtloc.world.court import load_court

# Modules adding sub-commands to `courtloc dataset` (this module adds `synth` itself).
DATASET_COMMAND_MODULES: tuple[ModuleType, ...] = (recording_cli,)


def register(sub: argparse._SubParsersAction) -> None:
    _register_calibrate(sub)
    dataset = sub.add_parser("dataset", help="make and collect datasets (seed format: images + pose_data.csv)")
    dataset_sub = dataset.add_subparsers(dest="dataset_command", metavar="SUBCOMMAND")
    dataset.set_defaults(func=lambda args: (dataset.print_help(), 2)[1])
    _register_synth(dataset_sub)
    for module in DATASET_COMMAND_MODULES:
        module.register_dataset(dataset_sub)


# ---- dataset synth -----------------------------------------------------------------------------------
def _register_synth(dataset_sub: argparse._SubParsersAction) -> None:
    p = dataset_sub.add_parser("synth", help="render a labelled synthetic dataset from the digital twin")
    p.add_argument("--court", required=True, help="court name (see world/courts) or JSON path")
    p.add_argument("--camera", default=None, help="camera name or JSON path (default: the court's camera)")
    p.add_argument("--n", type=positive_int, required=True, help="number of frames")
    p.add_argument("--out", required=True, help="output directory (resumable: existing frames are kept)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--kind", choices=("raw", "edges"), default="raw",
                   help="raw camera frames (randomised) or seed-style edge-dot images")
    p.add_argument("--render-options", default=None, help="JSON file of RenderOptions (default per kind)")
    p.set_defaults(func=_synth)


def _synth(args: argparse.Namespace) -> int:
    # A bad file, field or name raises (ValidationError, OSError, ValueError): one line from courtloc.cli.
    render = None
    if args.render_options:
        render = RenderOptions.model_validate(json.loads(open(args.render_options).read()))
    config = SynthConfig(court=args.court, camera=args.camera, n=args.n, out=args.out, seed=args.seed,
                         kind=args.kind, render=render)
    start = time.monotonic()

    def progress(done: int, total: int, written: int) -> None:
        if done == total or done % 25 == 0:
            rate = written / max(time.monotonic() - start, 1e-6)
            bar = "#" * int(30 * done / total)
            print(f"\r[{bar:<30}] {done}/{total} ({written} rendered, {rate:.0f}/s)", end="", file=sys.stderr, flush=True)

    summary = synth(config, progress)
    print(file=sys.stderr)
    print(json.dumps(summary))
    return 0


# ---- calibrate ---------------------------------------------------------------------------------------
def _register_calibrate(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("calibrate", help="fit the camera: to labelled edge-dot images (seed format, the options "
                                         "below), or `calibrate intrinsics` / `calibrate mount` for a new robot")
    p.add_argument("--data", help="directory of the images named in the CSV")
    p.add_argument("--csv", help="pose CSV: image_filename, x, y, orientation_z")
    p.add_argument("--court", help="court name or JSON path")
    p.add_argument("--init", default=None, help="starting camera (name or JSON); default: a rough nominal guess")
    p.add_argument("--frames", type=positive_int, default=300, help="frames used, spread evenly over the CSV")
    p.add_argument("--lag", type=float, default=None, help="image->label lag in seconds (default: the seed's 0.0147)")
    p.add_argument("--fit-scale", action="store_true", help="also fit a court scale factor")
    p.add_argument("--fit-line-width", action="store_true",
                   help="also fit one change of every white element's width (edges move along their normals)")
    p.add_argument("--check-frames", type=nonnegative_int, default=0,
                   help="render this many labelled frames with the fit and compare their hits with the dots")
    p.add_argument("--out", default=None, help="write the fitted camera JSON here")
    p.set_defaults(func=_calibrate)

    register_calibrate_verbs(p.add_subparsers(dest="calibrate_command", metavar="{intrinsics,mount}"))


def _calibrate(args: argparse.Namespace) -> int:
    missing = [f"--{name}" for name in ("data", "csv", "court") if not getattr(args, name)]
    if missing:
        raise UsageError(f"calibrate needs {', '.join(missing)} (or a sub-command: intrinsics, mount)")
    lag = SEED_LAG_S if args.lag is None else args.lag
    # A bad file or name raises (ValueError, OSError): one line from courtloc.cli.
    court = load_court(args.court)
    options = CalibrationOptions(frames=args.frames, lag_s=lag, fit_scale=args.fit_scale,
                                 fit_line_width=args.fit_line_width)
    labels = read_pose_csv(args.csv)
    dots = load_dot_frames(args.data, args.csv, options.frames, lag, options.min_dots, labels=labels)
    initial = load_camera(args.init) if args.init else nominal_camera(dots.width, dots.height)
    result = calibrate(court, dots, initial, options)
    print(result.report())
    if args.check_frames:
        lagged = lag_corrected(labels, lag)
        picks = np.unique(np.linspace(0, len(lagged) - 1, args.check_frames).round().astype(int))
        dist = dot_reproduction(court, result.camera, args.data, lagged, picks)
        print(f"twin check on {len(picks)} frames, {len(dist)} seed dots: distance to nearest twin hit "
              f"median {np.median(dist):.2f} px, within 1 px {100 * np.mean(dist <= 1):.1f}%, "
              f"within 2 px {100 * np.mean(dist <= 2):.1f}%")
    if args.out:
        camera = result.camera.model_copy(update={
            "name": court.name,
            "provenance": f"courtloc calibrate on {len(dots.filenames)} frames, {result.dots} dots: residual median "
                          f"{result.residual_px_median:.2f} px, p95 {result.residual_px_p95:.2f} px; lag {lag} s",
        })
        with open(args.out, "w") as handle:
            handle.write(json.dumps(camera.model_dump(), indent=1) + "\n")
        print(f"camera written to {args.out}")
    return 0
