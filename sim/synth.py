"""Synthetic datasets in the seed format: images + pose_data.csv (image_filename, x, y, orientation_z).

Poses are drawn uniformly over the court's standing area and all headings; frame i depends only on
(seed, i), so an interrupted run resumes where it stopped and gives the same files as an uninterrupted one.
"""
from __future__ import annotations

import csv
import json
import logging
import math
import os
from pathlib import Path
from typing import Callable, Literal, Optional

import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from courtloc.sim.edges import hits_image, paper_scan_hits
from courtloc.sim.labels import SEED_COLUMNS, yaw_to_orientation_z
from courtloc.sim.render import Renderer, RenderOptions
from courtloc.world.camera import load_camera
from courtloc.world.court import load_court

log = logging.getLogger(__name__)

CSV_NAME = "pose_data.csv"
META_NAME = "synth_meta.json"
IMAGE_DIR = "images"


class SynthConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")
    court: str = "seed-gazebo"
    camera: Optional[str] = None
    n: int = Field(gt=0)
    out: Path
    seed: int = 0
    kind: Literal["raw", "edges"] = "raw"
    margin_m: float = Field(0.2, ge=0)
    render: Optional[RenderOptions] = Field(None, description="default: randomised for raw, light noise for edges")
    jpeg_quality: int = Field(95, ge=10, le=100)

    def render_options(self) -> RenderOptions:
        if self.render is not None:
            return self.render
        if self.kind == "raw":
            return RenderOptions.randomised()
        # Edge images keep the seed's look; a little sensor noise and blur jitters edges by a pixel or so.
        return RenderOptions(noise_sigma=(0.0, 2.0), blur_sigma=(0.0, 0.6))

    def identity(self) -> dict:
        """What must match for a resumed run to continue the same dataset."""
        return {"court": self.court, "camera": self.camera, "seed": self.seed, "kind": self.kind,
                "margin_m": self.margin_m, "render": self.render_options().model_dump(mode="json")}


def image_name(seed: int, index: int) -> str:
    return f"img_synth_s{seed}_{index:07d}.jpg"


def sample_pose(court, seed: int, index: int, margin: float) -> tuple[float, float, float]:
    rng = np.random.default_rng([seed, index, 1])
    hx, hy = court.area_half_extent_m
    return (float(rng.uniform(-hx + margin, hx - margin)), float(rng.uniform(-hy + margin, hy - margin)),
            float(rng.uniform(-math.pi, math.pi)))


def _read_rows(path: Path) -> dict[str, list[str]]:
    if not path.is_file():
        return {}
    with path.open(newline="") as handle:
        reader = csv.reader(handle)
        header = next(reader, None)
        if header is None:
            return {}
        if tuple(header) != SEED_COLUMNS:
            raise ValueError(f"{path} exists with columns {header}, not {list(SEED_COLUMNS)}")
        # A crash can leave a partial last line: keep complete rows only.
        return {row[0]: row for row in reader if len(row) == len(SEED_COLUMNS)}


def synth(config: SynthConfig, progress: Callable[[int, int, int], None] | None = None) -> dict:
    """Write the dataset; returns counts. progress(done, total, written) is called after each frame."""

    court = load_court(config.court)
    camera = load_camera(config.camera or court.default_camera)
    out = Path(config.out)
    images = out / IMAGE_DIR
    images.mkdir(parents=True, exist_ok=True)
    meta_path = out / META_NAME
    identity = config.identity()
    if meta_path.is_file():
        previous = json.loads(meta_path.read_text())
        if previous != identity:
            raise ValueError(f"{out} holds a dataset made with other settings ({meta_path}); use a new --out")
    else:
        meta_path.write_text(json.dumps(identity, indent=1) + "\n")
    csv_path = out / CSV_NAME
    rows = _read_rows(csv_path)
    renderer = Renderer(court, camera)
    options = config.render_options()
    written = skipped = 0
    if not csv_path.is_file() or not rows:
        with csv_path.open("w", newline="") as handle:
            csv.writer(handle).writerow(SEED_COLUMNS)
    with csv_path.open("a", newline="") as handle:
        writer = csv.writer(handle)
        for i in range(config.n):
            name = image_name(config.seed, i)
            if name in rows and (images / name).is_file():
                skipped += 1
            else:
                pose = sample_pose(court, config.seed, i, config.margin_m)
                frame = renderer.render(pose, options, np.random.default_rng([config.seed, i, 2]))
                image = frame if config.kind == "raw" else hits_image(paper_scan_hits(frame), frame.shape[0], frame.shape[1])
                tmp = images / (name + ".tmp.jpg")
                if not cv2.imwrite(str(tmp), image, [cv2.IMWRITE_JPEG_QUALITY, config.jpeg_quality]):
                    raise OSError(f"could not write {tmp}")
                os.replace(tmp, images / name)  # never leave a half-written image under the final name
                if name not in rows:
                    row = [name, repr(pose[0]), repr(pose[1]), repr(float(yaw_to_orientation_z(pose[2])))]
                    writer.writerow(row)
                    handle.flush()
                    rows[name] = row
                written += 1
            if progress:
                progress(i + 1, config.n, written)
    return {"total": config.n, "written": written, "skipped": skipped, "out": str(out)}
