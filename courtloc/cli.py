"""The `courtloc` command: one entry point, each sub-command defined next to the code it drives."""
from __future__ import annotations

import argparse
import logging
import os
import struct
import sys
import traceback
from importlib import import_module
from typing import NoReturn, Sequence

from pydantic import ValidationError

from courtloc.cli_errors import RUN_EXIT, USAGE_EXIT, UsageError
from courtloc.common.signals import terminate_as_interrupt

# Command -> the module that registers it: each exposes `register(subparsers)`, adding its sub-command(s)
# with `set_defaults(func=...)`. Only the module of the command given is imported: importing all of them
# costs ~2.5 s (scipy, cv2, every stage's config) before `courtloc pose set` can answer, ~0.6-1 s for one.
COMMAND_MODULES: dict[str, str] = {
    "bench": "courtloc.bench",
    "calibrate": "courtloc.sim.cli", "dataset": "courtloc.sim.cli",
    "shooter": "courtloc.shooter_cli",
    "run": "courtloc.stage_cli", "router": "courtloc.stage_cli",
    "up": "courtloc.up_cli",
    "model": "courtloc.model_cli",
    "pose": "courtloc.pose_cli",
    "train": "courtloc.training.cli", "explain": "courtloc.training.cli",
    "eval": "courtloc.lab.eval_cli", "duplicates": "courtloc.lab.eval_cli",
    "localizer": "courtloc.lab.localizer_cli",
    "preprocess": "courtloc.preprocess_cli",
    "secure": "courtloc.security.cli",
    "record": "courtloc.recording.cli", "replay": "courtloc.recording.cli",
    "monitor": "courtloc.monitor.cli",
    "export": "courtloc.export_cli",
    "ros": "courtloc.ros.cli",
    "foxglove": "courtloc.foxglove.cli",
    "doctor": "courtloc.doctor",
}

EPILOG = """\
conventions of every command:
  --json FILE   write the command's JSON result to FILE; `--json -` writes it to standard output
                instead of the text report
  --timeout S   commands that join a robot's bus (run, record, replay, monitor, model, pose, dataset
                capture, calibrate mount --live, ros bridge, foxglove) wait for its router up to S
                seconds, naming the endpoint, then give up with one line
  a mistake (a missing file, a bad number, an unknown name, no router) is one line on standard error and
  a non-zero exit (2: the command line or an input file, 1: the run failed); -v adds the traceback
"""

class OneLineParser(argparse.ArgumentParser):
    """argparse's errors as one line (the usage is one `--help` away); sub-parsers inherit the class."""

    def error(self, message: str) -> NoReturn:
        if "expected one argument" in message:  # argparse reads a negative number as an option
            message += " (a value starting with '-' goes after '=', e.g. --start-side=-x)"
        self.exit(USAGE_EXIT, f"{self.prog}: {message} (see {self.prog} --help)\n")


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The parser for `argv` (None: every command): with a known command in it, only that command's module
    is imported and registered; otherwise (help, a typo) all of them, so help and errors list every command."""
    parser = OneLineParser(prog="courtloc", description=__doc__, epilog=EPILOG,
                           formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("-v", "--verbose", action="count", default=0,
                        help="more log output (-vv for debug); a mistake's traceback")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    named = _command_of(argv)
    modules = [COMMAND_MODULES[named]] if named in COMMAND_MODULES else list(dict.fromkeys(COMMAND_MODULES.values()))
    for module in modules:
        import_module(module).register(sub)
    _name_commands(parser)
    return parser


def _command_of(argv: Sequence[str] | None) -> str | None:
    """The command word of a command line: its first word that is not the top-level -v option."""
    for word in argv or ():
        if word == "--verbose" or (len(word) > 1 and word[0] == "-" and set(word[1:]) == {"v"}):  # -v, -vv, ...
            continue
        return None if word.startswith("-") else word
    return None


def _name_commands(parser: argparse.ArgumentParser) -> None:
    """Every (sub-)parser leaves its full name (`courtloc secure sign`) in args.prog_name for messages."""
    parser.set_defaults(prog_name=parser.prog)
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for child in action.choices.values():
                _name_commands(child)


def user_error(exc: BaseException) -> tuple[str, int] | None:
    """(one line, exit code) for the exception kinds a user's input causes; None for anything else (a bug:
    its traceback is the useful report)."""
    if isinstance(exc, UsageError):
        return str(exc), exc.exit_code
    if isinstance(exc, ValidationError):
        return "; ".join(_validation_line(e) for e in exc.errors(include_url=False)), USAGE_EXIT
    if isinstance(exc, OSError) and exc.filename is not None:  # missing, unreadable, a folder for a file...
        return f"{exc.filename}: {exc.strerror or exc}", USAGE_EXIT
    if isinstance(exc, (FileNotFoundError, FileExistsError, IsADirectoryError, NotADirectoryError,
                        PermissionError)):  # raised by our own code with the path in the message
        return str(exc), USAGE_EXIT
    if isinstance(exc, OSError):
        return str(exc), RUN_EXIT
    if isinstance(exc, (struct.error, EOFError, UnicodeDecodeError)):  # a file that is not what it claims
        return f"not a readable file of the expected kind ({type(exc).__name__}: {exc})", USAGE_EXIT
    kind = f"{type(exc).__module__}.{type(exc).__qualname__}"
    if kind.startswith("mcap.") or kind == "zenoh.ZError" or type(exc).__name__ == "ZError":
        return str(exc).split(" at ")[0], RUN_EXIT  # zenoh appends its source location
    if kind.startswith(("google.protobuf.", "onnx.", "onnxruntime.")):  # a file that is not a usable ONNX model
        return f"not a usable ONNX model ({type(exc).__name__}: {exc})", USAGE_EXIT
    if isinstance(exc, ValueError):  # ConfigError, an unknown court or camera name, a bad value
        return str(exc), USAGE_EXIT
    if isinstance(exc, ImportError) and exc.name:  # an optional extra that is not installed
        return f"{exc.name} is not installed ({exc}): see README, Development", USAGE_EXIT
    return None


def _validation_line(error: dict) -> str:
    where = ".".join(str(p) for p in error.get("loc", ())) or "value"
    given = error.get("input")
    shown = "" if isinstance(given, dict) or given is None else f", got {_clip(repr(given))}"
    return f"{where}: {_clip(str(error.get('msg', 'invalid')))}{shown}"


def _clip(text: str, limit: int = 80) -> str:
    """A value quoted in a one-line message: a whole file pasted into it helps nobody."""
    return text if len(text) <= limit else text[:limit] + "..."


def _one_line(text: str) -> str:
    return " | ".join(line.strip() for line in text.strip().splitlines() if line.strip()) or "failed"


def main(argv: Sequence[str] | None = None) -> None:
    words = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(words)
    args = parser.parse_args(words)
    level = logging.WARNING - 10 * min(args.verbose, 2)
    logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    if not getattr(args, "func", None):
        parser.print_help()
        sys.exit(USAGE_EXIT)
    terminate_as_interrupt()
    try:
        code = args.func(args)
    except KeyboardInterrupt:
        sys.exit(130)
    except Exception as exc:  # noqa: BLE001 - sorted below: a user's mistake is one line, a bug re-raised
        said = user_error(exc)
        if said is None:
            raise
        if args.verbose:
            traceback.print_exc()
        line, exit_code = said
        print(f"{args.prog_name}: {_one_line(line)}", file=sys.stderr)
        sys.exit(exit_code)
    sys.exit(int(code or 0))


def run() -> None:
    """The process entry point (`courtloc`, `python -m courtloc`): `main`, then exit without finalizing the
    interpreter.

    When a command returns it has closed its zenoh session, but zenoh's own threads may still be releasing
    the Python callbacks they held, which needs the GIL. A thread that asks for the GIL while the interpreter
    finalizes is ended inside Rust frames, and glibc aborts the whole process ("FATAL: exception not
    rethrown", exit -6 instead of 0): seen on `courtloc monitor` stopping under load. So the exit code,
    streams and log handlers are settled here and the process ends directly. In-process callers (tests)
    use `main`, which raises SystemExit as usual, or `exit_status`, the path this takes up to the exit.
    """
    code = exit_status()
    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


def exit_status(argv: Sequence[str] | None = None) -> int:
    """`main`'s SystemExit as the process's exit code (what `run` ends the process with); a bug's exception
    propagates, as it would out of `run`."""
    try:
        main(argv)
    except SystemExit as exc:
        if exc.code is None or isinstance(exc.code, int):
            return int(exc.code or 0)
        print(exc.code, file=sys.stderr)  # what the interpreter does with SystemExit("message")
        return 1
    return 0
