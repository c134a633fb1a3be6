"""Device kernels: the balloon's and the stent's contact with the coil, and signed wall distances
of arbitrary points (for fitting a device into the vessel).

The balloon is a tube about an axis polyline (stations k = 0..K−1, mm) whose
radius at station k is r_k = f · r_cap,k with f ∈ [0, 1] the inflation of its
world (set by the host between frames) and r_cap,k = min(nominal radius, wall
distance of the station): it grows to its nominal diameter but never through the
vessel wall. A node at x sees, on each axis segment, the closest axis point p(t)
and the radius r(t) interpolated there; the gap is |x − p(t)| − r(t) − d/2 on the
segment where it is smallest, and the force is the contact law of that gap along
(x − p)/|x − p| (out of the balloon).
"""

import warp as wp

from .contact import (FAR_MM, contact_force_magnitude, edge_in_contact_pass, from_fixed, segment_closest_params,
                      to_fixed, vec3l, wall_query)
from .rod import F64_0, F64_1


@wp.kernel
def wall_distances(mesh: wp.uint64, vertices: wp.array(dtype=wp.vec3d), faces: wp.array(dtype=wp.int32),
                   origin: wp.vec3d, points: wp.array(dtype=wp.vec3d), distance: wp.array(dtype=wp.float64)):
    """Signed distance (mm, > 0 inside the lumen) of each point to the wall."""
    i = wp.tid()
    face, dist, inward = wall_query(mesh, vertices, faces, 0, origin, points[i], FAR_MM)
    distance[i] = dist


@wp.kernel
def balloon_contact(
    x: wp.array(dtype=wp.vec3d),
    free: wp.array(dtype=wp.int32),
    world_of: wp.array(dtype=wp.int32),
    running: wp.array(dtype=wp.int32),
    node_radius: wp.array(dtype=wp.float64),
    contact_share: wp.array(dtype=wp.float64),
    stations: wp.array(dtype=wp.vec3d),
    cap_radius: wp.array(dtype=wp.float64),
    station_first: wp.array(dtype=wp.int32),
    station_count: wp.array(dtype=wp.int32),
    inflation: wp.array(dtype=wp.float64),
    p0: wp.float64,
    c0: wp.float64,
    u_linear: wp.float64,
    force: wp.array(dtype=wp.vec3d),
):
    """Balloon force on each free node (µN; zero without a balloon or when deflated),
    times its contact share (½ at a free end, as the wall's)."""
    i = wp.tid()
    f = wp.vec3d(F64_0, F64_0, F64_0)
    w = world_of[i]
    fraction = inflation[w]
    count = station_count[w]
    if free[i] != 0 and running[w] != 0 and count >= 2 and fraction > F64_0:
        best = FAR_MM
        normal = f
        first = station_first[w]
        for k in range(first, first + count - 1):
            a = stations[k]
            b = stations[k + 1]
            ab = b - a
            t = wp.clamp(wp.dot(x[i] - a, ab) / wp.dot(ab, ab), F64_0, F64_1)
            delta = x[i] - (a + t * ab)
            dist = wp.length(delta)
            gap = dist - fraction * ((F64_1 - t) * cap_radius[k] + t * cap_radius[k + 1]) - node_radius[i]
            if gap < best and dist > wp.float64(1.0e-12):
                best = gap
                normal = delta / dist
        if best < c0:
            f = contact_share[i] * contact_force_magnitude(best, p0, c0, u_linear) * normal
    force[i] = f


@wp.kernel
def add_forces(extra: wp.array(dtype=wp.vec3d), force: wp.array(dtype=wp.vec3d)):
    i = wp.tid()
    force[i] = force[i] + extra[i]


@wp.kernel
def strut_contact(
    x: wp.array(dtype=wp.vec3d),
    free: wp.array(dtype=wp.int32),
    has_next: wp.array(dtype=wp.int32),
    world_of: wp.array(dtype=wp.int32),
    running: wp.array(dtype=wp.int32),
    node_radius: wp.array(dtype=wp.float64),
    grid: wp.uint64,
    strut_start: wp.array(dtype=wp.vec3d),
    strut_end: wp.array(dtype=wp.vec3d),
    strut_radius: wp.float64,
    query_radius: wp.float64,
    p0: wp.float64,
    c0: wp.float64,
    u_linear: wp.float64,
    force_start: wp.array(dtype=wp.vec3d),
    force_end: wp.array(dtype=wp.vec3d),
):
    """Stent struts on coil edge a: the coil–coil segment–segment law of the gap
    |p_a − p_s| − (r_a + r_strut) between the closest points of edge a and each
    strut (fixed rods, found in a static hash grid of strut midpoints grouped by
    world), split between a's nodes by the barycentric weight; fixed-point sums."""
    a = wp.tid()
    sum_start = vec3l()
    sum_end = vec3l()
    w = world_of[a]
    if edge_in_contact_pass(free, has_next, a) and running[w] != 0:
        pa0 = x[a]
        pa1 = x[a + 1]
        mid = wp.float64(0.5) * (pa0 + pa1)
        query = wp.hash_grid_query(grid, mid, query_radius, w)
        s = int(0)
        while wp.hash_grid_query_next(query, s):
            st = segment_closest_params(pa0, pa1, strut_start[s], strut_end[s])
            delta = pa0 + st[0] * (pa1 - pa0) - strut_start[s] - st[1] * (strut_end[s] - strut_start[s])
            dist = wp.length(delta)
            gap = dist - node_radius[a] - strut_radius
            if gap < c0 and dist > wp.float64(1.0e-12):
                f = (contact_force_magnitude(gap, p0, c0, u_linear) / dist) * delta
                sum_start = sum_start + to_fixed((F64_1 - st[0]) * f)
                sum_end = sum_end + to_fixed(st[0] * f)
    force_start[a] = from_fixed(sum_start)
    force_end[a] = from_fixed(sum_end)


@wp.kernel
def gather_edge_forces(free: wp.array(dtype=wp.int32), has_next: wp.array(dtype=wp.int32),
                       force_start: wp.array(dtype=wp.vec3d), force_end: wp.array(dtype=wp.vec3d),
                       force: wp.array(dtype=wp.vec3d)):
    """Node i's shares of edges i (start) and i − 1 (end)."""
    i = wp.tid()
    f = wp.vec3d(F64_0, F64_0, F64_0)
    if free[i] != 0:
        if has_next[i] != 0:
            f = f + force_start[i]
        if i >= 1:
            if has_next[i - 1] != 0:
                f = f + force_end[i - 1]
    force[i] = f
