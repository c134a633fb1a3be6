"""Linearly implicit Euler (Baraff & Witkin 1998): the system, its per-coil
banded preconditioner and the conjugate-gradient pieces.

One step, per free node (velocity form, M lumped masses, H ≈ ∂²W/∂x²)::

    (M + dt B + dt² H) v' = M v + dt F(x)   (v of nodes in the catheter: the pusher's)
    x' = x + dt v'

B = β(|v|) I per node, the damping law's secant coefficient at the old velocity,
β = c (1 − e^{−|v|/k}) / |v| (c/k at rest): the damping is solved together with
the elastic terms. (Applying it after the solve, as the reference does, is a
splitting whose error grows as dt² k_s/m: the stiff stretching springs behind the
catheter tip then carry a spurious compression — the push force came out
+600 µN at 117 µs and +5000 µN at 467 µs on the small seed case, against the
reference's −530 µN.)

(BDF2, ``ImplicitSolver(method="bdf2")``: the same matrix at h = 2/3 dt, right side
M (4/3 v − 1/3 v₋₁) + h F − h² H (x − x₋₁)/(3 h), x' = 4/3 x − 1/3 x₋₁ + h v'.)

and per spinning edge (twist inertia J, twist damping b)::

    (J + dt b + dt² H_θ) ω' = J ω + dt T

H is positive semi-definite:

* stretching: the exact edge Hessian k_s [(1 − l̄/l)₊ (I − t tᵀ) + t tᵀ]
  (its negative part for a compressed edge dropped);
* bending: Gauss–Newton, k_b Jᵀ J with κ ≈ t₁ − t₀ (exact for small bends of
  a straight rod: the squared second difference);
* contact, the law's stiffness k(h) along the normal n: a wall contact adds
  k n nᵀ to its node; a coil–coil contact (gap gradient w over the two edges'
  four nodes) adds k w wᵀ ⊗ n nᵀ, applied matrix-free from the recorded pairs
  (``system_product``); fold contacts a Gershgorin diagonal 2 k n nᵀ;
* twist: k_t on the twist difference of neighbouring edges, plus the bending
  energy's dependence on the frame angle (Gauss–Newton ½ k_b |K̄|²), a
  tridiagonal system per coil (Thomas algorithm).

Everything but the coil–coil term is banded along each coil (3×3 blocks,
bandwidth 2). The preconditioner is that band with the coil–coil term replaced
by its Gershgorin diagonal 2 k |w_a| n nᵀ per node (Σ|w| = 2: it dominates the
pair's true matrix), factorised by block LDLᵀ, one thread per coil. No sums
across threads in an order that depends on anything but the world's own nodes,
so an ensemble member equals its single run.

For a mode of stiffness k whose matrix entry is a ≥ k/2 the step is stable
at any dt (the amplification matrix has determinant m/(m + dt² a) < 1 and
trace ≥ −1 − det).
"""

import warp as wp

from .contact import (
    NO_LIST,
    NO_PARAMS,
    REACH_MARGIN_MM,
    bonded,
    contact_stiffness,
    edge_in_contact_pass,
    edge_is_obstacle,
    fixed_outer,
    from_fixed,
    next_partner,
    pair_in_reach_at_end,
    relative_move,
    rest_offset,
    swept_apart,
    segment_closest_params,
    to_fixed,
    vec3l,
)
from .chord import chord_stiffness
from .elastic import bonded_span, edge_torque
from .integrate import hold_node
from .rod import F64_0, F64_1, clamp_vertex, director_normal, edge_valid, rotate_about, transport, vertex_valid


OVERFLOW = wp.constant(-1)  # an edge with more touching pairs than its record holds


@wp.func
def sym_outer(n: wp.vec3d, k: wp.float64) -> wp.mat33d:
    return k * wp.outer(n, n)


@wp.func
def edge_stretch_hessian(x: wp.array(dtype=wp.vec3d), k_stretch: wp.array(dtype=wp.float64),
                         rest_length: wp.array(dtype=wp.float64), e: int) -> wp.mat33d:
    """∂²W_s/∂x_{e+1}² of edge e (µN/mm), its compressive (negative) part dropped."""
    d = x[e + 1] - x[e]
    length = wp.length(d)
    t = d / length
    tt = wp.outer(t, t)
    lateral = wp.max(F64_1 - rest_length[e] / length, F64_0)
    eye = wp.identity(n=3, dtype=wp.float64)
    return k_stretch[e] * (lateral * (eye - tt) + tt)


@wp.func
def edge_jacobian(x: wp.array(dtype=wp.vec3d), e: int) -> wp.mat33d:
    """∂t_e/∂x_{e+1} = (I − t tᵀ)/|e| (1/mm)."""
    d = x[e + 1] - x[e]
    length = wp.length(d)
    t = d / length
    return (wp.identity(n=3, dtype=wp.float64) - wp.outer(t, t)) / length


@wp.func
def edge_jacobian_or_zero(x: wp.array(dtype=wp.vec3d), has_next: wp.array(dtype=wp.int32), e: int) -> wp.mat33d:
    if e < 0 or e >= has_next.shape[0]:
        return wp.mat33d()
    if has_next[e] == 0:
        return wp.mat33d()
    return edge_jacobian(x, e)


@wp.func
def bends(has_next: wp.array(dtype=wp.int32), clamp_tangent: wp.array(dtype=wp.vec3d), j: int) -> bool:
    """Vertex j bends: an interior node, or a coil's first node clamped with its
    tangent (its previous edge virtual and fixed, so its G is zero)."""
    if j < 0 or j + 1 >= has_next.shape[0]:
        return False
    return vertex_valid(has_next, j) or clamp_vertex(clamp_tangent, j)


@wp.func
def vertex_bends(has_next: wp.array(dtype=wp.int32), clamp_tangent: wp.array(dtype=wp.vec3d),
                 k_bend: wp.array(dtype=wp.float64), j: int) -> wp.float64:
    """k_b of vertex j, 0 where j is not a vertex."""
    if not bends(has_next, clamp_tangent, j):
        return F64_0
    return k_bend[j]


@wp.func
def fold_stiffness(x: wp.array(dtype=wp.vec3d), has_next: wp.array(dtype=wp.int32),
                   node_radius: wp.array(dtype=wp.float64), i: int, span: int, p0: wp.float64, c0: wp.float64,
                   u_linear: wp.float64) -> wp.mat33d:
    """Diagonal (Gershgorin, 2 k n nᵀ) stiffness of node i's fold contacts (elastic.fold_force)."""
    h = wp.mat33d()
    for side in range(2):
        j = i + 2 * span
        first = i
        if side == 1:
            j = i - 2 * span
            first = j
        if bonded_span(has_next, first, 2 * span):
            delta = x[i] - x[j]
            dist = wp.length(delta)
            if dist > wp.float64(1.0e-12):
                k = contact_stiffness(dist - node_radius[i] - node_radius[j], p0, c0, u_linear)
                h = h + sym_outer(delta / dist, wp.float64(2.0) * k)
    return h


@wp.func
def to_fixed_sym(m: wp.mat33d):
    """A symmetric 3×3 block as two fixed-point vectors (diagonal, then xy xz yz)."""
    return to_fixed(wp.vec3d(m[0, 0], m[1, 1], m[2, 2])), to_fixed(wp.vec3d(m[0, 1], m[0, 2], m[1, 2]))


@wp.func
def from_fixed_sym(diag: vec3l, off: vec3l) -> wp.mat33d:
    d = from_fixed(diag)
    o = from_fixed(off)
    return wp.mat33d(d[0], o[0], o[1], o[0], d[1], o[2], o[1], o[2], d[2])


REST_BOUND_MARGIN_MM = wp.constant(wp.float64(1.0e-9))  # mm: far above rounding of mm-scale lengths


@wp.func
def pair_rest_offset(rest_x: wp.array(dtype=wp.vec3d), coil_of: wp.array(dtype=wp.int32),
                     node_radius: wp.array(dtype=wp.float64), a: int, b: int, c0: wp.float64) -> wp.float64:
    """Shift (mm) of a same-coil pair's gap: its rest clearance's contact.rest_offset
    (0 for two coils; the rest shape only, so one value serves x and x_end). 0 without
    the closest points where the midpoints' bound on the rest clearance (apart less both
    half-lengths and radii) exceeds c0 by ``REST_BOUND_MARGIN_MM`` (rounding cannot reach
    it, so the value is the closest points' own 0)."""
    if coil_of[a] != coil_of[b]:
        return F64_0
    ra0 = rest_x[a]
    rb0 = rest_x[b]
    apart = wp.length(wp.float64(0.5) * (ra0 + rest_x[a + 1] - rb0 - rest_x[b + 1]))
    halves = wp.float64(0.5) * (wp.length(rest_x[a + 1] - ra0) + wp.length(rest_x[b + 1] - rb0))
    if apart - halves - node_radius[a] - node_radius[b] > c0 + REST_BOUND_MARGIN_MM:
        return F64_0
    rst = segment_closest_params(ra0, rest_x[a + 1], rb0, rest_x[b + 1])
    rest_gap = wp.length(ra0 + rst[0] * (rest_x[a + 1] - ra0) - rb0 - rst[1] * (rest_x[b + 1] - rb0)) \
        - node_radius[a] - node_radius[b]
    return rest_offset(rest_gap, c0)


@wp.kernel
def rest_offsets(rest_x: wp.array(dtype=wp.vec3d), coil_of: wp.array(dtype=wp.int32),
                 has_next: wp.array(dtype=wp.int32), node_radius: wp.array(dtype=wp.float64),
                 coil_first: wp.array(dtype=wp.int32), coil_last: wp.array(dtype=wp.int32), exclusion: int,
                 c0: wp.float64, count: wp.array(dtype=wp.int32), partner: wp.array2d(dtype=wp.int32),
                 offset: wp.array2d(dtype=wp.float64)):
    """Each edge a's same-coil partners b (not bonded) with a nonzero :func:`pair_rest_offset`
    (a, b) (mm), in partner order (the rest shape's: once per model); more than the record
    holds: count OVERFLOW (the offsets are then computed: :func:`noted_rest_offset`)."""
    a = wp.tid()
    found = int(0)
    if has_next[a] != 0:
        c = coil_of[a]
        for b in range(coil_first[c], coil_last[c]):
            if has_next[b] != 0 and not bonded(coil_of, exclusion, a, b) and found != OVERFLOW:
                value = pair_rest_offset(rest_x, coil_of, node_radius, a, b, c0)
                if value != F64_0:
                    if found == partner.shape[1]:
                        found = OVERFLOW
                    else:
                        partner[a, found] = b
                        offset[a, found] = value
                        found += 1
    count[a] = found


@wp.func
def noted_rest_offset(rest_count: wp.array(dtype=wp.int32), rest_b: wp.array2d(dtype=wp.int32),
                      rest_value: wp.array2d(dtype=wp.float64), rest_x: wp.array(dtype=wp.vec3d),
                      coil_of: wp.array(dtype=wp.int32), node_radius: wp.array(dtype=wp.float64), a: int, b: int,
                      c0: wp.float64) -> wp.float64:
    """:func:`pair_rest_offset` (a, b) (mm) of a pair that is not bonded, from a's record
    (:func:`rest_offsets`: a partner it does not list has none), or computed where the
    record overflowed."""
    listed = rest_count[a]
    if listed == OVERFLOW:
        return pair_rest_offset(rest_x, coil_of, node_radius, a, b, c0)
    for k in range(listed):
        if rest_b[a, k] == b:
            return rest_value[a, k]
    return F64_0


@wp.func
def pair_gap(x: wp.array(dtype=wp.vec3d), coil_of: wp.array(dtype=wp.int32),
             node_radius: wp.array(dtype=wp.float64), a: int, b: int, offset: wp.float64, known: wp.vec2d):
    """Edges a and b at positions ``x``: closest-point parameters (s, t) (``known`` unless
    NO_PARAMS: segment_closest_params' own at ``x``), the vector from b's closest point to a's (mm),
    its length and the gap (mm; a same-coil pair counted from its rest clearance: ``offset``,
    pair_rest_offset)."""
    pa0 = x[a]
    pa1 = x[a + 1]
    pb0 = x[b]
    pb1 = x[b + 1]
    st = known
    if known[0] < F64_0:
        st = segment_closest_params(pa0, pa1, pb0, pb1)
    delta = pa0 + st[0] * (pa1 - pa0) - pb0 - st[1] * (pb1 - pb0)
    dist = wp.length(delta)
    gap = dist - node_radius[a] - node_radius[b]
    if coil_of[a] == coil_of[b]:
        gap = gap + offset
    return st, delta, dist, gap


@wp.kernel
def edge_ends(x: wp.array(dtype=wp.vec3d), x_end: wp.array(dtype=wp.vec3d), has_next: wp.array(dtype=wp.int32),
              node_radius: wp.array(dtype=wp.float64), end_mid: wp.array(dtype=wp.vec3d),
              end_half: wp.array(dtype=wp.float64), sweep: wp.array(dtype=wp.float64),
              end_move: wp.array(dtype=wp.float64), node_move: wp.array(dtype=wp.vec3d)):
    """Each edge at the chord's predicted end: its midpoint (mm) and half-length plus
    radius (mm), for pair_in_reach_at_end; and ``sweep`` (mm): the larger half-length
    plus radius at x and x_end, plus how far the midpoint moves between them, for
    swept_apart; ``end_move`` (mm): the larger of its two nodes' moves from x to x_end, for
    pair_stiffness (a coil's last node: its position, 0, 0, 0); ``node_move`` (mm): each node's
    move x_end − x, for contact.relative_move."""
    e = wp.tid()
    node_move[e] = x_end[e] - x[e]
    if has_next[e] == 0:
        end_mid[e] = x_end[e]
        end_half[e] = F64_0
        sweep[e] = F64_0
        end_move[e] = F64_0
        return
    m = wp.float64(0.5) * (x_end[e] + x_end[e + 1])
    end_mid[e] = m
    half = wp.float64(0.5) * wp.length(x_end[e + 1] - x_end[e]) + node_radius[e]
    end_half[e] = half
    half_x = wp.float64(0.5) * wp.length(x[e + 1] - x[e]) + node_radius[e]
    sweep[e] = wp.max(half, half_x) + wp.length(m - wp.float64(0.5) * (x[e] + x[e + 1]))
    end_move[e] = wp.max(wp.length(x_end[e] - x[e]), wp.length(x_end[e + 1] - x[e + 1]))


@wp.func
def pair_stiffness(x: wp.array(dtype=wp.vec3d), rest_x: wp.array(dtype=wp.vec3d), coil_of: wp.array(dtype=wp.int32),
                   free: wp.array(dtype=wp.int32), has_next: wp.array(dtype=wp.int32),
                   fixed: wp.array(dtype=wp.int32), node_radius: wp.array(dtype=wp.float64),
                   mid: wp.array(dtype=wp.vec3d), a: int, b: int, reach_a: wp.float64, p0: wp.float64,
                   c0: wp.float64, u_linear: wp.float64, far: wp.float64, x_end: wp.array(dtype=wp.vec3d),
                   end_mid: wp.array(dtype=wp.vec3d), end_half: wp.array(dtype=wp.float64),
                   end_move: wp.array(dtype=wp.float64), node_move: wp.array(dtype=wp.vec3d), chord: int,
                   rest_count: wp.array(dtype=wp.int32), rest_b: wp.array2d(dtype=wp.int32),
                   rest_value: wp.array2d(dtype=wp.float64), known_st: wp.vec2d):
    """Edge b's contact on edge a, for exactly the pairs contact.pair_contact
    evaluates: 1 if touching, closest-point parameters (s on a, t on b), the law's
    stiffness k (µN/mm) and the unit normal n from b to a. Two parts of one coil closer than
    c0 in the rest shape start at their rest clearance (contact.rest_offset), as the
    force does. With ``chord`` the stiffness is the law's chord between the gap at x
    and at the predicted end ``x_end`` (kernels/chord.py), and a pair out of range at
    x that enters it at ``x_end`` is a contact too (with x_end's parameters and normal);
    ``end_mid``, ``end_half``, ``end_move``, ``node_move``: edge_ends. A pair whose gap at x exceeds
    c0 by more than both edges' moves, or by more than their nodes' largest relative move
    (contact.relative_move; and ``REACH_MARGIN_MM``), stays out of range at x_end (the segments'
    distance moves no more): no gap there is computed. The rest offset from a's record
    (``rest_count``, ``rest_b``, ``rest_value``: :func:`noted_rest_offset`). ``known_st``: the closest-point
    parameters at x where known (the contact pass's: contact.note_candidate), else NO_PARAMS."""
    hit = int(0)
    st = wp.vec2d(F64_0, F64_0)
    k = F64_0
    normal = wp.vec3d(F64_0, F64_0, F64_0)
    if edge_is_obstacle(free, has_next, fixed, b):
        apart = wp.length(mid[a] - mid[b])
        near = apart <= far and apart < reach_a + wp.float64(0.5) * wp.length(x[b + 1] - x[b]) + node_radius[b]
        near_end = False
        if chord != 0:
            near_end = pair_in_reach_at_end(end_mid, end_half, a, b, c0, far)
        if near or near_end:
            offset = noted_rest_offset(rest_count, rest_b, rest_value, rest_x, coil_of, node_radius, a, b, c0)
            st, delta, dist, gap = pair_gap(x, coil_of, node_radius, a, b, offset, known_st)
            gap_end = gap
            if chord != 0:
                if gap >= c0 + end_move[a] + end_move[b] + REACH_MARGIN_MM:
                    near_end = False
                elif near_end and gap >= c0 and gap >= c0 + relative_move(node_move, a, b) + REACH_MARGIN_MM:
                    near_end = False
                gap_end = c0  # out of reach at x_end: its gap is ≥ c0 there (no entry, the tangent)
                st_end = st
                delta_end = delta
                dist_end = dist
                if near_end:
                    st_end, delta_end, dist_end, gap_end = pair_gap(x_end, coil_of, node_radius, a, b, offset,
                                                                    NO_PARAMS)
                if near_end and not (gap < c0 and dist > wp.float64(1.0e-12)) and gap_end < c0 and dist_end > wp.float64(1.0e-12):
                    st, delta, dist = st_end, delta_end, dist_end  # enters during the step
            if (gap < c0 or gap_end < c0) and dist > wp.float64(1.0e-12):
                hit = 1
                k = chord_stiffness(gap, gap_end, p0, c0, u_linear)
                normal = delta / dist
    return hit, st, k, normal


@wp.func
def add_pair(a: int, b: int, st: wp.vec2d, k: wp.float64, normal: wp.vec3d, sums: wp.array2d(dtype=vec3l),
             pair_count: wp.array(dtype=wp.int32), pair_b: wp.array2d(dtype=wp.int32),
             pair_st: wp.array2d(dtype=wp.vec2d), pair_k: wp.array2d(dtype=wp.float64),
             pair_n: wp.array2d(dtype=wp.vec3d)):
    """Edge a's side of a touching pair (partner b, closest-point parameters (s on a, t on b),
    stiffness k µN/mm, unit normal n from b to a): its Gershgorin blocks (1 − s) 2k n nᵀ and
    s 2k n nᵀ added to a's fixed-point sums (``sums`` row a: start diagonal, start upper, end
    diagonal, end upper; integer addition, so any order gives the same sum) and the pair noted
    in a's record at the next free slot (:func:`finish_pair_records` sorts it by partner; a
    count beyond the record's width: overflowed)."""
    d, o = fixed_outer((F64_1 - st[0]) * wp.float64(2.0) * k, normal)
    wp.atomic_add(sums, a, 0, d)
    wp.atomic_add(sums, a, 1, o)
    d, o = fixed_outer(st[0] * wp.float64(2.0) * k, normal)
    wp.atomic_add(sums, a, 2, d)
    wp.atomic_add(sums, a, 3, o)
    slot = wp.atomic_add(pair_count, a, 1)
    if slot < pair_b.shape[1]:
        pair_b[a, slot] = b
        pair_st[a, slot] = st
        pair_k[a, slot] = k
        pair_n[a, slot] = normal


@wp.func
def evaluates_pair(a: int, b: int, chord: int, neighbour_count: wp.array(dtype=wp.int32)) -> bool:
    """Edge a's chord pass evaluates its pair with edge b (both in the pass): the lower edge does
    (contact.visit_pair's side), except, with the chord, where one of the two searches the grid (its
    neighbour list overflowed: NO_LIST) and the other walks a list: then the one with the list, which
    holds every partner within the list radius, while the grid, searched around the edge's midpoint at
    x, may miss a pair that comes into reach only at the predicted end (contact.edge_contact then
    overflows the list side's chord record, so it walks its whole list)."""
    a_grid = neighbour_count[a] == NO_LIST
    b_grid = neighbour_count[b] == NO_LIST
    if chord != 0 and a_grid != b_grid:
        return b_grid
    return b > a


@wp.kernel
def clear_pair_records(pair_count: wp.array(dtype=wp.int32), sums: wp.array2d(dtype=vec3l)):
    """Empty each edge's pair record and block sums before :func:`edge_contact_stiffness` adds to them."""
    a = wp.tid()
    pair_count[a] = 0
    for j in range(4):
        sums[a, j] = vec3l()


@wp.kernel
def finish_pair_records(sums: wp.array2d(dtype=vec3l), pair_count: wp.array(dtype=wp.int32),
                        pair_b: wp.array2d(dtype=wp.int32), pair_st: wp.array2d(dtype=wp.vec2d),
                        pair_k: wp.array2d(dtype=wp.float64), pair_n: wp.array2d(dtype=wp.vec3d),
                        stiff_start: wp.array(dtype=wp.mat33d), stiff_end: wp.array(dtype=wp.mat33d)):
    """Edge a's Gershgorin blocks on its start and end node (µN/mm) from its sums, and its
    pair record sorted by partner (sums over it then run in an order that does not depend
    on the order the pairs were added); more pairs than the record holds: count OVERFLOW
    (they then enter only through the Gershgorin blocks)."""
    a = wp.tid()
    stiff_start[a] = from_fixed_sym(sums[a, 0], sums[a, 1])
    stiff_end[a] = from_fixed_sym(sums[a, 2], sums[a, 3])
    count = pair_count[a]
    if count > pair_b.shape[1]:
        pair_count[a] = OVERFLOW
        return
    for i in range(1, count):
        b = pair_b[a, i]
        st = pair_st[a, i]
        k = pair_k[a, i]
        n = pair_n[a, i]
        slot = i
        while slot > 0 and pair_b[a, slot - 1] > b:
            pair_b[a, slot] = pair_b[a, slot - 1]
            pair_st[a, slot] = pair_st[a, slot - 1]
            pair_k[a, slot] = pair_k[a, slot - 1]
            pair_n[a, slot] = pair_n[a, slot - 1]
            slot = slot - 1
        pair_b[a, slot] = b
        pair_st[a, slot] = st
        pair_k[a, slot] = k
        pair_n[a, slot] = n


@wp.kernel(enable_backward=False)
def edge_contact_stiffness(
    x: wp.array(dtype=wp.vec3d),
    rest_x: wp.array(dtype=wp.vec3d),
    free: wp.array(dtype=wp.int32),
    has_next: wp.array(dtype=wp.int32),
    coil_of: wp.array(dtype=wp.int32),
    world_of: wp.array(dtype=wp.int32),
    running: wp.array(dtype=wp.int32),
    fixed: wp.array(dtype=wp.int32),
    node_radius: wp.array(dtype=wp.float64),
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
    touch_count: wp.array(dtype=wp.int32),
    touch_b: wp.array2d(dtype=wp.int32),
    sums: wp.array2d(dtype=vec3l),
    pair_count: wp.array(dtype=wp.int32),
    pair_b: wp.array2d(dtype=wp.int32),
    pair_st: wp.array2d(dtype=wp.vec2d),
    pair_k: wp.array2d(dtype=wp.float64),
    pair_n: wp.array2d(dtype=wp.vec3d),
    x_end: wp.array(dtype=wp.vec3d),
    end_mid: wp.array(dtype=wp.vec3d),
    end_half: wp.array(dtype=wp.float64),
    sweep: wp.array(dtype=wp.float64),
    end_move: wp.array(dtype=wp.float64),
    chord: int,
    chord_count: wp.array(dtype=wp.int32),
    chord_b: wp.array2d(dtype=wp.int32),
    chord_st: wp.array2d(dtype=wp.vec2d),
    noted_chord: int,
    node_move: wp.array(dtype=wp.vec3d),
    rest_count: wp.array(dtype=wp.int32),
    rest_b: wp.array2d(dtype=wp.int32),
    rest_value: wp.array2d(dtype=wp.float64),
):
    """Coil–coil contact stiffness (µN/mm), each pair evaluated once (``pair_stiffness``
    from its lower edge a, or from a when b runs no pass of its own: an edge in the
    catheter, or searches the grid where a walks a list: :func:`evaluates_pair`) and
    added to both edges (:func:`add_pair`: a's side, and b's mirrored, with (t, s) and
    −n, when b runs its pass): Gershgorin block sums and pair records, cleared by
    :func:`clear_pair_records`, finished by :func:`finish_pair_records`. Edge a's candidates:
    the partners that contact.edge_contact noted within a hair of touching at the same
    state (``touch_count``, ``touch_b``, noted on both sides; every pair this finds touching
    is among them), or, when more than the record holds, a's partners found as
    contact.edge_contact finds them. With ``chord`` (kernels/chord.py) every neighbour-list
    partner is a candidate (a pair may enter the contact range on the way to the predicted
    end ``x_end``), those swept_apart skipped (``end_mid``, ``end_half``, ``sweep``,
    ``end_move``, ``node_move``: edge_ends); with ``noted_chord``, only those
    contact.edge_contact noted as chord candidates at this step's predicted end
    (``chord_count``, ``chord_b``, noted on both sides; every pair with a block is among
    them; ``chord_st``: the closest-point parameters at x where the contact pass evaluated the
    pair from a), or, when more than the record holds, every listed partner."""
    a = wp.tid()
    w = world_of[a]
    radius = query_radius[w]
    noted = touch_count[a]
    if edge_in_contact_pass(free, has_next, a) and running[w] != 0 and (noted > 0 or chord != 0):
        reach_a = wp.float64(0.5) * wp.length(x[a + 1] - x[a]) + node_radius[a] + c0
        candidates = neighbours  # a's neighbour list (NO_LIST: the grid)
        listed = neighbour_count[a]
        if noted <= touch_b.shape[1] and chord == 0:  # the partners the contact pass noted touching
            candidates = touch_b
            listed = noted
        over_noted = chord != 0 and noted_chord != 0 and chord_count[a] <= chord_b.shape[1]
        if over_noted:  # the noted chord candidates
            candidates = chord_b
            listed = chord_count[a]
        if listed == NO_LIST:  # the grid (built only here: next_partner reads it only then)
            query = wp.hash_grid_query(grid, mid[a], grid_radius, w)
        k = int(0)
        b = int(0)
        while next_partner(query, k, b, a, candidates, listed, coil_of, exclusion):
            b_runs = edge_in_contact_pass(free, has_next, b)
            if b_runs and not evaluates_pair(a, b, chord, neighbour_count):  # b's own pass evaluates it
                continue
            if chord != 0 and swept_apart(mid, sweep, a, b, c0):  # neither near: no block
                continue
            known_st = NO_PARAMS
            if over_noted:
                known_st = chord_st[a, k - 1]
            hit, st, kc, normal = pair_stiffness(x, rest_x, coil_of, free, has_next, fixed, node_radius, mid, a, b,
                                                 reach_a, p0, c0, u_linear, radius, x_end, end_mid, end_half,
                                                 end_move, node_move, chord, rest_count, rest_b, rest_value, known_st)
            if hit == 0:
                continue
            add_pair(a, b, st, kc, normal, sums, pair_count, pair_b, pair_st, pair_k, pair_n)
            if b_runs:
                add_pair(b, a, wp.vec2d(st[1], st[0]), kc, -normal, sums, pair_count, pair_b, pair_st, pair_k,
                         pair_n)


@wp.func
def damping_rate(speed: wp.float64, c: wp.float64, k: wp.float64) -> wp.float64:
    """Secant coefficient of the damping law at ``speed`` (g/s = µN·s/mm):
    c (1 − exp(−s/k)) / s, so that β v is the law's force; c/k at rest."""
    r = speed / k
    if r < wp.float64(1.0e-6):
        return c / k * (F64_1 - wp.float64(0.5) * r)
    return c * (F64_1 - wp.exp(-r)) / speed


@wp.kernel
def assemble_blocks(
    x: wp.array(dtype=wp.vec3d),
    v: wp.array(dtype=wp.vec3d),
    force: wp.array(dtype=wp.vec3d),
    free: wp.array(dtype=wp.int32),
    free_next: wp.array(dtype=wp.int32),
    has_next: wp.array(dtype=wp.int32),
    clamp_tangent: wp.array(dtype=wp.vec3d),
    inv_mass: wp.array(dtype=wp.float64),
    damping_c: wp.array(dtype=wp.float64),
    damping_k: wp.float64,
    k_stretch: wp.array(dtype=wp.float64),
    rest_length: wp.array(dtype=wp.float64),
    k_bend: wp.array(dtype=wp.float64),
    wall_stiffness: wp.array(dtype=wp.mat33d),
    wall_scale: wp.float64,
    stiff_start: wp.array(dtype=wp.mat33d),
    stiff_end: wp.array(dtype=wp.mat33d),
    coil_contact: int,
    node_radius: wp.array(dtype=wp.float64),
    fold_span: int,
    p0: wp.float64,
    c0: wp.float64,
    u_linear: wp.float64,
    dt: wp.float64,
    diag: wp.array(dtype=wp.mat33d),
    diag_exact: wp.array(dtype=wp.mat33d),
    upper1: wp.array(dtype=wp.mat33d),
    upper2: wp.array(dtype=wp.mat33d),
    rhs: wp.array(dtype=wp.vec3d),
):
    """Row i of M + dt² H: its diagonal block (``diag_exact``; ``diag`` with the
    Gershgorin coil–coil contact added, for the preconditioner) and its blocks
    (i, i+1), (i, i+2) (g, µN·s²/mm), and M v + dt F (g·mm/s). Rows with no node within two that is
    free before or after the step (deep in the catheter: no coupling to an
    unknown) are M alone."""
    i = wp.tid()
    n = x.shape[0]
    h = wp.mat33d()
    u1 = wp.mat33d()
    u2 = wp.mat33d()
    mass = F64_1 / inv_mass[i]
    near_free = bool(False)
    for j in range(wp.max(i - 2, 0), wp.min(i + 3, n)):
        if free[j] != 0 or free_next[j] != 0:
            near_free = True
    if not near_free:
        diag[i] = mass * wp.identity(n=3, dtype=wp.float64)
        diag_exact[i] = diag[i]
        upper1[i] = h
        upper2[i] = h
        rhs[i] = mass * v[i] + dt * force[i]
        return
    if has_next[i] != 0:
        ks = edge_stretch_hessian(x, k_stretch, rest_length, i)
        h = h + ks
        u1 = u1 - ks
    if i >= 1:
        if has_next[i - 1] != 0:
            h = h + edge_stretch_hessian(x, k_stretch, rest_length, i - 1)
    # bending (Gauss–Newton): vertex j has J = (G_{j-1}, −G_{j-1} − G_j, G_j), G_e = ∂t_e/∂x_{e+1}
    g_1 = edge_jacobian_or_zero(x, has_next, i - 1)
    g0 = edge_jacobian_or_zero(x, has_next, i)
    g1 = edge_jacobian_or_zero(x, has_next, i + 1)
    kb_prev = vertex_bends(has_next, clamp_tangent, k_bend, i - 1)  # vertex i−1: node i is its next node
    kb_mid = vertex_bends(has_next, clamp_tangent, k_bend, i)  # vertex i: node i is its middle node
    kb_next = vertex_bends(has_next, clamp_tangent, k_bend, i + 1)  # vertex i+1: node i is its previous node
    mid_i = -(g_1 + g0)
    h = h + kb_prev * (g_1 * g_1) + kb_mid * (mid_i * mid_i) + kb_next * (g0 * g0)
    u1 = u1 + kb_mid * (mid_i * g0) - kb_next * (g0 * (g0 + g1))
    u2 = u2 + kb_next * (g0 * g1)
    if free[i] != 0:
        h = h + wall_scale * wall_stiffness[i]
        h = h + fold_stiffness(x, has_next, node_radius, i, fold_span, p0, c0, u_linear)
    dt2 = dt * dt
    mass = mass + dt * damping_rate(wp.length(v[i]), damping_c[i], damping_k)  # damping linearised at v
    diag_exact[i] = mass * wp.identity(n=3, dtype=wp.float64) + dt2 * h
    if free[i] != 0 and coil_contact != 0:  # the preconditioner's Gershgorin coil–coil contact
        if has_next[i] != 0:
            h = h + stiff_start[i]
        if i >= 1:
            if has_next[i - 1] != 0:
                h = h + stiff_end[i - 1]
    diag[i] = mass * wp.identity(n=3, dtype=wp.float64) + dt2 * h
    upper1[i] = dt2 * u1
    upper2[i] = dt2 * u2
    rhs[i] = (F64_1 / inv_mass[i]) * v[i] + dt * force[i]


@wp.kernel
def hold_nodes(
    x_in: wp.array(dtype=wp.vec3d),
    v_in: wp.array(dtype=wp.vec3d),
    free_in: wp.array(dtype=wp.int32),
    advance_in: wp.array(dtype=wp.float64),
    fixed: wp.array(dtype=wp.int32),
    coil_of: wp.array(dtype=wp.int32),
    world_of: wp.array(dtype=wp.int32),
    coil_world: wp.array(dtype=wp.int32),
    arc_s: wp.array(dtype=wp.float64),
    catheter_path: wp.array(dtype=wp.vec3d),
    catheter_first: wp.array(dtype=wp.int32),
    catheter_count: wp.array(dtype=wp.int32),
    active_coil: wp.array(dtype=wp.int32),
    push_speed: wp.array(dtype=wp.float64),
    running: wp.array(dtype=wp.int32),
    dt: wp.float64,
    x_out: wp.array(dtype=wp.vec3d),
    v_out: wp.array(dtype=wp.vec3d),
    free_out: wp.array(dtype=wp.int32),
    advance_out: wp.array(dtype=wp.float64),
):
    """integrate.hold_node alone: the free nodes are only flagged (free_out = 1),
    the coil solve moves them."""
    hold_node(wp.tid(), x_in, v_in, free_in, advance_in, fixed, coil_of, world_of, coil_world, arc_s, catheter_path,
              catheter_first, catheter_count, active_coil, push_speed, running, dt, x_out, v_out, free_out,
              advance_out)


@wp.func
def unknown(free: wp.array(dtype=wp.int32), fixed: wp.array(dtype=wp.int32), i: int) -> bool:
    return free[i] != 0 and fixed[i] == 0


@wp.func
def solving(free: wp.array(dtype=wp.int32), fixed: wp.array(dtype=wp.int32), world_of: wp.array(dtype=wp.int32),
            running: wp.array(dtype=wp.int32), i: int) -> bool:
    """Node i is an unknown of this step's system: free, not clamped, its world running."""
    return unknown(free, fixed, i) and running[world_of[i]] != 0


@wp.kernel
def factor_coils(
    coil_first: wp.array(dtype=wp.int32),
    coil_last: wp.array(dtype=wp.int32),
    coil_world: wp.array(dtype=wp.int32),
    running: wp.array(dtype=wp.int32),
    free: wp.array(dtype=wp.int32),
    fixed: wp.array(dtype=wp.int32),
    diag: wp.array(dtype=wp.mat33d),
    upper1: wp.array(dtype=wp.mat33d),
    upper2: wp.array(dtype=wp.mat33d),
    inv_d: wp.array(dtype=wp.mat33d),
    lower1: wp.array(dtype=wp.mat33d),
    lower2: wp.array(dtype=wp.mat33d),
):
    """One coil's banded preconditioner P (the blocks with the Gershgorin contact
    diagonal), restricted to its unknowns, as block LDLᵀ: L₁ = block (i, i−1)
    of L, L₂ = (i, i−2), D⁻¹ per node; a held node's row is the identity."""
    c = wp.tid()
    if running[coil_world[c]] == 0:
        return
    first = coil_first[c]
    last = coil_last[c]
    eye = wp.identity(n=3, dtype=wp.float64)
    zero = wp.mat33d()
    for i in range(first, last + 1):
        if not unknown(free, fixed, i):
            inv_d[i] = eye
            lower1[i] = zero
            lower2[i] = zero
            continue
        a1 = zero  # block (i, i−1) among the unknowns
        a2 = zero  # block (i, i−2)
        if i - 1 >= first:
            if unknown(free, fixed, i - 1):
                a1 = wp.transpose(upper1[i - 1])
        if i - 2 >= first:
            if unknown(free, fixed, i - 2):
                a2 = wp.transpose(upper2[i - 2])
        l2 = zero
        l1 = zero
        d = diag[i]
        if i - 2 >= first:
            l2 = a2 * inv_d[i - 2]
            d = d - a2 * wp.transpose(l2)
        if i - 1 >= first:
            c1 = a1
            if i - 2 >= first:
                c1 = a1 - a2 * wp.transpose(lower1[i - 1])
            l1 = c1 * inv_d[i - 1]
            d = d - c1 * wp.transpose(l1)
        inv_d[i] = wp.inverse(d)
        lower1[i] = l1
        lower2[i] = l2


@wp.kernel
def precondition(
    coil_first: wp.array(dtype=wp.int32),
    coil_last: wp.array(dtype=wp.int32),
    coil_world: wp.array(dtype=wp.int32),
    running: wp.array(dtype=wp.int32),
    free: wp.array(dtype=wp.int32),
    fixed: wp.array(dtype=wp.int32),
    inv_d: wp.array(dtype=wp.mat33d),
    lower1: wp.array(dtype=wp.mat33d),
    lower2: wp.array(dtype=wp.mat33d),
    r: wp.array(dtype=wp.vec3d),
    y: wp.array(dtype=wp.vec3d),
    z: wp.array(dtype=wp.vec3d),
):
    """z = P⁻¹ r on one coil (forward and back substitution through its LDLᵀ);
    zero on held nodes."""
    c = wp.tid()
    if running[coil_world[c]] == 0:
        return
    first = coil_first[c]
    last = coil_last[c]
    zv = wp.vec3d(F64_0, F64_0, F64_0)
    for i in range(first, last + 1):
        yi = zv
        if unknown(free, fixed, i):
            yi = r[i]
            if i - 1 >= first:
                yi = yi - lower1[i] * y[i - 1]
            if i - 2 >= first:
                yi = yi - lower2[i] * y[i - 2]
        y[i] = yi
    next1 = zv
    next2 = zv
    for k in range(last - first + 1):
        i = last - k
        zi = zv
        if unknown(free, fixed, i):
            zi = inv_d[i] * y[i]
            if i + 1 <= last:
                zi = zi - wp.transpose(lower1[i + 1]) * next1
            if i + 2 <= last:
                zi = zi - wp.transpose(lower2[i + 2]) * next2
        z[i] = zi
        next2 = next1
        next1 = zi


@wp.func
def pair_product(x: wp.array(dtype=wp.vec3d), a: int, k: int, pair_b: wp.array2d(dtype=wp.int32),
                 pair_st: wp.array2d(dtype=wp.vec2d), pair_k: wp.array2d(dtype=wp.float64),
                 pair_n: wp.array2d(dtype=wp.vec3d)) -> wp.vec3d:
    """k n (n · ∂g/∂x x) of edge a's k-th recorded pair (the gap's rate along its normal, times k)."""
    b = pair_b[a, k]
    st = pair_st[a, k]
    n = pair_n[a, k]
    rate = (F64_1 - st[0]) * x[a] + st[0] * x[a + 1] - (F64_1 - st[1]) * x[b] - st[1] * x[b + 1]
    return (pair_k[a, k] * wp.dot(n, rate)) * n


@wp.kernel
def system_product(
    x: wp.array(dtype=wp.vec3d),
    b: wp.array(dtype=wp.vec3d),
    residual: int,
    free: wp.array(dtype=wp.int32),
    fixed: wp.array(dtype=wp.int32),
    has_next: wp.array(dtype=wp.int32),
    world_of: wp.array(dtype=wp.int32),
    running: wp.array(dtype=wp.int32),
    diag_exact: wp.array(dtype=wp.mat33d),
    upper1: wp.array(dtype=wp.mat33d),
    upper2: wp.array(dtype=wp.mat33d),
    stiff_start: wp.array(dtype=wp.mat33d),
    stiff_end: wp.array(dtype=wp.mat33d),
    pair_count: wp.array(dtype=wp.int32),
    pair_b: wp.array2d(dtype=wp.int32),
    pair_st: wp.array2d(dtype=wp.vec2d),
    pair_k: wp.array2d(dtype=wp.float64),
    pair_n: wp.array2d(dtype=wp.vec3d),
    dt: wp.float64,
    out: wp.array(dtype=wp.vec3d),
):
    """Row i of A x, A = M + dt² (H + K_c) with the coil–coil contact stiffness
    K_c exact (each recorded pair's k wᵀw ⊗ n nᵀ, summed in partner order;
    an overflowed edge's pairs through the Gershgorin diagonal); with
    ``residual``, b − A x instead. Zero on rows that are not unknowns."""
    i = wp.tid()
    zv = wp.vec3d(F64_0, F64_0, F64_0)
    if not solving(free, fixed, world_of, running, i):
        out[i] = zv
        return
    n = x.shape[0]
    y = diag_exact[i] * x[i]
    if i + 1 < n:
        y = y + upper1[i] * x[i + 1]
    if i + 2 < n:
        y = y + upper2[i] * x[i + 2]
    if i >= 1:
        y = y + wp.transpose(upper1[i - 1]) * x[i - 1]
    if i >= 2:
        y = y + wp.transpose(upper2[i - 2]) * x[i - 2]
    contact = zv
    if has_next[i] != 0:  # edge i: node i is its start
        count = pair_count[i]
        if count == OVERFLOW:
            contact = contact + stiff_start[i] * x[i]
        for k in range(wp.max(count, 0)):
            contact = contact + (F64_1 - pair_st[i, k][0]) * pair_product(x, i, k, pair_b, pair_st, pair_k,
                                                                          pair_n)
    if i >= 1:
        if has_next[i - 1] != 0:  # edge i−1: node i is its end
            count = pair_count[i - 1]
            if count == OVERFLOW:
                contact = contact + stiff_end[i - 1] * x[i]
            for k in range(wp.max(count, 0)):
                contact = contact + pair_st[i - 1, k][0] * pair_product(x, i - 1, k, pair_b, pair_st, pair_k,
                                                                        pair_n)
    y = y + dt * dt * contact
    if residual != 0:
        y = b[i] - y
    out[i] = y


@wp.kernel
def settling_worlds(running: wp.array(dtype=wp.int32), active_coil: wp.array(dtype=wp.int32),
                    settling: wp.array(dtype=wp.int32)):
    """Per world: 1 where it runs and no pusher drives a coil (active_coil < 0), else 0
    (the worlds that take the conjugate-gradient iterations beyond the push's)."""
    w = wp.tid()
    settling[w] = wp.where(running[w] != 0 and active_coil[w] < 0, 1, 0)


@wp.kernel
def impulse_start(
    change: wp.array(dtype=wp.vec3d),
    v: wp.array(dtype=wp.vec3d),
    inv_mass: wp.array(dtype=wp.float64),
    damping_c: wp.array(dtype=wp.float64),
    damping_k: wp.float64,
    dt: wp.float64,
    free: wp.array(dtype=wp.int32),
    fixed: wp.array(dtype=wp.int32),
    world_of: wp.array(dtype=wp.int32),
    running: wp.array(dtype=wp.int32),
    node_theta: wp.array(dtype=wp.float64),
    theta: wp.float64,
    gated: int,
    y: wp.array(dtype=wp.vec3d),
    rhs: wp.array(dtype=wp.vec3d),
):
    """Start and right side of A y = (M + dt B) Δv_f: the friction change ``change`` (mm/s)
    as the impulse that moves a node by Δv_f against its inertia and the step's damping
    (B at the old velocities ``v``, as assemble_blocks has it) where no stiff term resists
    (A also holds the wall's and devices' friction blocks, kernels/friction_damping.py: a node
    stuck on them resists it); y = Δv_f on the unknowns (on a gated row θ_i ≠ θ, whose
    unknown is u with v' changing by θ/θ_i of it: θ_i/θ Δv_f, its mass M θ/θ_i), 0 elsewhere
    (held nodes keep theirs)."""
    i = wp.tid()
    zv = wp.vec3d(F64_0, F64_0, F64_0)
    y[i] = zv
    rhs[i] = zv
    if solving(free, fixed, world_of, running, i):
        scale = F64_1
        if gated != 0 and node_theta[i] != theta:
            scale = node_theta[i] / theta
        mass = F64_1 / inv_mass[i]
        y[i] = scale * change[i]
        rhs[i] = (mass + scale * dt * damping_rate(wp.length(v[i]), damping_c[i], damping_k)) * change[i]


@wp.kernel
def keep_dissipative_change(
    world_node_range: wp.array2d(dtype=wp.int32),
    running: wp.array(dtype=wp.int32),
    free: wp.array(dtype=wp.int32),
    fixed: wp.array(dtype=wp.int32),
    inv_mass: wp.array(dtype=wp.float64),
    v_predicted: wp.array(dtype=wp.vec3d),
    y: wp.array(dtype=wp.vec3d),
    node_theta: wp.array(dtype=wp.float64),
    theta: wp.float64,
    gated: int,
    change: wp.array(dtype=wp.vec3d),
):
    """One world: the velocity change y, the solve of A y = (M + dt B) Δv_f (on a gated row
    θ_i ≠ θ the solve's unknown is u, and v' changes by θ/θ_i of it), into ``change``, scaled
    by the largest s ≤ 1 that leaves the world's kinetic energy (translation, fixed-order
    sums) no higher than at ``v_predicted``: s = −2 Σ m v·y / Σ m |y|² where the whole of y
    would raise it, 0 where any part would."""
    w = wp.tid()
    if running[w] == 0:
        return
    first = world_node_range[w, 0]
    last = world_node_range[w, 1]
    cross = F64_0  # Σ m v·y
    square = F64_0  # Σ m |y|²
    for i in range(first, last + 1):
        if unknown(free, fixed, i):
            d = y[i]
            if gated != 0 and node_theta[i] != theta:
                d = (theta / node_theta[i]) * d
                y[i] = d
            mass = F64_1 / inv_mass[i]
            cross = cross + mass * wp.dot(v_predicted[i], d)
            square = square + mass * wp.length_sq(d)
    scale = F64_1
    if wp.float64(2.0) * cross + square > F64_0:  # the whole change raises the kinetic energy
        scale = wp.max(-wp.float64(2.0) * cross / square, F64_0)
    for i in range(first, last + 1):
        if unknown(free, fixed, i):
            change[i] = scale * y[i]


@wp.kernel
def pcg_begin(
    world_node_range: wp.array2d(dtype=wp.int32),
    running: wp.array(dtype=wp.int32),
    r: wp.array(dtype=wp.vec3d),
    z: wp.array(dtype=wp.vec3d),
    p: wp.array(dtype=wp.vec3d),
    rz: wp.array(dtype=wp.float64),
):
    """One world: p = z, rz = r·z (a fixed-order sum over its nodes)."""
    w = wp.tid()
    if running[w] == 0:
        return
    total = F64_0
    for i in range(world_node_range[w, 0], world_node_range[w, 1] + 1):
        total = total + wp.dot(r[i], z[i])
        p[i] = z[i]
    rz[w] = total


@wp.kernel
def pcg_advance(
    world_node_range: wp.array2d(dtype=wp.int32),
    running: wp.array(dtype=wp.int32),
    p: wp.array(dtype=wp.vec3d),
    q: wp.array(dtype=wp.vec3d),
    rz: wp.array(dtype=wp.float64),
    x: wp.array(dtype=wp.vec3d),
    r: wp.array(dtype=wp.vec3d),
):
    """One world: α = r·z / p·q (q = A p), x += α p, r −= α q."""
    w = wp.tid()
    if running[w] == 0:
        return
    first = world_node_range[w, 0]
    last = world_node_range[w, 1]
    pq = F64_0
    for i in range(first, last + 1):
        pq = pq + wp.dot(p[i], q[i])
    alpha = F64_0
    if pq > F64_0:
        alpha = rz[w] / pq
    for i in range(first, last + 1):
        x[i] = x[i] + alpha * p[i]
        r[i] = r[i] - alpha * q[i]


@wp.kernel
def pcg_direction(
    world_node_range: wp.array2d(dtype=wp.int32),
    running: wp.array(dtype=wp.int32),
    r: wp.array(dtype=wp.vec3d),
    z: wp.array(dtype=wp.vec3d),
    rz: wp.array(dtype=wp.float64),
    p: wp.array(dtype=wp.vec3d),
):
    """One world: β = r·z (new) / r·z (old), p = z + β p."""
    w = wp.tid()
    if running[w] == 0:
        return
    first = world_node_range[w, 0]
    last = world_node_range[w, 1]
    total = F64_0
    for i in range(first, last + 1):
        total = total + wp.dot(r[i], z[i])
    beta = F64_0
    if rz[w] > F64_0:
        beta = total / rz[w]
    for i in range(first, last + 1):
        p[i] = z[i] + beta * p[i]
    rz[w] = total


@wp.kernel
def start_velocity(
    v_in: wp.array(dtype=wp.vec3d),
    v_held: wp.array(dtype=wp.vec3d),
    free: wp.array(dtype=wp.int32),
    fixed: wp.array(dtype=wp.int32),
    world_of: wp.array(dtype=wp.int32),
    running: wp.array(dtype=wp.int32),
    v: wp.array(dtype=wp.vec3d),
):
    """The solve's start: unknowns at their old velocity, held nodes at theirs."""
    i = wp.tid()
    if solving(free, fixed, world_of, running, i):
        v[i] = v_in[i]
    else:
        v[i] = v_held[i]


@wp.kernel
def finish_nodes(
    x_in: wp.array(dtype=wp.vec3d),
    v_in: wp.array(dtype=wp.vec3d),
    v_solved: wp.array(dtype=wp.vec3d),
    free: wp.array(dtype=wp.int32),
    fixed: wp.array(dtype=wp.int32),
    world_of: wp.array(dtype=wp.int32),
    running: wp.array(dtype=wp.int32),
    dt: wp.float64,
    theta: wp.float64,
    x_out: wp.array(dtype=wp.vec3d),
    v_out: wp.array(dtype=wp.vec3d),
):
    """Unknown node i: the solved (already damped) velocity, and
    x' = x + dt ((1 − θ) v + θ v') (θ = 1: x + dt v'). Held nodes keep what
    hold_nodes gave them."""
    i = wp.tid()
    if not solving(free, fixed, world_of, running, i):
        return
    v_out[i] = v_solved[i]
    x_out[i] = x_in[i] + dt * ((F64_1 - theta) * v_in[i] + theta * v_solved[i])


@wp.kernel
def theta_start(
    rhs: wp.array(dtype=wp.vec3d),
    a_v: wp.array(dtype=wp.vec3d),
    theta: wp.float64,
    free: wp.array(dtype=wp.int32),
    fixed: wp.array(dtype=wp.int32),
    world_of: wp.array(dtype=wp.int32),
    running: wp.array(dtype=wp.int32),
    residual: wp.array(dtype=wp.vec3d),
):
    """The θ-method's right side from the one assembled at θ dt, M v + θ dt F, and A v
    (A = M + θ dt B + θ² dt² H at the solve's start v: the old velocities, held nodes at
    their new ones): (M v + θ dt F − (1 − θ) A v) / θ = M v + dt F − (1 − θ) dt B v
    − θ (1 − θ) dt² H v (g·mm/s), and the start's residual, that right side − A v (zero on
    rows that are not unknowns): the one product serves both."""
    i = wp.tid()
    if not solving(free, fixed, world_of, running, i):
        residual[i] = wp.vec3d(F64_0, F64_0, F64_0)
        return
    b = (rhs[i] - (F64_1 - theta) * a_v[i]) / theta
    rhs[i] = b
    residual[i] = b - a_v[i]


@wp.kernel
def keep_history(x_in: wp.array(dtype=wp.vec3d), v_in: wp.array(dtype=wp.vec3d), x_prev: wp.array(dtype=wp.vec3d),
                 v_prev: wp.array(dtype=wp.vec3d)):
    """The BDF2 step's history: the step's start becomes the next step's previous state."""
    i = wp.tid()
    x_prev[i] = x_in[i]
    v_prev[i] = v_in[i]


@wp.kernel
def bdf2_history_rate(x: wp.array(dtype=wp.vec3d), x_prev: wp.array(dtype=wp.vec3d), h: wp.float64,
                      y: wp.array(dtype=wp.vec3d)):
    """y = (x − x₋₁) / (3 h) (mm/s), h = 2/3 dt: the BDF2 positions' history part
    x' − x = h (y + v') as a velocity, every node (held ones couple through H)."""
    i = wp.tid()
    y[i] = (x[i] - x_prev[i]) / (wp.float64(3.0) * h)


@wp.kernel
def bdf2_rhs(
    v: wp.array(dtype=wp.vec3d),
    v_prev: wp.array(dtype=wp.vec3d),
    y: wp.array(dtype=wp.vec3d),
    a_y: wp.array(dtype=wp.vec3d),
    inv_mass: wp.array(dtype=wp.float64),
    damping_c: wp.array(dtype=wp.float64),
    damping_k: wp.float64,
    h: wp.float64,
    friction: int,
    wall_block: wp.array(dtype=wp.mat33d),
    device_block: wp.array(dtype=wp.mat33d),
    rhs: wp.array(dtype=wp.vec3d),
):
    """BDF2's right side from the one assembled at h = 2/3 dt (M v + h F) and
    A y (A = M + h B + h² H, y from :func:`bdf2_history_rate`):
    M (4/3 v − 1/3 v₋₁) + h F − h² H y, with h² H y = A y − (M + h B) y
    (g·mm/s; only unknown rows are read). With ``friction``, B holds the node's
    wall and device friction blocks too (kernels/friction_damping.py)."""
    i = wp.tid()
    mass = F64_1 / inv_mass[i]
    mass_b = mass + h * damping_rate(wp.length(v[i]), damping_c[i], damping_k)  # as assemble_blocks has it
    third = F64_1 / wp.float64(3.0)
    damped = mass_b * y[i]
    if friction != 0:
        damped = damped + h * ((wall_block[i] + device_block[i]) * y[i])
    rhs[i] = rhs[i] + mass * third * (v[i] - v_prev[i]) - (a_y[i] - damped)


@wp.kernel
def finish_nodes_bdf2(
    x_in: wp.array(dtype=wp.vec3d),
    x_prev: wp.array(dtype=wp.vec3d),
    v_solved: wp.array(dtype=wp.vec3d),
    free: wp.array(dtype=wp.int32),
    fixed: wp.array(dtype=wp.int32),
    world_of: wp.array(dtype=wp.int32),
    running: wp.array(dtype=wp.int32),
    h: wp.float64,
    x_out: wp.array(dtype=wp.vec3d),
    v_out: wp.array(dtype=wp.vec3d),
):
    """Unknown node i: x' = 4/3 x − 1/3 x₋₁ + h v' (h = 2/3 dt), the solved velocity.
    Held nodes keep what hold_nodes gave them."""
    i = wp.tid()
    if not solving(free, fixed, world_of, running, i):
        return
    v_out[i] = v_solved[i]
    x_out[i] = x_in[i] + (x_in[i] - x_prev[i]) / wp.float64(3.0) + h * v_solved[i]


@wp.func
def spin_free(free: wp.array(dtype=wp.int32), fixed: wp.array(dtype=wp.int32), has_next: wp.array(dtype=wp.int32),
              e: int) -> bool:
    """Edge e spins (as integrate.update_frames has it): it exists, each node is
    free or clamped, and not both are clamped."""
    if e < 0 or not edge_valid(has_next, e):
        return False
    held0 = fixed[e] != 0
    held1 = fixed[e + 1] != 0
    return (free[e] != 0 or held0) and (free[e + 1] != 0 or held1) and not (held0 and held1)


@wp.kernel
def transport_frames(
    x_in: wp.array(dtype=wp.vec3d),
    x_out: wp.array(dtype=wp.vec3d),
    m1_in: wp.array(dtype=wp.vec3d),
    has_next: wp.array(dtype=wp.int32),
    world_of: wp.array(dtype=wp.int32),
    running: wp.array(dtype=wp.int32),
    m1_out: wp.array(dtype=wp.vec3d),
):
    """Each edge's director carried to its new tangent by parallel transport (as
    integrate.update_frames does before it turns it); a stopped world's and a
    missing edge's directors unchanged."""
    e = wp.tid()
    if running[world_of[e]] == 0 or not edge_valid(has_next, e):
        m1_out[e] = m1_in[e]
        return
    t_old = wp.normalize(x_in[e + 1] - x_in[e])
    t_new = wp.normalize(x_out[e + 1] - x_out[e])
    m1_out[e] = director_normal(transport(m1_in[e], t_old, t_new), t_new)


@wp.kernel
def solve_spin(
    coil_first: wp.array(dtype=wp.int32),
    coil_last: wp.array(dtype=wp.int32),
    coil_world: wp.array(dtype=wp.int32),
    running: wp.array(dtype=wp.int32),
    free: wp.array(dtype=wp.int32),
    fixed: wp.array(dtype=wp.int32),
    has_next: wp.array(dtype=wp.int32),
    clamp_tangent: wp.array(dtype=wp.vec3d),
    omega: wp.array(dtype=wp.float64),
    grad_theta: wp.array(dtype=wp.vec2d),
    inv_inertia: wp.array(dtype=wp.float64),
    twist_damping: wp.array(dtype=wp.float64),
    k_twist: wp.array(dtype=wp.float64),
    k_bend: wp.array(dtype=wp.float64),
    rest_K0: wp.array(dtype=wp.vec2d),
    rest_K1: wp.array(dtype=wp.vec2d),
    x_out: wp.array(dtype=wp.vec3d),
    dt: wp.float64,
    scratch_c: wp.array(dtype=wp.float64),
    scratch_d: wp.array(dtype=wp.float64),
    m1_out: wp.array(dtype=wp.vec3d),
    omega_out: wp.array(dtype=wp.float64),
):
    """One coil's edge spins (rad/s): (J + dt b + dt² H_θ) ω' = J ω + dt T, H_θ
    tridiagonal (twist k_t between neighbouring edges; bending ½ k_b |K̄|² on
    each edge of a vertex), by the Thomas algorithm; edges that do not spin
    keep ω' = 0. The torque T is taken at the *new* positions with the directors
    already transported to them (``m1_out``, :func:`transport_frames`; its
    gradient ``grad_theta`` from elastic.vertex_theta_gradients): positions, then
    twist (Gauss–Seidel), so the quasi-static twist follows the positions it
    belongs to instead of lagging a step behind them (solved side by side, the two
    traded a period-2 oscillation at the free end of a pre-curved coil at large
    steps). Each spinning edge's director is then turned by ω' dt.
    A stopped world keeps its directors and spins."""
    c = wp.tid()
    first = coil_first[c]
    last = coil_last[c]
    if running[coil_world[c]] == 0:
        for e in range(first, last + 1):
            omega_out[e] = omega[e]
        return
    dt2 = dt * dt
    half = wp.float64(0.5)
    prev_c = F64_0
    prev_d = F64_0
    for e in range(first, last):
        if not spin_free(free, fixed, has_next, e):
            scratch_c[e] = F64_0
            scratch_d[e] = F64_0
            prev_c = F64_0
            prev_d = F64_0
            continue
        inertia = F64_1 / inv_inertia[e]
        h = F64_0
        lower = F64_0
        upper = F64_0
        if bends(has_next, clamp_tangent, e):  # vertex e: edges e−1 (or a clamp's virtual one), e
            h = h + half * k_bend[e] * wp.length_sq(rest_K1[e]) + k_twist[e]
            if spin_free(free, fixed, has_next, e - 1):
                lower = -dt2 * k_twist[e]
        if e + 1 < has_next.shape[0]:
            if vertex_valid(has_next, e + 1):  # vertex e+1: edges e, e+1
                h = h + half * k_bend[e + 1] * wp.length_sq(rest_K0[e + 1]) + k_twist[e + 1]
                if spin_free(free, fixed, has_next, e + 1):
                    upper = -dt2 * k_twist[e + 1]
        a = inertia + dt * twist_damping[e] + dt2 * h
        r = inertia * omega[e] + dt * edge_torque(has_next, clamp_tangent, grad_theta, e)
        denom = a - lower * prev_c
        prev_c = upper / denom
        prev_d = (r - lower * prev_d) / denom
        scratch_c[e] = prev_c
        scratch_d[e] = prev_d
    following = F64_0
    for k in range(last - first + 1):
        e = last - k
        if not edge_valid(has_next, e):
            omega_out[e] = F64_0
            following = F64_0
            continue
        w = F64_0
        if spin_free(free, fixed, has_next, e):
            w = scratch_d[e] - scratch_c[e] * following
            t_new = wp.normalize(x_out[e + 1] - x_out[e])
            m1_out[e] = director_normal(rotate_about(m1_out[e], t_new, w * dt), t_new)
        omega_out[e] = w
        following = w


@wp.kernel
def predict_positions(
    x: wp.array(dtype=wp.vec3d),
    v: wp.array(dtype=wp.vec3d),
    x_held: wp.array(dtype=wp.vec3d),
    free_next: wp.array(dtype=wp.int32),
    inv_mass: wp.array(dtype=wp.float64),
    damping_c: wp.array(dtype=wp.float64),
    damping_k: wp.float64,
    dt: wp.float64,
    x_end: wp.array(dtype=wp.vec3d),
):
    """The predicted end x̃ (mm) of the chord contact stiffness: for a node free after
    the step its damped free flight x + dt m v / (m + dt β) (β the damping law's secant
    coefficient at v, as assemble_blocks takes it); elsewhere where hold_nodes put it
    (the catheter's, a clamped node's, a stopped world's)."""
    i = wp.tid()
    if free_next[i] != 0:
        mass = F64_1 / inv_mass[i]
        x_end[i] = x[i] + dt * (mass / (mass + dt * damping_rate(wp.length(v[i]), damping_c[i], damping_k))) * v[i]
    else:
        x_end[i] = x_held[i]


@wp.kernel
def end_of_solve(
    x: wp.array(dtype=wp.vec3d),
    v_solved: wp.array(dtype=wp.vec3d),
    x_held: wp.array(dtype=wp.vec3d),
    free_next: wp.array(dtype=wp.int32),
    dt: wp.float64,
    x_end: wp.array(dtype=wp.vec3d),
):
    """The chord's predicted end from a first (tangent) solve: x + dt v* for a node free
    after the step, where hold_nodes put it otherwise (mm)."""
    i = wp.tid()
    if free_next[i] != 0:
        x_end[i] = x[i] + dt * v_solved[i]
    else:
        x_end[i] = x_held[i]
