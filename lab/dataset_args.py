"""The command-line options every dataset-reading command shares (argparse only: the CLI stays fast)."""
from __future__ import annotations

import argparse
from pathlib import Path


def add_dataset_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--data", type=Path, required=True, help="dataset folder (images/ + pose_data.csv)")
    parser.add_argument("--csv", type=Path, default=None, help="label CSV (default DATA/pose_data.csv)")
    parser.add_argument("--kind", choices=("dots", "raw"), default="dots",
                        help="images are edge-dot images (seed) or raw camera frames")
