"""`python -m courtloc.router_main [--listen EP] [--config FILE]`: `courtloc router` (the same `run_router`)
without loading the rest of the CLI, whose sub-commands import most of the product (measured: importing
courtloc.cli takes 1.30 s, courtloc.stage_cli 0.91 s). The launcher starts (and restarts) its router this way
(stage_cli.router_argv), and so do the tests."""
from __future__ import annotations

import argparse
import logging
import os
import sys
from typing import Sequence

from courtloc.cli_errors import USAGE_EXIT, UsageError
from courtloc.stage_cli import add_router_arguments, run_router

PROG = "courtloc router"


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog=PROG, description=__doc__)
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")
    add_router_arguments(parser)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING - 10 * min(args.verbose, 2),
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        return run_router(args)
    except UsageError as exc:
        print(f"{PROG}: {exc}", file=sys.stderr)
        return exc.exit_code
    except (ValueError, OSError) as exc:  # a bad deployment or credential file: the message names it
        print(f"{PROG}: {exc}", file=sys.stderr)
        return USAGE_EXIT


if __name__ == "__main__":
    try:
        code = main()
    except SystemExit as exc:  # argparse's own exit
        code = exc.code if isinstance(exc.code, int) else 0 if exc.code is None else 1
    # As courtloc.cli.run: end without interpreter finalization, which zenoh's threads can abort.
    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)
