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

from .contact import (FAR_MM, add_edge_shares, contact_force_magnitude, contact_stiffness, edge_in_contact_pass,
                      from_fixed, segment_closest_params, to_fixed, vec3l, wall_query)
from .chord import chord_stiffness
from .implicit import from_fixed_sym, to_fixed_sym
from .rod import F64_0, F64_1


@wp.kernel
def wall_distances(mesh: wp.uint64, vertices: wp.array(dtype=wp.vec3d), faces: wp.array(dtype=wp.int32),
                   origin: wp.vec3d, points: wp.array(dtype=wp.vec3d), distance: wp.array(dtype=wp.float64)):
    """Signed distance (mm, > 0 inside the lumen) of each point to the wall."""
    i = wp.tid()
    face, dist, inward = wall_query(mesh, vertices, faces, 0, origin, points[i], FAR_MM)
    distance[i] = dist


@wp.func
def balloon_gap(p: wp.vec3d, radius: wp.float64, stations: wp.array(dtype=wp.vec3d),
                cap_radius: wp.array(dtype=wp.float64), first: int, count: int, fraction: wp.float64):
    """(gap mm, unit normal out of the balloon) of a node of radius ``radius`` at p:
    the axis segment where |p − a(t)| − fraction · r(t) − radius is smallest."""
    best = FAR_MM
    normal = wp.vec3d(F64_0, F64_0, F64_0)
    for k in range(first, first + count - 1):
        a = stations[k]
        ab = stations[k + 1] - a
        t = wp.clamp(wp.dot(p - a, ab) / wp.dot(ab, ab), F64_0, F64_1)
        delta = p - (a + t * ab)
        dist = wp.length(delta)
        gap = dist - fraction * ((F64_1 - t) * cap_radius[k] + t * cap_radius[k + 1]) - radius
        if gap < best and dist > wp.float64(1.0e-12):
            best = gap
            normal = delta / dist
    return best, normal


@wp.kernel
def point_balloon_gaps(points: wp.array(dtype=wp.vec3d), radius: wp.float64, stations: wp.array(dtype=wp.vec3d),
                       cap_radius: wp.array(dtype=wp.float64), count: int, gaps: wp.array(dtype=wp.float64)):
    """Gap (mm) between a sphere of ``radius`` at each point and the fully inflated balloon of ``count`` stations
    (:func:`balloon_gap`; < 0: overlapping): for the checks before a run."""
    i = wp.tid()
    gap, normal = balloon_gap(points[i], radius, stations, cap_radius, 0, count, F64_1)
    gaps[i] = gap


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
        gap, normal = balloon_gap(x[i], node_radius[i], stations, cap_radius, station_first[w], count, fraction)
        if gap < c0:
            f = contact_share[i] * contact_force_magnitude(gap, p0, c0, u_linear) * normal
    force[i] = f


@wp.kernel
def add_forces(extra: wp.array(dtype=wp.vec3d), force: wp.array(dtype=wp.vec3d)):
    i = wp.tid()
    force[i] = force[i] + extra[i]


@wp.func
def strut_gap(pa0: wp.vec3d, pa1: wp.vec3d, s0: wp.vec3d, s1: wp.vec3d, edge_radius: wp.float64,
              strut_radius: wp.float64):
    """(s, gap mm, δ, |δ|) of coil edge pa0–pa1 and strut s0–s1: closest points
    pa0 + s (pa1 − pa0) and s0 + t (s1 − s0), δ from the strut's to the edge's, gap
    |δ| less the two radii; gap FAR_MM where they meet (no normal)."""
    st = segment_closest_params(pa0, pa1, s0, s1)
    delta = pa0 + st[0] * (pa1 - pa0) - s0 - st[1] * (s1 - s0)
    dist = wp.length(delta)
    gap = FAR_MM
    if dist > wp.float64(1.0e-12):
        gap = dist - edge_radius - strut_radius
    return st[0], gap, delta, dist


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
            along, gap, delta, dist = strut_gap(pa0, pa1, strut_start[s], strut_end[s], node_radius[a],
                                                strut_radius)
            if gap < c0:
                f = (contact_force_magnitude(gap, p0, c0, u_linear) / dist) * delta
                sum_start = sum_start + to_fixed((F64_1 - along) * f)
                sum_end = sum_end + to_fixed(along * f)
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
        f = add_edge_shares(f, force_start, force_end, has_next, i)
    force[i] = f


# --- contact stiffness for the linearly implicit step (implicit.py) ------------------
# Gauss–Newton, as the wall's: the law's stiffness k(h) = −d|F|/dh along the contact
# normal n (the curvature term |F| ∂n/∂x, which makes the Hessian indefinite about a
# convex obstacle, is dropped), so the system matrix stays positive definite.


@wp.kernel
def balloon_stiffness(
    x: wp.array(dtype=wp.vec3d),
    free: wp.array(dtype=wp.int32),
    fixed: wp.array(dtype=wp.int32),
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
    dt: wp.float64,
    diag: wp.array(dtype=wp.mat33d),
    diag_exact: wp.array(dtype=wp.mat33d),
    x_end: wp.array(dtype=wp.vec3d),
    chord: int,
):
    """Adds dt² s_i k n nᵀ of node i's balloon contact (the gap and normal balloon_contact
    uses, s_i its contact share) to its diagonal block of M + dt² H (g). With ``chord``, k
    is the law's chord between the gap at x and at the predicted end ``x_end``
    (kernels/chord.py), and a contact that enters the range there counts (its normal)."""
    i = wp.tid()
    w = world_of[i]
    fraction = inflation[w]
    count = station_count[w]
    if free[i] != 0 and fixed[i] == 0 and running[w] != 0 and count >= 2 and fraction > F64_0:
        gap, normal = balloon_gap(x[i], node_radius[i], stations, cap_radius, station_first[w], count, fraction)
        gap_end = gap
        if chord != 0:
            gap_end, normal_end = balloon_gap(x_end[i], node_radius[i], stations, cap_radius, station_first[w], count,
                                              fraction)
            if gap >= c0:
                normal = normal_end
        if gap < c0 or gap_end < c0:
            block = (dt * dt * contact_share[i] * chord_stiffness(gap, gap_end, p0, c0, u_linear)) * \
                wp.outer(normal, normal)
            diag[i] = diag[i] + block
            diag_exact[i] = diag_exact[i] + block


@wp.kernel
def strut_stiffness(
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
    start: wp.array(dtype=wp.mat33d),
    end: wp.array(dtype=wp.mat33d),
    cross: wp.array(dtype=wp.mat33d),
    x_end: wp.array(dtype=wp.vec3d),
    chord: int,
):
    """Edge a's strut contacts (the pairs strut_contact finds): with w = (1 − s, s) the
    weights of its two nodes, Σ k w wᵀ ⊗ n nᵀ as its blocks (start, start), (end, end)
    and (start, end) (µN/mm); the struts are fixed, so this is all the stiffness they
    add. Fixed-point sums: independent of the grid's order. With ``chord``, k is the law's
    chord between the gap at x and at the predicted end ``x_end`` (kernels/chord.py), and a
    strut the edge enters the range of there counts (with that end's s and normal)."""
    a = wp.tid()
    s_diag = vec3l()
    s_off = vec3l()
    e_diag = vec3l()
    e_off = vec3l()
    c_diag = vec3l()
    c_off = vec3l()
    w = world_of[a]
    if edge_in_contact_pass(free, has_next, a) and running[w] != 0:
        pa0 = x[a]
        pa1 = x[a + 1]
        query = wp.hash_grid_query(grid, wp.float64(0.5) * (pa0 + pa1), query_radius, w)
        s = int(0)
        while wp.hash_grid_query_next(query, s):
            along, gap, delta, dist = strut_gap(pa0, pa1, strut_start[s], strut_end[s], node_radius[a],
                                                strut_radius)
            gap_end = gap
            if chord != 0:
                along_end, gap_end, delta_end, dist_end = strut_gap(x_end[a], x_end[a + 1], strut_start[s],
                                                                    strut_end[s], node_radius[a], strut_radius)
                if gap >= c0:
                    along, delta, dist = along_end, delta_end, dist_end
            if gap < c0 or gap_end < c0:
                nn = (chord_stiffness(gap, gap_end, p0, c0, u_linear) / (dist * dist)) * wp.outer(delta, delta)
                d, o = to_fixed_sym((F64_1 - along) * (F64_1 - along) * nn)
                s_diag = s_diag + d
                s_off = s_off + o
                d, o = to_fixed_sym(along * along * nn)
                e_diag = e_diag + d
                e_off = e_off + o
                d, o = to_fixed_sym(along * (F64_1 - along) * nn)
                c_diag = c_diag + d
                c_off = c_off + o
    start[a] = from_fixed_sym(s_diag, s_off)
    end[a] = from_fixed_sym(e_diag, e_off)
    cross[a] = from_fixed_sym(c_diag, c_off)


@wp.kernel
def add_strut_stiffness(
    has_next: wp.array(dtype=wp.int32),
    start: wp.array(dtype=wp.mat33d),
    end: wp.array(dtype=wp.mat33d),
    cross: wp.array(dtype=wp.mat33d),
    dt: wp.float64,
    diag: wp.array(dtype=wp.mat33d),
    diag_exact: wp.array(dtype=wp.mat33d),
    upper1: wp.array(dtype=wp.mat33d),
):
    """Row i of M + dt² H gains dt² × its edges' strut blocks: (i, i) from edge i
    (start) and edge i − 1 (end), (i, i + 1) from edge i (g). Zero blocks where no
    strut touches (strut_stiffness writes every edge)."""
    i = wp.tid()
    dt2 = dt * dt
    block = wp.mat33d()
    if has_next[i] != 0:
        block = block + start[i]
        upper1[i] = upper1[i] + dt2 * cross[i]
    if i >= 1:
        if has_next[i - 1] != 0:
            block = block + end[i - 1]
    diag[i] = diag[i] + dt2 * block
    diag_exact[i] = diag_exact[i] + dt2 * block
