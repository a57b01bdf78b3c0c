"""`courtloc bench KIND`: every benchmark of the project behind one command.

Each entry names a module exposing `add_arguments(parser)` and `run(args) -> int`.
"""
from __future__ import annotations

import argparse
import importlib

BENCHES: dict[str, str] = {
    "pipeline": "courtloc.bench_pipeline",
    "preprocess": "courtloc.services.preprocess.bench",
    "render": "courtloc.sim.bench_render",
    "paper": "courtloc.localizer.model_bench",
    "localize": "courtloc.localizer.bench",
    "soak": "courtloc.bench_soak",
    "infer": "courtloc.services.infer.bench",
    "twin": "courtloc.bench_twin",
}


def register(sub: argparse._SubParsersAction) -> None:
    bench = sub.add_parser("bench", help="measure speed and memory (never asserted in tests)")
    kinds = bench.add_subparsers(dest="bench_kind", metavar="KIND")
    for kind, module_name in BENCHES.items():
        module = importlib.import_module(module_name)
        parser = kinds.add_parser(kind, help=(module.__doc__ or "").strip().splitlines()[0])
        module.add_arguments(parser)
        parser.set_defaults(func=module.run)
