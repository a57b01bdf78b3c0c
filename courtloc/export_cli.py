"""`courtloc export`: turn our artefacts into other tools' formats (`export onnx`, `export rosbag2`).

Extending it: add a module name to EXPORT_COMMAND_MODULES; the module exposes
`register_export(export_subparsers)` and adds its sub-command there with `set_defaults(func=handler)`,
like a top-level command module (handler(args) -> exit code; heavy imports inside it).
"""
from __future__ import annotations

import argparse
import importlib

EXPORT_COMMAND_MODULES: tuple[str, ...] = ("courtloc.training.cli", "courtloc.ros.cli")


def register(sub: argparse._SubParsersAction) -> None:
    export = sub.add_parser("export", help="export to other tools' formats: onnx (paper network), rosbag2")
    export_sub = export.add_subparsers(dest="export_command", metavar="FORMAT")
    export.set_defaults(func=lambda args: (export.print_help(), 2)[1])
    for name in EXPORT_COMMAND_MODULES:
        importlib.import_module(name).register_export(export_sub)
