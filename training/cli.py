"""`courtloc train`, `courtloc export onnx`, `courtloc explain`: the training-side commands (need the `train` extra)."""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from courtloc.cli_errors import UsageError
from courtloc.cliargs import nonnegative_int, positive_float, positive_int
from courtloc.lab.dataset_args import add_dataset_arguments


def register_export(export_sub: argparse._SubParsersAction) -> None:
    """The hook of `courtloc export` (courtloc/export_cli.py EXPORT_COMMAND_MODULES): `export onnx`."""
    export = export_sub.add_parser("onnx", help="export a trained paper network to dense + sparse ONNX with manifests")
    export.add_argument("weights", type=Path, help="OUT/model.pt written by `courtloc train`")
    export.add_argument("--out", type=Path, required=True, help="folder for NAME-dense.onnx / NAME-sparse.onnx")
    export.add_argument("--graphs", nargs="+", choices=("dense", "sparse"), default=["dense", "sparse"])
    export.add_argument("--name", default="paper-mlp")
    export.add_argument("--version", type=positive_int, default=1)
    export.add_argument("--court", default="seed-gazebo")
    export.add_argument("--camera", default="seed-gazebo")
    export.add_argument("--golden-error-m", type=positive_float, default=None,
                        help="accuracy the manifests state on the golden inputs (default: the exported graph's "
                             "worst golden error plus a quarter, rounded up to 5 cm)")
    export.set_defaults(func=_export)


def register(sub: argparse._SubParsersAction) -> None:
    train = sub.add_parser("train", help="train the paper network on a seed-format dataset (needs torch)")
    add_dataset_arguments(train)
    train.add_argument("--out", type=Path, required=True, help="run folder: checkpoints, loss curve, model.pt")
    train.add_argument("--train-recordings", nargs="+", default=None, metavar="REC")
    train.add_argument("--val-recordings", nargs="*", default=None, metavar="REC",
                       help="held-out recordings (default: the last one); give none to train without validation")
    train.add_argument("--arch", choices=("paper", "mobilenet_v2", "efficientnet_b0"), default="paper",
                       help="the paper's MLP, or a CNN baseline (needs torchvision)")
    train.add_argument("--crop-top", type=nonnegative_int, default=200)
    train.add_argument("--epochs", type=positive_int, default=15)
    train.add_argument("--batch-size", type=positive_int, default=8)
    train.add_argument("--lr", type=positive_float, default=1e-4)
    train.add_argument("--seed", type=int, default=0)
    train.add_argument("--resume", action="store_true", help="continue from OUT/last.pt")
    train.add_argument("--frame-step", type=positive_int, default=1, metavar="K",
                       help="train on every K-th frame of the training recordings (budget option; default all)")
    train.add_argument("--val-frame-step", type=positive_int, default=1, metavar="K",
                       help="per-epoch validation on every K-th held-out frame (budget option; default all)")
    train.add_argument("--downscale", type=positive_int, default=1, metavar="K",
                       help="CNN baselines only: K x K max-pool inside the network (input stays full size)")
    train.add_argument("--no-progress", action="store_true")
    train.set_defaults(func=_train)

    explain = sub.add_parser("explain", help="Integrated Gradients saliency PNGs of the paper network")
    explain.add_argument("--model", type=Path, required=True, help="OUT/model.pt written by `courtloc train`")
    explain.add_argument("images", type=Path, nargs="+", help="edge-dot images")
    explain.add_argument("--out", type=Path, required=True)
    explain.add_argument("--steps", type=positive_int, default=32, help="Riemann steps along the straight path")
    explain.set_defaults(func=_explain)


def _train(args: argparse.Namespace) -> int:
    if args.arch == "paper" and args.downscale != 1:
        raise UsageError("--downscale is for the CNN baselines only")
    _require_file(args.data, "dataset folder", folder=True)
    from courtloc.training.trainer import TrainConfig, train  # needs torch: the train extra

    cfg = TrainConfig(data=args.data, csv=args.csv, kind=args.kind, out=args.out,
                      train_recordings=args.train_recordings, val_recordings=args.val_recordings,
                      crop_top=args.crop_top, epochs=args.epochs, batch_size=args.batch_size, lr=args.lr,
                      seed=args.seed, resume=args.resume, progress=not args.no_progress,
                      frame_step=args.frame_step, val_frame_step=args.val_frame_step, downscale=args.downscale)
    if args.arch != "paper":
        from courtloc.training.baselines import BaselineUnavailable, train_baseline  # needs torch: the train extra

        try:
            summary = train_baseline(cfg, args.arch)
        except BaselineUnavailable as exc:
            raise UsageError(str(exc)) from None
    else:
        summary = train(cfg)
    print(json.dumps(summary["metrics"], indent=1))
    return 0


def _export(args: argparse.Namespace) -> int:
    _require_file(args.weights, "weights")
    from courtloc.training.export import export_paper  # needs torch: the train extra

    written = export_paper(args.weights, args.out, args.graphs, args.name, args.version, args.court, args.camera,
                           args.golden_error_m)
    for kind, path in written.items():
        print(f"{kind}: {path}")
    return 0


def _explain(args: argparse.Namespace) -> int:
    for path in (args.model, *args.images):
        _require_file(path, "file")
    from courtloc.training.explain import explain_images  # needs torch: the train extra

    for path in explain_images(args.model, args.images, args.out, args.steps):
        print(path)
    return 0


def _require_file(path: Path, what: str, folder: bool = False) -> None:
    """Said before torch is imported (seconds) and a run folder is made: a wrong path is one line."""
    if not (path.is_dir() if folder else path.is_file()):
        raise UsageError(f"{what} {path} {'is not a folder' if path.exists() else 'does not exist'}")
