"""`courtloc eval` (and `courtloc duplicates`): a model's pose errors on a labelled dataset (runtime stack only: onnxruntime, no torch)."""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from courtloc.cliargs import add_json_argument, json_to_stdout, positive_float, positive_int
from courtloc.lab.dataset_args import add_dataset_arguments
from courtloc.lab.datasets import Dataset, duplicate_report
from courtloc.lab.eval import evaluate, open_model, write_plots, write_predictions_csv


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
    parser.add_argument("--no-progress", action="store_true")
    parser.set_defaults(func=_eval)

    report = sub.add_parser("duplicates", help="recordings, frame counts and duplicate frames of a labelled dataset")
    add_dataset_arguments(report)
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


def _eval(args: argparse.Namespace) -> int:
    dataset = Dataset(args.data, csv_path=args.csv, kind=args.kind)
    indices = dataset.indices_of(args.recordings) if args.recordings else None
    model = open_model(args.model, threads=args.threads, tracking=not args.no_tracking)
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
