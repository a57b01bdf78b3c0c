"""Shared fixtures. Data from ../shared is optional: tests that need it skip cleanly when it is absent."""
from __future__ import annotations

import os
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
