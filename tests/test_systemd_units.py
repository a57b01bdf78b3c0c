"""The robot's systemd units: valid for systemd, restart on failure, journald, a dedicated user, and
every ExecStart is a real `courtloc` command line."""
from __future__ import annotations

import configparser
import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from courtloc.cli import build_parser
from courtloc.common.services_table import SERVICES

UNITS = Path(__file__).resolve().parents[1] / "deploy" / "systemd"
SERVICE_FILES = sorted(UNITS.glob("*.service"))
INSTALLED_COMMAND = "/opt/courtloc/venv/bin/courtloc"
INSTALLED_ENV = "/etc/courtloc/courtloc.env"


def _unit(path: Path) -> configparser.RawConfigParser:
    parser = configparser.RawConfigParser(strict=False, interpolation=None)
    parser.optionxform = str  # systemd keys are case-sensitive
    parser.read_string(path.read_text())
    return parser


def _target_stages() -> list[str]:
    wants = _unit(UNITS / "courtloc.target")["Unit"]["Wants"].split()
    return [m.group(1) for w in wants if (m := re.fullmatch(r"courtloc-stage@(\w+)\.service", w))]


def test_units_exist_and_the_target_starts_every_stage() -> None:
    assert {p.name for p in SERVICE_FILES} == {"courtloc-router.service", "courtloc-stage@.service"}
    assert sorted(_target_stages()) == sorted(SERVICES)
    assert "courtloc-router.service" in _unit(UNITS / "courtloc.target")["Unit"]["Wants"].split()
    assert _unit(UNITS / "courtloc.target")["Install"]["WantedBy"] == "multi-user.target"


@pytest.mark.parametrize("path", SERVICE_FILES, ids=lambda p: p.name)
def test_service_unit_policy(path: Path) -> None:
    unit = _unit(path)
    assert "network-online.target" in unit["Unit"]["After"].split()
    assert "network-online.target" in unit["Unit"]["Wants"].split()
    service = unit["Service"]
    assert service["Restart"] == "on-failure"
    assert service["User"] == "courtloc" and service["Group"] == "courtloc", "a dedicated, unprivileged user"
    assert service["EnvironmentFile"] == INSTALLED_ENV
    assert service["StandardOutput"] == "journal" and service["StandardError"] == "journal"
    assert unit["Install"]["WantedBy"] == "courtloc.target"


def test_stages_may_take_the_realtime_priorities_robot_toml_suggests() -> None:
    """robot.toml's [realtime] example asks for SCHED_FIFO 10; the unprivileged stage unit must permit it (else
    the stage refuses to start), and stay below the kernel's threaded IRQ handlers (50)."""
    limit = int(_unit(UNITS / "courtloc-stage@.service")["Service"]["LimitRTPRIO"])
    example = Path(__file__).resolve().parents[1] / "deploy" / "configs" / "robot.toml"
    asked = [int(m) for m in re.findall(r"^# fifo_priority = (\d+)$", example.read_text(), re.M)]
    assert asked and max(asked) <= limit < 50


@pytest.mark.parametrize("path", SERVICE_FILES, ids=lambda p: p.name)
def test_exec_start_is_a_real_courtloc_command(path: Path, tmp_path: Path) -> None:
    argv = shlex.split(_unit(path)["Service"]["ExecStart"])
    assert argv[0] == INSTALLED_COMMAND
    env = dict(line.split("=", 1) for line in (UNITS / "courtloc.env").read_text().splitlines()
               if line and not line.startswith("#"))
    used = set(re.findall(r"\$\{(\w+)\}", " ".join(argv)))
    assert used <= set(env), f"ExecStart uses {used - set(env)} not set in courtloc.env"
    instances = SERVICES if "%i" in argv else [None]
    for stage in instances:
        args = [a.replace("%i", stage or "") for a in argv[1:]]
        args = [re.sub(r"\$\{\w+\}", str(tmp_path / "robot.toml"), a) for a in args]
        parsed = build_parser().parse_args(args)
        assert callable(parsed.func), f"{args} is not a courtloc command"
        if stage:
            assert parsed.service == stage


@pytest.mark.skipif(not shutil.which("systemd-analyze"), reason="systemd-analyze not installed")
def test_systemd_analyze_verify_accepts_the_units(tmp_path: Path) -> None:
    """systemd's own checker, on copies pointing at this checkout's `courtloc` and env file."""
    command = Path(sys.executable).with_name("courtloc")
    if not os.access(command, os.X_OK):
        pytest.skip("no courtloc script next to this Python")
    for item in UNITS.iterdir():
        text = item.read_text().replace(INSTALLED_COMMAND, str(command)).replace(INSTALLED_ENV,
                                                                                 str(tmp_path / "courtloc.env"))
        (tmp_path / item.name).write_text(text)
    units = [tmp_path / "courtloc-router.service", tmp_path / "courtloc.target"]
    for stage in SERVICES:
        instance = tmp_path / f"courtloc-stage@{stage}.service"
        instance.symlink_to(tmp_path / "courtloc-stage@.service")
        units.append(instance)
    done = subprocess.run(["systemd-analyze", "verify", "--man=no", *map(str, units)],
                          capture_output=True, text=True, timeout=60, cwd=tmp_path)
    ours = [line for line in (done.stdout + done.stderr).splitlines() if "courtloc" in line]
    assert done.returncode == 0 and not ours, done.stdout + done.stderr
