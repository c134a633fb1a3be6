"""Checks of a scene's set-up before the first step (one clear message each).

* The catheter tip must lie inside the lumen (the wall's winding number, via
  its ``wp.Mesh``), at least the coil's radius from the wall, and so must a given
  catheter centerline lie inside: otherwise :class:`SetupError` naming the scene
  file, the key and the fix (exit 2).
* Warnings, for a run that may go on but will likely disappoint: a catheter
  pointing away from the sac, a coil whose segments make it more than 1 % shorter than its
  length (coarse on its loops), coils whose volume exceeds MAX_PACKING of the
  sac, a loop far larger than the sac, a given step that would take hours or that
  skips contacts.
* A balloon that would deflate only after the time limit is refused (SetupError).

Units mm, s.
"""

from __future__ import annotations

import math

import numpy as np
import warp as wp

from .sac import side_in_doubt
from .settings import Scene, coarse_segment_coils, fine_segment_coils

MAX_PACKING = 0.5  # coil volume / sac volume above which a set-up is warned about (clinical: 20–35 %)
MAX_LOOP_OVER_SAC = 2.0  # loop diameter / the sac's equivalent-sphere diameter warned about
CENTERLINE_SAMPLE_MM = 0.1  # spacing of the checked points along a catheter centerline
MAX_LENGTH_SHORTFALL = 0.01  # a coil's chords this much shorter than its length_mm is warned about
MAX_STEPS = 1e7  # a given dt_s taking more steps than this to the time limit is warned about (hours of run time)
MAX_ADVANCE_PER_C0 = 2.0  # a given implicit dt_s moving the pusher more than this × c0 a step is warned about


class SetupError(ValueError):
    """A set-up that cannot be deployed; the message names the file, the key and the fix."""


@wp.kernel
def _depth_inside(mesh: wp.uint64, points: wp.array(dtype=wp.vec3), max_distance: float,
                  depth: wp.array(dtype=float)):
    """Distance of each point to the surface, > 0 inside (winding number), < 0 outside."""
    i = wp.tid()
    query = wp.mesh_query_point_sign_winding_number(mesh, points[i], max_distance)
    if query.result:
        closest = wp.mesh_eval_position(mesh, query.face, query.u, query.v)
        depth[i] = -query.sign * wp.length(points[i] - closest)
    else:
        depth[i] = -max_distance


def depth_inside_wall_mm(wall, points_mm: np.ndarray, device=None) -> np.ndarray:
    """Per point: its distance to the wall (mm), positive inside the lumen, negative
    outside (the sign from the winding number of a ``wp.Mesh``, robust near seams).
    ``wall``: a :class:`warpcoil.wall.WallMesh`."""
    origin = 0.5 * (wall.vertices_mm.min(axis=0) + wall.vertices_mm.max(axis=0))
    points = np.atleast_2d(np.asarray(points_mm, dtype=np.float64)) - origin
    mesh = wp.Mesh(points=wp.array((wall.vertices_mm - origin).astype(np.float32), dtype=wp.vec3, device=device),
                   indices=wp.array(np.asarray(wall.faces, dtype=np.int32).ravel(), dtype=wp.int32, device=device),
                   support_winding_number=True)
    span = float(np.ptp(wall.vertices_mm, axis=0).max())
    max_distance = 10.0 * span + float(np.abs(points).max(initial=0.0))
    out = wp.zeros(len(points), dtype=float, device=device)
    wp.launch(_depth_inside, len(points), device=device, inputs=[
        mesh.id, wp.array(points.astype(np.float32), dtype=wp.vec3, device=device), max_distance, out])
    return out.numpy().astype(np.float64)


def _polyline_samples(points: np.ndarray, spacing_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Points every ≤ spacing along a polyline, and the index of the segment each lies on."""
    samples, segment = [], []
    for k, (a, b) in enumerate(zip(points[:-1], points[1:])):
        count = max(1, math.ceil(np.linalg.norm(b - a) / spacing_mm))
        t = np.linspace(0.0, 1.0, count + 1)[:-1, None]
        samples.append(a + t * (b - a))
        segment += [k] * count
    samples.append(points[-1:])
    segment.append(len(points) - 2)
    return np.vstack(samples), np.array(segment)


def _vec(values) -> str:
    return "[" + ", ".join(f"{v:.3g}" for v in np.round(np.asarray(values, dtype=float), 4) + 0.0) + "]"


def check_catheter(scene: Scene, anatomy, device=None) -> list[str]:
    """Raise SetupError for a tip (or centerline) outside the lumen, or a tip closer to the wall than the
    coil's radius; warn when the catheter points away from the sac. ``anatomy``: the resolved Anatomy."""
    wall = anatomy.wall
    if wall is None:
        return []
    catheter = anatomy.catheter
    tip = np.asarray(catheter.tip_mm, dtype=np.float64)
    depth = float(depth_inside_wall_mm(wall, tip, device)[0])
    low, high = wall.vertices_mm.min(axis=0), wall.vertices_mm.max(axis=0)
    if depth <= 0.0:
        if catheter.placement == "neck":
            raise SetupError(
                f"{scene.where}: catheter.depth_mm = {catheter.depth_mm:g} puts the tip at {_vec(tip)} mm, "
                f"{-depth:.3g} mm outside the lumen; fix: give a depth that stays inside the sac ("
                + (f"less than {catheter.depth_mm:g} mm: the sac is shallower there along the neck normal"
                   if catheter.depth_mm > 0.0 else "above 0 mm: 0 is the neck's centroid, below it the parent vessel")
                + ", or check neck.sac_point_mm picks the sac's side)")
        raise SetupError(
            f"{scene.where}: catheter.tip {_vec(tip)} mm is {-depth:.3g} mm outside the lumen (the wall spans "
            f"{_vec(low)} to {_vec(high)} mm); fix: move catheter.tip inside the wall, a little inside the sac")
    if catheter.centerline_mm is not None:
        line = np.asarray(catheter.centerline_mm, dtype=np.float64)
        samples, segment = _polyline_samples(line, CENTERLINE_SAMPLE_MM)
        outside = np.flatnonzero(depth_inside_wall_mm(wall, samples, device) <= 0.0)
        if outside.size:
            k = int(segment[outside[0]])
            raise SetupError(
                f"{scene.where}: catheter.centerline leaves the lumen at {_vec(samples[outside[0]])} mm, between "
                f"points {k} and {k + 1}; fix: route the centerline inside the vessel and sac (every point and the "
                "straight pieces between them)")
    radius = 0.5 * max(c.wire_diameter_mm for c in scene.coils)
    if depth < radius:  # (a warning once: the wall then shoved every node leaving the catheter, the whole push)
        key = "catheter.depth_mm" if catheter.placement == "neck" else "catheter.tip"
        raise SetupError(f"{scene.where}: {key}: the tip {_vec(tip)} mm is {depth:.3g} mm from the wall, less than "
                         f"the coil's radius d/2 = {radius:.3g} mm: the coil would leave the catheter inside the wall "
                         "(and a catheter's own wall is thicker still); fix: "
                         + (f"a catheter.depth_mm that puts the tip at least {radius - depth:.2g} mm further from "
                            "the wall" if catheter.placement == "neck" else
                            f"move the tip at least {radius - depth:.2g} mm further into the lumen"))
    warnings = []
    centre = _sac_centre_mm(anatomy)
    direction = np.asarray(catheter.direction, dtype=np.float64)
    to_centre = centre - tip
    if np.dot(direction, to_centre) < 0.0:
        angle = math.degrees(math.acos(np.clip(np.dot(direction, to_centre) / max(np.linalg.norm(to_centre), 1e-12),
                                               -1.0, 1.0)))
        warnings.append(f"{scene.where}: catheter direction {_vec(direction)} points away from the sac (at "
                        f"{angle:.0f}° to the line from the tip to the sac's centre {_vec(centre)} mm): the coil will "
                        "first run into the wall next to the tip; check catheter.direction (or catheter.angle_deg)")
    return warnings


def balloon_gap_mm(anatomy, point_mm: np.ndarray, radius_mm: float) -> float:
    """Gap (mm) between a sphere of ``radius_mm`` at ``point_mm`` and the inflated balloon (< 0:
    overlapping; inf without a balloon), as the steps' kernels/devices.balloon_gap takes it."""
    from .kernels import devices

    if anatomy.balloon is None:
        return math.inf
    stations, radii = (np.asarray(a, dtype=np.float64) for a in anatomy.balloon)
    gaps = wp.zeros(1, dtype=wp.float64, device="cpu")
    wp.launch(devices.point_balloon_gaps, 1, device="cpu", inputs=[
        wp.array(np.asarray(point_mm, dtype=np.float64).reshape(1, 3), dtype=wp.vec3d, device="cpu"),
        float(radius_mm), wp.array(stations, dtype=wp.vec3d, device="cpu"),
        wp.array(radii, dtype=wp.float64, device="cpu"), len(stations), gaps])
    return float(gaps.numpy()[0])


def check_balloon(scene: Scene, anatomy) -> None:
    """Raise SetupError for a catheter tip within the coil's radius of the inflated balloon: the
    coil would leave the catheter inside it and be squeezed out (measured: push force −305 mN,
    stretching 58 565 nJ, reported completed)."""
    tip = np.asarray(anatomy.catheter.tip_mm, dtype=np.float64)
    radius = 0.5 * max(c.wire_diameter_mm for c in scene.coils)
    gap = balloon_gap_mm(anatomy, tip, radius)
    if gap < 0.0:
        key = "catheter.depth_mm" if anatomy.catheter.placement == "neck" else "catheter.tip"
        raise SetupError(
            f"{scene.where}: balloon.axis: the catheter tip {_vec(tip)} mm lies inside the inflated balloon "
            f"({-gap:.3g} mm within its surface, with the coil's radius d/2 = {radius:.3g} mm): the coil would leave "
            f"the catheter inside it; fix: end the balloon's axis farther from the tip (its end caps are round, of "
            f"its radius) or move the tip out of it ({key})")


def check_deflation(scene: Scene) -> None:
    """Raise SetupError for a ``balloon.deflate_at_s`` whose deflation would not end within the run's
    time limit: a run ends only once its balloon has deflated, so it could only time out (and the
    deflation it names would never have happened)."""
    from .deploy import time_limit_s
    from .preshape import rest_centerline

    balloon = scene.balloon
    if balloon is None or balloon.deflate_at_s is None:
        return
    lengths_mm = [float(np.linalg.norm(np.diff(rest_centerline(c), axis=0), axis=1).sum()) for c in scene.coils]
    limit_s = time_limit_s(scene.simulation, lengths_mm)  # (the coils' chords, as the run takes them)
    deflated_s = balloon.deflate_at_s + balloon.deflation_time_s
    if deflated_s <= limit_s:
        return
    limit = (f"simulation.max_time_s = {limit_s:g} s" if scene.simulation.max_time_s is not None else
             f"the default time limit (the push time + 2 s = {limit_s:.3g} s)")
    earliest = limit_s - balloon.deflation_time_s
    raise SetupError(f"{scene.where}: balloon.deflate_at_s = {balloon.deflate_at_s:g} s: the balloon would be "
                     f"deflated only at {deflated_s:.3g} s (with deflation_time_s = {balloon.deflation_time_s:g} s), "
                     f"after {limit}, and a run ends only once its balloon has deflated, so it could only time out; "
                     "fix: " + (f"deflate_at_s = {earliest:.3g} or less, or " if earliest > 0.0 else "")
                     + f"max_time_s = {deflated_s + 2.0:.3g} or more (or leave deflate_at_s out: the balloon then "
                     "deflates when the last coil detaches)")


def check_sac_side(scene: Scene, anatomy) -> list[str]:
    """Warn when only the pieces' sizes told the sac's side of the neck (no flat vessel cap, no
    neck.sac_point_mm) and the other piece is not small: a parent vessel larger than the sac is
    then taken as the sac (a helper's curved tube: everything herniated, 0 % packing, no word)."""
    sac = anatomy.sac
    if not side_in_doubt(sac):
        return []
    return [f"{scene.where}: neck: the wall has no flat vessel cap to tell the sac's side of the neck, so the larger "
            f"piece ({sac.volume_mm3:.4g} mm³) is taken as the sac, the other being {sac.neck.other_volume_mm3:.4g} "
            "mm³; if the sac is the other, give neck.sac_point_mm (a point inside the sac)"]


def _sac_centre_mm(anatomy) -> np.ndarray:
    import trimesh

    if anatomy.sac is not None:
        return np.asarray(anatomy.sac.closed_surface.center_mass)
    wall = anatomy.wall
    return np.asarray(trimesh.Trimesh(wall.vertices_mm, wall.faces, process=False).center_mass)


def check_wall_bodies(scene: Scene, anatomy) -> list[str]:
    """A warning when the wall mesh holds more than one separate closed body (a lumen is one): the
    sac volume, and so the packing density, counts them all, and a body inside the lumen, wound as
    read, reads as outside it rather than as an obstacle."""
    wall = anatomy.wall
    volumes = wall.body_volumes_mm3 if wall is not None else ()
    if len(volumes) < 2:
        return []
    shown = ", ".join(f"{v:.3g}" for v in volumes[:4]) + (", …" if len(volumes) > 4 else "")
    return [f"{scene.where}: wall.mesh {wall.source}: the surface has {len(volumes)} separate closed bodies "
            f"(signed volumes {shown} mm³) where a lumen is one: the sac volume and packing density count them all, "
            "and a body inside the lumen reads as outside it; fix: keep only the lumen surface in the file (in a "
            "mesh editor: separate by loose parts, delete the others)"]


def check_capacity(scene: Scene, sac_volume_mm3: float | None) -> list[str]:
    """Warnings for coils that cannot fit: volume over MAX_PACKING of the sac, a loop
    over MAX_LOOP_OVER_SAC × the sac's equivalent-sphere diameter."""
    if not sac_volume_mm3:
        return []
    warnings = []
    volume = sum(math.pi * (c.wire_diameter_mm / 2.0) ** 2 * c.length_mm for c in scene.coils)
    if volume > MAX_PACKING * sac_volume_mm3:
        stall = scene.simulation.stall_packing * sac_volume_mm3
        filled, at_mm = 0.0, 0.0
        for coil in scene.coils:  # the deployed length at which the sac holds stall_packing
            area = math.pi * (coil.wire_diameter_mm / 2.0) ** 2
            take = min(coil.length_mm, max(stall - filled, 0.0) / area)
            filled, at_mm = filled + take * area, at_mm + take
        when = (f"; the run will end as jammed (stalled) when the coil in the sac fills "
                f"{100 * scene.simulation.stall_packing:.0f} % of it, after about {at_mm:.0f} mm"
                if filled >= stall * (1 - 1e-9) else "")
        warnings.append(
            f"{scene.where}: the coils' volume {volume:.3g} mm³ is {100 * volume / sac_volume_mm3:.0f} % of the "
            f"sac's {sac_volume_mm3:.3g} mm³ (clinical packing is 20–35 %; above {100 * MAX_PACKING:.0f} % the sac "
            f"cannot hold them){when}; use shorter coils (coil.length_mm)")
    sac_diameter = (6.0 * sac_volume_mm3 / math.pi) ** (1.0 / 3.0)
    for k, coil in enumerate(scene.coils):
        if coil.loop_diameter_mm > MAX_LOOP_OVER_SAC * sac_diameter:
            warnings.append(
                f"{scene.where}: coil[{k}].loop_diameter_mm = {coil.loop_diameter_mm:g} is "
                f"{coil.loop_diameter_mm / sac_diameter:.1f}× the sac's size ({sac_diameter:.2g} mm, the diameter "
                "of a sphere of its volume): the coil cannot form its loops; choose a loop about the sac's size")
    return warnings


def check_coil_lengths(scene: Scene) -> list[str]:
    """Warnings for coils whose segments sample their pre-shape so coarsely that the chords (the
    discrete coil) fall more than MAX_LENGTH_SHORTFALL short of ``length_mm``."""
    from .preshape import rest_centerline

    warnings = []
    for k, coil in enumerate(scene.coils):
        rest = rest_centerline(coil)
        chords_mm = float(np.linalg.norm(np.diff(rest, axis=0), axis=1).sum())
        short = 1.0 - chords_mm / coil.length_mm
        if short > MAX_LENGTH_SHORTFALL:
            fine_mm = 0.95 * coil.l0 * math.sqrt(MAX_LENGTH_SHORTFALL / short)  # the shortfall goes as l0²
            warnings.append(f"{scene.where}: coil[{k}]: its {len(rest) - 1} segments of {coil.l0:g} mm sample the "
                            f"pre-shape's loops coarsely: as chords they make the coil {100 * short:.1f} % shorter "
                            f"than length_mm ({chords_mm:.4g} of {coil.length_mm:g} mm), and its deployed length and "
                            f"packing density with it; fix: segment_length_mm = {fine_mm:.2g} or less keeps it within "
                            f"{100 * MAX_LENGTH_SHORTFALL:g} %")
    return warnings


def check_porous(scene: Scene, anatomy) -> None:
    """Raise SetupError when ``[output] porous`` asks for more than MAX_POROUS_VOXELS voxels
    (the field is computed after the run: refused before it, not after)."""
    from .porous import MAX_POROUS_VOXELS, porous_grid_shape, porous_surface, porous_voxel_mm

    surface = porous_surface(anatomy.sac, anatomy.wall) if scene.output.porous else None
    if surface is None:
        return
    vertices = surface[0]
    h = porous_voxel_mm(scene.output.porous_voxel_mm, [c.d for c in scene.coils])
    count = math.prod(porous_grid_shape(vertices, h))
    if count > MAX_POROUS_VOXELS:
        span = np.ptp(vertices, axis=0)
        coarser = (float(np.prod(span)) / MAX_POROUS_VOXELS) ** (1.0 / 3.0) * 1.05
        raise SetupError(f"{scene.where}: output.porous_voxel_mm: voxels of {h:g} mm make {count:.3g} over the "
                         f"sac's bounding box ({_vec(span)} mm), more than {MAX_POROUS_VOXELS:.0e}; fix: "
                         f"porous_voxel_mm = {coarser:.2g} or more")


def check_regions(scene: Scene, anatomy) -> None:
    """Raise SetupError for a given ``[regions] voxel_mm`` that makes more than MAX_REGION_VOXELS
    voxels over the sac's bounding box, or fewer than MIN_VOXELS_ACROSS across the neck band, the
    boundary band or the sac's narrowest extent (the densities are computed after the run: refused before it)."""
    from .sac import MAX_REGION_VOXELS, MIN_VOXELS_ACROSS

    h, regions = scene.regions.voxel_mm, scene.regions
    if h is None or anatomy.sac is None:
        return
    vertices = np.asarray(anatomy.sac.closed_surface.vertices, dtype=np.float64)
    span = np.ptp(vertices, axis=0)
    count = math.prod(int(n) + 2 for n in np.ceil(span / h))
    if count > MAX_REGION_VOXELS:
        coarser = (float(np.prod(span)) / MAX_REGION_VOXELS) ** (1.0 / 3.0) * 1.05
        raise SetupError(f"{scene.where}: regions.voxel_mm: voxels of {h:g} mm make {count:.3g} over the sac's "
                         f"bounding box ({_vec(span)} mm), more than {MAX_REGION_VOXELS:.0e}; fix: voxel_mm = "
                         f"{coarser:.2g} or more (or remove it: the default, d_min/4, is capped)")
    d_max = max(c.wire_diameter_mm for c in scene.coils)
    lengths = {"neck_band_mm": 4.0 * d_max if regions.neck_band_mm is None else regions.neck_band_mm,
               "boundary_mm": 2.0 * d_max if regions.boundary_mm is None else regions.boundary_mm,
               "the sac's narrowest extent": float(span.min())}
    name, thinnest = min(lengths.items(), key=lambda item: item[1])
    if h * MIN_VOXELS_ACROSS > thinnest:
        raise SetupError(f"{scene.where}: regions.voxel_mm: voxels of {h:g} mm are too coarse to resolve the "
                         f"regions: {name} = {thinnest:.3g} mm is less than {MIN_VOXELS_ACROSS} voxels across; fix: "
                         f"voxel_mm = {thinnest / MIN_VOXELS_ACROSS:.2g} or less (the default is d_min/4 = "
                         f"{0.25 * min(c.wire_diameter_mm for c in scene.coils):.2g} mm)")


def check_wall_field(scene: Scene, anatomy, extent: tuple) -> None:
    """Raise SetupError when ``[contact] wall_voxel_mm`` (with wall_query "sdf") has the wall field's faces
    propose more than MAX_CANDIDATE_TILES tiles (the field is built before the first step: an int32 overflow
    or memory beyond reach). ``extent``: the field's (band, region), solver.wall_field_extent."""
    from .wall_field import MAX_CANDIDATE_TILES, candidate_tiles

    if scene.contact.wall_query != "sdf" or anatomy.wall is None:
        return
    vertices = anatomy.wall.vertices_mm
    origin = 0.5 * (vertices.min(axis=0) + vertices.max(axis=0))  # the wall's frame (model.WallModel)
    band, (centre, radius) = extent
    local, region = vertices - origin, (centre - origin, radius)
    h = scene.contact.wall_voxel_mm
    count = candidate_tiles(local, anatomy.wall.faces, band, h, region)
    if count <= MAX_CANDIDATE_TILES:
        return
    coarser = h * (count / MAX_CANDIDATE_TILES) ** (1.0 / 3.0)  # (the count goes as ~1/h³)
    while candidate_tiles(local, anatomy.wall.faces, band, coarser, region) > MAX_CANDIDATE_TILES:
        coarser *= 1.05
    raise SetupError(f"{scene.where}: contact.wall_voxel_mm: voxels of {h:g} mm make the wall field's faces propose "
                     f"{count:.3g} tiles of 8³ voxels, more than {MAX_CANDIDATE_TILES:.0e}; fix: wall_voxel_mm = "
                     f"{math.ceil(coarser * 1e4) / 1e4:g} or more (the default is 0.04)")


def check_integrator(scene: Scene, step_bound_s: float) -> list[str]:
    """Warnings for an implicit scene: a ``dt_s`` within the explicit stability bound
    (``step_bound_s``, s: a step the reference takes as it is, at ~3× the cost per step, the seed
    case ~300 against ~100 µs, as a scene written for the reference when it was the default
    would give), segments below d/2 (outside its validated range: a released coil gains energy)
    or above 2d (its accuracy not measured there), and wall friction (its push force is the
    reference's only at tiny steps)."""
    sim = scene.simulation
    if sim.integrator != "implicit":
        return []
    warnings = []
    if sim.dt_s is not None and sim.dt_s <= step_bound_s:
        warnings.append(f"{scene.where}: simulation.dt_s = {sim.dt_s:g} s is within the explicit step bound "
                        f"({step_bound_s:.3g} s) on the implicit step (the default integrator), which gains nothing "
                        f"there and costs ~3× a symplectic step; add integrator = \"symplectic\" for the reference, or "
                        f"remove dt_s for the implicit step's own (set by accuracy)")
    validated = "on the implicit step, which is validated for d/2 ≤ l0 ≤ 2d"
    for k in fine_segment_coils(scene.coils)[:1]:
        coil = scene.coils[k]
        warnings.append(f"{scene.where}: coil[{k}].segment_length_mm = {coil.l0:g} mm is below d/2 = "
                        f"{0.5 * coil.d:g} mm {validated}: below it a released coil gains energy at its free ends "
                        "and the run may fail (docs/FORMULATION.md \"Implicit step: segments shorter than d/2\"); "
                        "add integrator = \"symplectic\" for such segments")
    for k in coarse_segment_coils(scene.coils)[:1]:
        coil = scene.coils[k]
        warnings.append(f"{scene.where}: coil[{k}].segment_length_mm = {coil.l0:g} mm is above 2d = "
                        f"{2.0 * coil.d:g} mm {validated} (`warpcoil bench accuracy`'s range): it runs, but its error "
                        f"against the reference is not measured there; fix: segment_length_mm ≤ {2.0 * coil.d:g}, or "
                        "integrator = \"symplectic\"")
    if scene.contact.friction_wall > 0.0:
        warnings.append(f"{scene.where}: contact.friction_wall on the implicit step: its "
                        f"impacts are inelastic, so the coil lies on the wall where the reference's bounces, and the "
                        f"push force comes out several times the reference's (docs/FORMULATION.md \"Implicit step: "
                        f"impacts are inelastic\"); add integrator = \"symplectic\" for push forces")
    return warnings


def check_step(scene: Scene, step_bound_s: float) -> list[str]:
    """Warnings for a given ``dt_s`` that takes more than MAX_STEPS steps to the time limit where the
    default would take fewer, or (implicit step) moves the pusher more than MAX_ADVANCE_PER_C0 × c0 a
    step: contact begins within c0, so a step starting outside it can end deep in the wall or a coil
    (the seed case's smallest wall gap: −0.019 mm at the default 0.8 c0, −0.025 at 1.7 c0, −0.112 at 3.4 c0).
    ``step_bound_s``: the explicit step bound (s; 0: unknown)."""
    from .deploy import time_limit_s
    from .implicit import IMPLICIT_ADVANCE_PER_C0, IMPLICIT_DT_MAX_S

    sim = scene.simulation
    if sim.dt_s is None:
        return []
    c0_mm = scene.contact.c0_mm or 0.1 * min(c.wire_diameter_mm for c in scene.coils)  # (model.py's rule)
    implicit = sim.integrator == "implicit"
    default_s = (min(IMPLICIT_ADVANCE_PER_C0 * c0_mm / sim.push_speed_mm_s, IMPLICIT_DT_MAX_S) if implicit
                 else sim.dt_safety * step_bound_s)
    limit_s = time_limit_s(sim, [c.length_mm for c in scene.coils])
    steps = limit_s / sim.dt_s
    if steps > MAX_STEPS and sim.dt_s < default_s:
        return [f"{scene.where}: simulation.dt_s = {sim.dt_s:g} s takes up to {steps:.2g} steps to the time limit "
                f"({limit_s:.3g} s simulated), hours of run time; the default step here is {default_s:.3g} s "
                f"({limit_s / default_s:.2g} steps): remove dt_s, or give a larger one"]
    advance_c0 = sim.push_speed_mm_s * sim.dt_s / c0_mm
    if implicit and advance_c0 > MAX_ADVANCE_PER_C0:
        return [f"{scene.where}: simulation.dt_s = {sim.dt_s:g} s moves the pusher {advance_c0:.2g} c0 a step "
                f"(c0 = {c0_mm:.3g} mm, the contact range; the default step here, {default_s:.3g} s, moves it "
                f"{IMPLICIT_ADVANCE_PER_C0:g} c0): a step that starts outside a contact can end deep in the wall "
                f"or a coil; remove dt_s, or give one of {MAX_ADVANCE_PER_C0 * c0_mm / sim.push_speed_mm_s:.2g} s "
                "or less"]
    return []


def preflight(scene: Scene, anatomy, device=None, step_bound_s: float = 0.0) -> list[str]:
    """Every check of a scene and its resolved Anatomy before the first step; returns
    the warnings (raises SetupError). ``step_bound_s``: the explicit step bound (s; 0: not checked)."""
    check_porous(scene, anatomy)
    check_regions(scene, anatomy)
    check_balloon(scene, anatomy)
    check_deflation(scene)
    notes = [f"{scene.where}: {note}" for note in scene.notes]
    notes += [f"{scene.where}: coil[{k}]: {note}" for k, coil in enumerate(scene.coils) for note in coil.notes]
    return (notes + check_wall_bodies(scene, anatomy) + check_sac_side(scene, anatomy)
            + check_catheter(scene, anatomy, device)
            + check_capacity(scene, anatomy.sac_volume_mm3)
            + check_coil_lengths(scene) + check_integrator(scene, step_bound_s) + check_step(scene, step_bound_s))
