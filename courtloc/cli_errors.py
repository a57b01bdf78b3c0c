"""The one kind of mistake every `courtloc` verb raises (courtloc.cli prints it as one line), and its exit codes.

Apart from courtloc.cli so that the verbs' modules, which the CLI imports, can raise it without a circle.
"""
from __future__ import annotations

USAGE_EXIT = 2  # a mistake in what was asked (argparse's own code for a bad command line)
RUN_EXIT = 1  # what was asked could not be done (no router, a write that failed)


class UsageError(Exception):
    """A mistake of the user's, said in one line: the handler prints it and exits with `exit_code`.

    Raise it from a command (or an argparse `type=` function raises argparse.ArgumentTypeError) instead
    of printing and returning a code: the top-level handler formats every known mistake the same way.
    """

    def __init__(self, message: str, exit_code: int = USAGE_EXIT) -> None:
        super().__init__(message)
        self.exit_code = exit_code
