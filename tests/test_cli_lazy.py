"""The command table: every command reaches its module, and a command imports only its own module."""
from __future__ import annotations

import argparse
import subprocess
import sys

from courtloc.cli import COMMAND_MODULES, build_parser


def _commands(parser: argparse.ArgumentParser) -> set[str]:
    return {name for action in parser._actions if isinstance(action, argparse._SubParsersAction)
            for name in action.choices}


def test_the_table_names_every_command_and_each_one_is_registered_by_its_module() -> None:
    assert _commands(build_parser()) == set(COMMAND_MODULES)
    for name in COMMAND_MODULES:
        assert name in _commands(build_parser([name])), name
        assert name in _commands(build_parser(["-v", name])), name
        assert _commands(build_parser(["-vvv", name])) == _commands(build_parser([name])), name  # not all of them


def test_a_command_imports_its_own_module_only() -> None:
    probe = ("import sys; from courtloc.cli import build_parser; build_parser(['pose', 'set', '1', '2', '0']); "
             "print(sorted(m for m in ('courtloc.bench', 'courtloc.sim.cli', 'courtloc.up_cli', 'scipy') "
             "if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=60, check=True)
    assert out.stdout.strip() == "[]"


def test_help_and_an_unknown_command_still_list_every_command() -> None:
    result = subprocess.run([sys.executable, "-m", "courtloc", "nonsense"], capture_output=True, text=True,
                            timeout=60)
    assert result.returncode == 2
    assert "invalid choice" in result.stderr and "'doctor'" in result.stderr and "'bench'" in result.stderr
