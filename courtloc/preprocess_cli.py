"""`courtloc preprocess IMAGE [--json]`: the radial-scan hits of one image, for users and for checks."""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from courtloc.common.config_loader import ConfigError, load_model
from courtloc.common.payloads import FrameError
from courtloc.scan.config import PreprocessConfig
from courtloc.scan.preprocessor import Preprocessor, read_image_file


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("preprocess", help="print the radial-scan hits (row, col, ray, d) of one image")
    parser.add_argument("image", help="an image file OpenCV can read (JPEG, PNG, ...), any size")
    parser.add_argument("--json", action="store_true",
                        help='print exactly {"width": W, "height": H, "hits": [[row, col, ray, d], ...]}')
    parser.add_argument("--config", type=Path, default=None,
                        help="a TOML/JSON file with PreprocessConfig fields (default: built-in defaults)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    try:
        config = load_model(args.config, PreprocessConfig)
    except ConfigError as exc:
        print(exc, file=sys.stderr)
        return 2
    # One image from disk may have any size; the expected-size check is for the camera stream.
    config = config.model_copy(update={"frame_width": None, "frame_height": None})
    try:
        bgr = read_image_file(args.image)
        hits = Preprocessor(config).process(bgr)
    except FrameError as exc:
        print(f"courtloc preprocess: {exc}", file=sys.stderr)
        return 1
    height, width = bgr.shape[:2]
    if args.json:
        print(json.dumps({"width": width, "height": height, "hits": hits.tolist()}))
        return 0
    lines = [f"{args.image}: {width}x{height}, {len(hits)} hits", "row col ray d"]
    lines += [f"{row} {col} {ray} {d}" for row, col, ray, d in hits.tolist()]
    print("\n".join(lines))
    return 0
