"""A geometric-localizer package: one folder that is everything the robot needs to localise.

    model.onnx       hits -> floor points (the camera as a per-pixel table), manifest in metadata_props
    court.json       the court model (courtloc.world.court format): the distance field is built from it at load
    camera.json      the camera model (courtloc.world.camera format): the fit's per-hit error model
    localizer.json   LocalizerConfig (robust fit, quality thresholds, search, symmetry mode)
    golden.npz       golden inputs: scan hits of twin frames at known poses (localizer/golden.py)
    README.md        what it is and how well it did (evaluation report)

The manifest names the three JSON files (extra.court_file ...) and the golden file (golden), with
their sha256, so a package whose parts do not belong together is refused at load. A part is a plain
file name inside the package folder (manifest.package_part). Packages are built by
`courtloc.lab.package_build`.
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

from courtloc.localizer.config import LocalizerConfig
from courtloc.localizer.manifest import MODEL_FILE, Manifest, ManifestError, package_part, read_manifest
from courtloc.localizer.model_file import ModelFile
from courtloc.models import bundled_root
from courtloc.world.camera import CameraModel, load_camera
from courtloc.world.court import Court, load_court

COURT_FILE = "court.json"
CAMERA_FILE = "camera.json"
CONFIG_FILE = "localizer.json"
KIND = "geometric"
# The accuracy a geometric package states on its golden frames (twin frames, tracked from the true pose):
# the bundled default's worst golden frame is a few cm off (docs/pit_tools.md); a package past these is broken.
GOLDEN_POSITION_M = 0.05
GOLDEN_YAW_DEG = 1.0


def file_sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@dataclass(frozen=True)
class Package:
    folder: Path
    manifest: Manifest
    court: Court
    camera: CameraModel
    config: LocalizerConfig

    @property
    def model_path(self) -> Path:
        return self.folder / MODEL_FILE


def load_package(model: ModelFile | Path, config_override: LocalizerConfig | None = None) -> Package:
    """Read and cross-check a package (its folder, or its model file already read); raises ManifestError
    on anything inconsistent."""
    if not isinstance(model, ModelFile):
        model = ModelFile.read(Path(model) / MODEL_FILE)
    model.verify_weights()
    folder, model_path, manifest = model.path.parent, model.path, model.manifest
    extra = manifest.extra
    if extra.get("localizer") != KIND or manifest.input.kind != "scan_hits":
        raise ManifestError(f"{model_path}: not a geometric localizer package (input kind "
                            f"{manifest.input.kind!r}, localizer {extra.get('localizer')!r})")
    parts = {key: package_part(folder, extra.get(f"{key}_file"), extra.get(f"{key}_sha256"), key)
             for key in ("court", "camera", "config")}
    court = load_court(parts["court"])
    camera = load_camera(parts["camera"])
    config = config_override or LocalizerConfig.model_validate(json.loads(parts["config"].read_text()))
    return Package(folder=folder, manifest=manifest, court=court, camera=camera, config=config)


def bundled_packages() -> dict[tuple[str, str], Path]:
    """(court, camera) of each shipped package's manifest -> its folder."""
    out: dict[tuple[str, str], Path] = {}
    for folder in sorted(p for p in bundled_root().iterdir() if (p / MODEL_FILE).is_file()):
        manifest = read_manifest(folder / MODEL_FILE)
        out.setdefault((manifest.court, manifest.camera), folder)
    return out


def bundled_package(court: str, camera: str) -> Path:
    """The shipped package built for this court and camera; ManifestError naming what ships otherwise."""
    packages = bundled_packages()
    if (court, camera) not in packages:
        shipped = ", ".join(f"{c} / {m}" for c, m in sorted(packages)) or "none"
        raise ManifestError(f"no bundled localizer package for court {court!r} with camera {camera!r} (shipped: "
                            f"{shipped}); build one with `courtloc localizer build --court {court} --camera {camera}` "
                            f"and push it")
    return packages[(court, camera)]
