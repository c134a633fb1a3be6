"""Device kernels: the balloon's contact with the coil, and signed wall distances
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

from .contact import FAR_MM, contact_force_magnitude, wall_query
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
    """Balloon force on each free node (µN; zero without a balloon or when deflated)."""
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
            f = contact_force_magnitude(best, p0, c0, u_linear) * normal
    force[i] = f


@wp.kernel
def add_forces(extra: wp.array(dtype=wp.vec3d), force: wp.array(dtype=wp.vec3d)):
    i = wp.tid()
    force[i] = force[i] + extra[i]
