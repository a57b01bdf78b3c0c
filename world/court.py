"""Court models: painted geometry of a court as data, loaded by name from world/courts/*.json.

Coordinates are court metres: origin at the court centre, x along the long side, y across.
Everything drawn is a polygon (lines are bands around a centreline), so the same geometry feeds the
renderer's texture, the white mask and the analytic white edges used by the calibrator and localizer.
"""
from __future__ import annotations

import json
import math
from importlib import resources
from pathlib import Path
from typing import Annotated, Literal, Union

import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict, Field, PrivateAttr, model_validator

Point = tuple[float, float]
# Chord length used to turn arcs into polygons; 1 cm chords on a 2.5 m arc deviate < 0.01 mm.
ARC_CHORD_M = 0.01


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class RectShape(_Strict):
    kind: Literal["rect"]
    x0: float
    y0: float
    x1: float
    y1: float

    def polygon(self) -> np.ndarray:
        return np.array([[self.x0, self.y0], [self.x1, self.y0], [self.x1, self.y1], [self.x0, self.y1]], float)


class PolygonShape(_Strict):
    kind: Literal["polygon"]
    points: list[Point] = Field(min_length=3)

    def polygon(self) -> np.ndarray:
        return np.asarray(self.points, float)


class EllipseSectorShape(_Strict):
    """A pie slice of an ellipse: the centre plus the arc between two parametric angles."""

    kind: Literal["ellipse_sector"]
    centre: Point
    semi_axes: tuple[float, float]
    start_deg: float = 0.0
    end_deg: float = 360.0

    def polygon(self) -> np.ndarray:
        arc = _ellipse_arc(self.centre, self.semi_axes, self.start_deg, self.end_deg)
        if abs(self.end_deg - self.start_deg) >= 360.0:
            return arc[:-1]
        return np.vstack([np.asarray(self.centre, float)[None], arc])


Shape = Annotated[Union[RectShape, PolygonShape, EllipseSectorShape], Field(discriminator="kind")]


class Region(_Strict):
    """A painted floor area: the union of `shapes` minus `holes`. Painted in file order."""

    name: str
    colour: str
    shapes: list[Shape] = Field(min_length=1)
    holes: list[Shape] = Field(default_factory=list)
    mirror: bool = Field(False, description="also paint the copy rotated 180 degrees about the centre")


class SegmentLine(_Strict):
    """A straight painted line: centreline a->b, `width` across, ends extended by `extend`."""

    name: str
    kind: Literal["segment"]
    a: Point
    b: Point
    width: float = Field(gt=0)
    extend: float = 0.0
    colour: str = "white"
    mirror: bool = False

    def polygon(self) -> np.ndarray:
        a, b = np.asarray(self.a, float), np.asarray(self.b, float)
        direction = b - a
        length = float(np.hypot(*direction))
        if length == 0:
            raise ValueError(f"line {self.name!r}: zero length")
        d = direction / length
        n = np.array([-d[1], d[0]])
        a, b = a - d * self.extend, b + d * self.extend
        h = self.width / 2
        return np.array([a - n * h, b - n * h, b + n * h, a + n * h])


class ArcLine(_Strict):
    """An elliptical (or circular) painted arc: the band between two concentric ellipses.

    width_x/width_y let a design squeezed along one axis keep its true look (the seed court's
    three-point line is a round arc squeezed along x, so its band is narrower at the apex).
    """

    name: str
    kind: Literal["arc"]
    centre: Point
    semi_axes: tuple[float, float]
    start_deg: float
    end_deg: float
    width: float | None = Field(None, gt=0)
    width_x: float | None = Field(None, gt=0)
    width_y: float | None = Field(None, gt=0)
    colour: str = "white"
    mirror: bool = False

    @model_validator(mode="after")
    def _widths(self) -> "ArcLine":
        if self.width_x is None:
            self.width_x = self.width
        if self.width_y is None:
            self.width_y = self.width
        if self.width_x is None or self.width_y is None:
            raise ValueError(f"arc {self.name!r}: give width, or width_x and width_y")
        return self

    def polygon(self) -> np.ndarray:
        ax, ay = self.semi_axes
        assert self.width_x is not None and self.width_y is not None
        outer = _ellipse_arc(self.centre, (ax + self.width_x / 2, ay + self.width_y / 2), self.start_deg, self.end_deg)
        inner = _ellipse_arc(self.centre, (ax - self.width_x / 2, ay - self.width_y / 2), self.start_deg, self.end_deg)
        return np.vstack([outer, inner[::-1]])


Line = Annotated[Union[SegmentLine, ArcLine], Field(discriminator="kind")]


class Ring(_Strict):
    x: float
    y: float
    z: float = 2.43


class WhitePolygon(BaseModel):
    """One white painted element as court-metre polygons (elements may overlap each other)."""

    model_config = ConfigDict(arbitrary_types_allowed=True)
    name: str
    exteriors: list[np.ndarray]
    holes: list[np.ndarray]


HsvTriple = tuple[int, int, int]


class ColourMark(_Strict):
    """A floor colour that tells the court's point-symmetric twins apart (robocon2025's red strip along +y and
    blue strip along -y): where it is painted (`colour`, a palette name) and how a camera sees it (OpenCV
    8-bit HSV boxes, inclusive, as `cv2.inRange` takes them: H 0..179, S and V 0..255)."""

    name: str
    colour: str
    hsv_ranges: list[tuple[HsvTriple, HsvTriple]] = Field(min_length=1)

    @model_validator(mode="after")
    def _boxes(self) -> "ColourMark":
        for lower, upper in self.hsv_ranges:
            if not all(0 <= v <= m for v, m in zip((*lower, *upper), (179, 255, 255) * 2)) or \
                    any(lo > hi for lo, hi in zip(lower, upper)):
                raise ValueError(f"mark {self.name!r}: HSV box {lower}..{upper} out of range or inverted")
        return self


class Court(_Strict):
    name: str
    provenance: str = ""
    length_m: float = Field(gt=0)
    width_m: float = Field(gt=0)
    area_half_extent_m: tuple[float, float] = Field(description="where a robot may stand: |x|, |y| limits")
    floor_half_extent_m: tuple[float, float] = Field(description="extent of the modelled floor (texture)")
    texture_resolution_m: float = Field(0.01, gt=0, le=0.1)
    render_pixel_offset_px: tuple[float, float] = Field(
        (0.0, 0.0),
        description="the renderer's pixel (u, v) shows what the camera model projects to (u + du, v + dv): "
        "emulates the rasterisation of the simulator a court was fitted from; 0 for real cameras",
    )
    palette: dict[str, tuple[int, int, int]] = Field(description="colour name -> RGB")
    white_colours: list[str] = Field(default_factory=lambda: ["white"])
    outside_colour: str = Field(description="floor colour beyond the modelled floor")
    background_colour: str = Field(description="dominant colour of the arena above the horizon")
    regions: list[Region] = Field(default_factory=list)
    lines: list[Line] = Field(default_factory=list)
    rings: list[Ring] = Field(min_length=1)
    default_camera: str
    marks: list[ColourMark] = Field(default_factory=list, description="floor colours that break the white "
                                    "paint's point symmetry (empty: nothing in a view tells the twins apart)")

    _cache: dict = PrivateAttr(default_factory=dict)

    @model_validator(mode="after")
    def _colours_known(self) -> "Court":
        used = {r.colour for r in self.regions} | {ln.colour for ln in self.lines}
        used |= {self.outside_colour, self.background_colour, *self.white_colours, *(m.colour for m in self.marks)}
        missing = sorted(used - set(self.palette))
        if missing:
            raise ValueError(f"court {self.name!r}: colours {missing} are not in the palette")
        return self

    # ---- geometry -------------------------------------------------------------------------------
    def contains(self, x: np.ndarray | float, y: np.ndarray | float, margin: float = 0.0) -> np.ndarray | bool:
        """True where (x, y) lies in the area a robot may stand on, shrunk by `margin` metres."""
        hx, hy = self.area_half_extent_m
        inside = (np.abs(np.asarray(x)) <= hx - margin) & (np.abs(np.asarray(y)) <= hy - margin)
        return bool(inside) if np.ndim(inside) == 0 else inside

    def painted_elements(self) -> list[tuple[str, str, list[np.ndarray], list[np.ndarray]]]:
        """(name, colour, exterior polygons, hole polygons) in painting order, mirrors expanded."""
        out: list[tuple[str, str, list[np.ndarray], list[np.ndarray]]] = []
        for region in self.regions:
            ext = [s.polygon() for s in region.shapes]
            holes = [s.polygon() for s in region.holes]
            out.append((region.name, region.colour, ext, holes))
            if region.mirror:
                out.append((region.name + " (mirrored)", region.colour, [-p for p in ext], [-p for p in holes]))
        for line in self.lines:
            poly = line.polygon()
            out.append((line.name, line.colour, [poly], []))
            if line.mirror:
                out.append((line.name + " (mirrored)", line.colour, [-poly], []))
        return out

    def white_polygons(self) -> list[WhitePolygon]:
        """Every white element as polygons. Elements may overlap; use white_edges() for true boundaries."""
        return [
            WhitePolygon(name=name, exteriors=ext, holes=holes)
            for name, colour, ext, holes in self.painted_elements()
            if colour in self.white_colours
        ]

    def raster(self, resolution_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Top-down (RGB float texture, white fraction, texel->court 3x3 transform), anti-aliased, cached."""
        key = ("raster", float(resolution_m))
        if key not in self._cache:
            self._cache[key] = _paint(self, float(resolution_m))
        return self._cache[key]

    def texel_to_court(self, resolution_m: float) -> np.ndarray:
        """3x3: texel (col, row, 1) -> court (x, y, 1); row 0 is +y, texel centres at integers."""
        hx, hy = self.floor_half_extent_m
        r = resolution_m
        return np.array([[r, 0.0, -hx + r / 2], [0.0, -r, hy - r / 2], [0.0, 0.0, 1.0]])

    def white_mask_topdown(self, resolution_m: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
        """(mask uint8 0/255 of everything white, texel->court 3x3 transform) over the modelled floor."""
        _, white, transform = self.raster(resolution_m)
        return ((white >= 0.5) * 255).astype(np.uint8), transform

    def white_edges(self, spacing_m: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
        """Points on the true boundary of the white area and unit normals pointing from white to not-white.

        Sampled on every white polygon's outline; a sample is kept only where the floor really
        changes colour across it (so overlaps of white elements leave no interior edges).
        """
        key = ("edges", float(spacing_m))
        if key in self._cache:
            return self._cache[key]
        probe = 0.02
        mask, transform = self.white_mask_topdown(self.texture_resolution_m)
        points, normals = [], []
        for wp in self.white_polygons():
            for ring, is_hole in [(p, False) for p in wp.exteriors] + [(p, True) for p in wp.holes]:
                p, n = _sample_outline(ring, spacing_m, outward=not is_hole)
                points.append(p)
                normals.append(n)
        pts = np.vstack(points)
        nrm = np.vstack(normals)
        outside = _lookup(mask, transform, pts + nrm * probe)
        inside = _lookup(mask, transform, pts - nrm * probe)
        keep = (outside == 0) & (inside > 0)
        self._cache[key] = (pts[keep], nrm[keep])
        return self._cache[key]

    def rgb(self, colour: str) -> tuple[int, int, int]:
        return tuple(int(c) for c in self.palette[colour])  # type: ignore[return-value]

    def mark_map(self, resolution_m: float) -> tuple[np.ndarray, np.ndarray]:
        """(int8 map: 1 + index of the mark painted at each texel, 0 none; texel->court 3x3) over the floor."""
        key = ("marks", float(resolution_m))
        if key not in self._cache:
            texture, _, transform = self.raster(resolution_m)
            labels = np.zeros(texture.shape[:2], np.int8)
            for index, mark in enumerate(self.marks):
                # Texels within a few levels of the mark's palette colour: the raster is anti-aliased at borders.
                close = np.abs(texture - np.array(self.rgb(mark.colour), np.float64)).max(axis=2) <= 4.0
                labels[close] = index + 1
            self._cache[key] = (labels, transform)
        return self._cache[key]


def _ellipse_arc(centre: Point, semi: tuple[float, float], start_deg: float, end_deg: float) -> np.ndarray:
    a, b = semi
    sweep = math.radians(end_deg - start_deg)
    n = max(8, int(math.ceil(abs(sweep) * max(a, b) / ARC_CHORD_M)))
    t = np.linspace(math.radians(start_deg), math.radians(end_deg), n + 1)
    return np.stack([centre[0] + a * np.cos(t), centre[1] + b * np.sin(t)], axis=1)


def _sample_outline(ring: np.ndarray, spacing: float, outward: bool) -> tuple[np.ndarray, np.ndarray]:
    """Points every `spacing` metres along a closed ring, with normals pointing out of the ring (or in)."""
    a = ring
    b = np.roll(ring, -1, axis=0)
    area2 = float(np.sum(a[:, 0] * b[:, 1] - b[:, 0] * a[:, 1]))
    pts, nrm = [], []
    for p, q in zip(a, b):
        d = q - p
        length = float(np.hypot(*d))
        if length < 1e-9:
            continue
        k = max(1, int(math.ceil(length / spacing)))
        s = (np.arange(k) + 0.5) / k
        pts.append(p + s[:, None] * d)
        u = d / length
        # For a counter-clockwise ring the outward normal is the edge direction turned clockwise.
        n = np.array([u[1], -u[0]]) if area2 > 0 else np.array([-u[1], u[0]])
        nrm.append(np.repeat((n if outward else -n)[None], k, axis=0))
    return np.vstack(pts), np.vstack(nrm)


def _lookup(mask: np.ndarray, texel_to_court: np.ndarray, xy: np.ndarray) -> np.ndarray:
    inv = np.linalg.inv(texel_to_court)
    col = np.rint(inv[0, 0] * xy[:, 0] + inv[0, 2]).astype(int)
    row = np.rint(inv[1, 1] * xy[:, 1] + inv[1, 2]).astype(int)
    ok = (col >= 0) & (col < mask.shape[1]) & (row >= 0) & (row < mask.shape[0])
    out = np.zeros(len(xy), np.uint8)
    out[ok] = mask[row[ok], col[ok]]
    return out


def _paint(court: Court, resolution_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    hx, hy = court.floor_half_extent_m
    width = int(round(2 * hx / resolution_m))
    height = int(round(2 * hy / resolution_m))
    transform = court.texel_to_court(resolution_m)
    inv = np.linalg.inv(transform)
    texture = np.empty((height, width, 3), np.float32)
    texture[:] = court.rgb(court.outside_colour)
    white = np.zeros((height, width), np.float32)
    shift = 4  # fixed-point bits of polygon vertices
    # Coverage by supersampling (cv2's LINE_AA fill inflates shapes by about half a texel, which moves
    # every edge outwards): 8x8 sub-samples for small elements, 4x4 for large areas to bound memory.
    fine_limit = 20_000_000

    def to_fixed(poly: np.ndarray, c0: int, r0: int, ss: int) -> np.ndarray:
        cols = inv[0, 0] * poly[:, 0] + inv[0, 2] - c0
        rows = inv[1, 1] * poly[:, 1] + inv[1, 2] - r0
        # Texel centre (c, r) covers [c - 0.5, c + 0.5); sub-sample centres sit at (c + 0.5) * ss - 0.5.
        pts = (np.stack([cols, rows], axis=1) + 0.5) * ss - 0.5
        return np.rint(pts * (1 << shift)).astype(np.int32)

    for _, colour, exteriors, holes in court.painted_elements():
        # Blend only inside the element's bounding box: most elements are thin lines.
        allpts = np.vstack(
            [np.column_stack([inv[0, 0] * p[:, 0] + inv[0, 2], inv[1, 1] * p[:, 1] + inv[1, 2]]) for p in exteriors])
        c0, r0 = np.maximum(np.floor(allpts.min(axis=0)).astype(int) - 1, 0)
        c1, r1 = np.minimum(np.ceil(allpts.max(axis=0)).astype(int) + 2, [width, height])
        if c1 <= c0 or r1 <= r0:
            continue
        if all(_is_axis_rect(p) for p in exteriors + holes):
            # Rectangles (the big floor areas) have exact separable coverage: no supersampling needed.
            a = np.zeros((r1 - r0, c1 - c0), np.float32)
            for poly in exteriors:
                np.maximum(a, _rect_coverage(poly, inv, c0, r0, c1, r1), out=a)
            for poly in holes:
                a *= 1.0 - _rect_coverage(poly, inv, c0, r0, c1, r1)
        else:
            ss = 8 if (r1 - r0) * (c1 - c0) * 64 <= fine_limit else 4
            fine = np.zeros(((r1 - r0) * ss, (c1 - c0) * ss), np.uint8)
            for poly in exteriors:
                cv2.fillPoly(fine, [to_fixed(poly, c0, r0, ss)], 255, lineType=cv2.LINE_8, shift=shift)
            for poly in holes:
                cv2.fillPoly(fine, [to_fixed(poly, c0, r0, ss)], 0, lineType=cv2.LINE_8, shift=shift)
            a = cv2.resize(fine, (c1 - c0, r1 - r0), interpolation=cv2.INTER_AREA).astype(np.float32) * (1.0 / 255.0)
        # Texels fully covered take the colour outright; only the anti-aliased rim needs blending.
        full = a >= 1.0
        rim_r, rim_c = np.nonzero((a > 0.0) & ~full)
        tex = texture[r0:r1, c0:c1]
        wh = white[r0:r1, c0:c1]
        rgb = np.asarray(court.rgb(colour), np.float32)
        is_white = 1.0 if colour in court.white_colours else 0.0
        np.copyto(tex, rgb, where=full[..., None])
        np.copyto(wh, is_white, where=full)
        ar = a[rim_r, rim_c]
        tex[rim_r, rim_c] += (rgb - tex[rim_r, rim_c]) * ar[:, None]
        wh[rim_r, rim_c] += (is_white - wh[rim_r, rim_c]) * ar
    return texture, white, transform


def _is_axis_rect(poly: np.ndarray) -> bool:
    if len(poly) != 4:
        return False
    xs, ys = np.unique(np.round(poly[:, 0], 9)), np.unique(np.round(poly[:, 1], 9))
    return len(xs) == 2 and len(ys) == 2


def _coverage_1d(lo: float, hi: float, start: int, stop: int) -> np.ndarray:
    """Fraction of each texel [c - 0.5, c + 0.5), c in start..stop-1, inside [lo, hi] (texel units)."""
    c = np.arange(start, stop, dtype=np.float64)
    return np.clip(np.minimum(c + 0.5, hi) - np.maximum(c - 0.5, lo), 0.0, 1.0)


def _rect_coverage(poly: np.ndarray, inv: np.ndarray, c0: int, r0: int, c1: int, r1: int) -> np.ndarray:
    cols = inv[0, 0] * poly[:, 0] + inv[0, 2]
    rows = inv[1, 1] * poly[:, 1] + inv[1, 2]
    cx = _coverage_1d(cols.min(), cols.max(), c0, c1)
    cy = _coverage_1d(rows.min(), rows.max(), r0, r1)
    return np.outer(cy, cx).astype(np.float32)


# ---- loading --------------------------------------------------------------------------------------
def _packaged(kind: str) -> Path:
    return Path(str(resources.files("courtloc.world") / kind))


def available_courts() -> list[str]:
    """Names of the courts shipped in world/courts/."""
    return sorted(p.stem for p in _packaged("courts").glob("*.json"))


def load_court(name_or_path: str | Path) -> Court:
    """A court by packaged name (see available_courts()) or by path to a court JSON file."""
    path = Path(name_or_path)
    if not (path.suffix == ".json" and path.is_file()):
        path = _packaged("courts") / f"{name_or_path}.json"
        if not path.is_file():
            raise ValueError(f"unknown court {str(name_or_path)!r}: expected one of {available_courts()} or a JSON path")
    return Court.model_validate(json.loads(path.read_text()))
