"""The router runs as a process of its own that loads zenoh and the access rules, not the CLI's libraries:
the robot's memory budget counts every library a process maps."""
from __future__ import annotations

import subprocess
import sys

import pytest

HEAVY = ("numpy", "cv2", "onnxruntime", "onnx", "scipy", "cryptography", "courtloc.services", "courtloc.lab",
         "courtloc.sim")


def _loaded(module: str, then: str = "") -> set[str]:
    code = (f"import importlib, sys; importlib.import_module({module!r}); {then}"
            f"print(' '.join(sorted(h for h in {HEAVY!r} if any(n == h or n.startswith(h + '.') "
            "for n in sys.modules))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60)
    return set(out.stdout.split())


def test_the_router_process_loads_none_of_the_stages_libraries() -> None:
    assert _loaded("courtloc.router_process") == set()


def test_the_cli_it_replaces_does_load_them() -> None:
    """The check above can fail: the full CLI (what the router ran as before) loads them."""
    every_command = "sys.modules['courtloc.cli'].build_parser(); "
    assert {"numpy", "onnxruntime", "courtloc.services"} <= _loaded("courtloc.cli", every_command)


@pytest.mark.parametrize("settings, says", [
    ('{"robot_id": "r", "listen": ["tcp/127.0.0.1:0"], "secure_dir": "/nonexistent-courtloc-dir"}',
     "router: credential file /nonexistent-courtloc-dir/ca.pem not found"),
    ('{"robot_id": "r"}', "router: 1 validation error for RouterSettings listen Field required"),
])
def test_a_router_that_cannot_start_says_why_in_one_line(settings: str, says: str) -> None:
    proc = subprocess.run([sys.executable, "-m", "courtloc.router_process", "--settings", settings],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 1
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(says), proc.stderr
