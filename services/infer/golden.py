"""The golden inputs a candidate is validated on: the ones its own package ships (made when it was
built, see localizer/golden_build.py), and the accuracy it must show on them. Nothing is rendered here."""
from __future__ import annotations

from pathlib import Path

from courtloc.localizer.golden import GoldenError, GoldenFrame, load_golden
from courtloc.localizer.manifest import Manifest, ManifestError, package_part
from courtloc.services.infer.config import InferConfig


class GoldenUnavailable(ValueError):
    """The package has no usable golden inputs."""


def package_golden(folder: Path, manifest: Manifest) -> list[GoldenFrame]:
    spec = manifest.golden
    if spec is None:
        raise GoldenUnavailable("the manifest names none (build the package with a current `courtloc localizer "
                                "build` or `courtloc export`)")
    try:
        frames = load_golden(package_part(folder, spec.file, spec.sha256, "golden"))
    except (ManifestError, GoldenError) as exc:
        raise GoldenUnavailable(str(exc)) from None
    if len(frames) != spec.n_frames:
        raise GoldenUnavailable(f"{len(frames)} frames in the file, the manifest says {spec.n_frames}")
    return frames


def accuracy_limits(manifest: Manifest, config: InferConfig) -> tuple[tuple[float, str], tuple[float | None, str]]:
    """(position limit m, where it comes from), (yaw limit deg or None, where it comes from): the tighter
    of the manifest's stated accuracy and the deployment's limit."""
    assert manifest.golden is not None
    stated = manifest.golden
    position = min((stated.max_position_error_m, "stated by the manifest"),
                   (config.max_golden_position_error_m, "deployment limit max_golden_position_error_m"))
    yaws = [(config.max_golden_yaw_error_deg, "deployment limit max_golden_yaw_error_deg")]
    if stated.max_yaw_error_deg is not None:
        yaws.append((stated.max_yaw_error_deg, "stated by the manifest"))
    return position, min(yaws)
