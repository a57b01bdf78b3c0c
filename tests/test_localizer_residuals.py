"""`courtloc localizer residuals` (lab/residuals.py): residuals at the true poses by paint kind and range."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
from localizer_kit import twin_setup

from courtloc.lab.residuals import residual_table
from courtloc.lab.seed_frames import SeedFrames

POSES = [(-1.0, 0.3, 0.1), (-2.0, -1.0, -0.2), (0.5, 2.0, 0.3), (-3.0, 0.0, 0.0), (1.0, -2.5, 2.9), (2.0, 1.0, 3.1)]


def _row(rows: list[dict], kind: str, lo: float) -> dict:
    return next(r for r in rows if r["kind"] == kind and r["range_m"][0] == lo)


def test_rendered_frames_at_their_true_poses_fit_the_near_lines() -> None:
    _, camera, localizer, _, raw = twin_setup(POSES)
    frames = SeedFrames(filenames=[f"twin_{k}.png" for k in range(len(POSES))], recordings=np.array(["twin"] * len(POSES)),
                        hits=list(raw.values()), truth=np.array(list(raw.keys()), float), width=camera.width,
                        height=camera.height)
    rows = residual_table(camera, localizer.field, localizer.config, frames, np.arange(len(POSES)))
    near = _row(rows, "thin band", 2.0)
    assert near["n"] >= 100 and abs(near["median_cm"]) < 1.0  # a pose or frame mix-up is decimetres off
    # A wrong pose moves every residual: the same frames 10 cm off along x are far from zero.
    off = SeedFrames(**{**frames.__dict__, "truth": frames.truth + (0.1, 0.0, 0.0)})
    moved = _row(residual_table(camera, localizer.field, localizer.config, off, np.arange(len(POSES))), "thin band", 2.0)
    assert abs(moved["median_cm"] - near["median_cm"]) > 1.0


def test_cli_shows_the_thin_band_bias_on_the_seed_data(seed_dir: Path, tmp_path: Path) -> None:
    def run(*extra: str) -> dict:
        out = tmp_path / f"r{len(extra)}.json"
        subprocess.run([sys.executable, "-m", "courtloc", "localizer", "residuals", "--data", str(seed_dir),
                        "--step", "15", "--json", str(out), *extra], check=True, capture_output=True, text=True)
        return json.loads(out.read_text())["recordings"]

    plain, corrected = run("--no-band-bias"), run()
    for rec in ("20250622", "20250625"):
        before, after = _row(plain[rec], "thin band", 6.0), _row(corrected[rec], "thin band", 6.0)
        assert before["median_cm"] > 4.0  # lines 6-8 m away: hits well past the modelled edge
        assert abs(after["median_cm"]) < 0.5 * before["median_cm"]
