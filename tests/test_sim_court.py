"""Court models: packaged files load, geometry matches the fitted seed world, masks and edges agree."""
from __future__ import annotations

import json

import numpy as np
import pytest

from courtloc.world.court import available_courts, load_court


def test_packaged_courts_load_by_name():
    assert {"seed-gazebo", "robocon2025"} <= set(available_courts())
    for name in available_courts():
        court = load_court(name)
        assert court.name == name
        assert court.rings and all(r.z == pytest.approx(2.43) for r in court.rings)


def test_unknown_court_is_a_clear_error():
    with pytest.raises(ValueError, match="unknown court 'nowhere'"):
        load_court("nowhere")


def test_court_file_with_unknown_colour_names_the_colour(tmp_path):
    data = load_court("robocon2025").model_dump()
    data["lines"][0]["colour"] = "mauve"
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(data))
    with pytest.raises(ValueError, match="mauve"):
        load_court(path)


def test_court_json_path_loads_and_is_editable(tmp_path):
    data = load_court("robocon2025").model_dump()
    data["name"] = "edited"
    data["rings"] = [{"x": 6.0, "y": 0.0, "z": 2.43}]
    path = tmp_path / "edited.json"
    path.write_text(json.dumps(data))
    court = load_court(path)
    assert court.name == "edited" and court.rings[0].x == 6.0


def test_seed_court_numbers_follow_the_reference(seed_world):
    ref = json.loads(seed_world.read_text())["court"]
    court = load_court("seed-gazebo")
    arc = next(ln for ln in court.lines if ln.kind == "arc")
    assert arc.centre[0] == pytest.approx(ref["three_point"]["ellipse_centre_abs_x"])
    assert arc.semi_axes == pytest.approx((ref["three_point"]["semi_axis_x"], ref["three_point"]["semi_axis_y"]))
    mask, transform = court.white_mask_topdown(0.01)
    inv = np.linalg.inv(transform)

    def white_at(x: float, y: float) -> bool:
        col, row, _ = inv @ [x, y, 1.0]
        return bool(mask[int(round(row)), int(round(col))])

    # On the apex of the ellipse, on the key front line, the centre line and the outer white floor.
    apex = ref["three_point"]["ellipse_centre_abs_x"] - ref["three_point"]["semi_axis_x"]
    assert white_at(apex, 0.0) and white_at(-apex, 0.0)
    assert white_at(ref["key"]["front_line_abs_x"], 0.5) and white_at(-ref["key"]["front_line_abs_x"], -0.5)
    assert white_at(0.0, 2.0)
    assert white_at(8.5, 0.0) and white_at(0.0, -5.5)
    # Court floor between lines, and the arena beyond the white floor, are not white.
    assert not white_at(1.0, 1.0) and not white_at(apex + 0.1, 0.0)
    assert not white_at(ref["outer_white_floor"]["abs_x"] + 0.05, 0.0)


def test_white_edges_lie_on_mask_boundaries_with_outward_normals():
    court = load_court("seed-gazebo")
    points, normals = court.white_edges(0.02)
    assert len(points) > 1000
    assert np.allclose(np.linalg.norm(normals, axis=1), 1.0)
    mask, transform = court.white_mask_topdown(0.01)
    inv = np.linalg.inv(transform)

    def sample(xy):
        col = np.rint(inv[0, 0] * xy[:, 0] + inv[0, 2]).astype(int)
        row = np.rint(inv[1, 1] * xy[:, 1] + inv[1, 2]).astype(int)
        return mask[row, col]

    assert np.all(sample(points + 0.03 * normals) == 0)
    assert np.all(sample(points - 0.03 * normals) == 255)
    # The centre line's ends sit inside the white floor: no edge is reported there.
    assert not np.any((np.abs(points[:, 0]) < 0.02) & (np.abs(points[:, 1]) > 4.05) & (np.abs(points[:, 1]) < 4.1))


def test_contains_area_and_vectorised():
    court = load_court("robocon2025")
    assert court.contains(7.4, 3.9) and not court.contains(7.6, 0.0)
    assert not court.contains(7.4, 0.0, margin=0.2)
    np.testing.assert_array_equal(court.contains(np.array([0.0, 8.0]), np.array([0.0, 0.0])), [True, False])


def test_robocon_rings_sit_above_the_arc_centres():
    court = load_court("robocon2025")
    arcs = [ln for ln in court.lines if ln.kind == "arc"]
    centres = {(a.centre[0], a.centre[1]) for a in arcs} | {(-a.centre[0], -a.centre[1]) for a in arcs if a.mirror}
    assert {(r.x, r.y) for r in court.rings} == centres
