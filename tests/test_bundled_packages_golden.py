"""Every package courtloc ships carries its golden inputs and passes the robot's own validation on them.

The infer stage validates a model again whenever it is activated or rolled back to (services/infer/
model_control.py), so a bundled package without golden inputs could never be served again once another
model had replaced it: `courtloc model rollback` to it would be refused."""
from __future__ import annotations

from pathlib import Path

import pytest

from courtloc.localizer.package import bundled_packages
from courtloc.services.infer.config import InferConfig
from courtloc.services.infer.validation import validate_candidate

PACKAGES = bundled_packages()


@pytest.mark.parametrize("court, camera", sorted(PACKAGES))
def test_bundled_package_ships_golden_inputs_it_meets(tmp_path: Path, court: str, camera: str) -> None:
    folder = PACKAGES[(court, camera)]
    config = InferConfig(court=court, camera=camera, store=tmp_path / "store")
    summary = validate_candidate(folder, config, pushed=False)  # ModelRefused (with the reason) otherwise
    assert summary.startswith("golden: ")


def test_bundled_packages_share_the_settings_their_docs_promise() -> None:
    """models/robocon2025 carries models/default's settings with the thin-band bias cleared (docs/localizer.md,
    "Bundled packages"). A package is built with the settings of its day: the robocon2025 one once kept
    acquisition settings two changes old (one confirming frame, priors growing at 1 m/s), and the twin bench
    measured those, not the documented rule."""
    from courtloc.localizer.package import load_package

    seed = load_package(PACKAGES[("seed-gazebo", "seed-gazebo")]).config
    court = load_package(PACKAGES[("robocon2025", "robocon2025")]).config
    without_bias = seed.fit.model_copy(update={"band_bias_widths": [], "band_bias_samples": []})
    assert court == seed.model_copy(update={"fit": without_bias})
