"""`courtloc eval` (and `courtloc duplicates`): a model's pose errors on a labelled dataset (runtime stack only: onnxruntime, no torch)."""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from courtloc.cli_errors import UsageError
from courtloc.cliargs import add_json_argument, json_to_stdout, positive_float, positive_int
from courtloc.lab.dataset_args import add_dataset_arguments
from courtloc.lab.datasets import Dataset, duplicate_report
from courtloc.lab.eval import StartHint, evaluate, open_model, write_plots, write_predictions_csv


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("eval", help="evaluate a localization model on a labelled dataset")
    add_dataset_arguments(parser)
    parser.add_argument("--model", type=Path, default=None,
                        help="a paper-network .onnx or a model folder (default: the bundled models/default)")
    parser.add_argument("--recordings", nargs="+", default=None, metavar="REC",
                        help="evaluate only these recordings")
    add_json_argument(parser, "the metrics")
    parser.add_argument("--plots", type=Path, default=None,
                        help="folder for plots (needs matplotlib) and per-frame predictions.csv")
    parser.add_argument("--threads", type=positive_int, default=1, help="onnxruntime intra-op threads")
    parser.add_argument("--no-tracking", action="store_true",
                        help="localise every frame on its own (default: consecutive frames of a recording "
                             "get the previous prediction as prior, as on the robot)")
    parser.add_argument("--start-side", default=None, metavar="{+x,-x}",
                        help="the robot starts in this half (given to the localizer as the infer stage would); "
                             "write --start-side=-x")
    parser.add_argument("--start-pose", default=None, metavar="X,Y,YAW",
                        help="the robot's start pose, metres and radians, at the first frame of each recording "
                             "(--start-pose=-3,1,0 when X is negative)")
    parser.add_argument("--data-court", default=None, metavar="NAME",
                        help="the court the data shows, when the data does not say (a synth folder does)")
    parser.add_argument("--no-progress", action="store_true")
    # No --kind given: what a `dataset synth` folder says it holds, else dots.
    parser.set_defaults(func=_eval, kind=None)

    report = sub.add_parser("duplicates", help="recordings, frame counts and duplicate frames of a labelled dataset")
    add_dataset_arguments(report)
    report.set_defaults(kind=None)
    report.add_argument("--jaccard", type=positive_float, default=0.1,
                        help="near-identical: Jaccard distance of the dot-pixel sets below this")
    report.set_defaults(func=_dataset)


def _dataset(args: argparse.Namespace) -> int:
    dataset = Dataset(args.data, csv_path=args.csv, kind=args.kind)
    result = duplicate_report(dataset, args.jaccard)
    print(json.dumps({"frames": len(dataset), "recordings": {r: int((dataset.recordings == r).sum())
                                                             for r in dataset.recording_ids()},
                      "duplicates": result.model_dump()}, indent=1))
    return 0


def parse_start(side: str | None, pose: str | None) -> StartHint | None:
    if side is None and pose is None:
        return None
    if side is not None and side not in ("+x", "-x"):
        raise UsageError(f"--start-side must be +x or -x, got {side!r}")
    parsed = None
    if pose is not None:
        try:
            parsed = tuple(float(v) for v in pose.split(","))
        except ValueError:
            parsed = ()
        if len(parsed) != 3 or not all(map(math.isfinite, parsed)):
            raise UsageError(f"--start-pose must be X,Y,YAW (metres, metres, radians), got {pose!r}")
    return StartHint(side=side, pose=parsed)


def _eval(args: argparse.Namespace) -> int:
    start = parse_start(args.start_side, args.start_pose)
    dataset = Dataset(args.data, csv_path=args.csv, kind=args.kind)
    indices = dataset.indices_of(args.recordings) if args.recordings else None
    model = open_model(args.model, threads=args.threads, tracking=not args.no_tracking, start=start)
    data_court = args.data_court or dataset.court
    if data_court is not None and data_court != model.manifest.court:
        print(f"courtloc eval: warning: the data shows court {data_court!r}, the model is built for "
              f"{model.manifest.court!r}", file=sys.stderr)
    result = evaluate(model, dataset, indices, progress=not args.no_progress)
    metrics = result.metrics.as_dict()
    text = json.dumps(metrics, indent=1)
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(text + "\n")
    if not json_to_stdout(args.json):
        print(text)
    if args.plots:
        args.plots.mkdir(parents=True, exist_ok=True)
        write_predictions_csv(result, args.plots / "predictions.csv")
        for path in write_plots(result, args.plots, title=model.manifest.name):
            print(f"plot: {path}")
    return 0
