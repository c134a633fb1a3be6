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


def _axis_stations(device: str, axis_mm, wall, source: str, room_mm: float, room_key: str, room_value: float
                   ) -> tuple[np.ndarray, np.ndarray]:
    """A device's axis resampled (stations, mm) and each station's wall distance (mm). Raises
    DeviceError naming ``{device}.axis`` when the axis has no length or leaves the lumen, and
    ``{device}.{room_key}`` (its value ``room_value``) when the device needs more than the wall
    distance ``room_mm`` somewhere on an axis inside the lumen."""
    axis = np.asarray(axis_mm, np.float64)
    if not np.linalg.norm(np.diff(axis, axis=0), axis=1).sum() > 0.0:
        raise DeviceError(f"{source}: {device}.axis: its points {np.round(axis, 3).tolist()} coincide: the axis has "
                          "no length; fix: give points along the parent vessel's centreline")
    stations = resample(axis)
    distance = wall_distances_mm(wall, stations)
    worst = int(np.argmin(distance))
    point = np.round(stations[worst], 3).tolist()
    if distance[worst] <= 0.0:
        raise DeviceError(f"{source}: {device}.axis: the point {point} is outside the lumen (wall distance "
                          f"{distance[worst]:.3f} mm); fix: move the axis onto the parent vessel's centreline")
    if distance[worst] <= room_mm:
        raise DeviceError(f"{source}: {device}.{room_key}: {room_value:g} mm needs more than the "
                          f"{distance[worst]:.3f} mm between the axis and the wall at {point}; fix: a "
                          f"{room_key} that fits the vessel there, or move the axis onto its centreline")
    return stations, distance


def balloon_geometry(spec: BalloonSpec, wall, source: str = "scene") -> tuple[np.ndarray, np.ndarray]:
    """(stations mm, capped radii mm): the axis resampled, each station's radius
    min(diameter/2, its wall distance). Raises DeviceError when the axis leaves
    the lumen or the balloon has no room (needs a wall)."""
    if wall is None:
        raise DeviceError(f"{source}: balloon: needs a [wall] (the vessel it is inflated in); fix: add [wall] or "
                          f"remove [balloon]")
    stations, distance = _axis_stations("balloon", spec.axis_mm, wall, source, 0.05 * spec.diameter_mm,
                                        "diameter_mm", spec.diameter_mm)
    return stations, np.minimum(0.5 * spec.diameter_mm, distance)


def deflation(spec: BalloonSpec, time_s: float, deflate_from_s: float | None) -> float:
    """Inflation fraction (1 inflated, 0 deflated) at ``time_s``; deflation starts at
    ``deflate_from_s`` (None: not yet) and takes ``deflation_time_s``."""
    if deflate_from_s is None:
        return 1.0
    return float(np.clip(1.0 - (time_s - deflate_from_s) / spec.deflation_time_s, 0.0, 1.0))


def _frames(stations: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit tangents and two normals per station, parallel-transported along the axis."""
    tangents = np.gradient(stations, axis=0)
    tangents /= np.linalg.norm(tangents, axis=1, keepdims=True)
    helper = np.eye(3)[int(np.argmin(np.abs(tangents[0])))]
    normal = np.cross(tangents[0], helper)
    normal /= np.linalg.norm(normal)
    normals = [normal]
    for t0, t1 in zip(tangents[:-1], tangents[1:]):
        n = normals[-1] - (normals[-1] @ t1) * t1  # transport: remove the new tangent's component
        normals.append(n / np.linalg.norm(n))
    normals = np.asarray(normals)
    return tangents, normals, np.cross(tangents, normals)


def stent_struts(spec, wall, source: str = "scene") -> tuple[np.ndarray, np.ndarray]:
    """(starts, ends) of the stent's struts, mm: a diamond lattice of closed cells
    (axial and circumferential diagonals ≈ ``cell_size_mm``) on the tube about the
    axis, apposed to the wall (radius = station wall distance − strut radius).
    Raises DeviceError when the axis leaves the lumen or the stent is smaller than
    the vessel (it would not appose)."""
    if wall is None:
        raise DeviceError(f"{source}: stent: needs a [wall] (the vessel it is deployed in); fix: add [wall] or "
                          f"remove [stent]")
    stations, distance = _axis_stations("stent", spec.axis_mm, wall, source, spec.strut_diameter_mm,
                                        "strut_diameter_mm", spec.strut_diameter_mm)
    if 2.0 * distance.max() > spec.diameter_mm:
        raise DeviceError(
            f"{source}: stent.diameter_mm = {spec.diameter_mm:g} mm is smaller than the vessel "
            f"({2.0 * distance.max():.2f} mm across at {np.round(stations[int(np.argmax(distance))], 3).tolist()}): "
            f"it would not appose; fix: diameter_mm ≥ {2.0 * distance.max():.2f}, or a shorter axis")
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(stations, axis=0), axis=1))])
    radius = distance - 0.5 * spec.strut_diameter_mm
    tangents, normals, binormals = _frames(stations)
    around = max(3, int(round(2.0 * np.pi * float(np.median(radius)) / spec.cell_size_mm)))
    rings = max(2, int(arc[-1] // (0.5 * spec.cell_size_mm)) + 1)

    def node(i: int, j: int) -> np.ndarray:
        s = min(j * 0.5 * spec.cell_size_mm, arc[-1])
        k = min(int(np.searchsorted(arc, s, side="right")) - 1, len(arc) - 2)
        f = (s - arc[k]) / (arc[k + 1] - arc[k])
        centre = (1 - f) * stations[k] + f * stations[k + 1]
        r = (1 - f) * radius[k] + f * radius[k + 1]
        angle = 2.0 * np.pi * (i + 0.5 * (j % 2)) / around
        n, b = normals[k], binormals[k]
        return centre + r * (np.cos(angle) * n + np.sin(angle) * b)

    starts, ends = [], []
    for j in range(rings - 1):
        for i in range(around):
            step = -1 if j % 2 == 0 else 1  # to the two nodes of the next ring half a cell around
            for other in (i, i + step):
                starts.append(node(i, j))
                ends.append(node(other % around, j + 1))
    return np.asarray(starts), np.asarray(ends)


def device_report(scene, anatomy, frames: list, deflate_from_s: float | None) -> dict | None:
    """result.json's ``device``: kind, geometry and state over time (None without one). A balloon's
    ``deflation_started_s`` is None where the run ended before its deflation started."""
    if scene.stent is not None:
        starts, ends, _ = anatomy.stent
        stent = scene.stent
        return dict(kind="stent", nominal_diameter_mm=stent.diameter_mm, cell_size_mm=stent.cell_size_mm,
                    strut_diameter_mm=stent.strut_diameter_mm, axis_mm=[list(map(float, p)) for p in stent.axis_mm],
                    struts=int(len(starts)), strut_length_mm=float(np.linalg.norm(ends - starts, axis=1).sum()),
                    state_over_time="fixed: in place before the first coil and left there")
    if scene.balloon is None:
        return None
    _, radii = anatomy.balloon
    balloon = scene.balloon
    if deflate_from_s is not None and (not frames or deflate_from_s > frames[-1].time_s):
        deflate_from_s = None  # (a deflate_at_s the run did not reach)
    return dict(kind="balloon", nominal_diameter_mm=balloon.diameter_mm,
                axis_mm=[list(map(float, p)) for p in balloon.axis_mm],
                inflated_radius_min_mm=float(radii.min()), inflated_radius_max_mm=float(radii.max()),
                deflation_started_s=deflate_from_s, deflation_time_s=balloon.deflation_time_s,
                inflation_over_time=[[f.time_s, f.balloon_inflation] for f in frames])


class ImplicitDeviceStiffness:
    """The balloon's and the stent's contact stiffness in the implicit step's
    matrix M + dt² H (kernels/devices.py: Gauss–Newton k n nᵀ per contact, as the
    wall's): a balloon contact adds to its node's diagonal block, a strut contact
    k w wᵀ ⊗ n nᵀ to the two nodes of its coil edge (within the band)."""

    def __init__(self, model):
        n, dev = model.node_count, model.device
        self._strut_blocks = tuple(wp.zeros(n, dtype=wp.mat33d, device=dev) for _ in range(3)) \
            if model.has_stent else None

    def add(self, solver, state, running: wp.array, dt: float, diag: wp.array, diag_exact: wp.array,
            upper1: wp.array, x_end: wp.array | None = None) -> None:
        """Add dt² × the device stiffness at ``state`` to the assembled blocks; with ``x_end``
        (the predicted end, mm) each contact's chord stiffness (kernels/chord.py)."""
        chord = int(x_end is not None)
        x_end = state.x if x_end is None else x_end
        m, dev, n, c = solver.model, solver.model.device, solver.model.node_count, solver.model.contact
        if solver.has_balloon:
            wp.launch(kernels.balloon_stiffness, n, device=dev, inputs=[
                state.x, state.free, m.fixed, m.world_of, running, m.node_radius, m.contact_share, m.balloon_stations,
                m.balloon_cap_radius, m.balloon_first, m.balloon_count, m.balloon_inflation, c.p0_uN, c.c0_mm,
                solver.contact_u_linear, dt, diag, diag_exact, x_end, chord])
        if solver.has_stent:
            start, end, cross = self._strut_blocks
            wp.launch(kernels.strut_stiffness, n, device=dev, inputs=[
                state.x, state.free, m.has_next, m.world_of, running, m.node_radius, solver._strut_grid.id,
                m.strut_start, m.strut_end, m.strut_radius_mm, solver._strut_query_mm, c.p0_uN, c.c0_mm,
                solver.contact_u_linear, start, end, cross, x_end, chord])
            wp.launch(kernels.add_strut_stiffness, n, device=dev, inputs=[
                m.has_next, start, end, cross, dt, diag, diag_exact, upper1])
