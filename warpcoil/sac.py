"""The neck (ostium), the sac it closes off, and what lies where (mm).

* :func:`neck_from_contour` / :func:`neck_from_plane` give a :class:`Neck`: the
  closed ostium contour on the wall, its centroid, the unit normal of its
  best-fit plane pointing into the sac and the area of the ostium surface (the
  fan of triangles from the centroid to the contour).
* :func:`sac_from_neck` cuts the wall along the contour and closes the sac
  side with the ostium fan: a watertight :class:`Sac` surface and its volume.
* :func:`inside_sac`, :func:`sac_surface`, :func:`herniated_length_mm`, :func:`catheter_from_neck`.
* :func:`regional_density`: coil volume fraction in the neck, boundary and core
  regions of the sac (docs/REGIONS.md).

Cutting the wall (no mesh surgery but one split): where the faces within reach of the contour are longer
than the ostium's equivalent diameter / CUT_EDGES_PER_OSTIUM (a CAD or boolean mesh's slivers), the wall is
first split to that edge length (the same surface; the original vertices keep their indices). Then the
faces within reach of the contour (a
face whose nearest vertex is closer to the contour than the face's longest
edge) form a band that holds every face the contour crosses. The faces off the
band fall into connected components that cannot reach each other without
crossing the band. Each band face, and each component by majority vote of its
faces near the contour, gets the side of the contour its centroid lies on,
measured across the contour in the wall's tangent plane. The two sides are then
made connected; the boundary vertices of a side are moved onto the contour and
a fan from the contour centroid closes it.

Which side is the sac (the rule, in this order):
1. ``sac_side_point_mm`` given: the side whose closed piece holds that point.
2. The wall has capped open ends (a flat fan of >= 10 triangles around one hub
   vertex, as `warpcoil.wall` and the usual capping tools make them, whose area
   is that of a disc at least a quarter of the ostium's equivalent diameter
   across: a hub of long slivers spans little): the side holding the
   largest cap holds the parent vessel's inlet, so the other side is the sac.
3. No caps (a sac-only wall such as `sphere_wall`): the larger closed piece is
   the sac; the plane only cut off what remains of the neck.
The neck normal then points to the side where the sac wall lies (area-weighted
mean height of the sac faces over the ostium plane > 0); :func:`sac_from_neck`
takes the side the normal points into.

Cutting is vectorised with numpy. The geometric queries (inside tests, distances
to the wall, rays onto the ostium, points near coil segments) run in Warp kernels
on Warp's BVH (:mod:`warpcoil.geometry`), on the CPU or the GPU.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import trimesh
from scipy.ndimage import distance_transform_edt
from trimesh.grouping import group_rows

from .geometry import SurfaceBVH, inside_points, inside_voxels, points_near_segments, ray_hits, surface_bvh, \
    surface_voxels
from .preshape import PreshapeError, read_centerline
from .wall import WallMesh, component_labels, read_vtk_polydata

CAP_MIN_VALENCE = 10  # a capped open end: a fan of at least this many triangles around one hub vertex
CAP_MAX_WARP = 0.02  # ... whose ring lies within this fraction of its diameter of a plane
CAP_MIN_FRACTION = 0.25  # ... and spans at least this fraction of the ostium's equivalent diameter
# the cut gives whole faces to a side: within reach of the contour, faces longer than the ostium's equivalent
# diameter / CUT_EDGES_PER_OSTIUM are split first (the same surface, finer: a boolean mesh's slivers moved the cut
# of a 57.3 mm³ dome off its contour, the pieces 149.6 of a 174.1 mm³ lumen; split, 57.31 + 116.82), up to
# CUT_MAX_FACES faces; the five AneuriskWeb walls need no split (their cuts are unchanged)
CUT_EDGES_PER_OSTIUM = 8
CUT_MAX_FACES = 2_000_000
PAIR_CHUNK = 1_000_000  # (point, contour segment) pairs handled at once
MAX_VOXELS = 4_000_000  # the default voxel edge grows so that the sac's bounding box holds at most this many
MAX_REGION_VOXELS = 20_000_000  # a given voxel_mm making more over the sac's box is refused before the run (~60 B each)
MIN_VOXELS_ACROSS = 2  # ... and one with fewer across the neck band, the boundary band or the sac (unresolved)
CONTOUR_SUFFIXES = (".vtk", ".vtp", ".csv", ".txt", ".xyz", ".npy")


class NeckError(ValueError):
    """A neck that cannot be used; the message names the file, the problem and the fix.
    ``sac_point``: the problem is the point given for the sac's side, not the neck itself."""

    def __init__(self, message: str, sac_point: bool = False) -> None:
        super().__init__(message)
        self.sac_point = sac_point


def _error(source: Path | str | None, problem: str, fix: str) -> NeckError:
    return NeckError(f"{source if source is not None else 'neck'}: {problem}; fix: {fix}")


# the neck's other piece, over the sac's volume, from which a sac side told only by the pieces' sizes is in
# doubt (anatomy refuses an explicit tip in that piece, preflight warns)
AMBIGUOUS_PIECE = 0.25


@dataclass(frozen=True)
class Neck:
    """Ostium of the sac."""

    contour_mm: np.ndarray  # (K, 3) closed ostium contour (last point != first)
    centroid_mm: np.ndarray  # (3,) arc-length-weighted centroid of the contour, the hub of the ostium fan
    normal: np.ndarray  # (3,) unit normal of the contour's best-fit plane, pointing into the sac
    area_mm2: float  # area of the ostium surface: the fan from the centroid to the contour
    # the other piece's volume (mm³) where only rule 3 (the larger piece) told the sac's side; else None
    other_volume_mm3: float | None = None


@dataclass(frozen=True)
class Sac:
    """Sac wall closed by the ostium fan: watertight, normals outward."""

    neck: Neck
    closed_surface: trimesh.Trimesh
    volume_mm3: float


@dataclass(frozen=True)
class RegionalDensity:
    """Coil volume fraction per sac region (docs/REGIONS.md); NaN for a region without voxels."""

    neck: float
    boundary: float
    core: float
    total_voxel: float
    neck_coverage: float  # fraction of the ostium surface within d/2 of a coil segment
    voxel_mm: float
    neck_band_mm: float
    boundary_mm: float


# --- public API ------------------------------------------------------------------
def neck_from_contour(path: str | Path, wall: WallMesh, *, sac_side_point_mm: np.ndarray | None = None) -> Neck:
    """Neck from an ostium contour file lying on ``wall``.

    ``.vtk``/``.vtp`` PolyData: the first polygon cell (else the first polyline
    cell); ``.csv``/``.txt``/``.xyz``: one point ``x y z`` (mm) per line; ``.npy``:
    a (K, 3) array. A repeated closing point is dropped.
    """
    path = Path(path)
    return _make_neck(_read_contour(path), wall, path, sac_side_point_mm, None)


def neck_from_plane(
    point_mm: np.ndarray, normal: np.ndarray, wall: WallMesh, *, sac_side_point_mm: np.ndarray | None = None
) -> Neck:
    """Neck whose contour is the loop of the plane ∩ wall nearest to ``point_mm``.

    The sign of ``normal`` is not used: the sac side follows the module's rule
    (pass ``sac_side_point_mm`` to choose it).
    """
    point = np.asarray(point_mm, dtype=np.float64).reshape(3)
    direction = np.asarray(normal, dtype=np.float64).reshape(3)
    length = float(np.linalg.norm(direction))
    if not (np.isfinite(point).all() and np.isfinite(direction).all() and length > 0.0):
        raise _error(None, f"plane point {point} / normal {direction} are not finite or the normal is zero",
                     "give a finite point and a non-zero normal")
    direction = direction / length
    return _make_neck(_plane_loop(wall, point, direction), wall, None, sac_side_point_mm, direction)


def sac_from_neck(wall: WallMesh, neck: Neck) -> Sac:
    """The wall on the side ``neck.normal`` points into, closed by the ostium fan."""
    loop = np.asarray(neck.contour_mm, dtype=np.float64)
    cut = _for_cutting(wall, loop)
    side = _wall_sides(cut, loop, None)
    heights = {s: _mean_height(cut, side == s, neck.centroid_mm, neck.normal) for s in (1, -1)}
    sac_side = max(heights, key=heights.get)
    surface = _close_piece(cut, side == sac_side, loop, neck.centroid_mm)
    volume = float(surface.volume)
    if not (surface.is_watertight and volume > 0.0):
        raise _error(wall.source, "the sac cut off by the neck is not a closed positive volume",
                     "check that the neck contour lies on this wall and goes once around the ostium")
    return Sac(neck=neck, closed_surface=surface, volume_mm3=volume)


def side_in_doubt(sac: Sac | None) -> bool:
    """Whether only the pieces' sizes told the sac's side of its neck (no flat vessel cap, no sac point) and the
    other piece is at least AMBIGUOUS_PIECE of the sac's volume, so it may be the sac."""
    other = sac.neck.other_volume_mm3 if sac is not None else None
    return other is not None and other >= AMBIGUOUS_PIECE * sac.volume_mm3


def in_other_piece(sac: Sac, wall: WallMesh, point_mm: np.ndarray) -> bool:
    """Whether ``point_mm`` lies in the lumen on the neck's other side (not in the sac)."""
    point = _points(np.asarray(point_mm, dtype=np.float64).reshape(1, 3))
    return bool(inside_points(surface_bvh(wall, wall.vertices_mm, wall.faces), point)[0]
                and not inside_sac(sac, point)[0])


def inside_sac(sac: Sac, points_mm: np.ndarray) -> np.ndarray:
    """Bool per point: inside the closed sac surface (side of the first face a ray along +z meets)."""
    return inside_points(sac_surface(sac), _points(points_mm))


def sac_surface(sac: Sac) -> SurfaceBVH:
    """The closed sac surface as a BVH (kept while ``sac`` lives): what :func:`inside_sac` tests against."""
    surface = sac.closed_surface
    return surface_bvh(sac, np.asarray(surface.vertices), np.asarray(surface.faces))


def herniated_length_mm(sac: Sac, wall: WallMesh, points_mm: np.ndarray, segment_lengths_mm: np.ndarray) -> float:
    """Coil length (per-node weights, mm) inside the lumen but not in the sac: in the parent vessel."""
    points = _points(points_mm)
    weights = np.asarray(segment_lengths_mm, dtype=np.float64).reshape(-1)
    if len(weights) != len(points):
        raise ValueError(f"herniated_length_mm: {len(points)} points but {len(weights)} segment lengths; "
                         "give one length (weight) per node")
    in_lumen = inside_points(surface_bvh(wall, wall.vertices_mm, wall.faces), points)
    outside = in_lumen & ~inside_sac(sac, points)
    return float(weights[outside].sum())


def catheter_from_neck(
    sac: Sac, depth_mm: float = 0.5, angle_deg: float = 0.0, azimuth_deg: float = 0.0,
    reference: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Tip = neck centroid + depth·normal (inside the sac); direction = the neck normal tilted.

    The tilt is ``angle_deg`` towards the azimuth ``azimuth_deg``, measured in
    the neck plane from the reference direction ``e1`` of :func:`neck_frame` (``reference``: the
    direction the wall defines, orientation.anatomy_normal, as a scene's catheter has it; without it
    the coordinate axes', which do not turn with the scene).
    """
    neck = sac.neck
    e1, e2, normal = neck_frame(neck.normal, reference)
    tip = neck.centroid_mm + depth_mm * normal
    angle, azimuth = np.radians(angle_deg), np.radians(azimuth_deg)
    towards = np.cos(azimuth) * e1 + np.sin(azimuth) * e2
    direction = np.cos(angle) * normal + np.sin(angle) * towards
    return tip, direction / np.linalg.norm(direction)


def neck_frame(normal: np.ndarray, reference: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Right-handed unit frame (e1, e2, n): e1 = ``reference`` (not along n; the scene path gives the wall's,
    orientation.anatomy_normal), or without it the coordinate axis least aligned with n, each projected onto
    the plane."""
    n = np.asarray(normal, dtype=np.float64)
    n = n / np.linalg.norm(n)
    if reference is not None:
        e1 = np.asarray(reference, dtype=np.float64)
        e1 = e1 - (e1 @ n) * n
        e1 /= np.linalg.norm(e1)
        return e1, np.cross(n, e1), n
    axis = np.eye(3)[int(np.argmin(np.abs(n)))]
    e1 = axis - (axis @ n) * n
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(n, e1), n


def regional_density(
    sac: Sac,
    coils_mm: list[np.ndarray],
    wire_diameters_mm: list[float],
    voxel_mm: float | None = None,
    neck_band_mm: float | None = None,
    boundary_mm: float | None = None,
) -> RegionalDensity:
    """Coil volume fraction in the neck, boundary and core regions of the sac (docs/REGIONS.md).

    Defaults, with d_min / d_max the smallest / largest wire diameter:
    voxel edge d_min/4 (grown so the sac's box holds <= MAX_VOXELS voxels),
    neck band 4·d_max, boundary 2·d_max.
    """
    segments_a, segments_b, radii = _coil_segments(coils_mm, wire_diameters_mm)
    d_min, d_max = float(min(wire_diameters_mm)), float(max(wire_diameters_mm))
    neck = sac.neck
    vertices, faces = np.asarray(sac.closed_surface.vertices), np.asarray(sac.closed_surface.faces)
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    if voxel_mm is None:
        voxel_mm = max(0.25 * d_min, float(np.prod(hi - lo) / MAX_VOXELS) ** (1.0 / 3.0))
    neck_band_mm = 4.0 * d_max if neck_band_mm is None else float(neck_band_mm)
    boundary_mm = 2.0 * d_max if boundary_mm is None else float(boundary_mm)
    for name, value in (("voxel_mm", voxel_mm), ("neck_band_mm", neck_band_mm), ("boundary_mm", boundary_mm)):
        if not (np.isfinite(value) and value > 0.0):
            raise ValueError(f"regional_density: {name} must be a positive number of mm, got {value}")
    h = float(voxel_mm)

    origin = lo - h
    shape = tuple(int(n) for n in np.ceil((hi - lo) / h).astype(np.int64) + 2)
    inside = inside_voxels(sac_surface(sac), origin, h, shape)
    flat = np.flatnonzero(inside)
    centres = origin + h * (np.column_stack(np.unravel_index(flat, shape)) + 0.5)
    filled = points_near_segments(centres, segments_a, segments_b, radii)

    # boundary: within boundary_mm of the centre of a voxel the sac wall (not the ostium fan) passes through
    hub = np.flatnonzero(np.all(vertices == neck.centroid_mm, axis=1))
    wall_part = SurfaceBVH(vertices, faces[~np.isin(faces, hub).any(axis=1)])
    crossed = surface_voxels(wall_part, origin, h, shape)
    near_wall = (distance_transform_edt(~crossed) <= boundary_mm / h)[inside]

    # neck: above the ostium fan (height map along the normal) by at most neck_band_mm
    frame = np.array(neck_frame(neck.normal))
    ostium = _OstiumMap.build(neck, frame, min(0.5 * h, d_min / 8.0))
    local = (centres - neck.centroid_mm) @ frame.T
    w_low, w_high = ostium.heights_at(local[:, :2])
    in_neck = (local[:, 2] >= w_low - h) & (local[:, 2] <= w_high + neck_band_mm)

    in_boundary = near_wall & ~in_neck
    in_core = ~near_wall & ~in_neck
    fraction = [float(filled[r].mean()) if r.any() else float("nan") for r in (in_neck, in_boundary, in_core)]
    total = float(filled.mean()) if len(filled) else float("nan")
    covered = points_near_segments(ostium.samples_mm, segments_a, segments_b, radii)
    coverage = float((ostium.weights * covered).sum() / ostium.weights.sum()) if len(covered) else float("nan")
    return RegionalDensity(
        neck=fraction[0], boundary=fraction[1], core=fraction[2], total_voxel=total, neck_coverage=coverage,
        voxel_mm=h, neck_band_mm=neck_band_mm, boundary_mm=boundary_mm,
    )


# --- neck construction -------------------------------------------------------------
def _read_contour(path: Path) -> np.ndarray:
    suffix = path.suffix.lower()
    if suffix not in CONTOUR_SUFFIXES:
        raise _error(path, f"unsupported neck contour format {suffix or 'without extension'!r}",
                     f"give one of {', '.join(CONTOUR_SUFFIXES)}")
    if not path.is_file():
        raise _error(path, "neck contour file does not exist", "check the path of the neck contour")
    if suffix in (".vtk", ".vtp"):
        return _read_vtk_contour(path)
    try:
        return read_centerline(path)
    except PreshapeError as exc:
        raise _error(path, f"cannot be read as a neck contour ({exc})",
                     "give one point 'x y z' in mm per line, going once around the ostium") from None


def _read_vtk_contour(path: Path) -> np.ndarray:
    """Points of the first polygon (else polyline) cell of a VTK PolyData file."""
    from vtkmodules.util.numpy_support import vtk_to_numpy

    try:
        data = read_vtk_polydata(path)
    except ValueError as exc:
        raise _error(path, f"cannot be read as VTK PolyData ({exc})", "check or re-export the neck file") from None
    for cells in (data.GetPolys(), data.GetLines()):
        if cells.GetNumberOfCells() > 0:
            offsets = vtk_to_numpy(cells.GetOffsetsArray())
            ids = vtk_to_numpy(cells.GetConnectivityArray())[offsets[0] : offsets[1]]
            return np.asarray(vtk_to_numpy(data.GetPoints().GetData())[ids], dtype=np.float64)
    raise _error(path, "holds no polygon or polyline cell", "store the ostium contour as one polygon or polyline cell")


def _make_neck(
    points: np.ndarray, wall: WallMesh, source: Path | None, hint: np.ndarray | None, plane_normal: np.ndarray | None
) -> Neck:
    loop = _clean_loop(points, source)
    _check_on_wall(loop, wall, source)
    cut = _for_cutting(wall, loop)
    side = _wall_sides(cut, loop, source)
    centroid = _loop_centroid(loop)
    pieces = {s: _close_piece(cut, side == s, loop, centroid) for s in (1, -1)}
    sac_side, by_volume = _sac_side(wall, cut, side, pieces, loop, centroid, hint, source)
    if plane_normal is None:
        plane_normal = np.linalg.svd(loop - centroid, full_matrices=False)[2][2]
    normal = plane_normal / np.linalg.norm(plane_normal)
    if _mean_height(cut, side == sac_side, centroid, normal) < 0.0:
        normal = -normal
    return Neck(contour_mm=loop, centroid_mm=centroid, normal=normal, area_mm2=_fan_area(loop, centroid),
                other_volume_mm3=float(pieces[-sac_side].volume) if by_volume else None)


def _clean_loop(points: np.ndarray, source: Path | None) -> np.ndarray:
    loop = np.asarray(points, dtype=np.float64)
    if loop.ndim != 2 or loop.shape[1] != 3:
        raise _error(source, f"neck contour has shape {loop.shape}, expected (K, 3)", "give x y z per point")
    if not np.isfinite(loop).all():
        raise _error(source, "neck contour has non-finite coordinates", "give finite coordinates in mm")
    step = np.linalg.norm(np.roll(loop, -1, axis=0) - loop, axis=1)
    loop = loop[step > 1e-9 * max(float(np.ptp(loop, axis=0).max()), 1e-300)]  # repeated (closing) points
    if len(loop) < 3:
        raise _error(source, f"neck contour has {len(loop)} distinct point(s)",
                     "give at least 3 points around the ostium")
    spread = np.linalg.svd(loop - loop.mean(axis=0), compute_uv=False)
    if spread[1] <= 1e-9 * spread[0]:
        raise _error(source, "neck contour points are collinear", "give a loop going once around the ostium")
    return loop


def _check_on_wall(loop: np.ndarray, wall: WallMesh, source: Path | None) -> None:
    """Every contour point and segment midpoint must lie within the longest wall edge of some wall vertex."""
    tri = wall.vertices_mm[wall.faces]
    longest = float(np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2).max())
    probes = np.vstack((loop, 0.5 * (loop + np.roll(loop, -1, axis=0))))
    gap = np.full(len(probes), np.inf)
    for rows in _row_chunks(len(probes), len(wall.vertices_mm)):
        diff = probes[rows, None, :] - wall.vertices_mm[None]
        gap[rows] = np.sqrt(np.einsum("ijk,ijk->ij", diff, diff).min(axis=1))
    worst = int(gap.argmax())
    if gap[worst] > longest:
        where = f"point {worst}" if worst < len(loop) else f"segment {worst - len(loop)} (between two points)"
        raise _error(source, f"neck contour {where} lies {gap[worst]:.3g} mm from the wall",
                     "give the contour in the wall's frame and units (mm), on the wall surface, "
                     "with points no farther apart than the wall's edge length")


def _loop_centroid(loop: np.ndarray) -> np.ndarray:
    following = np.roll(loop, -1, axis=0)
    weights = np.linalg.norm(following - loop, axis=1)
    return (0.5 * (loop + following) * weights[:, None]).sum(axis=0) / weights.sum()


def _fan_area(loop: np.ndarray, centroid: np.ndarray) -> float:
    spokes = loop - centroid
    return float(0.5 * np.linalg.norm(np.cross(spokes, np.roll(spokes, -1, axis=0)), axis=1).sum())


FLAT_CUT_TOLERANCE = 1.0e-4  # a face within this many median edge lengths of the neck plane lies along it
# (counted within the loop's reach of the plane point: a flat cap far off at the same height is no concern)


def _plane_loop(wall: WallMesh, point: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Ordered points of the loop of plane ∩ wall nearest to ``point`` (one point per crossed edge).

    A vertex on the plane counts as above it. Each crossed face links the edge
    where its winding goes from above to below to the edge where it comes back:
    a permutation of the crossed edges whose cycles are the loops.
    """
    vertices, faces = wall.vertices_mm, wall.faces
    height = (vertices - point) @ normal
    above = height >= 0.0
    face_edges = np.stack((faces, np.roll(faces, -1, axis=1)), axis=2)  # (F, 3, 2), winding order
    down = above[face_edges[..., 0]] & ~above[face_edges[..., 1]]
    up = ~above[face_edges[..., 0]] & above[face_edges[..., 1]]
    crossed = down.any(axis=1)
    if not crossed.any():
        raise _error(wall.source, f"the plane through {point} with normal {normal} does not cut the wall",
                     "give a plane point at the ostium")
    edge_ids, node = np.unique(np.sort(face_edges[down | up], axis=1), axis=0, return_inverse=True)
    node_of = np.full(down.shape, -1)
    node_of[down | up] = node.ravel()
    successor = np.empty(len(edge_ids), dtype=np.int64)
    successor[node_of[down]] = node_of[up]  # one down and one up edge per crossed face, in face order
    a, b = edge_ids.T
    t = height[a] / (height[a] - height[b])
    points = vertices[a] + t[:, None] * (vertices[b] - vertices[a])
    loop_id, rank = _cycles(successor)
    gap = np.full(len(edge_ids), np.inf)
    np.minimum.at(gap, loop_id, np.linalg.norm(points - point, axis=1))
    members = np.flatnonzero(loop_id == int(np.argmin(gap)))
    loop = points[members[np.argsort(-rank[members], kind="stable")]]
    _refuse_flat_cut(wall, point, normal, height, loop)
    return loop


def _refuse_flat_cut(wall: WallMesh, point: np.ndarray, normal: np.ndarray, height: np.ndarray,
                     loop: np.ndarray) -> None:
    """NeckError when the plane lies along faces of a flat part of the wall within the loop's reach of
    ``point`` (``height``: the vertices' heights over the plane, mm): "on the plane counts as above"
    traces the rounding of their heights across the flat part, so the loop there is not the ostium."""
    vertices, faces = wall.vertices_mm, wall.faces
    edges = np.linalg.norm(vertices[faces] - vertices[np.roll(faces, -1, axis=1)], axis=2)
    along = np.abs(height[faces]).max(axis=1) <= FLAT_CUT_TOLERANCE * float(np.median(edges))
    reach = float(np.linalg.norm(loop - point, axis=1).max()) + float(edges.max())
    along &= np.linalg.norm(vertices[faces].mean(axis=1) - point, axis=1) <= reach
    if along.any():
        step = 0.5 * float(np.median(edges[along]))
        raise _error(wall.source, f"the plane through {point} with normal {normal} lies along {int(along.sum())} "
                     "faces of a flat part of the wall, where its cut is undefined",
                     f"move the plane point off the flat part along the normal (e.g. by {step:.2g} mm) to where the "
                     "plane crosses the ostium")


def _cycles(successor: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per node of a permutation: its cycle (lowest node) and its steps to that node along the cycle."""
    count = len(successor)
    rounds = int(np.ceil(np.log2(max(count, 2)))) + 1
    label, jump = np.arange(count), successor.copy()
    for _ in range(rounds):
        label = np.minimum(label, label[jump])
        jump = jump[jump]
    root = label == np.arange(count)
    jump = np.where(root, np.arange(count), successor)
    steps = (~root).astype(np.int64)
    for _ in range(rounds):
        steps = steps + steps[jump]
        jump = jump[jump]
    return label, steps


# --- cutting the wall along the contour ----------------------------------------------
def _for_cutting(wall: WallMesh, loop: np.ndarray) -> WallMesh:
    """``wall``, or (where its faces within reach of the contour ``loop`` are longer than the ostium's equivalent
    diameter / CUT_EDGES_PER_OSTIUM) the same surface split to that edge length (trimesh.remesh.subdivide_to_size:
    the original vertices first, with their indices), unless that makes more than CUT_MAX_FACES faces."""
    vertices, faces = wall.vertices_mm, wall.faces
    tri = vertices[faces]
    longest = np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2).max(axis=1)
    centroid = _loop_centroid(loop)
    target = 2.0 * np.sqrt(_fan_area(loop, centroid) / np.pi) / CUT_EDGES_PER_OSTIUM
    reach = np.linalg.norm(loop - centroid, axis=1).max() + longest
    near = np.linalg.norm(tri.mean(axis=1) - centroid, axis=1) <= reach
    if not (target > 0.0 and longest[near].max(initial=0.0) > target):
        return wall
    if float((np.ceil(longest / target) ** 2).sum()) > CUT_MAX_FACES:
        return wall
    split_vertices, split_faces = trimesh.remesh.subdivide_to_size(vertices, faces, max_edge=target)
    return replace(wall, vertices_mm=np.asarray(split_vertices, dtype=np.float64),
                   faces=np.asarray(split_faces, dtype=np.int32))


def _wall_sides(wall: WallMesh, loop: np.ndarray, source: Path | None) -> np.ndarray:
    """Side of the contour per wall face: +1 or -1 (connected pieces), 0 for other bodies of the wall."""
    mesh = trimesh.Trimesh(wall.vertices_mm, wall.faces, process=False)
    vertices, faces, count = wall.vertices_mm, wall.faces, len(wall.faces)
    tri = vertices[faces]
    longest = np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2).max(axis=1)
    centre = loop.mean(axis=0)
    reach = np.linalg.norm(loop - centre, axis=1).max() + longest.max()
    vertex_gap = np.full(len(vertices), np.inf)
    close = np.linalg.norm(vertices - centre, axis=1) <= reach
    vertex_gap[close] = _nearest_on_loop(vertices[close], loop)[0]
    face_gap = vertex_gap[faces].min(axis=1)
    band = face_gap <= longest * (1.0 + 1e-6)
    if not band.any():
        raise _error(source, "the neck contour does not touch the wall", "give a contour lying on the wall")
    adjacency = mesh.face_adjacency
    body = component_labels(adjacency, count)
    in_body = np.isin(body, body[band])
    free = component_labels(adjacency[~band[adjacency].any(axis=1)], count)

    near = np.flatnonzero(in_body & (face_gap <= 3.0 * longest[band].max()))
    centres = mesh.triangles_center[near]
    _, segment, foot = _nearest_on_loop(centres, loop)
    tangent = np.roll(loop, -1, axis=0)[segment] - loop[segment]
    across = np.cross(tangent, mesh.face_normals[near])
    local = np.sign(np.einsum("ij,ij->i", centres - foot, across)).astype(np.int8)
    vote = np.bincount(free[near], weights=local, minlength=count)
    side = np.where(in_body, np.sign(vote[free]), 0).astype(np.int8)
    side[near[band[near]]] = local[band[near]]
    off_band = side[~band]
    if not ((off_band == 1).any() and (off_band == -1).any()):
        raise _error(source, "cutting the wall along the neck contour leaves a single piece",
                     "give a closed contour that goes once around the ostium on the wall and leaves more than "
                     "about two rows of wall triangles on each side")

    side[in_body & (side == 0)] = -1  # undecided faces (no vote, degenerate): settled by the connectivity below
    area = mesh.area_faces
    for s in (1, -1):  # one connected piece per side: stray islands join the other side
        members = side == s
        label = component_labels(adjacency[members[adjacency].all(axis=1)], count)
        main = np.bincount(label[members], weights=area[members], minlength=count).argmax()
        side[members & (label != main)] = -s
    return side


def _close_piece(wall: WallMesh, mask: np.ndarray, loop: np.ndarray, centroid: np.ndarray) -> trimesh.Trimesh:
    """Faces ``mask`` of the wall, boundary vertices moved onto the contour, closed by a fan from ``centroid``."""
    faces = wall.faces[mask]
    used, local = np.unique(faces, return_inverse=True)
    local = local.reshape(-1, 3)
    vertices = wall.vertices_mm[used].copy()
    edges = np.stack((local, np.roll(local, -1, axis=1)), axis=2).reshape(-1, 2)
    boundary = edges[group_rows(np.sort(edges, axis=1), require_count=1)]  # directed as in their faces
    rim = np.unique(boundary)
    vertices[rim] = _nearest_on_loop(vertices[rim], loop)[2]
    fan = np.column_stack((boundary[:, 1], boundary[:, 0], np.full(len(boundary), len(vertices))))
    return trimesh.Trimesh(np.vstack((vertices, centroid)), np.vstack((local, fan)), process=False)


def _mean_height(wall: WallMesh, mask: np.ndarray, centroid: np.ndarray, normal: np.ndarray) -> float:
    """Area-weighted mean height of the faces ``mask`` over the plane (centroid, normal)."""
    tri = wall.vertices_mm[wall.faces[mask]]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    return float(((tri.mean(axis=1) - centroid) @ normal * area).sum() / max(area.sum(), 1e-300))


def _sac_side(
    wall: WallMesh, cut: WallMesh, side: np.ndarray, pieces: dict[int, trimesh.Trimesh], loop: np.ndarray,
    centroid: np.ndarray, hint: np.ndarray | None, source: Path | None,
) -> tuple[int, bool]:
    """(+1 or -1: the sac's side of the contour, by the rule in the module docstring; whether rule 3,
    the larger piece, told it). ``side`` per face of ``cut`` (:func:`_for_cutting`); the caps are ``wall``'s."""
    if hint is not None:
        point = np.asarray(hint, dtype=np.float64).reshape(1, 3)
        holding = [s for s, piece in pieces.items() if inside_points(SurfaceBVH(piece.vertices, piece.faces), point)[0]]
        if len(holding) != 1:
            raise NeckError(str(_error(source, f"the sac-side point {point[0]} lies in "
                                          f"{'neither' if not holding else 'both'} of the two lumen pieces cut off "
                                          "by the neck", "give a point inside the sac lumen")), sac_point=True)
        return holding[0], False
    ostium_diameter = 2.0 * np.sqrt(_fan_area(loop, centroid) / np.pi)
    cap_of_face, cap_area, cap_hub = _caps(wall, CAP_MIN_FRACTION * ostium_diameter)
    capped = cap_of_face >= 0
    if capped.any():
        largest = int(np.argmax(cap_area))
        around = (cap_of_face == largest if cut is wall  # (the cut's faces at the hub: split, the same disc)
                  else (cut.faces == cap_hub[largest]).any(axis=1))
        vessel_side = np.sign(side[around].sum())
        if vessel_side != 0:
            return int(-vessel_side), False
    return (1 if pieces[1].volume >= pieces[-1].volume else -1), True


def _caps(wall: WallMesh, min_diameter_mm: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Capped open ends: flat fans around a hub vertex. Cap index per face (-1: none), cap areas, hub vertices."""
    vertices, faces = wall.vertices_mm, wall.faces
    valence = np.bincount(faces.ravel(), minlength=len(vertices))
    hubs = np.flatnonzero(valence >= CAP_MIN_VALENCE)
    cap_of_face = np.full(len(faces), -1)
    if not len(hubs):
        return cap_of_face, np.zeros(0), np.zeros(0, dtype=np.int64)
    hub_index = np.full(len(vertices), -1)
    hub_index[hubs] = np.arange(len(hubs))
    owner = hub_index[faces].max(axis=1)
    member = np.flatnonzero(owner >= 0)
    owner = owner[member]
    tri = vertices[faces[member]]
    doubled = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normal = np.zeros((len(hubs), 3))
    np.add.at(normal, owner, doubled)
    normal /= np.maximum(np.linalg.norm(normal, axis=1), 1e-300)[:, None]
    offset = tri - vertices[hubs[owner]][:, None, :]
    warp = np.zeros(len(hubs))
    np.maximum.at(warp, owner, np.abs(np.einsum("fvk,fk->fv", offset, normal[owner])).max(axis=1))
    area = 0.5 * np.bincount(owner, weights=np.linalg.norm(doubled, axis=1), minlength=len(hubs))
    diameter = 2.0 * np.sqrt(area / np.pi)  # (a disc's; a fan of long slivers, a CAD mesh's hub, spans little)
    flat = (warp <= CAP_MAX_WARP * diameter) & (diameter >= min_diameter_mm)
    keep = np.flatnonzero(flat)
    renumber = np.full(len(hubs), -1)
    renumber[keep] = np.arange(len(keep))
    cap_of_face[member] = renumber[owner]
    return cap_of_face, area[keep], hubs[keep]


# --- geometry kernels ------------------------------------------------------------------
def _points(points_mm: np.ndarray) -> np.ndarray:
    points = np.asarray(points_mm, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3) in mm, got {points.shape}")
    return points


def _row_chunks(rows: int, width: int) -> Iterator[slice]:
    step = max(1, PAIR_CHUNK // max(width, 1))
    for start in range(0, rows, step):
        yield slice(start, start + step)


def _nearest_on_loop(points: np.ndarray, loop: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distance, segment index and foot point of each point's nearest point on the closed polyline."""
    start = loop
    step = np.roll(loop, -1, axis=0) - loop
    length2 = np.maximum(np.einsum("ij,ij->i", step, step), 1e-300)
    distance = np.empty(len(points))
    segment = np.empty(len(points), dtype=np.int64)
    for rows in _row_chunks(len(points), len(loop)):
        offset = points[rows, None, :] - start[None]
        t = np.clip(np.einsum("pkj,kj->pk", offset, step) / length2, 0.0, 1.0)
        gap = offset - t[..., None] * step
        d2 = np.einsum("pkj,pkj->pk", gap, gap)
        segment[rows] = d2.argmin(axis=1)
        distance[rows] = np.sqrt(d2[np.arange(len(d2)), segment[rows]])
    t = np.clip(np.einsum("ij,ij->i", points - start[segment], step[segment]) / length2[segment], 0.0, 1.0)
    return distance, segment, start[segment] + t[:, None] * step[segment]


def _coil_segments(
    coils_mm: list[np.ndarray], wire_diameters_mm: list[float]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Segment starts, ends and radii (mm) of all coils."""
    if len(coils_mm) != len(wire_diameters_mm) or not len(coils_mm):
        raise ValueError(f"regional_density: {len(coils_mm)} coils but {len(wire_diameters_mm)} wire diameters; "
                         "give one diameter per coil and at least one coil")
    starts, ends, radii = [], [], []
    for k, (coil, diameter) in enumerate(zip(coils_mm, wire_diameters_mm)):
        nodes = np.asarray(coil, dtype=np.float64)
        if nodes.ndim != 2 or nodes.shape[1] != 3 or not np.isfinite(nodes).all():
            raise ValueError(f"regional_density: coil {k} must be a finite (N, 3) array in mm, got shape {nodes.shape}")
        if not (np.isfinite(diameter) and diameter > 0.0):
            raise ValueError(f"regional_density: wire diameter {k} must be > 0 mm, got {diameter}")
        starts.append(nodes[:-1])
        ends.append(nodes[1:])
        radii.append(np.full(max(len(nodes) - 1, 0), 0.5 * float(diameter)))
    return np.concatenate(starts), np.concatenate(ends), np.concatenate(radii)


@dataclass(frozen=True)
class _OstiumMap:
    """The ostium fan sampled on a square grid (spacing, in the neck frame) seen along the neck normal."""

    low_uv: np.ndarray  # (2,) grid origin
    spacing_mm: float
    dims: tuple[int, int]
    w_low: np.ndarray  # (nu*nv,) lowest / highest fan height over each grid point, +inf / -inf where none
    w_high: np.ndarray
    samples_mm: np.ndarray  # (S, 3) the fan's points over the grid points, world frame
    weights: np.ndarray  # (S,) fan area each sample stands for, in units of spacing²

    @classmethod
    def build(cls, neck: Neck, frame: np.ndarray, spacing_mm: float) -> _OstiumMap:
        spokes = (neck.contour_mm - neck.centroid_mm) @ frame.T
        corners = np.vstack((spokes, np.zeros(3)))  # the contour and the hub
        fan = SurfaceBVH(corners, _fan_faces(len(spokes)))
        low, high = corners[:, :2].min(axis=0), corners[:, :2].max(axis=0)
        nu, nv = (np.ceil((high - low) / spacing_mm).astype(np.int64) + 1).tolist()
        i, j = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
        below = corners[:, 2].min() - 1.0
        grid = np.column_stack((low[0] + spacing_mm * i.ravel(), low[1] + spacing_mm * j.ravel(), np.full(nu * nv, below)))
        column, _, t, normal = ray_hits(fan, grid, np.array([0.0, 0.0, 1.0]), 1e-6 * spacing_mm)
        w = below + t
        w_low, w_high = np.full(nu * nv, np.inf), np.full(nu * nv, -np.inf)
        np.minimum.at(w_low, column, w)
        np.maximum.at(w_high, column, w)
        samples = neck.centroid_mm + np.column_stack((grid[column, :2], w)) @ frame
        return cls(low, spacing_mm, (nu, nv), w_low, w_high, samples, 1.0 / np.maximum(np.abs(normal[:, 2]), 1e-3))

    def heights_at(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Lowest and highest fan height over the grid point nearest to each (u, v) (inf / -inf: off the ostium)."""
        index = np.rint((uv - self.low_uv) / self.spacing_mm).astype(np.int64)
        on = np.all((index >= 0) & (index < np.array(self.dims)), axis=1)
        key = np.where(on, index[:, 0] * self.dims[1] + index[:, 1], 0)
        return np.where(on, self.w_low[key], np.inf), np.where(on, self.w_high[key], -np.inf)


def _fan_faces(count: int) -> np.ndarray:
    """Triangles (hub = vertex ``count``, contour k, contour k+1) of the fan over a closed loop of ``count`` points."""
    k = np.arange(count)
    return np.column_stack((np.full(count, count), k, (k + 1) % count))

