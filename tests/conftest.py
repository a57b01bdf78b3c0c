"""Shared fixtures. Data from ../shared is optional: tests that need it skip cleanly when it is absent."""
from __future__ import annotations

import os
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]


def shared_dir() -> Path:
    """The workplace's shared folder: $COURTLOC_SHARED, else ../shared beside the repository."""
    return Path(os.environ.get("COURTLOC_SHARED", REPO_ROOT.parent / "shared"))


@pytest.fixture(scope="session")
def seed_dir() -> Path:
    path = shared_dir() / "datasets" / "seed-gazebo"
    if not (path / "pose_data.csv").is_file():
        pytest.skip("seed-gazebo dataset not present")
    return path


@pytest.fixture(scope="session")
def seed_world() -> Path:
    path = shared_dir() / "reference" / "seed-gazebo-world.json"
    if not path.is_file():
        pytest.skip("seed-gazebo reference world not present")
    return path


@pytest.fixture()
def small_disk(tmp_path: Path) -> Iterator[Path]:
    """An 8 MiB filesystem of its own (tmpfs), so the disk really fills up; skipped where mounting is not allowed."""
    mount_point = tmp_path / "disk"
    mount_point.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=8m", "tmpfs", str(mount_point)],
                          capture_output=True, text=True)
    if done.returncode:
        pytest.skip(f"cannot mount a small tmpfs here: {done.stderr.strip() or done.returncode}")
    try:
        yield mount_point
    finally:
        subprocess.run(["umount", str(mount_point)], check=True)
