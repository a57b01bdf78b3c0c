"""`courtloc export`: turn our artefacts into other tools' formats (`export onnx`, `export rosbag2`).

Extending it: add a module to EXPORT_COMMAND_MODULES; the module exposes `register_export(export_subparsers)`
and adds its sub-command there with `set_defaults(func=handler)`, like a top-level command module.
"""
from __future__ import annotations

import argparse
from types import ModuleType

from courtloc.ros import cli as ros_cli
from courtloc.training import cli as training_cli

EXPORT_COMMAND_MODULES: tuple[ModuleType, ...] = (training_cli, ros_cli)


def register(sub: argparse._SubParsersAction) -> None:
    export = sub.add_parser("export", help="export to other tools' formats: onnx (paper network), rosbag2")
    export_sub = export.add_subparsers(dest="export_command", metavar="FORMAT")
    export.set_defaults(func=lambda args: (export.print_help(), 2)[1])
    for module in EXPORT_COMMAND_MODULES:
        module.register_export(export_sub)
