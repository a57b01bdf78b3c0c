"""Shared set-up of the localizer tests: the seed twin's court, camera, localizer and rendered frames."""
from __future__ import annotations

from courtloc.localizer.geometric import GeometricLocalizer
from courtloc.localizer.projection import FloorProjector
from courtloc.world.camera import load_camera
from courtloc.world.court import load_court


def twin_setup(poses):  # noqa: ANN001, ANN201
    """(court, camera, localizer, projector, {pose: radial-scan hits of the rendered frame})."""
    from courtloc.sim.edges import scan_hits
    from courtloc.sim.render import Renderer

    court, camera = load_court("seed-gazebo"), load_camera("seed-gazebo")
    localizer = GeometricLocalizer(court, camera)
    renderer = Renderer(court, camera)
    projector = FloorProjector(camera, localizer.config.edge_offset_px, localizer.config.max_range_m)
    return court, camera, localizer, projector, {pose: scan_hits(renderer.render(pose)) for pose in poses}
