"""The process entry point (`courtloc.cli.run`): exit codes as `main` gives them, and no interpreter
finalization afterwards (zenoh threads may still release Python callbacks then: see run's docstring)."""
from __future__ import annotations

import subprocess
import sys

SCRIPT = ("import atexit, sys\n"
          "atexit.register(lambda: print('finalized', flush=True))\n"
          "from courtloc.cli import run\n"
          "sys.argv = ['courtloc', *{args!r}]\n"
          "run()\n")


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", SCRIPT.format(args=list(args))], capture_output=True, text=True,
                          timeout=120)


def test_exit_codes_and_output_survive_and_finalization_is_skipped() -> None:
    ok = _run("--help")
    assert ok.returncode == 0 and "COMMAND" in ok.stdout
    assert "finalized" not in ok.stdout  # atexit handlers run only when the interpreter finalizes
    usage = _run()
    assert usage.returncode == 2 and "usage: courtloc" in usage.stdout
    bad = _run("localizer", "residuals")  # a required option missing: argparse's own exit
    assert bad.returncode == 2 and "--data" in bad.stderr and "finalized" not in bad.stdout
