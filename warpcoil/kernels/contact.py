"""Contact pass: MODEL.md's exponential pressure–overclosure law (Abaqus form,
corrected), the one implementation used by coil–wall and coil–coil contact.

With clearance h (mm, > 0 apart) and u = 1 − h/c0::

    |F| = 0                                              h ≥ c0
    |F| = P0/(e−1) · u (e^u − 1)                         1 < u < 7
    |F| = P0/(e−1) · [7(e^7 − 1) + (8e^7 − 1)(u − 7)]     u ≥ 7

|F|(0) = P0, |F|(−6 c0) ≈ 4463.43 P0, value and slope continuous at u = 7.
"""

import warp as wp

from .rod import F64_0, F64_1

E_MINUS_1 = wp.constant(wp.float64(1.718281828459045))
U_LINEAR = wp.constant(wp.float64(7.0))


@wp.func
def contact_law(h: wp.float64, p0: wp.float64, c0: wp.float64, u_linear: wp.float64):
    """|F| (µN) and its stiffness −d|F|/dh (µN/mm) at clearance h (mm) for force P0 (µN)
    at zero clearance and onset c0 (mm), from one exponential.

    ``u_linear`` is where the exponential gives way to its tangent line: 7 in
    MODEL.md; a solver may start it earlier (see Solver.contact_u_linear) so the
    law's stiffness never exceeds what its explicit step can integrate."""
    if h >= c0:
        return wp.float64(0.0), wp.float64(0.0)
    u = wp.float64(1.0) - h / c0
    u_exp = wp.min(u, u_linear)
    e = wp.exp(u_exp)
    k = p0 / (E_MINUS_1 * c0) * (e * (wp.float64(1.0) + u_exp) - wp.float64(1.0))
    if u < u_linear:
        return p0 / E_MINUS_1 * u * (e - wp.float64(1.0)), k
    return p0 / E_MINUS_1 * (u_linear * (e - wp.float64(1.0)) + (e * (wp.float64(1.0) + u_linear) - wp.float64(1.0))
                             * (u - u_linear)), k


@wp.func
def contact_force_magnitude(h: wp.float64, p0: wp.float64, c0: wp.float64, u_linear: wp.float64) -> wp.float64:
    """|F| (µN) at clearance h (mm): :func:`contact_law`'s force."""
    f, k = contact_law(h, p0, c0, u_linear)
    return f


@wp.func
def contact_stiffness(h: wp.float64, p0: wp.float64, c0: wp.float64, u_linear: wp.float64) -> wp.float64:
    """−d|F|/dh (µN/mm): :func:`contact_law`'s local stiffness."""
    f, k = contact_law(h, p0, c0, u_linear)
    return k


@wp.kernel
def evaluate_law(
    h: wp.array(dtype=wp.float64), p0: wp.float64, c0: wp.float64, u_linear: wp.float64,
    force: wp.array(dtype=wp.float64), stiffness: wp.array(dtype=wp.float64),
):
    """The law and its stiffness at each clearance (for validation and the step bound)."""
    i = wp.tid()
    force[i] = contact_force_magnitude(h[i], p0, c0, u_linear)
    stiffness[i] = contact_stiffness(h[i], p0, c0, u_linear)


# --- fixed-point sums -------------------------------------------------------------
# Contact forces on a node are sums over partners found in hash-grid order, which
# depends on the grid (its cell size, rebuild time, the other ensemble members in
# it, the device's sort). Summed as integers of FIXED_POINT_PER_UN units per µN
# (resolution 1.5e-8 µN), they are exactly order-independent: the same forces
# bit for bit on CPU and CUDA, with any skin, alone or batched. A term above
# FIXED_POINT_LIMIT_UN (1 kN: only a run that has already blown up) makes the
# sum NaN, so the int64 sum (range ±1.4e11 µN) cannot overflow.
FIXED_POINT_PER_UN = wp.constant(wp.float64(67108864.0))  # 2^26
FIXED_POINT_LIMIT_UN = wp.constant(wp.float64(1.0e9))
vec3l = wp.types.vector(length=3, dtype=wp.int64)


@wp.func
def to_fixed(f: wp.vec3d) -> vec3l:
    """µN → fixed point (|components| clamped to FIXED_POINT_LIMIT_UN; NaN → 0;
    the caller flags both through :func:`finite_vec`)."""
    out = vec3l()
    for k in range(3):
        c = wp.clamp(f[k], -FIXED_POINT_LIMIT_UN, FIXED_POINT_LIMIT_UN)
        if c == c:
            out[k] = wp.int64(c * FIXED_POINT_PER_UN)
    return out


@wp.func
def from_fixed(f: vec3l) -> wp.vec3d:
    return wp.vec3d(wp.float64(f[0]), wp.float64(f[1]), wp.float64(f[2])) / FIXED_POINT_PER_UN


@wp.func
def finite_vec(f: wp.vec3d) -> bool:
    """Every component finite and within FIXED_POINT_LIMIT_UN."""
    return wp.abs(f[0]) <= FIXED_POINT_LIMIT_UN and wp.abs(f[1]) <= FIXED_POINT_LIMIT_UN and \
        wp.abs(f[2]) <= FIXED_POINT_LIMIT_UN


# --- coil–wall -----------------------------------------------------------------
FAR_MM = wp.constant(wp.float64(1.0e6))
NO_FACE = wp.constant(-1)
NO_ANCHOR = wp.constant(-1)
ANCHOR_SHARE = wp.constant(wp.float64(0.9))  # of the slack a node may move before it is searched again
ANCHOR_MARGIN_MM = wp.constant(wp.float64(1.0e-5))  # ≫ the float32 BVH's error in picking the closest face


@wp.func
def wall_query_sided(mesh: wp.uint64, vertices: wp.array(dtype=wp.vec3d), faces: wp.array(dtype=wp.int32),
                     face_first: int, origin: wp.vec3d, p: wp.vec3d, max_dist: wp.float64, confirm_within: wp.float64):
    """:func:`wall_query`, whose "outside" answer is confirmed by the winding number only
    within ``confirm_within`` (mm) of the wall: farther out the pseudo-normal's side is
    taken as it is (for a caller that needs no side there)."""
    local = p - origin
    local32 = wp.vec3f(wp.float32(local[0]), wp.float32(local[1]), wp.float32(local[2]))
    q = wp.mesh_query_point_sign_normal(mesh, local32, wp.float32(max_dist))
    zero = wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(0.0))
    if not q.result:
        return NO_FACE, max_dist, zero
    f = q.face
    base = 3 * (face_first + f)
    v0 = vertices[faces[base]]
    v1 = vertices[faces[base + 1]]
    v2 = vertices[faces[base + 2]]
    u = wp.float64(q.u)
    v = wp.float64(q.v)
    delta = local - (u * v0 + v * v1 + (wp.float64(1.0) - u - v) * v2)
    dist = wp.length(delta)
    inside = q.sign < wp.float32(0.0)
    if not inside and dist <= confirm_within:
        inside = wp.mesh_query_point_sign_winding_number(mesh, local32, wp.float32(max_dist)).sign < wp.float32(0.0)
    inward = -wp.normalize(wp.cross(v1 - v0, v2 - v0))  # faces are wound with outward normals
    if dist > wp.float64(1.0e-12):
        inward = delta / dist
        if not inside:
            inward = -inward
    if inside:
        return f, dist, inward
    return f, -dist, inward


@wp.func
def wall_query(mesh: wp.uint64, vertices: wp.array(dtype=wp.vec3d), faces: wp.array(dtype=wp.int32),
               face_first: int, origin: wp.vec3d, p: wp.vec3d, max_dist: wp.float64):
    """Closest wall face within ``max_dist`` of a point: (face or NO_FACE, signed
    distance in mm, > 0 inside the lumen, unit normal pointing into the lumen).

    The BVH (float32, mesh stored relative to ``origin``) finds the face and the
    inside/outside sign (angle-weighted pseudo-normal); the distance is then
    evaluated in float64 on that face (the mesh's faces start at ``face_first``
    in the flat ``faces`` array of every wall of an ensemble). Warp's
    pseudo-normal sums the normals of every face within 10⁻³ mean edge lengths
    of the closest distance, adjacent or not, so near a vessel's medial axis
    (opposite walls equidistant) it can call an inside point outside; an
    "outside" answer is therefore confirmed by the winding number (exact for
    the closed wall; the mesh is built with ``support_winding_number``)."""
    return wall_query_sided(mesh, vertices, faces, face_first, origin, p, max_dist, FAR_MM)


# Feature flags of a wall triangle abc (``owners``): the edges and vertices it counts
# in the wall's feature sum (each edge and vertex is counted by one of its faces).
OWN_EDGE_AB = wp.constant(1)
OWN_EDGE_BC = wp.constant(2)
OWN_EDGE_CA = wp.constant(4)
OWN_VERTEX_A = wp.constant(8)
OWN_VERTEX_B = wp.constant(16)
OWN_VERTEX_C = wp.constant(32)
BOX_MARGIN_MM = wp.constant(wp.float64(1.0e-4))  # ≫ float32 rounding of the BVH's boxes and closest points
# a face farther than the contact range by this is skipped with its edges and vertices (each at
# least as far: they belong to the closed face); ≫ the float64 rounding of either distance
FEATURE_SKIP_MM = wp.constant(wp.float64(1.0e-9))


@wp.func
def closest_on_segment(p: wp.vec3d, a: wp.vec3d, b: wp.vec3d) -> wp.vec3d:
    ab = b - a
    length_sq = wp.dot(ab, ab)
    t = wp.float64(0.0)
    if length_sq > wp.float64(0.0):
        t = wp.clamp(wp.dot(p - a, ab) / length_sq, wp.float64(0.0), wp.float64(1.0))
    return a + t * ab


@wp.func
def closest_on_triangle(p: wp.vec3d, a: wp.vec3d, b: wp.vec3d, c: wp.vec3d) -> wp.vec3d:
    """Point of triangle abc closest to p, float64 (Ericson, Real-Time Collision
    Detection, §5.1.5; a degenerate triangle falls back to its edges)."""
    ab = b - a
    ac = c - a
    ap = p - a
    d1 = wp.dot(ab, ap)
    d2 = wp.dot(ac, ap)
    if d1 <= wp.float64(0.0) and d2 <= wp.float64(0.0):
        return a
    bp = p - b
    d3 = wp.dot(ab, bp)
    d4 = wp.dot(ac, bp)
    if d3 >= wp.float64(0.0) and d4 <= d3:
        return b
    vc = d1 * d4 - d3 * d2
    if vc <= wp.float64(0.0) and d1 >= wp.float64(0.0) and d3 <= wp.float64(0.0):
        return closest_on_segment(p, a, b)
    cp = p - c
    d5 = wp.dot(ab, cp)
    d6 = wp.dot(ac, cp)
    if d6 >= wp.float64(0.0) and d5 <= d6:
        return c
    vb = d5 * d2 - d1 * d6
    if vb <= wp.float64(0.0) and d2 >= wp.float64(0.0) and d6 <= wp.float64(0.0):
        return closest_on_segment(p, a, c)
    va = d3 * d6 - d5 * d4
    if va <= wp.float64(0.0) and d4 - d3 >= wp.float64(0.0) and d5 - d6 >= wp.float64(0.0):
        return closest_on_segment(p, b, c)
    total = va + vb + vc
    if not (total > wp.float64(0.0)):  # degenerate (sliver) triangle: nearest of its edges
        q = closest_on_segment(p, a, b)
        r = closest_on_segment(p, b, c)
        if wp.length_sq(p - r) < wp.length_sq(p - q):
            q = r
        r = closest_on_segment(p, c, a)
        if wp.length_sq(p - r) < wp.length_sq(p - q):
            q = r
        return q
    return a + (vb / total) * ab + (vc / total) * ac


@wp.func
def wall_feature_sum(mesh: wp.uint64, vertices: wp.array(dtype=wp.vec3d), faces: wp.array(dtype=wp.int32),
                     owners: wp.array(dtype=wp.int32), face_first: int, p: wp.vec3d, radius: wp.float64,
                     p0: wp.float64, c0: wp.float64, u_linear: wp.float64, with_stiffness: int):
    """Wall force (µN) on a node sphere at ``p`` (relative to the mesh origin) in the
    lumen: Σ_faces F(d_f) − Σ_edges F(d_e) + Σ_vertices F(d_v), each the law of the
    distance from p to that closed face, edge or vertex, along p − its closest point.
    Where one face is closest (a flat facet, a ridge, a vertex) the terms of the
    shared edges and vertices cancel the repeats exactly and leave the single
    closest-point force; in a groove between facets both faces push. Every term
    is continuous in p with a continuous gradient, so is the sum: the force of a
    potential with no jumps at facet edges (the closest-face normal of
    :func:`wall_query` jumps there). Fixed-point sum: order-independent. A face
    beyond the contact range is skipped with its edges and vertices (none of
    them nearer than the face: no term in range, the same sum).
    Also returns the distance (mm, float64) from p to the closest face within
    reach (FAR_MM if none): exact whenever it is below ``radius + c0``, and, with
    ``with_stiffness``, the normal part of −∂F/∂p (µN/mm, for the implicit step):
    the same features' k(h) n nᵀ with the same signs, summed in fixed point. One
    closest face gives the single law's k n nᵀ; in a groove, or where faces meet
    at a crease, every face that pushes adds its own direction (the net force's
    direction alone misses them). Without it the matrix is zero."""
    reach = radius + c0 + BOX_MARGIN_MM
    centre = wp.vec3f(wp.float32(p[0]), wp.float32(p[1]), wp.float32(p[2]))
    query = wp.mesh_query_sphere(mesh, centre, wp.float32(reach))  # faces within reach (float32 closest point)
    f = int(0)
    total = vec3l()
    diagonal = vec3l()
    off = vec3l()
    nearest = FAR_MM
    while wp.mesh_query_next(query, f):
        k = face_first + f
        a = vertices[faces[3 * k]]
        b = vertices[faces[3 * k + 1]]
        c = vertices[faces[3 * k + 2]]
        closest = closest_on_triangle(p, a, b, c)
        dist = wp.length(p - closest)
        nearest = wp.min(nearest, dist)
        if dist >= radius + c0 + FEATURE_SKIP_MM:  # its edges and vertices are no nearer: no term in range
            continue
        own = owners[k]
        t, d, o = feature_terms(p, closest, radius, p0, c0, u_linear, with_stiffness)
        total, diagonal, off = total + t, diagonal + d, off + o
        if own & OWN_EDGE_AB:
            t, d, o = feature_terms(p, closest_on_segment(p, a, b), radius, p0, c0, u_linear, with_stiffness)
            total, diagonal, off = total - t, diagonal - d, off - o
        if own & OWN_EDGE_BC:
            t, d, o = feature_terms(p, closest_on_segment(p, b, c), radius, p0, c0, u_linear, with_stiffness)
            total, diagonal, off = total - t, diagonal - d, off - o
        if own & OWN_EDGE_CA:
            t, d, o = feature_terms(p, closest_on_segment(p, c, a), radius, p0, c0, u_linear, with_stiffness)
            total, diagonal, off = total - t, diagonal - d, off - o
        if own & OWN_VERTEX_A:
            t, d, o = feature_terms(p, a, radius, p0, c0, u_linear, with_stiffness)
            total, diagonal, off = total + t, diagonal + d, off + o
        if own & OWN_VERTEX_B:
            t, d, o = feature_terms(p, b, radius, p0, c0, u_linear, with_stiffness)
            total, diagonal, off = total + t, diagonal + d, off + o
        if own & OWN_VERTEX_C:
            t, d, o = feature_terms(p, c, radius, p0, c0, u_linear, with_stiffness)
            total, diagonal, off = total + t, diagonal + d, off + o
    dd = from_fixed(diagonal)
    oo = from_fixed(off)
    return from_fixed(total), nearest, wp.mat33d(dd[0], oo[0], oo[1], oo[0], dd[1], oo[2], oo[1], oo[2], dd[2])


@wp.func
def fixed_outer(k: wp.float64, n: wp.vec3d):
    """k n nᵀ (µN/mm) in fixed point: its diagonal (xx, yy, zz) and upper (xy, xz, yz) entries."""
    return (to_fixed(k * wp.vec3d(n[0] * n[0], n[1] * n[1], n[2] * n[2])),
            to_fixed(k * wp.vec3d(n[0] * n[1], n[0] * n[2], n[1] * n[2])))


@wp.func
def feature_terms(p: wp.vec3d, closest: wp.vec3d, radius: wp.float64, p0: wp.float64, c0: wp.float64,
                  u_linear: wp.float64, with_stiffness: int):
    """One feature's force (µN) and, with ``with_stiffness``, its stiffness −∂F/∂p along
    its normal, k(h) n nᵀ (µN/mm; the turn of n left out), fixed point: force, then the
    stiffness's diagonal (xx, yy, zz) and upper (xy, xz, yz) entries."""
    delta = p - closest
    dist = wp.length(delta)
    force = vec3l()
    diagonal = vec3l()
    upper = vec3l()
    if dist < radius + c0 and dist > wp.float64(1.0e-12):
        magnitude, k = contact_law(dist - radius, p0, c0, u_linear)
        force = to_fixed((magnitude / dist) * delta)
        if with_stiffness != 0:
            diagonal, upper = fixed_outer(k, delta / dist)
    return force, diagonal, upper


@wp.func
def field_sample(volume: wp.uint64, local: wp.vec3d, grad_tolerance: wp.float64):
    """The wall's narrow-band field (warpcoil/wall_field.py) at ``local`` (wall
    frame, mm): whether to trust it, the signed distance (mm, > 0 in the lumen)
    and the unit inward normal, from the trilinear interpolant and its gradient.
    Trusted: all eight corners inside the band (a corner outside is NaN, so the
    sample is) and the gradient's length within ``grad_tolerance`` of 1 (it
    drops below 1 where the stencil straddles a crease of the wall)."""
    uvw = wp.volume_world_to_index(volume, wp.vec3f(wp.float32(local[0]), wp.float32(local[1]),
                                                    wp.float32(local[2])))
    g = wp.vec3f(wp.float32(0.0), wp.float32(0.0), wp.float32(0.0))
    d = wp.volume_sample_grad_f(volume, uvw, wp.Volume.LINEAR, g)
    grad = wp.volume_world_to_index_dir(volume, g)  # ∂d/∂x = (∂d/∂u) / h for a voxel of size h
    n = wp.vec3d(wp.float64(grad[0]), wp.float64(grad[1]), wp.float64(grad[2]))
    size = wp.length(n)
    trusted = d == d and wp.abs(size - wp.float64(1.0)) <= grad_tolerance
    if trusted:
        n = n / size
    return trusted, wp.float64(d), n


@wp.func
def wall_search(mesh: wp.uint64, vertices: wp.array(dtype=wp.vec3d), faces: wp.array(dtype=wp.int32),
                owners: wp.array(dtype=wp.int32), face_first: int, origin: wp.vec3d, p: wp.vec3d,
                radius: wp.float64, p0: wp.float64, c0: wp.float64, u_linear: wp.float64,
                anchor_margin: wp.float64, reach: wp.float64, with_stiffness: int):
    """The BVH search of a node sphere at ``p`` within ``reach`` of its contact range:
    (face or NO_FACE, the signed query distance mm, the signed centre distance mm, the
    wall force µN before the contact share, the feature sum's stiffness µN/mm, 1 where
    the force is the feature sum's). In the lumen within range: the feature sum, its
    exact distance; outside the lumen: the law along the closest face's inward normal."""
    contact_range = radius + c0
    face, dist, inward = wall_query(mesh, vertices, faces, face_first, origin, p, reach)
    signed = dist
    f = wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(0.0))
    k_sum = wp.mat33d()
    from_sum = 0
    if face != NO_FACE and dist > wp.float64(0.0):
        if dist < contact_range + anchor_margin:
            summed, nearest, k_sum = wall_feature_sum(mesh, vertices, faces, owners, face_first, p - origin, radius,
                                                      p0, c0, u_linear, with_stiffness)
            if nearest < contact_range:
                f = summed
                from_sum = 1
                signed = nearest
    elif face != NO_FACE:  # outside the lumen: pushed back along the closest face's normal
        f = contact_force_magnitude(dist - radius, p0, c0, u_linear) * inward
    return face, dist, signed, f, k_sum, from_sum


@wp.func
def wall_stiffness(f: wp.vec3d, from_sum: int, k_sum: wp.mat33d, gap: wp.float64, p0: wp.float64, c0: wp.float64,
                   u_linear: wp.float64) -> wp.mat33d:
    """The wall's stiffness (µN/mm) behind a force ``f`` found at ``gap`` (mm): the feature sum's Σ ± k n nᵀ
    where the force is its sum (``from_sum``), else the law's k n nᵀ along the force; zero without a force."""
    k = wp.mat33d()
    magnitude = wp.length(f)
    if magnitude > wp.float64(0.0):
        if from_sum != 0:
            k = k_sum
        else:
            n = f / magnitude
            k = contact_stiffness(gap, p0, c0, u_linear) * wp.outer(n, n)
    return k


@wp.kernel
def wall_contact(
    x: wp.array(dtype=wp.vec3d),
    free: wp.array(dtype=wp.int32),
    world_of: wp.array(dtype=wp.int32),
    running: wp.array(dtype=wp.int32),
    node_radius: wp.array(dtype=wp.float64),
    contact_share: wp.array(dtype=wp.float64),
    meshes: wp.array(dtype=wp.uint64),
    face_first: wp.array(dtype=wp.int32),
    origins: wp.array(dtype=wp.vec3d),
    vertices: wp.array(dtype=wp.vec3d),
    faces: wp.array(dtype=wp.int32),
    owners: wp.array(dtype=wp.int32),
    p0: wp.float64,
    c0: wp.float64,
    u_linear: wp.float64,
    search_mm: wp.float64,
    guard_steps: int,
    fields: wp.array(dtype=wp.uint64),
    grad_tolerance: wp.float64,
    anchor_margin: wp.float64,
    sided_skip: int,
    inside: wp.array(dtype=wp.int32),
    anchor: wp.array(dtype=wp.vec3d),
    anchor_slack: wp.array(dtype=wp.float64),
    quiet_steps: wp.array(dtype=wp.int32),
    seen_x: wp.array(dtype=wp.vec3d),
    seen_distance: wp.array(dtype=wp.float64),
    force: wp.array(dtype=wp.vec3d),
    centre_distance: wp.array(dtype=wp.float64),
    searches: wp.array(dtype=wp.int32),
    with_stiffness: int,
    stiffness: wp.array(dtype=wp.mat33d),
):
    """Wall force on each free node (µN; the wall of the node's ensemble member,
    none where its mesh id is 0), times the node's ``contact_share`` (½ at a free
    end: the law acts per node patch d·l̄, as the mass is lumped). In the lumen: the contact law summed over the
    wall's faces, edges and vertices within reach (:func:`wall_feature_sum`; on a
    flat facet the law of the gap h = distance − d/2 along the facet's normal).
    Outside the lumen: the law of h = −distance − d/2 along the closest face's
    inward normal.

    The BVH search is limited to ``search_mm`` beyond the contact range: a node
    farther from the wall feels no force, and keeps the side (``inside``: 1 in
    the lumen, 0 outside, −1 not yet known) it had when last seen near the
    wall — it cannot change side without coming near it, as long as a step
    moves it less than ``search_mm``. Nodes whose side is unknown (just out of
    the catheter) get a full search.

    A node found in the lumen with a slack s = (distance − d/2 − c0) > 0 to the
    contact range (s ≥ ``search_mm`` when no face was within reach) is anchored
    there: while it stays within 0.9 s − ``anchor_margin`` of its anchor (≥ 1e-5 mm;
    with a field, also ≥ the field's error bound, so the field cannot see contact
    there either) the wall cannot be within its contact range, so the force is exactly zero and it is not searched
    again — except every ``guard_steps`` steps (0: always search, as for exact
    distances). A node not anchored takes distance and normal from its world's
    narrow-band field (``fields``, 0: none) where the field is trusted
    (:func:`field_sample`), from the BVH elsewhere.

    In the lumen within the contact range, the distance is the exact (float64)
    distance to the closest face, from the feature sum's faces. A node that was
    last searched in the lumen at centre distance s (``seen_x``,
    ``seen_distance``) and has since moved less than s − ``anchor_margin`` is still
    in the lumen (the distance is 1-Lipschitz), so with ``sided_skip`` its signed
    BVH query is skipped: the feature sum alone gives force and distance (and,
    the node being in the lumen at that exact distance, a new (``seen_x``,
    ``seen_distance``) to go on from: a node sliding along the wall is not searched
    in full again), and only if it finds no face within the contact range is the
    node searched in full. The result is bit-identical to the full search (tested).
    Counts each node's signed BVH queries (``searches``). Writes the centre's signed distance (mm; for a node not
    searched, or with no face in reach, the distance plus slack bound it was
    anchored with; +FAR in the catheter or without a wall). With ``with_stiffness``
    (the implicit step) also each node's wall stiffness (µN/mm, the law's full k: an
    upper bound at a half-share end node), as its force was taken: in the lumen
    within reach of faces, the feature sum's Σ ± k n nᵀ (:func:`wall_feature_sum`:
    every face that pushes, in its own direction); otherwise (a trusted field, or
    outside the lumen) the law's k n nᵀ along the force; zero without a force."""
    i = wp.tid()
    f = wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(0.0))
    k_sum = wp.mat33d()
    from_sum = False
    signed = FAR_MM
    w = world_of[i]
    mesh = meshes[w]
    if free[i] != 0 and running[w] != 0 and mesh != wp.uint64(0):
        reach = node_radius[i] + c0 + search_mm
        side = inside[i]
        quiet = quiet_steps[i]
        moved = wp.length(x[i] - anchor[i])
        done = False  # distance and force known without the BVH
        if side > 0 and quiet != NO_ANCHOR and quiet < guard_steps and moved < ANCHOR_SHARE * anchor_slack[i] - anchor_margin:
            quiet_steps[i] = quiet + 1
            signed = node_radius[i] + c0 + anchor_slack[i] - moved
            done = True
        elif fields[w] != wp.uint64(0):
            trusted, sampled, normal = field_sample(fields[w], x[i] - origins[w], grad_tolerance)
            if trusted:
                signed = sampled
                inside[i] = wp.where(signed > wp.float64(0.0), 1, 0)
                quiet_steps[i] = NO_ANCHOR
                f = contact_force_magnitude(signed - node_radius[i], p0, c0, u_linear) * normal
                done = True
        contact_range = node_radius[i] + c0
        if not done and sided_skip != 0 and side > 0 and quiet == NO_ANCHOR:
            if wp.length(x[i] - seen_x[i]) < seen_distance[i] - anchor_margin:  # still in the lumen
                summed, nearest, k_sum = wall_feature_sum(mesh, vertices, faces, owners, face_first[w],
                                                          x[i] - origins[w], node_radius[i], p0, c0, u_linear,
                                                          with_stiffness)
                if nearest < contact_range:
                    f = summed
                    from_sum = True
                    signed = nearest
                    done = True
                    seen_x[i] = x[i]  # in the lumen at that distance: a new certificate
                    seen_distance[i] = nearest
        if not done:  # the BVH
            searches[i] = searches[i] + 1
            if side < 0:
                reach = FAR_MM
            face, dist, signed, f, k_sum, by_sum = wall_search(mesh, vertices, faces, owners, face_first[w],
                                                               origins[w], x[i], node_radius[i], p0, c0, u_linear,
                                                               anchor_margin, reach, with_stiffness)
            from_sum = by_sum != 0
            if face == NO_FACE:
                if side == 0:
                    signed = -reach
            elif dist > wp.float64(0.0):
                inside[i] = 1
            else:
                inside[i] = 0
            slack = signed - contact_range
            if inside[i] == 1 and slack > wp.float64(0.0):
                anchor[i] = x[i]
                anchor_slack[i] = slack
                quiet_steps[i] = 0
            else:
                quiet_steps[i] = NO_ANCHOR
            seen_x[i] = x[i]
            seen_distance[i] = wp.where(inside[i] == 1, signed, wp.float64(0.0))
    elif free[i] == 0:
        inside[i] = -1
        quiet_steps[i] = NO_ANCHOR
    force[i] = contact_share[i] * f
    centre_distance[i] = signed
    if with_stiffness != 0:
        stiffness[i] = wall_stiffness(force[i], wp.where(from_sum, 1, 0), k_sum, signed - node_radius[i], p0, c0,
                                      u_linear)


@wp.func
def sample_point(x: wp.array(dtype=wp.vec3d), node_radius: wp.array(dtype=wp.float64),
                 centre_distance: wp.array(dtype=wp.float64), e: int, s: wp.float64):
    """Edge e's point at parameter s (mm), its radius (interpolated, mm) and a lower bound of its signed wall
    centre distance (mm) from its nodes' (``centre_distance``: exact, or lower bounds; 1-Lipschitz)."""
    length = wp.length(x[e + 1] - x[e])
    radius = (wp.float64(1.0) - s) * node_radius[e] + s * node_radius[e + 1]
    bound = wp.max(centre_distance[e] - s * length, centre_distance[e + 1] - (wp.float64(1.0) - s) * length)
    return x[e] + s * (x[e + 1] - x[e]), radius, bound


@wp.func
def sample_wall_term(mesh: wp.uint64, vertices: wp.array(dtype=wp.vec3d), faces: wp.array(dtype=wp.int32),
                     owners: wp.array(dtype=wp.int32), face_first: int, origin: wp.vec3d, field: wp.uint64,
                     grad_tolerance: wp.float64, p: wp.vec3d, radius: wp.float64, p0: wp.float64, c0: wp.float64,
                     u_linear: wp.float64, anchor_margin: wp.float64, reach: wp.float64, with_stiffness: int):
    """The wall's law on a sphere of ``radius`` at p (a contact sample between two nodes), as
    :func:`wall_contact` takes it for a node it searches: from the trusted field, else the BVH (the feature
    sum in the lumen, the law along the closest face's inward normal outside it): (force µN before any
    weight, stiffness µN/mm)."""
    f = wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(0.0))
    k = wp.mat33d()
    signed = FAR_MM
    by_field = False
    if field != wp.uint64(0):
        trusted, sampled, normal = field_sample(field, p - origin, grad_tolerance)
        if trusted:
            by_field = True
            signed = sampled
            f = contact_force_magnitude(sampled - radius, p0, c0, u_linear) * normal
    k_sum = wp.mat33d()
    from_sum = 0
    if not by_field:
        face, dist, signed, f, k_sum, from_sum = wall_search(mesh, vertices, faces, owners, face_first, origin, p,
                                                             radius, p0, c0, u_linear, anchor_margin, reach,
                                                             with_stiffness)
    if with_stiffness != 0:
        k = wall_stiffness(f, from_sum, k_sum, signed - radius, p0, c0, u_linear)
    return f, k


@wp.kernel
def wall_sample_contact(
    x: wp.array(dtype=wp.vec3d),
    free: wp.array(dtype=wp.int32),
    has_next: wp.array(dtype=wp.int32),
    world_of: wp.array(dtype=wp.int32),
    running: wp.array(dtype=wp.int32),
    node_radius: wp.array(dtype=wp.float64),
    contact_samples: wp.array(dtype=wp.int32),
    meshes: wp.array(dtype=wp.uint64),
    face_first: wp.array(dtype=wp.int32),
    origins: wp.array(dtype=wp.vec3d),
    vertices: wp.array(dtype=wp.vec3d),
    faces: wp.array(dtype=wp.int32),
    owners: wp.array(dtype=wp.int32),
    p0: wp.float64,
    c0: wp.float64,
    u_linear: wp.float64,
    search_mm: wp.float64,
    fields: wp.array(dtype=wp.uint64),
    grad_tolerance: wp.float64,
    anchor_margin: wp.float64,
    centre_distance: wp.array(dtype=wp.float64),
    force: wp.array(dtype=wp.vec3d),
    with_stiffness: int,
    stiffness: wp.array(dtype=wp.mat33d),
):
    """The wall at the contact samples of segments longer than 1.5 d (model.contact_samples_per_edge: K − 1
    points between an edge's nodes at s = m/K, each of weight 1/K, the nodes' own weights their contact
    share over K, passed so to :func:`wall_contact`), added to node i's wall ``force`` (µN) in gather form:
    the samples of edge i (start: weight 1 − s) and of edge i − 1 (end: weight s), each edge with both nodes
    out of the catheter. A sample is searched only where its nodes' centre distances (``centre_distance``
    from wall_contact: exact, or a lower bound; each 1-Lipschitz) leave it possibly within its contact
    range. With ``with_stiffness`` (the implicit step) node i's wall ``stiffness`` becomes its own over K
    plus its shares (1 − s, s) of each sample's: the lumped blocks bound the sample's true 2 × 2 block from
    above, as the node's own full k bounds its share of the law. A coil with K = 1 is left as it is."""
    i = wp.tid()
    w = world_of[i]
    mesh = meshes[w]
    samples = contact_samples[i]
    if samples > 1 and free[i] != 0 and running[w] != 0 and mesh != wp.uint64(0):
        total = wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(0.0))
        k_total = wp.mat33d()
        weight = wp.float64(1.0) / wp.float64(samples)
        for side in range(2):  # edge i (i its start), then edge i − 1 (i its end)
            e = i - side
            ok = e >= 0
            if ok:
                ok = has_next[e] != 0
            if ok:
                ok = free[e] != 0 and free[e + 1] != 0
            if ok:
                for m in range(1, samples):
                    s = wp.float64(m) / wp.float64(samples)
                    p, radius, bound = sample_point(x, node_radius, centre_distance, e, s)
                    if bound < radius + c0 + anchor_margin:
                        f, k = sample_wall_term(mesh, vertices, faces, owners, face_first[w], origins[w], fields[w],
                                                grad_tolerance, p, radius, p0, c0, u_linear, anchor_margin,
                                                radius + c0 + search_mm, with_stiffness)
                        share = weight * wp.where(side == 0, wp.float64(1.0) - s, s)
                        total = total + share * f
                        k_total = k_total + share * k
        force[i] = force[i] + total
        if with_stiffness != 0:
            stiffness[i] = weight * stiffness[i] + k_total


# --- coil–coil -----------------------------------------------------------------
TOUCH_MARGIN_MM = wp.constant(wp.float64(1.0e-9))  # ≫ the rounding of two evaluations of one gap
NO_PARAMS = wp.constant(wp.vec2d(-1.0, -1.0))  # closest-point parameters (s, t) not known (they lie in [0, 1]²)


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


@wp.func
def bonded(coil_of: wp.array(dtype=wp.int32), exclusion: int, a: int, b: int) -> bool:
    """Edges a and b are bonded neighbours (b = a included): the same coil, at most
    ``exclusion`` edges apart along it; they never touch."""
    return coil_of[b] == coil_of[a] and wp.abs(b - a) <= exclusion


@wp.kernel
def edge_midpoints(
    x: wp.array(dtype=wp.vec3d),
    has_next: wp.array(dtype=wp.int32),
    built_mid: wp.array(dtype=wp.vec3d),
    half_skin: wp.float64,
    mid: wp.array(dtype=wp.vec3d),
    rebuild: wp.array(dtype=wp.int32),
):
    """Midpoint of each edge (the last node of a coil, which has none, keeps its
    own position); raises ``rebuild`` when a midpoint has moved more than half
    the skin since the neighbour grid was built (every thread that raises it
    writes the same 1, so the result does not depend on thread order)."""
    i = wp.tid()
    m = x[i]
    if has_next[i] != 0:
        m = wp.float64(0.5) * (x[i] + x[i + 1])
    mid[i] = m
    if not (wp.length(m - built_mid[i]) <= half_skin):  # NaN also rebuilds
        rebuild[0] = 1


@wp.kernel
def mark_built(mid: wp.array(dtype=wp.vec3d), built_mid: wp.array(dtype=wp.vec3d), rebuild: wp.array(dtype=wp.int32),
               overflow: wp.array(dtype=wp.int32)):
    """The neighbour lists are being built from ``mid``: remember it, clear the rebuild
    and list-overflow flags."""
    i = wp.tid()
    built_mid[i] = mid[i]
    if i == 0:
        rebuild[0] = 0
        overflow[0] = 0


NO_LIST = wp.constant(-1)  # an edge whose neighbour list overflowed searches the grid instead


@wp.kernel
def build_neighbours(
    grid: wp.uint64,
    built_mid: wp.array(dtype=wp.vec3d),
    has_next: wp.array(dtype=wp.int32),
    coil_of: wp.array(dtype=wp.int32),
    world_of: wp.array(dtype=wp.int32),
    exclusion: int,
    list_radius: wp.float64,
    neighbours: wp.array2d(dtype=wp.int32),
    count: wp.array(dtype=wp.int32),
):
    """Neighbour list of edge a at the grid's build: every edge of its world (not a
    bonded neighbour) whose midpoint is within ``list_radius`` (= query radius +
    skin) of a's, in grid order; NO_LIST when more than the list holds."""
    a = wp.tid()
    found = int(0)
    if has_next[a] != 0:
        query = wp.hash_grid_query(grid, built_mid[a], list_radius, world_of[a])
        b = int(0)
        while wp.hash_grid_query_next(query, b):
            keep = has_next[b] != 0 and not bonded(coil_of, exclusion, a, b)
            if keep and found != NO_LIST and wp.length(built_mid[a] - built_mid[b]) <= list_radius:
                if found < neighbours.shape[1]:
                    neighbours[a, found] = b
                    found += 1
                else:
                    found = NO_LIST
    count[a] = found


WALK_MARGIN_MM = wp.constant(wp.float64(1.0e-9))  # ≫ the rounding of mm-scale midpoint distances
SQUARED_ROUNDING = wp.constant(wp.float64(1.0e-12))  # relative: ≫ a squared distance's rounding against its length's


@wp.kernel
def coil_midpoint_steps(built_mid: wp.array(dtype=wp.vec3d), coil_first: wp.array(dtype=wp.int32),
                        coil_last: wp.array(dtype=wp.int32), step: wp.array(dtype=wp.float64)):
    """Per coil: the longest distance between consecutive midpoints along it at the
    build (mm; ``walk_neighbours``' skip bound)."""
    c = wp.tid()
    longest = wp.float64(0.0)
    finite = bool(True)
    for i in range(coil_first[c], coil_last[c]):
        d = wp.length(built_mid[i + 1] - built_mid[i])
        if not (d <= wp.float64(1.0e300)):  # NaN or inf (a world gone unstable): no bound, no skip
            finite = False
        longest = wp.max(longest, d)
    if not finite:
        longest = wp.float64(wp.inf)
    step[c] = longest


# walk_neighbours computes a skip (a square root and a division) only where it passes at least this many edges;
# nearer, testing each edge is cheaper (measured on the seed case: 4 → 12 cut a build late in the push by ~40 %)
WALK_SKIP_MIN = wp.constant(12)


@wp.kernel
def walk_neighbours(
    built_mid: wp.array(dtype=wp.vec3d),
    has_next: wp.array(dtype=wp.int32),
    coil_of: wp.array(dtype=wp.int32),
    world_of: wp.array(dtype=wp.int32),
    world_node_range: wp.array2d(dtype=wp.int32),
    coil_last: wp.array(dtype=wp.int32),
    coil_step: wp.array(dtype=wp.float64),
    exclusion: int,
    list_radius: wp.float64,
    neighbours: wp.array2d(dtype=wp.int32),
    count: wp.array(dtype=wp.int32),
    overflow: wp.array(dtype=wp.int32),
):
    """:func:`build_neighbours`' lists without the hash grid: edge a walks its world's
    edges in index order and keeps every edge (not a bonded neighbour) whose midpoint
    is within ``list_radius`` of a's (the same test, so the same set; a different
    order, which no reader depends on). From a midpoint at distance D beyond
    list_radius + WALK_SKIP_MIN L (L: ``coil_step``, the longest step between
    consecutive midpoints of its coil) it skips the next (D − list_radius)/L − 1 of
    its coil, none of which can be within list_radius (triangle inequality). An
    overflowed list (NO_LIST) raises ``overflow``: the hash grid is then built for
    its grid search."""
    a = wp.tid()
    found = int(0)
    if has_next[a] != 0:
        w = world_of[a]
        b = world_node_range[w, 0]
        last = world_node_range[w, 1]
        here = built_mid[a]
        inside = list_radius * (F64_1 - SQUARED_ROUNDING)  # surely within, squared below: no square root
        inside_sq = inside * inside
        outside = list_radius * (F64_1 + SQUARED_ROUNDING)  # surely beyond above
        outside_sq = outside * outside
        while b <= last and found != NO_LIST:  # coil by coil
            c = coil_of[b]
            end = coil_last[c]
            step = coil_step[c]
            far = list_radius + WALK_MARGIN_MM + wp.float64(WALK_SKIP_MIN) * step
            far_sq = far * far
            while b <= end:
                d = here - built_mid[b]
                apart_sq = wp.dot(d, d)
                if apart_sq > far_sq and step > F64_0:
                    apart = wp.sqrt(apart_sq)
                    b = wp.min(b + int(wp.min((apart - list_radius - WALK_MARGIN_MM) / step, wp.float64(1.0e6))),
                               end + 1)
                    continue
                if apart_sq <= outside_sq and has_next[b] != 0 and not bonded(coil_of, exclusion, a, b):
                    if apart_sq <= inside_sq or wp.length(d) <= list_radius:
                        if found == neighbours.shape[1]:
                            found = NO_LIST
                            break
                        neighbours[a, found] = b
                        found += 1
                b += 1
    count[a] = found
    if found == NO_LIST:
        overflow[0] = 1


@wp.func
def next_partner(query: wp.ref[wp.HashGridQuery[wp.float64]], k: wp.ref[int], b: wp.ref[int], a: int,
                 neighbours: wp.array2d(dtype=wp.int32), listed: int, coil_of: wp.array(dtype=wp.int32),
                 exclusion: int) -> bool:
    """Advance ``b`` to edge a's next candidate partner; False when there is none.
    The candidates: row a of a partner list (``neighbours``: the neighbour list, or
    the implicit step's touching record; ``listed`` entries, ``k`` the next one),
    or, when it overflowed (NO_LIST), what ``query`` (the build's grid around a)
    finds, bonded neighbours skipped. One iterator for both, so each pass writes its pair
    body once; kernels calling it need ``enable_backward=False`` (wp.ref)."""
    if listed != NO_LIST:
        if k >= listed:
            return False
        b = neighbours[a, k]
        k = k + 1
        return True
    q = query  # Warp 1.19's hash_grid_query_next advances a local, not a wp.ref: copy in and out
    found = int(0)
    more = bool(True)
    while more:
        more = wp.hash_grid_query_next(q, found)
        if more and not bonded(coil_of, exclusion, a, found):
            break
    query = q
    b = found
    return more


@wp.func
def rest_offset(rest_gap: wp.float64, c0: wp.float64) -> wp.float64:
    """Shift (mm, in [0, c0]) of a same-coil clearance whose rest value ``rest_gap``
    is below c0: c0 − rest_gap. The law then begins at the rest clearance (at
    h = 0 if the rest shape has them touching), so neighbouring turns of a tight
    pre-shape do not repel each other at rest."""
    return wp.clamp(c0 - rest_gap, wp.float64(0.0), c0)


@wp.func
def point_segment_term(p: wp.vec3d, rest_p: wp.vec3d, radius: wp.float64, share: wp.float64,
                       x: wp.array(dtype=wp.vec3d), rest_x: wp.array(dtype=wp.vec3d),
                       node_radius: wp.array(dtype=wp.float64), b: int, p0: wp.float64, c0: wp.float64,
                       u_linear: wp.float64, rest_near: bool):
    """½ ``share`` × the law of the gap between a sphere of ``radius`` (mm) at ``p`` (a node
    or a contact sample, rest position ``rest_p``) and capsule b (|p − closest point of
    edge b| − radius − r_b, plus the rest offset of a same-coil pair): (force on p along
    p − closest point, µN; the closest point's parameter t on b). ``rest_near`` False:
    the pair's rest offset is 0 (:func:`rest_apart`), not computed."""
    pb0 = x[b]
    pb1 = x[b + 1]
    eb = pb1 - pb0
    t = wp.float64(0.0)
    length_sq = wp.dot(eb, eb)
    if length_sq > wp.float64(0.0):
        t = wp.clamp(wp.dot(p - pb0, eb) / length_sq, wp.float64(0.0), wp.float64(1.0))
    delta = p - pb0 - t * eb
    dist = wp.length(delta)
    gap = dist - radius - node_radius[b]
    f = wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(0.0))
    if gap < c0 and dist > wp.float64(1.0e-12):
        if rest_near:
            rest = closest_on_segment(rest_p, rest_x[b], rest_x[b + 1])
            gap = gap + rest_offset(wp.length(rest_p - rest) - radius - node_radius[b], c0)
        if gap < c0:
            f = (wp.float64(0.5) * share * contact_force_magnitude(gap, p0, c0, u_linear) / dist) * delta
    return f, t


@wp.func
def node_segment_term(x: wp.array(dtype=wp.vec3d), rest_x: wp.array(dtype=wp.vec3d),
                      node_radius: wp.array(dtype=wp.float64), share: wp.float64, j: int, b: int, p0: wp.float64,
                      c0: wp.float64, u_linear: wp.float64, rest_near: bool):
    """:func:`point_segment_term` of node j (weight ``share``: its contact share over its
    coil's contact samples per edge) on capsule b."""
    return point_segment_term(x[j], rest_x[j], node_radius[j], share, x, rest_x, node_radius, b, p0, c0, u_linear,
                              rest_near)


@wp.func
def point_node_term(p: wp.vec3d, rest_p: wp.vec3d, radius: wp.float64, x: wp.array(dtype=wp.vec3d),
                    rest_x: wp.array(dtype=wp.vec3d), node_radius: wp.array(dtype=wp.float64), k: int,
                    p0: wp.float64, c0: wp.float64, u_linear: wp.float64, rest_near: bool) -> wp.vec3d:
    """The law of the gap between a sphere of ``radius`` (mm) at ``p`` (rest position
    ``rest_p``) and node sphere k (with a same-coil pair's rest offset; ``rest_near``
    False: 0, not computed), along p − x_k: the force on p of the term φ(|p − x_k|)."""
    delta = p - x[k]
    dist = wp.length(delta)
    gap = dist - radius - node_radius[k]
    f = wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(0.0))
    if gap < c0 and dist > wp.float64(1.0e-12):
        if rest_near:
            gap = gap + rest_offset(wp.length(rest_p - rest_x[k]) - radius - node_radius[k], c0)
        if gap < c0:
            f = (contact_force_magnitude(gap, p0, c0, u_linear) / dist) * delta
    return f


@wp.func
def node_node_term(x: wp.array(dtype=wp.vec3d), rest_x: wp.array(dtype=wp.vec3d),
                   node_radius: wp.array(dtype=wp.float64),
                   j: int, k: int, p0: wp.float64, c0: wp.float64, u_linear: wp.float64,
                   rest_near: bool) -> wp.vec3d:
    """:func:`point_node_term` of node j on node k: the force on j of the term φ(|x_j − x_k|)."""
    return point_node_term(x[j], rest_x[j], node_radius[j], x, rest_x, node_radius, k, p0, c0, u_linear, rest_near)


@wp.func
def edge_samples(x: wp.array(dtype=wp.vec3d), rest_x: wp.array(dtype=wp.vec3d),
                 node_radius: wp.array(dtype=wp.float64), samples: int, a: int, b: int, joint_b: wp.float64,
                 p0: wp.float64, c0: wp.float64, u_linear: wp.float64, rest_near: bool):
    """The terms of edge a's contact samples (its ``samples`` − 1 interior points at
    parameters m / ``samples``, each of weight 1 / ``samples``: the coil's samples per edge)
    on capsule b, with their correction at joint b when ``joint_b`` (1: node b joins
    edges b − 1 and b, both touched): (forces on a's start and end node, reactions on b's
    start and end node, µN), each summed over the samples in order."""
    zero = wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(0.0))
    own_start = zero
    own_end = zero
    react_start = zero
    react_end = zero
    share = wp.float64(1.0) / wp.float64(samples)
    for m in range(1, samples):
        s = wp.float64(m) / wp.float64(samples)
        p = x[a] + s * (x[a + 1] - x[a])
        rest_p = rest_x[a] + s * (rest_x[a + 1] - rest_x[a])
        radius = (wp.float64(1.0) - s) * node_radius[a] + s * node_radius[a + 1]
        f, t = point_segment_term(p, rest_p, radius, share, x, rest_x, node_radius, b, p0, c0, u_linear, rest_near)
        g = f
        react_start = react_start - (wp.float64(1.0) - t) * f
        react_end = react_end - t * f
        if joint_b > wp.float64(0.0):
            w = wp.float64(0.5) * share * joint_b
            n = point_node_term(p, rest_p, radius, x, rest_x, node_radius, b, p0, c0, u_linear, rest_near)
            g = g - w * n
            react_start = react_start + w * n
        own_start = own_start + (wp.float64(1.0) - s) * g
        own_end = own_end + s * g
    return own_start, own_end, react_start, react_end


@wp.func
def counted(free: wp.array(dtype=wp.int32), has_next: wp.array(dtype=wp.int32), fixed: wp.array(dtype=wp.int32),
            coil_of: wp.array(dtype=wp.int32), exclusion: int, e: int, other: int) -> bool:
    """Edge e is an obstacle that edge ``other`` (and the nodes it owns) touches: it
    exists, can be touched and is no bonded neighbour of ``other``."""
    if e < 0:
        return False
    if not edge_is_obstacle(free, has_next, fixed, e):
        return False
    return not bonded(coil_of, exclusion, other, e)


@wp.func
def joint(free: wp.array(dtype=wp.int32), has_next: wp.array(dtype=wp.int32), fixed: wp.array(dtype=wp.int32),
          coil_of: wp.array(dtype=wp.int32), exclusion: int, k: int, other: int) -> wp.float64:
    """1 when node k joins two edges (k − 1 and k, one coil) that edge ``other``'s
    nodes both touch: the chain's capsules overlap in k's sphere, counted once too
    often in the sum over capsules; else 0."""
    if k < 1:
        return wp.float64(0.0)
    if has_next[k] == 0 or has_next[k - 1] == 0:
        return wp.float64(0.0)
    if counted(free, has_next, fixed, coil_of, exclusion, k - 1, other) and \
            counted(free, has_next, fixed, coil_of, exclusion, k, other):
        return wp.float64(1.0)
    return wp.float64(0.0)


@wp.func
def owned_nodes(has_next: wp.array(dtype=wp.int32), e: int) -> int:
    """Nodes that edge e owns in the contact sums: its start node, and its end node
    when that is its coil's last node (which has no edge of its own)."""
    if has_next[e + 1] == 0:
        return 2
    return 1


REST_APART_MARGIN_MM = wp.constant(wp.float64(1.0e-9))  # mm: far above rounding of mm-scale lengths


@wp.func
def rest_apart(rest_x: wp.array(dtype=wp.vec3d), node_radius: wp.array(dtype=wp.float64), a: int, b: int,
               c0: wp.float64) -> bool:
    """Edges a and b are more than c0 (+ REST_APART_MARGIN_MM) apart in the rest shape by
    their bounding spheres (rest midpoints' distance less both half-lengths and the
    largest radius of each edge): every rest clearance between their nodes and capsules
    is then above c0 and its rest_offset exactly 0."""
    ra0 = rest_x[a]
    ra1 = rest_x[a + 1]
    rb0 = rest_x[b]
    rb1 = rest_x[b + 1]
    apart = wp.length(wp.float64(0.5) * (ra0 + ra1 - rb0 - rb1))
    halves = wp.float64(0.5) * (wp.length(ra1 - ra0) + wp.length(rb1 - rb0))
    radii = wp.max(node_radius[a], node_radius[a + 1]) + wp.max(node_radius[b], node_radius[b + 1])
    return apart - halves - radii > c0 + REST_APART_MARGIN_MM


@wp.func
def rest_clearance_gap(rest_x: wp.array(dtype=wp.vec3d), node_radius: wp.array(dtype=wp.float64), a: int, b: int,
                       gap: wp.float64, c0: wp.float64) -> wp.float64:
    """Segment gap of same-coil edges a and b seen from a, counted from their rest
    clearance when within c0 (the capsules' rest gap's ``rest_offset``)."""
    if gap < c0:
        ra0 = rest_x[a]
        rb0 = rest_x[b]
        rst = segment_closest_params(ra0, rest_x[a + 1], rb0, rest_x[b + 1])
        return gap + rest_offset(wp.length(ra0 + rst[0] * (rest_x[a + 1] - ra0) - rb0 - rst[1] * (
            rest_x[b + 1] - rb0)) - node_radius[a] - node_radius[b], c0)
    return gap


@wp.func
def pair_forces(x: wp.array(dtype=wp.vec3d), rest_x: wp.array(dtype=wp.vec3d), coil_of: wp.array(dtype=wp.int32),
                free: wp.array(dtype=wp.int32), has_next: wp.array(dtype=wp.int32),
                fixed: wp.array(dtype=wp.int32), node_radius: wp.array(dtype=wp.float64),
                contact_share: wp.array(dtype=wp.float64), contact_samples: wp.array(dtype=wp.int32),
                mid: wp.array(dtype=wp.vec3d), a: int, b: int,
                exclusion: int, reach_a: wp.float64, p0: wp.float64, c0: wp.float64, u_linear: wp.float64,
                far: wp.float64):
    """The forces that the terms of the coil–coil energy joining edge a's and edge
    b's nodes put on the nodes of both edges, each term evaluated once: (a's start
    and end node, b's start and end node, µN; segment gap (twice: seen from a and b), or
    ``far`` when not evaluated). Each side's forces are summed exactly as
    :func:`pair_contact` from that side sums them (node–node terms enter b's side
    negated: φ(|x_k − x_j|) is φ(|x_j − x_k|)), so they are bit-identical to
    evaluating the pair twice; the gap is evaluated once, for both (and returned a third time as
    the segments' own gap, before any rest clearance: −FAR_MM when not evaluated, with their closest points'
    parameters (s, t) from a: NO_PARAMS when not evaluated). The gap of
    two parts of one coil closer than c0 at
    rest is counted from their rest clearance (``rest_offset`` of the capsules'
    rest gap, as the implicit step's ``pair_stiffness``): turns that touch in the
    pre-shape are not touching.

    Energy (each coil a chain of capsules of radius d/2 around its edges, each node
    a sphere): W = ½ Σ_j s_j [Σ_b φ(node j, capsule b) − Σ_k φ(node j, joint k)] over
    the nodes j of one edge and the capsules b and joints k of the other chain,
    φ the potential of the contact law, s_j node j's contact share (its Voronoi
    length over its coil's segment length: ½ at a free end, like its mass); the
    joint terms remove the capsules' overlap at each joint, so a node in front of
    a straight chain feels the law of its distance to the chain once, and two
    parallel chains one law per node (P0 per node patch d·l0, P0/2 for an end
    node's half patch). Every term is C¹ in the positions (the capsule–capsule
    closest points jump between segment ends when two segments turn parallel; a
    node's closest point on a segment does not), so the forces have no jumps.
    A coil whose edges are longer than 1.5 d (``contact_samples`` K > 1) adds K − 1
    contact samples per edge between its nodes, each in the same sum with weight 1/K
    (its nodes' weights s_j / K; :func:`edge_samples`).
    Evaluated when the midpoints are within ``far`` (the world's query radius:
    the same cutoff whichever way b was found) and the bounding spheres meet; a
    pair whose segments are farther apart than c0 (+ TOUCH_MARGIN_MM) has no term
    in range (each node–capsule and node–node distance is at least the segments',
    and a rest offset only adds to a gap) and returns zero forces at once."""
    zero = wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(0.0))
    fa_start = zero
    fa_end = zero
    fb_start = zero
    fb_end = zero
    gap_a = far
    gap_b = far
    raw = -FAR_MM
    st = NO_PARAMS
    between = mid[a] - mid[b]
    beyond = far * (wp.float64(1.0) + SQUARED_ROUNDING)  # squared: surely farther than ``far`` (no square root)
    if wp.dot(between, between) <= beyond * beyond and edge_is_obstacle(free, has_next, fixed, b):
        pa0 = x[a]
        pa1 = x[a + 1]
        pb0 = x[b]
        pb1 = x[b + 1]
        # bounding spheres first: most candidates end here
        apart = wp.length(between)
        if apart <= far and apart < reach_a + wp.float64(0.5) * wp.length(pb1 - pb0) + node_radius[b]:
            st = segment_closest_params(pa0, pa1, pb0, pb1)
            gap_a = wp.length(pa0 + st[0] * (pa1 - pa0) - pb0 - st[1] * (pb1 - pb0)) - node_radius[a] - node_radius[b]
            raw = gap_a
            if gap_a >= c0 + TOUCH_MARGIN_MM:  # no term in range: every node is at least as far, offsets add
                return fa_start, fa_end, fb_start, fb_end, gap_a, gap_a, raw, st
            # a same-coil pair near in the rest shape: its terms count from their rest clearances
            rest_near = coil_of[a] == coil_of[b] and not rest_apart(rest_x, node_radius, a, b, c0)
            if rest_near:  # beyond the rest clearance, as the law sees it
                gap_a = rest_clearance_gap(rest_x, node_radius, a, b, gap_a, c0)
            gap_b = gap_a  # the same segment pair (b's own evaluation may differ in the last bit)
            two_a = owned_nodes(has_next, a) == 2
            two_b = owned_nodes(has_next, b) == 2
            # each node's weight: its contact share over its coil's contact samples per edge (1 for l0 ≤ 1.5 d)
            samples_a = contact_samples[a]
            samples_b = contact_samples[b]
            share_a0 = contact_share[a] / wp.float64(samples_a)
            share_a1 = contact_share[a + 1] / wp.float64(samples_a)
            share_b0 = contact_share[b] / wp.float64(samples_b)
            share_b1 = contact_share[b + 1] / wp.float64(samples_b)
            # node–capsule terms: a's nodes on capsule b, b's nodes on capsule a (force on the node, parameter)
            ta0, sa0 = node_segment_term(x, rest_x, node_radius, share_a0, a, b, p0, c0, u_linear, rest_near)
            ta1 = zero
            sa1 = wp.float64(0.0)
            if two_a:
                ta1, sa1 = node_segment_term(x, rest_x, node_radius, share_a1, a + 1, b, p0, c0, u_linear, rest_near)
            tb0, sb0 = node_segment_term(x, rest_x, node_radius, share_b0, b, a, p0, c0, u_linear, rest_near)
            tb1 = zero
            sb1 = wp.float64(0.0)
            if two_b:
                tb1, sb1 = node_segment_term(x, rest_x, node_radius, share_b1, b + 1, a, p0, c0, u_linear, rest_near)
            # joint corrections w_mq φ(a + m, b + q) (force on a + m)
            ja0 = joint(free, has_next, fixed, coil_of, exclusion, a, b)
            ja1 = joint(free, has_next, fixed, coil_of, exclusion, a + 1, b)
            jb0 = joint(free, has_next, fixed, coil_of, exclusion, b, a)
            jb1 = joint(free, has_next, fixed, coil_of, exclusion, b + 1, a)
            w00 = wp.float64(0.5) * (share_a0 * jb0 + share_b0 * ja0)
            w01 = wp.float64(0.0)
            w10 = wp.float64(0.0)
            w11 = wp.float64(0.0)
            if two_b:
                w01 = wp.float64(0.5) * (share_a0 * jb1 + share_b1 * ja0)
            if two_a:
                w10 = wp.float64(0.5) * (share_a1 * jb0 + share_b0 * ja1)
            if two_a and two_b:
                w11 = wp.float64(0.5) * (share_a1 * jb1 + share_b1 * ja1)
            n00 = zero
            n01 = zero
            n10 = zero
            n11 = zero
            if w00 > wp.float64(0.0):
                n00 = node_node_term(x, rest_x, node_radius, a, b, p0, c0, u_linear, rest_near)
            if w01 > wp.float64(0.0):
                n01 = node_node_term(x, rest_x, node_radius, a, b + 1, p0, c0, u_linear, rest_near)
            if w10 > wp.float64(0.0):
                n10 = node_node_term(x, rest_x, node_radius, a + 1, b, p0, c0, u_linear, rest_near)
            if w11 > wp.float64(0.0):
                n11 = node_node_term(x, rest_x, node_radius, a + 1, b + 1, p0, c0, u_linear, rest_near)
            # a's side: its nodes' terms with their joint corrections, then the reactions of b's nodes
            f = ta0
            if w00 > wp.float64(0.0):
                f = f - w00 * n00
            if w01 > wp.float64(0.0):
                f = f - w01 * n01
            fa_start = fa_start + f
            if two_a:
                f = ta1
                if w10 > wp.float64(0.0):
                    f = f - w10 * n10
                if w11 > wp.float64(0.0):
                    f = f - w11 * n11
                fa_end = fa_end + f
            fa_start = fa_start - (wp.float64(1.0) - sb0) * tb0
            fa_end = fa_end - sb0 * tb0
            if two_b:
                fa_start = fa_start - (wp.float64(1.0) - sb1) * tb1
                fa_end = fa_end - sb1 * tb1
            # b's side, as b's own evaluation sums it (φ(b + q, a + m) = −n_mq)
            f = tb0
            if w00 > wp.float64(0.0):
                f = f - w00 * (-n00)
            if w10 > wp.float64(0.0):
                f = f - w10 * (-n10)
            fb_start = fb_start + f
            if two_b:
                f = tb1
                if w01 > wp.float64(0.0):
                    f = f - w01 * (-n01)
                if w11 > wp.float64(0.0):
                    f = f - w11 * (-n11)
                fb_end = fb_end + f
            fb_start = fb_start - (wp.float64(1.0) - sa0) * ta0
            fb_end = fb_end - sa0 * ta0
            if two_a:
                fb_start = fb_start - (wp.float64(1.0) - sa1) * ta1
                fb_end = fb_end - sa1 * ta1
            if samples_a > 1 or samples_b > 1:  # segments above 1.5 d: their contact samples, each side as b's own
                oa_start, oa_end, rb_start, rb_end = edge_samples(x, rest_x, node_radius, samples_a, a, b, jb0, p0, c0,
                                                                  u_linear, rest_near)
                ob_start, ob_end, ra_start, ra_end = edge_samples(x, rest_x, node_radius, samples_b, b, a, ja0, p0, c0,
                                                                  u_linear, rest_near)
                fa_start = fa_start + oa_start + ra_start
                fa_end = fa_end + oa_end + ra_end
                fb_start = fb_start + ob_start + rb_start
                fb_end = fb_end + ob_end + rb_end
    return fa_start, fa_end, fb_start, fb_end, gap_a, gap_b, raw, st


@wp.func
def pair_contact(x: wp.array(dtype=wp.vec3d), rest_x: wp.array(dtype=wp.vec3d), coil_of: wp.array(dtype=wp.int32),
                 free: wp.array(dtype=wp.int32), has_next: wp.array(dtype=wp.int32),
                 fixed: wp.array(dtype=wp.int32), node_radius: wp.array(dtype=wp.float64),
                 contact_share: wp.array(dtype=wp.float64), contact_samples: wp.array(dtype=wp.int32),
                 mid: wp.array(dtype=wp.vec3d), a: int, b: int,
                 exclusion: int, reach_a: wp.float64, p0: wp.float64, c0: wp.float64, u_linear: wp.float64,
                 far: wp.float64):
    """Edge a's side of :func:`pair_forces`: (fixed-point forces on a's start and end
    node, segment gap or ``far`` when not evaluated, 1 if touching, 1 if non-finite)."""
    f_start, f_end, fb_start, fb_end, gap, gap_b, raw, st = pair_forces(
        x, rest_x, coil_of, free, has_next, fixed, node_radius, contact_share, contact_samples, mid, a, b, exclusion,
        reach_a, p0, c0, u_linear, far)
    bad = int(0)
    if not (finite_vec(f_start) and finite_vec(f_end) and gap == gap):
        bad = 1
    touching = int(0)
    if gap < c0:
        touching = 1
    return to_fixed(f_start), to_fixed(f_end), gap, touching, bad


@wp.func
def add_side(e: int, f_start: wp.vec3d, f_end: wp.vec3d, gap: wp.float64, c0: wp.float64,
             sum_start: wp.array(dtype=vec3l), sum_end: wp.array(dtype=vec3l), min_gap: wp.array(dtype=wp.float64),
             contacts: wp.array(dtype=wp.int32), bad: wp.array(dtype=wp.int32)):
    """Adds one side of a pair to edge e's fixed-point sums (integer addition:
    the result does not depend on the order; a side with no force, e.g. a pair with no
    term in range, adds nothing to them), smallest gap and touching count."""
    if wp.length_sq(f_start) + wp.length_sq(f_end) != wp.float64(0.0):  # NaN too
        wp.atomic_add(sum_start, e, to_fixed(f_start))
        wp.atomic_add(sum_end, e, to_fixed(f_end))
    wp.atomic_min(min_gap, e, gap)
    if gap < c0:
        wp.atomic_add(contacts, e, 1)
    if not (finite_vec(f_start) and finite_vec(f_end) and gap == gap):
        wp.atomic_max(bad, e, 1)


@wp.func
def note_touching(e: int, other: int, touch_count: wp.array(dtype=wp.int32),
                  touch_b: wp.array2d(dtype=wp.int32)) -> int:
    """Note ``other`` among edge e's touching partners, in whatever order they come
    (readers must not depend on it); a count above the record's width means it overflowed.
    Returns its slot (≥ the width: not recorded)."""
    slot = wp.atomic_add(touch_count, e, 1)
    if slot < touch_b.shape[1]:
        touch_b[e, slot] = other
    return slot


@wp.func
def note_candidate(e: int, other: int, st: wp.vec2d, chord_count: wp.array(dtype=wp.int32),
                   chord_b: wp.array2d(dtype=wp.int32), chord_st: wp.array2d(dtype=wp.vec2d)):
    """:func:`note_touching` into the chord-candidate record, with the pair's closest-point
    parameters (s, t) from e at x (pair_forces', reused by the chord pass; NO_PARAMS: not known)."""
    slot = note_touching(e, other, chord_count, chord_b)
    if slot < chord_b.shape[1]:
        chord_st[e, slot] = st


REACH_MARGIN_MM = wp.constant(wp.float64(1.0e-9))  # mm: far above rounding of mm-scale lengths (pair_in_reach_at_end)
SIDE_MARGIN_MM = wp.constant(wp.float64(1.0e-9))  # mm: ≫ the rounding between a pair's two sides' reach and gap


@wp.func
def pair_in_reach_at_end(end_mid: wp.array(dtype=wp.vec3d), end_half: wp.array(dtype=wp.float64), a: int, b: int,
                         c0: wp.float64, far: wp.float64) -> bool:
    """Edges a and b at the chord's predicted end may be within the contact range: their
    midpoints within ``far`` and within both half-lengths, radii and c0 (kernels/implicit.edge_ends'
    values), widened by ``REACH_MARGIN_MM`` so that no rounding drops a pair in range
    (a pair it adds beyond them is out of range and adds nothing). Symmetric in a and b, bit for bit."""
    apart = wp.length(end_mid[a] - end_mid[b])
    return apart <= far + REACH_MARGIN_MM and apart < end_half[a] + end_half[b] + c0 + REACH_MARGIN_MM


@wp.func
def swept_apart(mid: wp.array(dtype=wp.vec3d), sweep: wp.array(dtype=wp.float64), a: int, b: int,
                c0: wp.float64) -> bool:
    """Edges a and b (midpoints ``mid`` at x) cannot be in reach at x nor at the predicted
    end (pair_stiffness's near and near_end both false): their midpoints farther apart
    than both sweeps and c0, widened by 2 ``REACH_MARGIN_MM`` (no square root; the
    triangle inequality through x_end's midpoints)."""
    d = mid[a] - mid[b]
    reach = sweep[a] + sweep[b] + c0 + wp.float64(2.0) * REACH_MARGIN_MM
    return wp.dot(d, d) > reach * reach


@wp.func
def relative_move(node_move: wp.array(dtype=wp.vec3d), a: int, b: int) -> wp.float64:
    """The largest move (mm) of one of edge a's nodes relative to one of edge b's between x and
    the predicted end (``node_move``: kernels/implicit.edge_ends). The two segments' distance
    changes by no more: a point of each moves by a convex combination of its nodes' moves, so
    their difference is a convex combination of the four differences."""
    largest = F64_0
    for i in range(2):
        for j in range(2):
            d = node_move[a + i] - node_move[b + j]
            largest = wp.max(largest, wp.dot(d, d))
    return wp.sqrt(largest)


@wp.func
def chord_candidate(x: wp.array(dtype=wp.vec3d), free: wp.array(dtype=wp.int32), has_next: wp.array(dtype=wp.int32),
                    fixed: wp.array(dtype=wp.int32), node_radius: wp.array(dtype=wp.float64),
                    mid: wp.array(dtype=wp.vec3d), a: int, b: int, reach_a: wp.float64, far: wp.float64,
                    raw: wp.float64, c0: wp.float64, end_mid: wp.array(dtype=wp.vec3d),
                    end_half: wp.array(dtype=wp.float64), end_move: wp.array(dtype=wp.float64),
                    sweep: wp.array(dtype=wp.float64), node_move: wp.array(dtype=wp.vec3d)) -> bool:
    """Pair (a, b) may have a chord stiffness on either side (kernels/implicit.pair_stiffness
    from a and from b): in reach at x (the bounding spheres, widened by SIDE_MARGIN_MM for
    b's own sum of the same lengths) or at the predicted end (symmetric), and its gap at x
    (``raw``, pair_forces' segment gap from a; −FAR_MM: not evaluated) not above c0 and both
    edges' moves (+ REACH_MARGIN_MM, the stiffness pass's own test, + SIDE_MARGIN_MM: b's
    closest points may round differently; a rest offset only adds). A pair it rejects adds
    zero blocks on both sides (``sweep``: kernels/implicit.edge_ends, for :func:`swept_apart`). An
    evaluated pair out of range at x whose gap exceeds c0 by more than the edges' :func:`relative_move`
    (+ the same margins) stays out of range at the end too (the stiffness pass's own test)."""
    if raw != -FAR_MM:  # evaluated (in reach at x from a: b is an obstacle): not too far, or not finite
        if raw >= c0 + end_move[a] + end_move[b] + REACH_MARGIN_MM + SIDE_MARGIN_MM:
            return False
        return not (raw >= c0 and raw >= c0 + relative_move(node_move, a, b) + REACH_MARGIN_MM + SIDE_MARGIN_MM)
    if not edge_is_obstacle(free, has_next, fixed, b):
        return False
    if swept_apart(mid, sweep, a, b, c0):  # the chord pass's own skip (symmetric)
        return False
    apart = wp.length(mid[a] - mid[b])
    if apart <= far + SIDE_MARGIN_MM and apart < reach_a + wp.float64(0.5) * wp.length(x[b + 1] - x[b]) \
            + node_radius[b] + SIDE_MARGIN_MM:
        return True
    return pair_in_reach_at_end(end_mid, end_half, a, b, c0, far)


@wp.func
def visit_pair(x: wp.array(dtype=wp.vec3d), rest_x: wp.array(dtype=wp.vec3d), coil_of: wp.array(dtype=wp.int32),
               free: wp.array(dtype=wp.int32), has_next: wp.array(dtype=wp.int32), fixed: wp.array(dtype=wp.int32),
               node_radius: wp.array(dtype=wp.float64), contact_share: wp.array(dtype=wp.float64),
               contact_samples: wp.array(dtype=wp.int32), mid: wp.array(dtype=wp.vec3d), a: int, b: int, exclusion: int,
               reach_a: wp.float64, p0: wp.float64,
               c0: wp.float64, u_linear: wp.float64, far: wp.float64, sum_start: wp.array(dtype=vec3l),
               sum_end: wp.array(dtype=vec3l), min_gap: wp.array(dtype=wp.float64),
               contacts: wp.array(dtype=wp.int32), bad: wp.array(dtype=wp.int32), record: int,
               touch_count: wp.array(dtype=wp.int32), touch_b: wp.array2d(dtype=wp.int32)):
    """Pair (a, b) found by edge a: evaluated here when a < b or b takes no force
    (an edge in the catheter: it runs no pass of its own), once for both sides;
    with ``record``, a pair within TOUCH_MARGIN_MM of touching is noted on both
    sides (:func:`note_touching`). Returns pair_forces' segment gap (−FAR_MM when not
    evaluated) and closest-point parameters, whether the pair was evaluated here, and whether b
    runs its own pass."""
    b_runs = edge_in_contact_pass(free, has_next, b)
    raw = -FAR_MM
    st = NO_PARAMS
    handled = False
    if b > a or not b_runs:
        handled = True
        fa_start, fa_end, fb_start, fb_end, gap_a, gap_b, raw_a, st_a = pair_forces(
            x, rest_x, coil_of, free, has_next, fixed, node_radius, contact_share, contact_samples, mid, a, b,
            exclusion, reach_a, p0, c0, u_linear, far)
        if raw_a == -FAR_MM:  # not evaluated: zero forces and the gap the sums start from (clear_edge_sums)
            return raw_a, st_a, handled, b_runs
        add_side(a, fa_start, fa_end, gap_a, c0, sum_start, sum_end, min_gap, contacts, bad)
        if b_runs:
            add_side(b, fb_start, fb_end, gap_b, c0, sum_start, sum_end, min_gap, contacts, bad)
        if record != 0 and gap_a < c0 + TOUCH_MARGIN_MM:
            note_touching(a, b, touch_count, touch_b)
            if b_runs:
                note_touching(b, a, touch_count, touch_b)
        raw = raw_a
        st = st_a
    return raw, st, handled, b_runs


@wp.kernel
def clear_edge_sums(world_of: wp.array(dtype=wp.int32), query_radius: wp.array(dtype=wp.float64),
                    sum_start: wp.array(dtype=vec3l), sum_end: wp.array(dtype=vec3l),
                    min_gap: wp.array(dtype=wp.float64), contacts: wp.array(dtype=wp.int32),
                    bad: wp.array(dtype=wp.int32), touch_count: wp.array(dtype=wp.int32),
                    chord_count: wp.array(dtype=wp.int32)):
    """Empty coil–coil sums and records before :func:`edge_contact` adds the pairs
    (smallest gap: the world's query radius, reported where no pair was evaluated)."""
    e = wp.tid()
    sum_start[e] = vec3l()
    sum_end[e] = vec3l()
    min_gap[e] = query_radius[world_of[e]]
    contacts[e] = 0
    bad[e] = 0
    touch_count[e] = 0
    chord_count[e] = 0


@wp.kernel(enable_backward=False)
def edge_contact(
    x: wp.array(dtype=wp.vec3d),
    rest_x: wp.array(dtype=wp.vec3d),
    free: wp.array(dtype=wp.int32),
    has_next: wp.array(dtype=wp.int32),
    coil_of: wp.array(dtype=wp.int32),
    world_of: wp.array(dtype=wp.int32),
    running: wp.array(dtype=wp.int32),
    fixed: wp.array(dtype=wp.int32),
    node_radius: wp.array(dtype=wp.float64),
    contact_share: wp.array(dtype=wp.float64),
    contact_samples: wp.array(dtype=wp.int32),
    grid: wp.uint64,
    neighbours: wp.array2d(dtype=wp.int32),
    neighbour_count: wp.array(dtype=wp.int32),
    mid: wp.array(dtype=wp.vec3d),
    query_radius: wp.array(dtype=wp.float64),
    grid_radius: wp.float64,
    exclusion: int,
    p0: wp.float64,
    c0: wp.float64,
    u_linear: wp.float64,
    sum_start: wp.array(dtype=vec3l),
    sum_end: wp.array(dtype=vec3l),
    min_gap: wp.array(dtype=wp.float64),
    contacts: wp.array(dtype=wp.int32),
    bad: wp.array(dtype=wp.int32),
    record: int,
    touch_count: wp.array(dtype=wp.int32),
    touch_b: wp.array2d(dtype=wp.int32),
    end_mid: wp.array(dtype=wp.vec3d),
    end_half: wp.array(dtype=wp.float64),
    end_move: wp.array(dtype=wp.float64),
    sweep: wp.array(dtype=wp.float64),
    chord_count: wp.array(dtype=wp.int32),
    chord_b: wp.array2d(dtype=wp.int32),
    chord_st: wp.array2d(dtype=wp.vec2d),
    note_chord: int,
    node_move: wp.array(dtype=wp.vec3d),
):
    """Coil–coil contact: the node–capsule terms (:func:`pair_forces`) joining edge a
    and every other edge b of the same ensemble member near it, each pair evaluated
    once (:func:`visit_pair`) and added to both edges' fixed-point sums, smallest
    capsule–capsule gaps and touching counts (cleared by :func:`clear_edge_sums`;
    integer sums commute, so the forces are bit-identical in any order, and to
    evaluating each pair from both sides). Candidates: a's neighbour list from the last
    build (every edge whose midpoint was within query radius + skin then, so
    every edge whose midpoint is now within its world's ``query_radius`` while no midpoint
    has moved half the skin), or, when the list overflowed, the grid of that
    build searched ``grid_radius`` (= query radius + half the skin) around a's
    current midpoint. Bonded neighbours (same coil, closer than ``exclusion``
    edges) are skipped. Edges in the catheter stand in for the catheter: free
    edges are pushed off them. With ``record``, each edge's partners within
    TOUCH_MARGIN_MM of touching are noted (``touch_count``, ``touch_b``) for the
    implicit step's contact stiffness. With ``note_chord``, also each pair that may have a
    chord stiffness in the implicit step, on both sides (:func:`chord_candidate`;
    ``chord_count``, ``chord_b``, cleared by :func:`clear_edge_sums`, and ``chord_st``: the
    closest-point parameters from the side that evaluated the pair, :func:`note_candidate`; ``end_mid``,
    ``end_half``, ``end_move``, ``sweep``, ``node_move``: kernels/implicit.edge_ends at this step's
    predicted end). An edge whose list overflowed, one with a partner whose list overflowed that the
    partner's grid search evaluates (it may miss the pair), and one that such a grid search
    found (the grid returns whole cells, which the found edge's own list may not hold)
    overflows its record: its chord pass walks its whole list then, as without the notes."""
    a = wp.tid()
    w = world_of[a]
    radius = query_radius[w]
    if edge_in_contact_pass(free, has_next, a) and running[w] != 0:
        reach_a = wp.float64(0.5) * wp.length(x[a + 1] - x[a]) + node_radius[a] + c0
        listed = neighbour_count[a]
        if listed == NO_LIST:  # the grid, grouped by world (built only here: next_partner reads it only then)
            query = wp.hash_grid_query(grid, mid[a], grid_radius, w)
        if note_chord != 0 and listed == NO_LIST:
            wp.atomic_add(chord_count, a, chord_b.shape[1] + 1)
        k = int(0)
        b = int(0)
        while next_partner(query, k, b, a, neighbours, listed, coil_of, exclusion):
            raw, st, handled, b_runs = visit_pair(x, rest_x, coil_of, free, has_next, fixed, node_radius,
                                                  contact_share, contact_samples, mid, a, b, exclusion, reach_a, p0, c0,
                                                  u_linear, radius, sum_start, sum_end, min_gap, contacts, bad, record,
                                                  touch_count, touch_b)
            if note_chord == 0:
                continue
            if handled:
                if chord_candidate(x, free, has_next, fixed, node_radius, mid, a, b, reach_a, radius, raw, c0,
                                   end_mid, end_half, end_move, sweep, node_move):
                    note_candidate(a, b, st, chord_count, chord_b, chord_st)
                    if b_runs:
                        if listed == NO_LIST:  # a's grid search found b, which b's own list may not hold
                            wp.atomic_add(chord_count, b, chord_b.shape[1] + 1)
                        else:
                            note_candidate(b, a, NO_PARAMS, chord_count, chord_b, chord_st)
            elif neighbour_count[b] == NO_LIST:
                wp.atomic_add(chord_count, a, chord_b.shape[1] + 1)


@wp.kernel
def finish_edge_contact(sum_start: wp.array(dtype=vec3l), sum_end: wp.array(dtype=vec3l),
                        bad: wp.array(dtype=wp.int32), force_start: wp.array(dtype=wp.vec3d),
                        force_end: wp.array(dtype=wp.vec3d), min_gap: wp.array(dtype=wp.float64)):
    """Edge e's coil–coil forces (µN) from its fixed-point sums; NaN (forces and
    gap) when a contribution was non-finite."""
    e = wp.tid()
    f_start = from_fixed(sum_start[e])
    f_end = from_fixed(sum_end[e])
    if bad[e] != 0:
        nan = wp.float64(wp.nan)
        f_start = wp.vec3d(nan, nan, nan)
        f_end = f_start
        min_gap[e] = nan
    force_start[e] = f_start
    force_end[e] = f_end


@wp.func
def add_edge_shares(f: wp.vec3d, start: wp.array(dtype=wp.vec3d), end: wp.array(dtype=wp.vec3d),
                    has_next: wp.array(dtype=wp.int32), i: int) -> wp.vec3d:
    """``f`` plus node i's shares of per-edge sums: edge i's ``start`` and edge i − 1's ``end``
    (in that order, each where the edge exists)."""
    if has_next[i] != 0:
        f = f + start[i]
    if i >= 1:
        if has_next[i - 1] != 0:
            f = f + end[i - 1]
    return f


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
        f = add_edge_shares(f, force_start, force_end, has_next, i)
    force[i] = f
