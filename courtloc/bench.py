"""`courtloc bench KIND`: every benchmark of the project behind one command.

Each entry is a module exposing `add_arguments(parser)` and `run(args) -> int`.
"""
from __future__ import annotations

import argparse
from types import ModuleType

from courtloc import bench_fuzz, bench_pipeline, bench_soak, bench_sweep, bench_twin
from courtloc.lab import bench_infer, bench_localize, bench_preprocess, model_bench
from courtloc.sim import bench_render, fusion_bench

BENCHES: dict[str, ModuleType] = {
    "pipeline": bench_pipeline,
    "preprocess": bench_preprocess,
    "render": bench_render,
    "paper": model_bench,
    "localize": bench_localize,
    "soak": bench_soak,
    "fuzz": bench_fuzz,
    "infer": bench_infer,
    "fusion": fusion_bench,
    "twin": bench_twin,
    "sweep": bench_sweep,
}


def register(sub: argparse._SubParsersAction) -> None:
    bench = sub.add_parser("bench", help="measure speed and memory (never asserted in tests)")
    kinds = bench.add_subparsers(dest="bench_kind", metavar="KIND")
    for kind, module in BENCHES.items():
        parser = kinds.add_parser(kind, help=(module.__doc__ or "").strip().splitlines()[0])
        module.add_arguments(parser)
        parser.set_defaults(func=module.run)
