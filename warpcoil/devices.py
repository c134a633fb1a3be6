"""Assist devices placed in the parent vessel: the balloon of balloon-assisted
coiling (kernels/devices.py has its contact). Units mm, s.

The balloon is an analytic tube about an axis polyline rather than a second
refitted wp.Mesh: its surface is known in closed form at every station, its
radius per station is capped by that station's distance to the wall (so it
fills the vessel without ever cutting the wall, however irregular the lumen),
inflation is a single number per world, and its contact costs one pass over a
few dozen axis segments per node with no BVH refit.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from .kernels import devices as kernels
from .scene import SceneError
from .settings import BalloonSpec

STATION_SPACING_MM = 0.25  # the axis is resampled this finely; the radius is linear between stations


class DeviceError(SceneError):
    """A device that does not fit the vessel; the message names the key and the fix."""


def wall_distances_mm(wall, points_mm: np.ndarray) -> np.ndarray:
    """Signed distance (mm, > 0 inside the lumen) of each point to a WallMesh."""
    from .model import WallModel

    model = WallModel.create(wall.vertices_mm, wall.faces, wall.volume_mm3, "cpu")
    out = wp.zeros(len(points_mm), dtype=wp.float64, device="cpu")
    wp.launch(kernels.wall_distances, len(points_mm), device="cpu", inputs=[
        model.mesh.id, model.vertices, model.faces, wp.vec3d(*model.origin),
        wp.array(np.asarray(points_mm, np.float64), dtype=wp.vec3d, device="cpu"), out])
    return out.numpy()


def resample(polyline_mm: np.ndarray, spacing_mm: float = STATION_SPACING_MM) -> np.ndarray:
    """Points along the polyline at most ``spacing_mm`` apart, its vertices included."""
    out = [polyline_mm[0]]
    for a, b in zip(polyline_mm[:-1], polyline_mm[1:]):
        pieces = max(1, int(np.ceil(np.linalg.norm(b - a) / spacing_mm)))
        out.extend(a + (b - a) * (k / pieces) for k in range(1, pieces + 1))
    return np.asarray(out)


def balloon_geometry(spec: BalloonSpec, wall, source: str = "scene") -> tuple[np.ndarray, np.ndarray]:
    """(stations mm, capped radii mm): the axis resampled, each station's radius
    min(diameter/2, its wall distance). Raises DeviceError when the axis leaves
    the lumen or the balloon has no room (needs a wall)."""
    if wall is None:
        raise DeviceError(f"{source}: balloon: needs a [wall] (the vessel it is inflated in); fix: add [wall] or "
                          f"remove [balloon]")
    stations = resample(np.asarray(spec.axis_mm, np.float64))
    distance = wall_distances_mm(wall, stations)
    worst = int(np.argmin(distance))
    if distance[worst] <= 0.05 * spec.diameter_mm:
        raise DeviceError(
            f"{source}: balloon.axis: the point {np.round(stations[worst], 3).tolist()} is "
            f"{'outside the lumen' if distance[worst] <= 0 else 'against the wall'} (wall distance "
            f"{distance[worst]:.3f} mm); fix: move the axis onto the parent vessel's centreline")
    return stations, np.minimum(0.5 * spec.diameter_mm, distance)


def deflation(spec: BalloonSpec, time_s: float, deflate_from_s: float | None) -> float:
    """Inflation fraction (1 inflated, 0 deflated) at ``time_s``; deflation starts at
    ``deflate_from_s`` (None: not yet) and takes ``deflation_time_s``."""
    if deflate_from_s is None:
        return 1.0
    return float(np.clip(1.0 - (time_s - deflate_from_s) / spec.deflation_time_s, 0.0, 1.0))
