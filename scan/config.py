"""Configuration of the preprocess stage: white mask, radial scan, paper crop and debug preview.

Every model forbids unknown fields, so a typo in a config file fails at start with the field's name.
"""
from __future__ import annotations

import math
from typing import Literal, Optional

from pydantic import BaseModel, ConfigDict, Field, model_validator

# OpenCV's 8-bit HSV: hue is 0..179 (degrees / 2), saturation and value are 0..255.
HUE_MAX = 179
SV_MAX = 255


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class HsvRange(_Strict):
    """An inclusive box in OpenCV HSV space, as `cv2.inRange` takes it."""

    lower: tuple[int, int, int]
    upper: tuple[int, int, int]

    @model_validator(mode="after")
    def _check_bounds(self) -> "HsvRange":
        for name, triple in (("lower", self.lower), ("upper", self.upper)):
            h, s, v = triple
            if not (0 <= h <= HUE_MAX and 0 <= s <= SV_MAX and 0 <= v <= SV_MAX):
                raise ValueError(f"{name}={triple}: H must be 0..{HUE_MAX}, S and V 0..{SV_MAX}")
        if any(lo > hi for lo, hi in zip(self.lower, self.upper)):
            raise ValueError(f"lower={self.lower} exceeds upper={self.upper} in some channel")
        return self


# Why these two boxes (numbers in docs/preprocess.md): white is "little colour, much light". The first box is
# neutral bright white of any hue (the twins' rendered lines) and stops above the Robocon 2025 twin's light
# grey floor (V ~183). The second admits white tape under warm indoor lamps: dimmer and yellow-tinted, so more
# saturation and less value are allowed, but only at warm hues, which keeps grey and blue-grey floors out;
# a wooden floor is too saturated for it.
DEFAULT_HSV_RANGES: tuple[HsvRange, ...] = (
    HsvRange(lower=(0, 0, 200), upper=(HUE_MAX, 40, SV_MAX)),
    HsvRange(lower=(5, 0, 160), upper=(35, 80, SV_MAX)),
)


class ScanConfig(_Strict):
    """Algorithm 1's rays: angles start..stop (inclusive) in `step_deg` steps from `origin`.

    The defaults reproduce the seed dataset's dots (measured, see docs/preprocess.md): rays from the
    bottom-centre pixel (W/2, H-1) and pixel coordinates truncated toward zero, as C's and Python's int().
    """

    angle_start_deg: float = 0.0
    angle_stop_deg: float = 180.0
    angle_step_deg: float = Field(default=2.0, gt=0.0)
    # Pixel coordinates (x=column, y=row) of the rays' common origin; None means the bottom-centre pixel
    # (W/2, H-1), which is where the seed images' rays start (the paper writes (W/2, H)).
    origin: Optional[tuple[float, float]] = None
    # How a sample's float coordinates become a pixel: "trunc" = toward zero (int(x)), which the seed images
    # match; "half_up" = floor(x + 0.5), the nearest pixel.
    rounding: Literal["trunc", "half_up"] = "trunc"
    # Last d walked (inclusive); None means the paper's max(H, W).
    max_d: Optional[int] = Field(default=None, gt=0)
    # A hit must also be an edge in brightness: the last white sample is brighter (HSV V) by at least this
    # much than the darkest of the hit and the `edge_drop_samples` - 1 samples after it on the ray. Paint
    # ends within a pixel or two; a floor that light, gloss or texture lifts past the white threshold fades
    # out over many, and without this rule its patches gave hundreds of hits that a wrong pose fitted
    # (docs/preprocess.md, "Edge drop"). 0: the paper's Algorithm 1 exactly (the seed dots' scan).
    min_edge_drop: int = Field(default=30, ge=0, le=255)
    edge_drop_samples: int = Field(default=3, ge=1, le=16)

    @model_validator(mode="after")
    def _check_angles(self) -> "ScanConfig":
        if self.angle_stop_deg < self.angle_start_deg:
            raise ValueError("angle_stop_deg must be >= angle_start_deg")
        if self.n_rays > 32767:
            raise ValueError("too many rays for the int16 ray index")
        return self

    @property
    def n_rays(self) -> int:
        # The small epsilon keeps a stop that is a whole number of steps (180/2) inclusive despite rounding.
        return int(math.floor((self.angle_stop_deg - self.angle_start_deg) / self.angle_step_deg + 1e-9)) + 1

    def angles_deg(self) -> list[float]:
        """Ray k's angle in degrees; the reference and the fast path both take their angles from here."""
        return [self.angle_start_deg + k * self.angle_step_deg for k in range(self.n_rays)]

    def origin_for(self, height: int, width: int) -> tuple[float, float]:
        return self.origin if self.origin is not None else (width / 2.0, float(height - 1))

    def max_d_for(self, height: int, width: int) -> int:
        return self.max_d if self.max_d is not None else max(height, width)


class MarkClass(_Strict):
    """A colour the scan reports where it sees it (`PreprocessConfig.marks`): a court's colour mark."""

    name: str = Field(max_length=64)
    hsv_ranges: tuple[HsvRange, ...] = Field(min_length=1)


class DebugPreviewConfig(_Strict):
    """A JPEG of the mask with the hits drawn on it, for a human watching; costly, so off and rate-limited."""

    enabled: bool = False
    max_rate_hz: float = Field(default=2.0, gt=0.0)
    jpeg_quality: int = Field(default=70, ge=1, le=100)


class PreprocessConfig(_Strict):
    hsv_ranges: tuple[HsvRange, ...] = Field(default=DEFAULT_HSV_RANGES, min_length=1)
    scan: ScanConfig = ScanConfig()
    # Expected frame size; a frame of another size is refused. None accepts any size (the CLI does this).
    frame_width: Optional[int] = Field(default=640, gt=0)
    frame_height: Optional[int] = Field(default=480, gt=0)
    # Rows cut from the top before the paper's model sees the dot image (480 - 200 = 280 rows remain).
    crop_top: int = Field(default=200, ge=0)
    # Radius of the dots drawn for the paper's model, as in the seed images.
    dot_radius: int = Field(default=2, ge=0)
    debug_preview: DebugPreviewConfig = DebugPreviewConfig()
    # The court's colour marks (filled from the deployment's court, `Court.marks`; in that order: a mark's
    # index is its place here): pixels of a grid `mark_grid_px` apart in those colours, at most `max_marks`.
    marks: tuple[MarkClass, ...] = Field(default=(), max_length=8)
    mark_grid_px: int = Field(default=8, ge=1, le=64)
    max_marks: int = Field(default=256, ge=1, le=1024)

    @model_validator(mode="after")
    def _check_crop(self) -> "PreprocessConfig":
        if self.frame_height is not None and self.crop_top >= self.frame_height:
            raise ValueError(f"crop_top={self.crop_top} leaves no rows of a {self.frame_height}-row frame")
        return self
