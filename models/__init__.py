"""Models shipped inside the package: the bundled localizer packages (data, no code)."""
from __future__ import annotations

from importlib import resources
from pathlib import Path

DEFAULT_PACKAGE = "default"


def bundled_root() -> Path:
    """The folder of the packages shipped with courtloc (models/ in the source tree)."""
    return Path(str(resources.files("courtloc.models")))


def bundled_package(name: str = DEFAULT_PACKAGE) -> Path:
    """The folder of a bundled localizer package (models/<name>/)."""
    return bundled_root() / name
