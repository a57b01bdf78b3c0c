"""`courtloc ARGS` run in this process through `courtloc.cli.exit_status`, the path the entry point takes up to
its exit: for command-line cases whose proof is the exit code and what is printed. Real processes remain where
the process itself is the point (test_cli_entry, the zenoh cases of test_cli_mistakes, whole runs)."""
from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Sequence

import pytest


@dataclass(frozen=True)
class Finished:
    """What a finished `courtloc` process would show (the fields of subprocess.CompletedProcess used here)."""

    returncode: int
    stdout: str
    stderr: str


def courtloc_in_process(argv: Sequence[str], capsys: pytest.CaptureFixture[str],
                        caplog: pytest.LogCaptureFixture) -> Finished:
    """A log record at WARNING or above would be a line on the process's stderr (main's logging.basicConfig),
    so it is one here too; an exception out of main would end the process with its traceback."""
    from courtloc.cli import exit_status

    capsys.readouterr()
    caplog.clear()
    try:
        code = exit_status(list(argv))
    except Exception as exc:  # noqa: BLE001 - a bug: the process would end with its traceback
        code, out, err = 1, capsys.readouterr().out, f"Traceback (in process): {type(exc).__name__}: {exc}\n"
    else:
        out, err = capsys.readouterr()
    logged = "".join(f"{record.levelname} {record.name}: {record.getMessage()}\n"
                     for record in caplog.records if record.levelno >= logging.WARNING)
    return Finished(code, out, logged + err)
