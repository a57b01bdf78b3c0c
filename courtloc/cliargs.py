"""Argument types and options shared by every `courtloc` verb, so a mistake reads the same everywhere.

The `type=` functions raise argparse.ArgumentTypeError: argparse names the option, and courtloc.cli's
parser prints it as one line. `--json` has one meaning (see courtloc.cli.EPILOG): a file, `-` for stdout.
"""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

JSON_STDOUT = "-"


def _number(text: str, kind: type) -> float:
    try:
        value = kind(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a{'n integer' if kind is int else ' number'}: {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"not a finite number: {text!r}")
    return value


def positive_int(text: str) -> int:
    value = int(_number(text, int))
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {value}")
    return value


def nonnegative_int(text: str) -> int:
    value = int(_number(text, int))
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {value}")
    return value


def positive_float(text: str) -> float:
    value = _number(text, float)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {value:g}")
    return value


def nonnegative_float(text: str) -> float:
    value = _number(text, float)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {value:g}")
    return value


def port_number(text: str) -> int:
    """A TCP port to serve on: 0..65535 (0: any free port)."""
    value = int(_number(text, int))
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"must be a TCP port 0..65535, got {value}")
    return value


class _StdoutPath(type(Path())):  # type: ignore[misc]  # the concrete Path class of this platform
    """`--json -`: a path whose write_text goes to standard output (its parent is '.', which exists)."""

    def write_text(self, data: str, encoding: str | None = None, errors: str | None = None,
                   newline: str | None = None) -> int:
        sys.stdout.write(data if data.endswith("\n") else data + "\n")
        sys.stdout.flush()
        return len(data)

    def is_stdout(self) -> bool:
        return True


def json_output(text: str) -> Path:
    """The `--json` argument: a file path, or `-` for standard output (write to it with `.write_text`)."""
    return _StdoutPath(JSON_STDOUT) if text == JSON_STDOUT else Path(text)


def json_to_stdout(path: Path | None) -> bool:
    """Whether `--json -` asked for the JSON on standard output instead of the text report."""
    return isinstance(path, _StdoutPath)


def add_json_argument(parser: argparse.ArgumentParser, what: str = "the result", required: bool = False) -> None:
    parser.add_argument("--json", type=json_output, default=None, required=required, metavar="FILE",
                        help=f"write {what} as JSON to FILE ('-': to standard output, instead of the text)")
