"""Geometric queries on triangle surfaces and coil segments, in Warp kernels (CPU or CUDA), mm.

* :class:`SurfaceBVH`: a triangle surface as a ``wp.Mesh`` (Warp's BVH, float32,
  vertices relative to the box centre so float32 keeps ~1e-6 of the size);
  :func:`surface_bvh` keeps one per owning object.
* :func:`inside_points`: the side of the first face a ray from the point meets
  (``wp.mesh_query_ray``): one ray per point, exact for a closed, outward-wound surface.
* :func:`lengths_outside`: each segment's length outside a closed surface, split at its
  crossing (bisection with :func:`inside_points`' test).
* :func:`inside_voxels`: voxel centres inside a closed surface from the crossings up each
  voxel column (``wp.mesh_query_ray``), one ray march per column.
* :func:`surface_voxels`: the voxels a surface passes through (``wp.mesh_query_point_no_sign``).
* :func:`ray_hits`: every crossing of parallel rays with a surface (``wp.mesh_query_ray``).
* :func:`points_near_segments`: points within a segment's radius of it (``wp.Bvh`` of
  the segments' radius-grown boxes, exact float64 distance on the candidates).

Every kernel writes only its own thread's output (gather form): results do not
depend on the device or the thread order.
"""

from __future__ import annotations

import weakref

import numpy as np
import warp as wp

from . import _warp  # noqa: F401  (kernel cache, init)

FAR_MM = 1.0e6  # mm, 'no limit' for ray and point queries
CROSSING_HALVINGS = 16  # bisection steps that place a segment's crossing of a surface (to 2⁻¹⁶ of its length)
STEP_VOXELS = 1.0e-4  # a column's march resumes this far (in voxel edges) past each hit


class SurfaceBVH:
    """A triangle surface (V, 3) mm / (F, 3) as a Warp mesh on ``device``."""

    def __init__(self, vertices_mm: np.ndarray, faces: np.ndarray, device=None):
        vertices = np.asarray(vertices_mm, dtype=np.float64)
        self.device = wp.get_device(device)
        self.centre_mm = 0.5 * (vertices.min(axis=0) + vertices.max(axis=0))
        self.faces = np.asarray(faces, dtype=np.int32).reshape(-1, 3)
        self.mesh = wp.Mesh(points=wp.array((vertices - self.centre_mm).astype(np.float32), dtype=wp.vec3,
                                            device=self.device),
                            indices=wp.array(self.faces.ravel(), dtype=wp.int32, device=self.device))

    def local(self, points_mm: np.ndarray) -> wp.array:
        return wp.array((np.asarray(points_mm, dtype=np.float64) - self.centre_mm).astype(np.float32),
                        dtype=wp.vec3, device=self.device)


_BVHS: dict[tuple[int, str], SurfaceBVH] = {}


def surface_bvh(owner: object, vertices_mm: np.ndarray, faces: np.ndarray, device=None) -> SurfaceBVH:
    """The SurfaceBVH of ``owner``'s surface, built on first use and kept while ``owner`` lives."""
    key = (id(owner), str(wp.get_device(device)))
    if key not in _BVHS:
        _BVHS[key] = SurfaceBVH(vertices_mm, faces, device)
        weakref.finalize(owner, _BVHS.pop, key, None)
    return _BVHS[key]


@wp.func
def first_hit_inside(mesh: wp.uint64, point: wp.vec3) -> int:
    """1 if the first face the ray from ``point`` along +z meets is seen from its back (inner) side."""
    hit = wp.mesh_query_ray(mesh, point, wp.vec3(0.0, 0.0, 1.0), FAR_MM)
    if hit.result and hit.sign < 0.0:
        return 1
    return 0


@wp.kernel
def _first_hit_inside(mesh: wp.uint64, points: wp.array(dtype=wp.vec3), inside: wp.array(dtype=wp.int8)):
    k = wp.tid()
    inside[k] = wp.int8(first_hit_inside(mesh, points[k]))


@wp.kernel
def _crossing(mesh: wp.uint64, a: wp.array(dtype=wp.vec3), b: wp.array(dtype=wp.vec3), halvings: int,
              t: wp.array(dtype=float)):
    """Where (fraction from a) the segment a → b crosses the surface: ``halvings`` bisections with first_hit_inside."""
    k = wp.tid()
    side = first_hit_inside(mesh, a[k])
    lo = float(0.0)
    hi = float(1.0)
    for _ in range(halvings):
        mid = 0.5 * (lo + hi)
        if first_hit_inside(mesh, a[k] + mid * (b[k] - a[k])) == side:
            lo = mid
        else:
            hi = mid
    t[k] = 0.5 * (lo + hi)


@wp.kernel
def _inside_columns(mesh: wp.uint64, origin: wp.vec3, h: float, ny: int, nz: int,
                           inside: wp.array(dtype=wp.int8)):
    """One voxel column per thread: march the ray up the column from its foot; past a hit on the front
    (outer) side of a face the column is inside, past one on the back side outside. Reading the side
    rather than toggling keeps a hit on an edge shared by two faces (found once or twice) from
    flipping the rest of the column."""
    c = wp.tid()
    direction = wp.vec3(0.0, 0.0, 1.0)
    foot = origin + h * wp.vec3(float(c // ny) + 0.5, float(c % ny) + 0.5, 0.0)
    travelled = float(0.0)  # along the unit direction, from the foot
    state = wp.int8(0)
    l = int(0)
    hit = wp.mesh_query_ray(mesh, foot, direction, FAR_MM)
    while hit.result:
        travelled = travelled + hit.t
        while l < nz and (float(l) + 0.5) * h < travelled:
            inside[c * nz + l] = state
            l = l + 1
        state = wp.where(hit.sign > 0.0, wp.int8(1), wp.int8(0))
        travelled = travelled + STEP_VOXELS * h
        hit = wp.mesh_query_ray(mesh, foot + travelled * direction, direction, FAR_MM)


@wp.kernel
def _surface_voxels(mesh: wp.uint64, origin: wp.vec3, h: float, ny: int, nz: int, crossed: wp.array(dtype=wp.int8)):
    k = wp.tid()
    i = k // (ny * nz)
    j = (k // nz) % ny
    l = k % nz
    centre = origin + h * wp.vec3(float(i) + 0.5, float(j) + 0.5, float(l) + 0.5)
    query = wp.mesh_query_point_no_sign(mesh, centre, 0.8661 * h)  # half the voxel's diagonal
    if query.result:
        gap = wp.mesh_eval_position(mesh, query.face, query.u, query.v) - centre
        if wp.max(wp.abs(gap)) <= 0.5 * h:
            crossed[k] = wp.int8(1)


@wp.kernel
def _count_hits(mesh: wp.uint64, starts: wp.array(dtype=wp.vec3), direction: wp.vec3, count: wp.array(dtype=int)):
    k = wp.tid()
    count[k] = wp.mesh_query_ray_count_intersections(mesh, starts[k], direction)


@wp.kernel
def _march_hits(mesh: wp.uint64, starts: wp.array(dtype=wp.vec3), direction: wp.vec3, first: wp.array(dtype=int),
                count: wp.array(dtype=int), step: float, face: wp.array(dtype=int), t: wp.array(dtype=float),
                normal: wp.array(dtype=wp.vec3)):
    """The ray's hits in order, each found from just past the previous one (face -1: fewer found than counted)."""
    k = wp.tid()
    travelled = float(0.0)
    for n in range(count[k]):
        hit = wp.mesh_query_ray(mesh, starts[k] + travelled * direction, direction, FAR_MM)
        if hit.result:
            travelled = travelled + hit.t
            face[first[k] + n] = hit.face
            t[first[k] + n] = travelled
            normal[first[k] + n] = hit.normal
            travelled = travelled + step
        else:
            face[first[k] + n] = -1


@wp.kernel
def _near_segments(points: wp.array(dtype=wp.vec3d), bvh: wp.uint64, a: wp.array(dtype=wp.vec3d),
                   b: wp.array(dtype=wp.vec3d), radius: wp.array(dtype=wp.float64), near: wp.array(dtype=wp.int8)):
    k = wp.tid()
    p = points[k]
    box = wp.vec3(float(p[0]), float(p[1]), float(p[2]))
    query = wp.bvh_query_aabb(bvh, box, box)
    s = int(0)
    while wp.bvh_query_next(query, s):
        step = b[s] - a[s]
        length2 = wp.dot(step, step)
        along = wp.float64(0.0)
        if length2 > wp.float64(0.0):
            along = wp.clamp(wp.dot(p - a[s], step) / length2, wp.float64(0.0), wp.float64(1.0))
        gap = p - a[s] - along * step
        if wp.dot(gap, gap) <= radius[s] * radius[s]:
            near[k] = wp.int8(1)


def inside_points(surface: SurfaceBVH, points_mm: np.ndarray) -> np.ndarray:
    """Bool per point: inside the closed, outward-wound surface, i.e. the first face the ray from the
    point along +z meets is seen from its back (inner) side."""
    points = np.asarray(points_mm, dtype=np.float64).reshape(-1, 3)
    inside = wp.zeros(len(points), dtype=wp.int8, device=surface.device)
    if len(points):
        wp.launch(_first_hit_inside, len(points), inputs=[surface.mesh.id, surface.local(points)], outputs=[inside],
                  device=surface.device)
    return inside.numpy().astype(bool)


def lengths_outside(surface: SurfaceBVH, points_mm: np.ndarray, starts: np.ndarray, ends: np.ndarray
                    ) -> np.ndarray:
    """Per segment from ``points_mm[starts]`` to ``points_mm[ends]`` (mm): its length outside the closed,
    outward-wound surface (mm): all of it where both ends are outside (:func:`inside_points`), none where both
    are inside, and where they differ the part on the outside end's side of the crossing that CROSSING_HALVINGS
    bisections with the same test place. A polyline's sum converges to its length outside, whatever its node
    spacing (a segment that leaves and re-enters between its ends counts as inside)."""
    points = np.asarray(points_mm, dtype=np.float64).reshape(-1, 3)
    outside = ~inside_points(surface, points)
    a, b = points[starts], points[ends]
    fraction = (outside[starts] & outside[ends]).astype(np.float64)
    cross = np.flatnonzero(outside[starts] != outside[ends])
    if len(cross):
        t = wp.zeros(len(cross), dtype=float, device=surface.device)
        wp.launch(_crossing, len(cross), inputs=[surface.mesh.id, surface.local(a[cross]), surface.local(b[cross]),
                                                 CROSSING_HALVINGS], outputs=[t], device=surface.device)
        t = t.numpy().astype(np.float64)
        fraction[cross] = np.where(outside[starts][cross], t, 1.0 - t)
    return fraction * np.linalg.norm(b - a, axis=1)


def inside_voxels(surface: SurfaceBVH, origin_mm: np.ndarray, h_mm: float, shape: tuple[int, int, int]) -> np.ndarray:
    """(nx, ny, nz) bool: voxel centres ``origin + h·(index + ½)`` inside the closed, outward-wound
    surface: the side of the last face crossed below them along their column (``origin`` below the surface)."""
    inside = wp.zeros(int(np.prod(shape)), dtype=wp.int8, device=surface.device)
    origin = wp.vec3(*(np.asarray(origin_mm, dtype=np.float64) - surface.centre_mm))
    wp.launch(_inside_columns, shape[0] * shape[1], inputs=[surface.mesh.id, origin, float(h_mm), shape[1],
                                                                   shape[2]], outputs=[inside], device=surface.device)
    return inside.numpy().astype(bool).reshape(shape)


def surface_voxels(surface: SurfaceBVH, origin_mm: np.ndarray, h_mm: float, shape: tuple[int, int, int]
                   ) -> np.ndarray:
    """(nx, ny, nz) bool: voxels (cubes of edge h at ``origin + h·index``) that hold the point of the
    surface nearest to their centre, i.e. the voxels the surface passes through (up to cube corners
    that the surface clips farther from the centre than its nearest point)."""
    count = int(np.prod(shape))
    crossed = wp.zeros(count, dtype=wp.int8, device=surface.device)
    origin = wp.vec3(*(np.asarray(origin_mm, dtype=np.float64) - surface.centre_mm))
    wp.launch(_surface_voxels, count, inputs=[surface.mesh.id, origin, float(h_mm), shape[1], shape[2]],
              outputs=[crossed], device=surface.device)
    return crossed.numpy().astype(bool).reshape(shape)


def ray_hits(surface: SurfaceBVH, starts_mm: np.ndarray, direction: np.ndarray, step_mm: float
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every crossing of the rays ``start + t·direction`` (t ≥ 0, unit direction) with the surface:
    (ray, face, t mm, unit face normal) per hit. Hits closer than ``step_mm`` along a ray count once."""
    starts = surface.local(starts_mm)
    unit = np.asarray(direction, dtype=np.float64) / np.linalg.norm(direction)
    towards = wp.vec3(*unit)
    device, rays = surface.device, len(starts)
    count = wp.zeros(rays, dtype=int, device=device)
    if rays:
        wp.launch(_count_hits, rays, inputs=[surface.mesh.id, starts, towards], outputs=[count], device=device)
    counts = count.numpy()
    first = np.concatenate(([0], np.cumsum(counts)[:-1])) if rays else np.zeros(0, dtype=np.int64)
    total = int(counts.sum())
    face = wp.full(total, -1, dtype=int, device=device)
    t = wp.zeros(total, dtype=float, device=device)
    normal = wp.zeros(total, dtype=wp.vec3, device=device)
    if total:
        wp.launch(_march_hits, rays, inputs=[surface.mesh.id, starts, towards,
                                             wp.array(first.astype(np.int32), dtype=int, device=device), count,
                                             float(step_mm)], outputs=[face, t, normal], device=device)
    ray = np.repeat(np.arange(rays), counts)
    found = face.numpy() >= 0
    return ray[found], face.numpy()[found], t.numpy()[found].astype(np.float64), normal.numpy()[found].astype(np.float64)


def points_near_segments(points_mm: np.ndarray, a_mm: np.ndarray, b_mm: np.ndarray, radius_mm: np.ndarray,
                         device=None) -> np.ndarray:
    """Bool per point: within ``radius[s]`` of some segment s = (a[s], b[s]) (exact float64 distance)."""
    points = np.asarray(points_mm, dtype=np.float64).reshape(-1, 3)
    a, b = np.asarray(a_mm, dtype=np.float64).reshape(-1, 3), np.asarray(b_mm, dtype=np.float64).reshape(-1, 3)
    radius = np.asarray(radius_mm, dtype=np.float64).reshape(-1)
    if not len(points) or not len(a):
        return np.zeros(len(points), dtype=bool)
    device = wp.get_device(device)
    grow = radius[:, None] + 1e-5 * (1.0 + np.abs(np.vstack((a, b))).max())  # float32 boxes hold every candidate
    lowers = (np.minimum(a, b) - grow).astype(np.float32)
    uppers = (np.maximum(a, b) + grow).astype(np.float32)
    bvh = wp.Bvh(wp.array(lowers, dtype=wp.vec3, device=device), wp.array(uppers, dtype=wp.vec3, device=device))
    near = wp.zeros(len(points), dtype=wp.int8, device=device)
    as_vec3d = lambda x: wp.array(x, dtype=wp.vec3d, device=device)  # noqa: E731
    wp.launch(_near_segments, len(points), inputs=[as_vec3d(points), bvh.id, as_vec3d(a), as_vec3d(b),
                                                   wp.array(radius, dtype=wp.float64, device=device)],
              outputs=[near], device=device)
    return near.numpy().astype(bool)
