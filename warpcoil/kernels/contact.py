"""Contact pass: MODEL.md's exponential pressure–overclosure law (Abaqus form,
corrected), the one implementation used by coil–wall and coil–coil contact.

With clearance h (mm, > 0 apart) and u = 1 − h/c0::

    |F| = 0                                              h ≥ c0
    |F| = P0/(e−1) · u (e^u − 1)                         1 < u < 7
    |F| = P0/(e−1) · [7(e^7 − 1) + (8e^7 − 1)(u − 7)]     u ≥ 7

|F|(0) = P0, |F|(−6 c0) ≈ 4463.43 P0, value and slope continuous at u = 7.
"""

import warp as wp

E_MINUS_1 = wp.constant(wp.float64(1.718281828459045))
U_LINEAR = wp.constant(wp.float64(7.0))


@wp.func
def contact_force_magnitude(h: wp.float64, p0: wp.float64, c0: wp.float64, u_linear: wp.float64) -> wp.float64:
    """|F| (µN) at clearance h (mm) for force P0 (µN) at zero clearance and onset c0 (mm).

    ``u_linear`` is where the exponential gives way to its tangent line: 7 in
    MODEL.md; a solver may start it earlier (see Solver.contact_u_linear) so the
    law's stiffness never exceeds what its explicit step can integrate."""
    if h >= c0:
        return wp.float64(0.0)
    u = wp.float64(1.0) - h / c0
    if u < u_linear:
        return p0 / E_MINUS_1 * u * (wp.exp(u) - wp.float64(1.0))
    e = wp.exp(u_linear)
    return p0 / E_MINUS_1 * (u_linear * (e - wp.float64(1.0)) + (e * (wp.float64(1.0) + u_linear) - wp.float64(1.0))
                             * (u - u_linear))


@wp.func
def contact_stiffness(h: wp.float64, p0: wp.float64, c0: wp.float64, u_linear: wp.float64) -> wp.float64:
    """−d|F|/dh (µN/mm): the law's local stiffness."""
    if h >= c0:
        return wp.float64(0.0)
    u = wp.min(wp.float64(1.0) - h / c0, u_linear)
    return p0 / (E_MINUS_1 * c0) * (wp.exp(u) * (wp.float64(1.0) + u) - wp.float64(1.0))


@wp.kernel
def evaluate_law(
    h: wp.array(dtype=wp.float64), p0: wp.float64, c0: wp.float64, u_linear: wp.float64,
    force: wp.array(dtype=wp.float64), stiffness: wp.array(dtype=wp.float64),
):
    """The law and its stiffness at each clearance (for validation and the step bound)."""
    i = wp.tid()
    force[i] = contact_force_magnitude(h[i], p0, c0, u_linear)
    stiffness[i] = contact_stiffness(h[i], p0, c0, u_linear)


# --- coil–wall -----------------------------------------------------------------
FAR_MM = wp.constant(wp.float64(1.0e6))


NO_FACE = wp.constant(-1)


@wp.func
def wall_query(mesh: wp.uint64, vertices: wp.array(dtype=wp.vec3d), faces: wp.array(dtype=wp.int32),
               origin: wp.vec3d, p: wp.vec3d, max_dist: wp.float64):
    """Closest wall face within ``max_dist`` of a point: (face or NO_FACE, signed
    distance in mm, > 0 inside the lumen, unit normal pointing into the lumen).

    The BVH (float32, mesh stored relative to ``origin``) finds the face and the
    inside/outside sign (angle-weighted pseudo-normal); the distance is then
    evaluated in float64 on that face."""
    local = p - origin
    q = wp.mesh_query_point_sign_normal(
        mesh, wp.vec3f(wp.float32(local[0]), wp.float32(local[1]), wp.float32(local[2])), wp.float32(max_dist))
    zero = wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(0.0))
    if not q.result:
        return NO_FACE, max_dist, zero
    f = q.face
    v0 = vertices[faces[3 * f]]
    v1 = vertices[faces[3 * f + 1]]
    v2 = vertices[faces[3 * f + 2]]
    u = wp.float64(q.u)
    v = wp.float64(q.v)
    delta = local - (u * v0 + v * v1 + (wp.float64(1.0) - u - v) * v2)
    dist = wp.length(delta)
    inside = q.sign < wp.float32(0.0)
    inward = -wp.normalize(wp.cross(v1 - v0, v2 - v0))  # faces are wound with outward normals
    if dist > wp.float64(1.0e-12):
        inward = delta / dist
        if not inside:
            inward = -inward
    if inside:
        return f, dist, inward
    return f, -dist, inward


@wp.kernel
def wall_contact(
    x: wp.array(dtype=wp.vec3d),
    free: wp.array(dtype=wp.int32),
    node_radius: wp.array(dtype=wp.float64),
    mesh: wp.uint64,
    vertices: wp.array(dtype=wp.vec3d),
    faces: wp.array(dtype=wp.int32),
    origin: wp.vec3d,
    p0: wp.float64,
    c0: wp.float64,
    u_linear: wp.float64,
    search_mm: wp.float64,
    inside: wp.array(dtype=wp.int32),
    force: wp.array(dtype=wp.vec3d),
    centre_distance: wp.array(dtype=wp.float64),
):
    """Wall force on each free node (µN): the contact law of the gap
    h = signed distance − d/2, along the inward wall normal.

    The BVH search is limited to ``search_mm`` beyond the contact range: a node
    farther from the wall feels no force, and keeps the side (``inside``: 1 in
    the lumen, 0 outside, −1 not yet known) it had when last seen near the
    wall — it cannot change side without coming near it, as long as a step
    moves it less than ``search_mm``. Nodes whose side is unknown (just out of
    the catheter) get a full search. Writes the centre's signed distance (mm;
    ± the search radius when no face is that close; +FAR in the catheter)."""
    i = wp.tid()
    f = wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(0.0))
    signed = FAR_MM
    if free[i] != 0:
        reach = node_radius[i] + c0 + search_mm
        side = inside[i]
        if side < 0:
            reach = FAR_MM
        face, signed, inward = wall_query(mesh, vertices, faces, origin, x[i], reach)
        if face == NO_FACE:
            if side == 0:
                signed = -reach
        else:
            if signed > wp.float64(0.0):
                inside[i] = 1
            else:
                inside[i] = 0
            f = contact_force_magnitude(signed - node_radius[i], p0, c0, u_linear) * inward
    else:
        inside[i] = -1
    force[i] = f
    centre_distance[i] = signed


# --- coil–coil -----------------------------------------------------------------
@wp.func
def segment_closest_params(p1: wp.vec3d, q1: wp.vec3d, p2: wp.vec3d, q2: wp.vec3d) -> wp.vec2d:
    """Parameters (s, t) in [0, 1]² of the closest points of segments p1q1 and p2q2
    (Ericson, Real-Time Collision Detection, §5.1.9)."""
    d1 = q1 - p1
    d2 = q2 - p2
    r = p1 - p2
    a = wp.dot(d1, d1)
    e = wp.dot(d2, d2)
    f = wp.dot(d2, r)
    c = wp.dot(d1, r)
    b = wp.dot(d1, d2)
    zero = wp.float64(0.0)
    one = wp.float64(1.0)
    denom = a * e - b * b
    s = zero
    if denom > wp.float64(1.0e-14) * a * e:
        s = wp.clamp((b * f - c * e) / denom, zero, one)
    t = (b * s + f) / e
    if t < zero:
        t = zero
        s = wp.clamp(-c / a, zero, one)
    elif t > one:
        t = one
        s = wp.clamp((b - c) / a, zero, one)
    return wp.vec2d(s, t)


@wp.func
def edge_in_contact_pass(free: wp.array(dtype=wp.int32), has_next: wp.array(dtype=wp.int32), e: int) -> bool:
    """Edge e feels coil contact when it exists and one of its nodes is free."""
    if has_next[e] == 0:
        return False
    return free[e] != 0 or free[e + 1] != 0


@wp.func
def edge_is_obstacle(free: wp.array(dtype=wp.int32), has_next: wp.array(dtype=wp.int32),
                     fixed: wp.array(dtype=wp.int32), e: int) -> bool:
    """Edge e can be touched: it exists and is free, or it lies in the catheter,
    where it stands in for the catheter (kinematic: it takes no force). Parked
    (withdrawn) and clamped edges cannot be touched."""
    if has_next[e] == 0:
        return False
    if free[e] != 0 or free[e + 1] != 0:
        return True
    return fixed[e] == 0 and fixed[e + 1] == 0


@wp.kernel
def edge_midpoints(x: wp.array(dtype=wp.vec3d), has_next: wp.array(dtype=wp.int32), mid: wp.array(dtype=wp.vec3d)):
    """Midpoint of each edge (the last node of a coil, which has none, keeps its own position)."""
    i = wp.tid()
    if has_next[i] != 0:
        mid[i] = wp.float64(0.5) * (x[i] + x[i + 1])
    else:
        mid[i] = x[i]


@wp.kernel
def edge_contact(
    x: wp.array(dtype=wp.vec3d),
    free: wp.array(dtype=wp.int32),
    has_next: wp.array(dtype=wp.int32),
    coil_of: wp.array(dtype=wp.int32),
    fixed: wp.array(dtype=wp.int32),
    node_radius: wp.array(dtype=wp.float64),
    grid: wp.uint64,
    mid: wp.array(dtype=wp.vec3d),
    query_radius: wp.float64,
    exclusion: int,
    p0: wp.float64,
    c0: wp.float64,
    u_linear: wp.float64,
    force_start: wp.array(dtype=wp.vec3d),
    force_end: wp.array(dtype=wp.vec3d),
    min_gap: wp.array(dtype=wp.float64),
    contacts: wp.array(dtype=wp.int32),
):
    """Segment–segment contact on edge a (so a segment cannot slip between two
    nodes): the law of the surface gap h = |p_a − p_b| − (r_a + r_b) between the
    closest points of a and every other edge b near it (hash grid of edge
    midpoints), along (p_a − p_b)/|p_a − p_b|, split between a's start and end
    node by the barycentric weight of p_a. Edges of the same coil closer than
    ``exclusion`` along it are bonded neighbours and skipped. Each pair is
    evaluated from both sides, so every edge writes only its own entries. Edges
    in the catheter stand in for the catheter: free edges are pushed off them."""
    a = wp.tid()
    zero = wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(0.0))
    f_start = zero
    f_end = zero
    gap_min = query_radius
    touching = int(0)
    if edge_in_contact_pass(free, has_next, a):
        pa0 = x[a]
        pa1 = x[a + 1]
        reach_a = wp.float64(0.5) * wp.length(pa1 - pa0) + node_radius[a] + c0
        query = wp.hash_grid_query(grid, mid[a], query_radius)
        b = int(0)
        while wp.hash_grid_query_next(query, b):
            skip = not edge_is_obstacle(free, has_next, fixed, b)
            if coil_of[b] == coil_of[a] and wp.abs(b - a) <= exclusion:
                skip = True
            if not skip:
                pb0 = x[b]
                pb1 = x[b + 1]
                # bounding spheres first: most candidates end here
                if wp.length(mid[a] - mid[b]) < reach_a + wp.float64(0.5) * wp.length(pb1 - pb0) + node_radius[b]:
                    st = segment_closest_params(pa0, pa1, pb0, pb1)
                    delta = pa0 + st[0] * (pa1 - pa0) - pb0 - st[1] * (pb1 - pb0)
                    dist = wp.length(delta)
                    gap = dist - node_radius[a] - node_radius[b]
                    gap_min = wp.min(gap_min, gap)
                    if gap < c0 and dist > wp.float64(1.0e-12):
                        f = (contact_force_magnitude(gap, p0, c0, u_linear) / dist) * delta
                        f_start = f_start + (wp.float64(1.0) - st[0]) * f
                        f_end = f_end + st[0] * f
                        touching += 1
    force_start[a] = f_start
    force_end[a] = f_end
    min_gap[a] = gap_min
    contacts[a] = touching


@wp.kernel
def gather_contact(
    free: wp.array(dtype=wp.int32),
    has_next: wp.array(dtype=wp.int32),
    wall_force: wp.array(dtype=wp.vec3d),
    force_start: wp.array(dtype=wp.vec3d),
    force_end: wp.array(dtype=wp.vec3d),
    force: wp.array(dtype=wp.vec3d),
):
    """Contact force on node i (µN): wall + its shares of edges i (start) and i−1 (end)."""
    i = wp.tid()
    f = wall_force[i]
    if free[i] != 0:
        if has_next[i] != 0:
            f = f + force_start[i]
        if i >= 1:
            if has_next[i - 1] != 0:
                f = f + force_end[i - 1]
    force[i] = f
