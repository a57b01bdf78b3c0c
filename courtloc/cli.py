"""The `courtloc` command: one entry point, each sub-command defined next to the code it drives."""
from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys
from typing import Sequence

# Each module here exposes `register(subparsers)`, adding its sub-command(s) with `set_defaults(func=...)`.
# Handlers import heavy libraries lazily so `courtloc --help` stays fast.
COMMAND_MODULES: tuple[str, ...] = (
    "courtloc.bench",
    "courtloc.sim.cli",
    "courtloc.services.shooter_bridge.cli",
    "courtloc.stage_cli",
    "courtloc.up_cli",
    "courtloc.model_cli",
    "courtloc.pose_cli",
    "courtloc.training.cli",
    "courtloc.localizer.eval_cli",
    "courtloc.localizer.cli",
    "courtloc.services.preprocess.cli",
    "courtloc.security.cli",
    "courtloc.recording.cli",
    "courtloc.monitor.cli",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="courtloc", description=__doc__)
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> None:
    parser = build_parser()
    args = parser.parse_args(argv)
    level = logging.WARNING - 10 * min(args.verbose, 2)
    logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    if not getattr(args, "func", None):
        parser.print_help()
        sys.exit(2)
    code = args.func(args)
    sys.exit(int(code or 0))


def run() -> None:
    """The process entry point (`courtloc`, `python -m courtloc`): `main`, then exit without finalizing the
    interpreter.

    When a command returns it has closed its zenoh session, but zenoh's own threads may still be releasing
    the Python callbacks they held, which needs the GIL. A thread that asks for the GIL while the interpreter
    finalizes is ended inside Rust frames, and glibc aborts the whole process ("FATAL: exception not
    rethrown", exit -6 instead of 0): seen on `courtloc monitor` stopping under load. So the exit code,
    streams and log handlers are settled here and the process ends directly. In-process callers (tests)
    use `main`, which raises SystemExit as usual.
    """
    try:
        main()
        code = 0
    except SystemExit as exc:
        if exc.code is None or isinstance(exc.code, int):
            code = int(exc.code or 0)
        else:  # what the interpreter does with SystemExit("message")
            print(exc.code, file=sys.stderr)
            code = 1
    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)
