"""Renderer: a robot pose -> the BGR frame its camera sees on a court.

The floor is one perspective warp of a cached top-down texture (the floor is a plane, so a homography
is exact); above the horizon an arena panorama is looked up by heading. Domain randomisation is applied
after that with cheap whole-frame operations so a frame costs a few milliseconds.
"""
from __future__ import annotations

import math
from typing import Literal, Optional

import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from courtloc.world.camera import CameraModel, Pose
from courtloc.world.court import Court

Range = tuple[float, float]
_PANORAMA_WIDTH = 2048  # pixels for 360 degrees of arena backdrop
_PANORAMA_HEIGHT = 512  # pixels for elevations 0..90 degrees
_LIGHT_FIELDS = 8  # distinct light falloffs a randomised frame picks from
_NOISE_BANK_SCALE = 1.5  # noise banks are this much larger than a frame; each frame takes a random window


def _range(lo_min: float = 0.0):
    def check(value: Range, name: str) -> Range:
        lo, hi = value
        if lo > hi or lo < lo_min:
            raise ValueError(f"{name}: expected min <= max and min >= {lo_min}, got {value}")
        return value

    return check


class OccluderOptions(BaseModel):
    model_config = ConfigDict(extra="forbid")
    max_count: int = Field(0, ge=0, le=20, description="up to this many occluders per frame")
    kinds: list[Literal["robot", "ball", "person"]] = Field(default_factory=lambda: ["robot", "ball", "person"])
    distance_m: Range = (0.8, 5.0)


class RenderOptions(BaseModel):
    """Domain randomisation. The defaults render a clean frame; `RenderOptions.randomised()` is a preset."""

    model_config = ConfigDict(extra="forbid")
    exposure_gain: Range = (1.0, 1.0)
    brightness_offset: Range = (0.0, 0.0)
    lighting_gradient: float = Field(0.0, ge=0.0, le=0.8, description="amplitude of a smooth light falloff")
    noise_sigma: Range = (0.0, 0.0)
    blur_sigma: Range = (0.0, 0.0)
    floor_texture: bool = Field(False, description="wood-like grain and a colour tint on the floor")
    floor_variants: int = Field(4, ge=1, le=32)
    occluders: OccluderOptions = OccluderOptions()
    jpeg_quality: Optional[int] = Field(None, ge=10, le=100)
    motion_blur_s: float = Field(0.0, ge=0.0, le=0.1, description="shutter open time: the frame averages the "
                                 "views over the motion of the last this-many seconds (0: no motion blur)")
    motion_blur_samples: int = Field(4, ge=2, le=16, description="views averaged over the shutter time")

    @model_validator(mode="after")
    def _check_ranges(self) -> "RenderOptions":
        _range(0.05)(self.exposure_gain, "exposure_gain")
        _range(-255.0)(self.brightness_offset, "brightness_offset")
        _range(0.0)(self.noise_sigma, "noise_sigma")
        _range(0.0)(self.blur_sigma, "blur_sigma")
        lo, hi = self.occluders.distance_m
        if not 0.3 <= lo <= hi:
            raise ValueError(f"occluders.distance_m must satisfy 0.3 <= min <= max, got {(lo, hi)}")
        return self

    @classmethod
    def randomised(cls) -> "RenderOptions":
        # Moderate on purpose: a light floor under stronger light really does turn "white" for the HSV
        # mask, and frames whose every floor pixel is a hit teach a model nothing.
        return cls(
            exposure_gain=(0.9, 1.1),
            brightness_offset=(-10.0, 10.0),
            lighting_gradient=0.15,
            noise_sigma=(0.0, 4.0),
            blur_sigma=(0.0, 1.0),
            floor_texture=True,
            occluders=OccluderOptions(max_count=3),
        )

    @property
    def is_clean(self) -> bool:
        return self == RenderOptions()


class Renderer:
    """Renders frames of one court through one camera. Caches the texture, maps and noise banks."""

    def __init__(self, court: Court, camera: CameraModel) -> None:
        self.court = court
        self.camera = camera
        self._texture = _bgr_uint8(court.raster(court.texture_resolution_m)[0])
        self._texel_to_court = court.texel_to_court(court.texture_resolution_m)
        self._border = tuple(float(c) for c in court.rgb(court.outside_colour)[::-1])
        self._variants: dict[int, np.ndarray] = {}
        self._noise_banks: dict[int, np.ndarray] = {}
        self._light_fields: dict[tuple[int, float], np.ndarray] = {}
        self._setup_sky()

    # ---- setup ----------------------------------------------------------------------------------
    def _setup_sky(self) -> None:
        cam = self.camera
        u, v = np.meshgrid(np.arange(cam.width, dtype=float), np.arange(cam.height, dtype=float))
        du, dv = self.court.render_pixel_offset_px
        pixels = np.column_stack([u.ravel() + du, v.ravel() + dv])
        rays = cam.pixel_rays(pixels)  # distortion included, so lens effects need no second pass
        sky = rays[:, 2] >= -1e-9
        self._sky_mask = sky.reshape(cam.height, cam.width)
        rows = np.nonzero(self._sky_mask.any(axis=1))[0]
        self._sky_rows = int(rows.max()) + 1 if len(rows) else 0
        n = self._sky_rows * cam.width
        az = np.arctan2(rays[:n, 1], rays[:n, 0])  # robot-frame azimuth, left positive
        el = np.arctan2(rays[:n, 2], np.hypot(rays[:n, 0], rays[:n, 1]))
        # Heading only shifts the panorama sideways, so the lookup map is fixed; a frame adds a whole-column
        # shift (0.18 degrees) to it and reads from a panorama laid out twice.
        scale = _PANORAMA_WIDTH / (2 * math.pi)
        map_x = (np.mod(az, 2 * math.pi) * scale).reshape(self._sky_rows, cam.width).astype(np.float32)
        map_y = np.clip((1.0 - el / (math.pi / 2)) * (_PANORAMA_HEIGHT - 1), 0, _PANORAMA_HEIGHT - 1)
        map_y = map_y.reshape(self._sky_rows, cam.width).astype(np.float32)
        self._sky_maps = cv2.convertMaps(map_x, map_y, cv2.CV_16SC2)
        pano = _arena_panorama(self.court)
        self._panorama = np.ascontiguousarray(np.concatenate([pano, pano, pano[:, :2]], axis=1))
        # Every pixel's floor point in the robot frame is fixed for a camera, so a pose is one affine map.
        floor = cam.pixel_to_floor(pixels)
        floor[~np.isfinite(floor)] = -1e6
        # Rows above the highest floor pixel are all arena: the floor lookup skips them.
        floor_rows = np.nonzero((~self._sky_mask).any(axis=1))[0]
        self._floor_top = int(floor_rows.min()) if len(floor_rows) else cam.height
        self._floor_xy = np.ascontiguousarray(
            floor.reshape(cam.height, cam.width, 2)[self._floor_top :].astype(np.float32))
        # Rows above the floor take the backdrop outright; only rows the horizon crosses need a mask.
        self._sky_split = min(self._floor_top, self._sky_rows)
        self._sky_mask3 = np.repeat(self._sky_mask[self._sky_split : self._sky_rows, :, None], 3, axis=2)

    # ---- per frame ------------------------------------------------------------------------------
    def render(self, pose: Pose, options: RenderOptions | None = None, rng: np.random.Generator | None = None,
               shutter_open_pose: Pose | None = None) -> np.ndarray:
        """640x480 (the camera's size) BGR uint8 frame at pose (x, y, yaw); same seed, same frame.

        With `options.motion_blur_s` > 0 and `shutter_open_pose` (where the robot was when the shutter
        opened, motion_blur_s before `pose`), the scene is the mean of views along that motion."""
        options = options or RenderOptions()
        rng = rng if rng is not None else np.random.default_rng(0)
        texture = self._texture
        if options.floor_texture:
            texture = self._variant(int(rng.integers(options.floor_variants)))
        if options.motion_blur_s > 0 and shutter_open_pose is not None and shutter_open_pose != tuple(pose):
            frame = self._motion_blurred(texture, shutter_open_pose, pose, options.motion_blur_samples)
        else:
            frame = self._view(texture, pose)
        if options.occluders.max_count:
            self._draw_occluders(frame, options.occluders, rng)
        return self._photometric(frame, options, rng)

    def _view(self, texture: np.ndarray, pose: Pose) -> np.ndarray:
        frame = self._warp_floor(texture, pose)
        self._draw_sky(frame, pose[2])
        return frame

    def _motion_blurred(self, texture: np.ndarray, start: Pose, end: Pose, samples: int) -> np.ndarray:
        """Mean of `samples` views evenly along start -> end (yaw the short way round)."""
        turn = math.atan2(math.sin(end[2] - start[2]), math.cos(end[2] - start[2]))
        total = np.zeros((self.camera.height, self.camera.width, 3), np.float32)
        for s in np.linspace(0.0, 1.0, samples):
            view = (start[0] + s * (end[0] - start[0]), start[1] + s * (end[1] - start[1]), start[2] + s * turn)
            cv2.accumulate(self._view(texture, view), total)
        return cv2.convertScaleAbs(total, alpha=1.0 / samples)

    def _warp_floor(self, texture: np.ndarray, pose: Pose) -> np.ndarray:
        x, y, yaw = pose
        c, s = math.cos(yaw), math.sin(yaw)
        court_from_robot = np.array([[c, -s, x], [s, c, y], [0.0, 0.0, 1.0]])
        texel_from_robot = (np.linalg.inv(self._texel_to_court) @ court_from_robot)[:2]
        frame = np.empty((self.camera.height, self.camera.width, 3), np.uint8)
        if self._floor_top >= self.camera.height:
            return frame
        maps = cv2.transform(self._floor_xy, texel_from_robot)
        # Fixed-point maps make the bilinear lookup about twice as fast as float maps.
        m1, m2 = cv2.convertMaps(maps, None, cv2.CV_16SC2)
        cv2.remap(texture, m1, m2, cv2.INTER_LINEAR, dst=frame[self._floor_top :], borderMode=cv2.BORDER_CONSTANT,
                  borderValue=self._border)
        return frame

    def _draw_sky(self, frame: np.ndarray, yaw: float) -> None:
        if not self._sky_rows:
            return
        shift = int(round(math.fmod(yaw, 2 * math.pi) * _PANORAMA_WIDTH / (2 * math.pi))) % _PANORAMA_WIDTH
        m1 = self._sky_maps[0].copy()
        m1[..., 0] += np.int16(shift)
        m2 = self._sky_maps[1]
        top = self._sky_split
        if top:
            cv2.remap(self._panorama, m1[:top], m2[:top], cv2.INTER_LINEAR, dst=frame[:top],
                      borderMode=cv2.BORDER_REPLICATE)
        if top < self._sky_rows:
            mixed = cv2.remap(self._panorama, m1[top:], m2[top:], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            np.copyto(frame[top : self._sky_rows], mixed, where=self._sky_mask3)

    def _draw_occluders(self, frame: np.ndarray, opts: OccluderOptions, rng: np.random.Generator) -> None:
        """Robots, balls and people standing on the floor in view, placed relative to the robot."""
        cam = self.camera
        count = int(rng.integers(opts.max_count + 1))
        half_fov = math.atan2(cam.width / 2, cam.fx)
        placed = []
        for _ in range(count):
            kind = opts.kinds[int(rng.integers(len(opts.kinds)))]
            dist = float(rng.uniform(*opts.distance_m))
            bearing = float(rng.uniform(-half_fov, half_fov)) + cam.mount.yaw
            centre = np.array([cam.mount.x + dist * math.cos(bearing), cam.mount.y + dist * math.sin(bearing)])
            colour = tuple(int(c) for c in rng.integers(20, 200, size=3))
            heading = float(rng.uniform(0, math.pi))
            placed.append((dist, kind, centre, colour, heading))
        # Far objects first so near ones cover them.
        for dist, kind, centre, colour, heading in sorted(placed, key=lambda p: -p[0]):
            if kind == "ball":
                self._draw_ball(frame, centre, 0.12, colour)
            elif kind == "robot":
                self._draw_box(frame, centre, (0.7, 0.7), 0.0, 0.9, heading, colour)
            else:
                self._draw_box(frame, centre, (0.25, 0.4), 0.0, 0.9, heading, tuple(c // 2 for c in colour))
                self._draw_box(frame, centre, (0.3, 0.45), 0.9, 1.5, heading, colour)
                self._draw_ball(frame, centre, 0.11, (60, 90, 140), z=1.62)

    def _draw_box(self, frame, centre, size, z0, z1, heading, colour) -> None:
        c, s = math.cos(heading), math.sin(heading)
        hx, hy = size[0] / 2, size[1] / 2
        corners = [(centre[0] + c * dx - s * dy, centre[1] + s * dx + c * dy) for dx in (-hx, hx) for dy in (-hy, hy)]
        pts = np.array([(x, y, z) for x, y in corners for z in (z0, z1)])
        uv = self.camera.robot_to_pixel(pts)
        if not np.all(np.isfinite(uv)):
            return
        hull = cv2.convexHull(np.clip(uv, -4000, 4000).astype(np.int32))
        cv2.fillConvexPoly(frame, hull, colour, lineType=cv2.LINE_AA)

    def _draw_ball(self, frame, centre, radius, colour, z: float | None = None) -> None:
        z = radius if z is None else z
        uv = self.camera.robot_to_pixel(np.array([[centre[0], centre[1], z]]))[0]
        depth = math.hypot(centre[0] - self.camera.mount.x, centre[1] - self.camera.mount.y)
        if not np.all(np.isfinite(uv)) or depth < 0.2:
            return
        r_px = int(round(self.camera.fx * radius / depth))
        cv2.circle(frame, (int(round(uv[0])), int(round(uv[1]))), max(r_px, 1), colour, -1, lineType=cv2.LINE_AA)

    def _photometric(self, frame: np.ndarray, opts: RenderOptions, rng: np.random.Generator) -> np.ndarray:
        gain = float(rng.uniform(*opts.exposure_gain))
        offset = float(rng.uniform(*opts.brightness_offset))
        if gain != 1.0 or offset != 0.0:
            frame = cv2.convertScaleAbs(frame, alpha=gain, beta=offset)
        if opts.lighting_gradient > 0:
            field = self._light_field(int(rng.integers(_LIGHT_FIELDS)), opts.lighting_gradient)
            frame = cv2.multiply(frame, field, scale=1.0 / 128.0)
        sigma = float(rng.uniform(*opts.blur_sigma))
        if sigma > 0.05:
            frame = cv2.GaussianBlur(frame, (0, 0), sigma)
        level = int(round(rng.uniform(*opts.noise_sigma)))
        if level > 0:
            bank = self._noise_bank(level)
            oy = int(rng.integers(bank.shape[0] - frame.shape[0]))
            ox = int(rng.integers(bank.shape[1] - frame.shape[1]))
            window = bank[oy : oy + frame.shape[0], ox : ox + frame.shape[1]]
            frame = cv2.add(frame, window, dtype=cv2.CV_8U)
        if opts.jpeg_quality is not None:
            ok, buf = cv2.imencode(".jpg", frame, [cv2.IMWRITE_JPEG_QUALITY, opts.jpeg_quality])
            frame = cv2.imdecode(buf, cv2.IMREAD_COLOR)
        return frame

    # ---- cached randomisation assets -------------------------------------------------------------
    def warm_up(self, options: RenderOptions) -> None:
        """Build every cached asset `options` can draw (floor variants, light fields, noise banks) now.

        Built on first use they cost 50-250 ms each: a camera rendering in real time missed 2-7 slots on
        each of its first frames, and the robot of a 2.5 m/s walk jumped up to 0.6 m between them."""
        if options.floor_texture:
            for index in range(options.floor_variants):
                self._variant(index)
        if options.lighting_gradient > 0:
            for index in range(_LIGHT_FIELDS):
                self._light_field(index, options.lighting_gradient)
        low, high = (int(round(v)) for v in options.noise_sigma)
        for level in range(max(low, 1), high + 1):
            self._noise_bank(level)

    def _variant(self, index: int) -> np.ndarray:
        if index not in self._variants:
            rng = np.random.default_rng(1000 + index)
            tex, white, _ = self.court.raster(self.court.texture_resolution_m)
            h, w = white.shape
            grain = cv2.resize(rng.normal(0, 1, (max(h // 40, 2), max(w // 4, 2))).astype(np.float32), (w, h), interpolation=cv2.INTER_CUBIC)
            blotch = cv2.resize(rng.normal(0, 1, (8, 12)).astype(np.float32), (w, h), interpolation=cv2.INTER_CUBIC)
            shade = 1.0 + 0.04 * grain + 0.05 * blotch
            tint = rng.normal(0, 6, 3).astype(np.float32)
            floor = 1.0 - white  # tint only the floor paint: lines keep their white
            out = tex * shade[..., None] + tint[None, None, :] * floor[..., None]
            self._variants[index] = _bgr_uint8(out)
        return self._variants[index]

    def _noise_bank(self, level: int) -> np.ndarray:
        if level not in self._noise_banks:
            h = int(self.camera.height * _NOISE_BANK_SCALE)
            w = int(self.camera.width * _NOISE_BANK_SCALE)
            noise = np.random.default_rng(level).normal(0, level, (h, w, 3))
            self._noise_banks[level] = np.clip(np.rint(noise), -127, 127).astype(np.int16)
        return self._noise_banks[level]

    def _light_field(self, index: int, amplitude: float) -> np.ndarray:
        """A smooth 3-channel gain field (128 = unchanged) for cv2.multiply, cached per (index, amplitude)."""
        key = (index, amplitude)
        if key not in self._light_fields:
            rng = np.random.default_rng(2000 + index)
            low = rng.uniform(-1, 1, (3, 4)).astype(np.float32)
            smooth = cv2.resize(low, (self.camera.width, self.camera.height), interpolation=cv2.INTER_CUBIC)
            field = np.clip(128.0 * (1.0 + amplitude * smooth), 0, 255).astype(np.uint8)
            self._light_fields[key] = cv2.merge([field, field, field])
        return self._light_fields[key]


def _bgr_uint8(rgb_float: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(np.clip(np.rint(rgb_float[..., ::-1]), 0, 255).astype(np.uint8))


def _arena_panorama(court: Court) -> np.ndarray:
    """A 360-degree arena backdrop: walls, darker stands and coloured banners; nothing white, so the line
    detector finds no false edges above the horizon."""
    base = np.array(court.rgb(court.background_colour)[::-1], np.float32)
    rows = np.linspace(0.0, 1.0, _PANORAMA_HEIGHT, dtype=np.float32)[:, None, None]  # 0 at zenith, 1 at horizon
    pano = np.repeat((base * (0.7 + 0.5 * rows)), _PANORAMA_WIDTH, axis=1)
    rng = np.random.default_rng(7)
    horizon = _PANORAMA_HEIGHT - 1
    for _ in range(24):
        x0 = int(rng.integers(_PANORAMA_WIDTH))
        width = int(rng.integers(40, 160))
        top = horizon - int(rng.integers(20, 90))
        colour = rng.integers(30, 150, size=3).astype(np.float32)
        pano[top : horizon - 8, x0 : x0 + width] = colour
    # Darker band just above the floor: boards around the arena.
    pano[horizon - 8 :] = base * 0.6
    return np.clip(pano, 0, 255).astype(np.uint8)
