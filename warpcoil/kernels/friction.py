"""Regularised Coulomb friction, applied implicitly at the velocity level.

(The reference step's law for every contact, and the implicit step's for coil pairs: the
implicit step solves wall and device friction inside its system, kernels/friction_damping.py.)

After the conservative forces and the damping have predicted the velocities v*,
every contact p (a node on the wall or on a device; two coil edges; a coil edge on
an edge still in the catheter, which stands in for the catheter) gets a friction
impulse along its tangential relative velocity w* at the contact points. With W
the contact's inverse effective mass (Σ of the squared barycentric weights over
the node masses; 0 for the wall, a device and the catheter) and N its normal
load (its actual normal force: the wall's or device's contact force; for a coil
edge pair the component, along the segment axes' closest-point normal, of the net
force of the pair's node–capsule terms, contact.pair_contact, so rest-touching
turns carry none), the regularised implicit law of one contact is

    w' = w* / (1 + dt c W),   c = μ N / max(|w*| − dt μ N W, v_reg)

exactly Coulomb's law for that contact: sliding (|w*| > a + v_reg, a = dt μ N W)
loses exactly a per step (|F_t| = μN), and below that the contact is a linear
damper μN/v_reg, so a tangential load F_t < μN creeps at v_reg F_t/(μN) < v_reg
(``v_reg`` = ``friction_speed_mm_s``). In velocities this is v' = (I − φ P_p) v*,
φ = dt c W/(1 + dt c W) ∈ [0, 1), P_p the orthogonal projection (in the mass
metric) onto the contact's tangential relative motion: it never reverses a slip
and conserves the pair's momentum.

All contacts act at once (gather form) as v' = (I − Σ_p ψ_p P_p) v*, ψ_p the slip fraction
as applied: ψ_p = min(φ_p, t_i over p's moving nodes i), t_i the node's cap, the largest t with
Σ_{p∋i} min(φ_p, t) ≤ 1 (none where the node's φ sum to at most 1; node_fraction_caps, from a
first pass that records each edge's pairs' φ, and the wall's and a device's). Since P_p only
touches p's nodes, Σ_p ψ_p P_p ≤ max_i Σ_{p∋i} ψ_p · I ≤ I, so the kinetic energy never rises
and no slip is reversed — whatever the contact network — and, being implicit, friction sets no
step limit. The cap takes from the contacts that would stop the node (large φ: stuck) and
leaves a sliding one (φ = dt μ N W / |w|, small against its slip) its whole law: a coil sliding
over others loses μN on each, also over a coil stuck on a third; the stuck contacts of a node
share what stops it. (An edge with more than FRICTION_PAIRS pairs: the scale min(1, 1/Σφ) on
its nodes' contacts instead. Until the nineteenth session α = min(1, 2/K), K the contacts
counted at the pair's nodes, scaled sliding too: a node sliding over a node of a crossing coil,
K = 4, lost μN/2, parallel coils μN/3; docs/FORMULATION.md. A bound of 2 instead of 1 lets two
stuck contacts reverse a node's slip each step: 40 %-packed frictional stress cases then never
came to rest.)

Normal guard: a contact's impulse is tangential to its own normal, but its
neighbours' impulses on shared nodes (other coil pairs, the wall) are not, and
summed they can slow or reverse a pair's separation (so crossing coils sank
through each other, held by friction). After the friction changes, GUARD_PASSES
Jacobi passes give each touching coil pair (segment gap < c0) whose closest points
now separate more slowly along its axes' normal an equal and opposite normal
impulse restoring 1/K of that shortfall, and take out any component of a node's
change into the wall or a device touching it: friction never drives a contact
into its obstacle (up to (1 − 1/K)^passes of a coil pair's shortfall). The passes stop
early at a fixed point (a pass that changed no friction change in any bit: every later
pass would change none either), so the result is the GUARD_PASSES passes' bit for bit:
on the seed case with wall friction, ~1.6 passes a step instead of 16. The
energy bound above does not cover these impulses (measured: no step raised the
kinetic energy; docs/FORMULATION.md).

Sums over partners are fixed-point (int64), as for the contact forces, so the
result does not depend on the order partners are found (CPU = CUDA, an ensemble
member = its single run).
"""

import warp as wp

from .contact import (NO_LIST, add_edge_shares, edge_in_contact_pass, edge_is_obstacle, from_fixed, next_partner,
                      pair_contact, rest_apart, rest_clearance_gap, segment_closest_params, to_fixed, vec3l)
from .rod import F64_0, F64_1


@wp.func
def tangential(v: wp.vec3d, n: wp.vec3d) -> wp.vec3d:
    return v - wp.dot(v, n) * n


@wp.func
def contact_normal(pa0: wp.vec3d, pa1: wp.vec3d, pb0: wp.vec3d, pb1: wp.vec3d, s: wp.float64, t: wp.float64,
                   fallback: wp.vec3d) -> wp.vec3d:
    """Unit normal from edge b to edge a: the direction between the segment axes'
    closest points (parameters s, t), or ``fallback`` where the axes meet (< 1e-9 mm)."""
    delta = pa0 + s * (pa1 - pa0) - pb0 - t * (pb1 - pb0)
    dist = wp.length(delta)
    if dist > wp.float64(1.0e-9):
        return delta / dist
    return fallback


@wp.func
def slip_fraction(mu: wp.float64, load: wp.float64, slip: wp.float64, inv_mass: wp.float64, v_reg: wp.float64,
                  dt: wp.float64) -> wp.float64:
    """φ = dt c W / (1 + dt c W) with c = μN / max(|w| − dt μ N W, v_reg): the share of
    the slip velocity one implicit step of regularised Coulomb friction removes."""
    a = dt * mu * load * inv_mass
    k = a / wp.max(slip - a, v_reg)  # dt c W
    return k / (F64_1 + k)


@wp.func
def node_contacts(contacts: wp.array(dtype=wp.int32), has_next: wp.array(dtype=wp.int32),
                  obstacle_force: wp.array(dtype=wp.vec3d), device_force: wp.array(dtype=wp.vec3d), i: int) -> int:
    """Contacts of node i: coil pairs of edges i and i − 1, the wall, a device."""
    k = int(0)
    if has_next[i] != 0:
        k += contacts[i]
    if i >= 1:
        if has_next[i - 1] != 0:
            k += contacts[i - 1]
    if wp.length_sq(obstacle_force[i]) > F64_0:
        k += 1
    if wp.length_sq(device_force[i]) > F64_0:
        k += 1
    return k


@wp.func
def pair_contacts(free: wp.array(dtype=wp.int32), has_next: wp.array(dtype=wp.int32),
                  contacts: wp.array(dtype=wp.int32), wall_force: wp.array(dtype=wp.vec3d),
                  device_force: wp.array(dtype=wp.vec3d), a: int, b: int) -> int:
    """The most contacts K of pair (a, b)'s moving nodes (b's when b is free)."""
    k = wp.max(node_contacts(contacts, has_next, wall_force, device_force, a),
               node_contacts(contacts, has_next, wall_force, device_force, a + 1))
    if free[b] != 0 or free[b + 1] != 0:
        k = wp.max(k, wp.max(node_contacts(contacts, has_next, wall_force, device_force, b),
                             node_contacts(contacts, has_next, wall_force, device_force, b + 1)))
    return k


@wp.func
def pair_weights(free: wp.array(dtype=wp.int32), inv_mass: wp.array(dtype=wp.float64), a: int, b: int,
                 s: wp.float64, t: wp.float64):
    """Edge pair (a, b) at closest-point parameters (s, t): a's and b's inverse effective
    masses there (1/g; b's 0 while both its nodes are in the catheter, which does not move)."""
    w_b = F64_0
    if free[b] != 0 or free[b + 1] != 0:
        w_b = (F64_1 - t) * (F64_1 - t) * inv_mass[b] + t * t * inv_mass[b + 1]
    w_a = (F64_1 - s) * (F64_1 - s) * inv_mass[a] + s * s * inv_mass[a + 1]
    return w_a, w_b


FRICTION_PAIRS = 16  # coil pairs with friction an edge records its slip fractions of (more: the node's fallback)
NO_CAP = wp.constant(wp.float64(1.0e30))  # a node whose contacts' slip fractions sum to at most 1: exact law
FRACTION_UNITS = wp.constant(wp.float64(67108864.0))  # fixed-point units of a slip fraction (2^26)
CAP_BISECTIONS = 60


@wp.func
def share(fraction_sum: wp.float64) -> wp.float64:
    """α = min(1, 1 / Σφ), Σφ the sum of the slip fractions of a node's contacts."""
    if fraction_sum <= F64_1:
        return F64_1
    return F64_1 / fraction_sum


@wp.func
def fraction_up(phi: wp.float64) -> wp.int64:
    """A slip fraction in fixed-point units, rounded up (sums of them bound the true sum from above)."""
    return wp.int64(wp.ceil(phi * FRACTION_UNITS))


@wp.func
def capped(phi: wp.float64, scale: wp.array(dtype=wp.float64), cap: wp.array(dtype=wp.float64), i: int,
           j: int) -> wp.float64:
    """φ of a contact of nodes i and j (i = j for an obstacle) as applied: min(φ·scale, cap) over both."""
    return wp.min(phi * wp.min(scale[i], scale[j]), wp.min(cap[i], cap[j]))


@wp.func
def pair_applied(phi: wp.float64, scale: wp.array(dtype=wp.float64), cap: wp.array(dtype=wp.float64),
                 free: wp.array(dtype=wp.int32), a: int, b: int) -> wp.float64:
    """Pair (a, b)'s applied slip fraction: its φ capped by each moving node's cap and scale (b's
    nodes when b is free; :func:`node_fraction_caps`)."""
    applied = capped(phi, scale, cap, a, a + 1)
    if free[b] != 0 or free[b + 1] != 0:
        applied = wp.min(applied, capped(phi, scale, cap, b, b + 1))
    return applied


@wp.func
def pair_slip(x: wp.array(dtype=wp.vec3d), rest_x: wp.array(dtype=wp.vec3d), v: wp.array(dtype=wp.vec3d),
              coil_of: wp.array(dtype=wp.int32), free: wp.array(dtype=wp.int32),
              has_next: wp.array(dtype=wp.int32), fixed: wp.array(dtype=wp.int32),
              node_radius: wp.array(dtype=wp.float64), contact_share: wp.array(dtype=wp.float64),
              contact_samples: wp.array(dtype=wp.int32), inv_mass: wp.array(dtype=wp.float64),
              mid: wp.array(dtype=wp.vec3d), a: int, b: int, exclusion: int, far: wp.float64, p0: wp.float64,
              c0: wp.float64, u_linear: wp.float64, mu_coil: wp.float64, mu_catheter: wp.float64,
              v_reg: wp.float64, dt: wp.float64):
    """The regularised Coulomb law of edge b on edge a: (φ, the slip at a's contact point (mm/s),
    s, the pair's inverse effective mass 1/g); φ = 0 where none. The normal n is the segment
    axes' closest-point direction (the force's where the axes meet); the load N is the normal
    component of the net force that the node–capsule terms of contact.pair_contact joining a
    and b put on a's nodes (½-weighted, with the joint corrections and a same-coil pair's rest
    offset, so turns that touch in the rest shape carry no load and get no friction); equal and
    opposite from b's side. The slip is that of the segments' closest points, less its part along
    n. (The force's own direction, up to ~40° off n in a deep overlap, let friction brake the
    pair's separation.)"""
    zero = wp.vec3d(F64_0, F64_0, F64_0)
    phi = F64_0
    slip = zero
    s = F64_0
    inv_m = F64_1
    if edge_is_obstacle(free, has_next, fixed, b):
        pa0 = x[a]
        pa1 = x[a + 1]
        pb0 = x[b]
        pb1 = x[b + 1]
        reach_a = wp.float64(0.5) * wp.length(pa1 - pa0) + node_radius[a] + c0
        f_start, f_end, gap, touching, bad = pair_contact(x, rest_x, coil_of, free, has_next, fixed, node_radius,
                                                          contact_share, contact_samples, mid, a, b, exclusion, reach_a,
                                                          p0, c0, u_linear, far)
        force = from_fixed(f_start) + from_fixed(f_end)  # the pair's normal force on edge a, µN
        load = wp.length(force)
        if touching != 0 and bad == 0 and load > F64_0:
            st = segment_closest_params(pa0, pa1, pb0, pb1)
            s = st[0]
            t = st[1]
            mu = mu_catheter
            vb = zero  # the catheter does not move
            w_a, w_b = pair_weights(free, inv_mass, a, b, s, t)
            if free[b] != 0 or free[b + 1] != 0:
                mu = mu_coil
                vb = (F64_1 - t) * v[b] + t * v[b + 1]
            n = contact_normal(pa0, pa1, pb0, pb1, s, t, force / load)
            load = wp.dot(force, n)  # its normal component: Coulomb's cone about the true normal
            if mu > F64_0 and load > F64_0:
                slip = tangential((F64_1 - s) * v[a] + s * v[a + 1] - vb, n)
                inv_m = w_a + w_b
                phi = slip_fraction(mu, load, wp.length(slip), inv_m, v_reg, dt)
    return phi, slip, s, inv_m


@wp.kernel(enable_backward=False)
def edge_friction(
    x: wp.array(dtype=wp.vec3d),
    rest_x: wp.array(dtype=wp.vec3d),
    v: wp.array(dtype=wp.vec3d),
    free: wp.array(dtype=wp.int32),
    has_next: wp.array(dtype=wp.int32),
    coil_of: wp.array(dtype=wp.int32),
    world_of: wp.array(dtype=wp.int32),
    running: wp.array(dtype=wp.int32),
    fixed: wp.array(dtype=wp.int32),
    node_radius: wp.array(dtype=wp.float64),
    contact_share: wp.array(dtype=wp.float64),
    contact_samples: wp.array(dtype=wp.int32),
    inv_mass: wp.array(dtype=wp.float64),
    contacts: wp.array(dtype=wp.int32),
    fraction_scale: wp.array(dtype=wp.float64),
    fraction_cap: wp.array(dtype=wp.float64),
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
    mu_coil: wp.float64,
    mu_catheter: wp.float64,
    v_reg: wp.float64,
    dt: wp.float64,
    apply: int,
    pair_phi: wp.array2d(dtype=wp.float64),
    pair_phi_count: wp.array(dtype=wp.int32),
    phi_sum: wp.array(dtype=wp.float64),
    dv_start: wp.array(dtype=wp.vec3d),
    dv_end: wp.array(dtype=wp.vec3d),
):
    """Edge a's coil contacts, found as contact.edge_contact finds them (positions ``x`` at the
    start of the step, ``contacts`` its per-edge counts, velocities ``v`` predicted); fixed-point
    sums. ``apply`` 0: their slip fractions φ, recorded (``pair_phi``, ``pair_phi_count``: up to
    FRICTION_PAIRS, −1 past that) and summed, rounded up, into ``phi_sum`` (for
    :func:`node_fraction_caps`); 1: the friction velocity changes of a's nodes (mm/s) into ``dv_start``
    and ``dv_end``, each pair's φ as applied (:func:`pair_applied`)."""
    a = wp.tid()
    sum_start = vec3l()
    sum_end = vec3l()
    recorded = int(0)
    w = world_of[a]
    radius = query_radius[w]
    if edge_in_contact_pass(free, has_next, a) and running[w] != 0 and contacts[a] > 0:
        listed = neighbour_count[a]
        if listed == NO_LIST:  # the grid (built only here: next_partner reads it only then)
            query = wp.hash_grid_query(grid, mid[a], grid_radius, w)
        k = int(0)
        b = int(0)
        while next_partner(query, k, b, a, neighbours, listed, coil_of, exclusion):
            phi, slip, s, inv_m = pair_slip(x, rest_x, v, coil_of, free, has_next, fixed, node_radius, contact_share,
                                            contact_samples, inv_mass, mid, a, b, exclusion, radius, p0, c0, u_linear,
                                            mu_coil, mu_catheter, v_reg, dt)
            if phi > F64_0:
                if apply == 0:
                    sum_start[0] = sum_start[0] + fraction_up(phi)
                    if recorded >= 0 and recorded < pair_phi.shape[1]:
                        pair_phi[a, recorded] = phi
                        recorded += 1
                    else:
                        recorded = -1
                else:
                    impulse = (-pair_applied(phi, fraction_scale, fraction_cap, free, a, b) / inv_m) * slip
                    sum_start = sum_start + to_fixed(((F64_1 - s) * inv_mass[a]) * impulse)  # on a's contact point
                    sum_end = sum_end + to_fixed((s * inv_mass[a + 1]) * impulse)
    if apply == 0:
        pair_phi_count[a] = recorded
        phi_sum[a] = wp.float64(sum_start[0]) / FRACTION_UNITS
    else:
        dv_start[a] = from_fixed(sum_start)
        dv_end[a] = from_fixed(sum_end)


@wp.func
def obstacle_fraction(f: wp.vec3d, v: wp.vec3d, mu: wp.float64, v_reg: wp.float64, inv_m: wp.float64,
                      dt: wp.float64) -> wp.float64:
    """φ of a fixed obstacle pushing with force f (its load and normal) on a node at velocity v."""
    load = wp.length(f)
    if load > F64_0 and mu > F64_0:
        return slip_fraction(mu, load, wp.length(tangential(v, f / load)), inv_m, v_reg, dt)
    return F64_0


@wp.func
def capped_sum(t: wp.float64, wall_phi: wp.float64, device_phi: wp.float64, pair_phi: wp.array2d(dtype=wp.float64),
               edges: wp.vec2i, counts: wp.vec2i) -> wp.int64:
    """Σ min(φ, t) over a node's contacts, in fixed-point units rounded up (order-independent)."""
    total = fraction_up(wp.min(wall_phi, t)) + fraction_up(wp.min(device_phi, t))
    for side in range(2):
        for k in range(counts[side]):
            total += fraction_up(wp.min(pair_phi[edges[side], k], t))
    return total


@wp.kernel
def node_fraction_caps(
    free_out: wp.array(dtype=wp.int32),
    has_next: wp.array(dtype=wp.int32),
    inv_mass: wp.array(dtype=wp.float64),
    wall_force: wp.array(dtype=wp.vec3d),
    device_force: wp.array(dtype=wp.vec3d),
    mu_wall: wp.float64,
    v_reg: wp.float64,
    phi_sum: wp.array(dtype=wp.float64),
    pair_phi: wp.array2d(dtype=wp.float64),
    pair_phi_count: wp.array(dtype=wp.int32),
    with_coil_terms: int,
    dt: wp.float64,
    v_out: wp.array(dtype=wp.vec3d),
    fraction_scale: wp.array(dtype=wp.float64),
    fraction_cap: wp.array(dtype=wp.float64),
):
    """Node i's cap t on its contacts' slip fractions (the wall's and a device's at its predicted
    velocity, every coil pair of edges i − 1 and i from edge_friction with ``apply`` 0): the largest
    t with Σ min(φ, t) ≤ 1 (NO_CAP when Σφ ≤ 1), found by bisection on fixed-point sums: sliding
    contacts (small φ) keep their whole law, the stuck ones share what stops the node. Where an
    edge's record overflowed, the scale min(1, 1/Σφ) on all of them instead (no cap)."""
    i = wp.tid()
    wall_phi = F64_0
    device_phi = F64_0
    if free_out[i] != 0:
        v = v_out[i]
        wall_phi = obstacle_fraction(wall_force[i], v, mu_wall, v_reg, inv_mass[i], dt)
        device_phi = obstacle_fraction(device_force[i], v, mu_wall, v_reg, inv_mass[i], dt)
    edges = wp.vec2i(i, i - 1)
    counts = wp.vec2i(0, 0)
    total = wall_phi + device_phi
    overflow = False
    if with_coil_terms != 0:
        for side in range(2):
            e = edges[side]
            if e >= 0:
                if has_next[e] != 0:
                    total += phi_sum[e]
                    if pair_phi_count[e] < 0:
                        overflow = True
                    else:
                        counts[side] = pair_phi_count[e]
    scale = F64_1
    cap = NO_CAP
    if overflow:
        scale = share(total)
    elif capped_sum(NO_CAP, wall_phi, device_phi, pair_phi, edges, counts) > wp.int64(FRACTION_UNITS):
        low = F64_0
        high = wp.max(wall_phi, device_phi)
        for side in range(2):
            for k in range(counts[side]):
                high = wp.max(high, pair_phi[edges[side], k])
        for _ in range(CAP_BISECTIONS):
            middle = wp.float64(0.5) * (low + high)
            if capped_sum(middle, wall_phi, device_phi, pair_phi, edges, counts) <= wp.int64(FRACTION_UNITS):
                low = middle
            else:
                high = middle
        cap = low
    fraction_scale[i] = scale
    fraction_cap[i] = cap


@wp.func
def obstacle_change(f: wp.vec3d, v: wp.vec3d, mu: wp.float64, v_reg: wp.float64, inv_m: wp.float64,
                    scale: wp.array(dtype=wp.float64), cap: wp.array(dtype=wp.float64), i: int,
                    dt: wp.float64) -> wp.vec3d:
    """Velocity change of node i from a fixed obstacle pushing with force f (its load and normal),
    its slip fraction (:func:`obstacle_fraction`) as applied (:func:`capped`)."""
    load = wp.length(f)
    if load > F64_0:
        phi = obstacle_fraction(f, v, mu, v_reg, inv_m, dt)
        return -capped(phi, scale, cap, i, i) * tangential(v, f / load)
    return wp.vec3d(F64_0, F64_0, F64_0)


@wp.kernel
def friction_change(
    free_out: wp.array(dtype=wp.int32),
    has_next: wp.array(dtype=wp.int32),
    world_of: wp.array(dtype=wp.int32),
    running: wp.array(dtype=wp.int32),
    inv_mass: wp.array(dtype=wp.float64),
    fraction_scale: wp.array(dtype=wp.float64),
    fraction_cap: wp.array(dtype=wp.float64),
    wall_force: wp.array(dtype=wp.vec3d),
    device_force: wp.array(dtype=wp.vec3d),
    mu_wall: wp.float64,
    v_reg: wp.float64,
    dv_start: wp.array(dtype=wp.vec3d),
    dv_end: wp.array(dtype=wp.vec3d),
    with_coil_terms: int,
    dt: wp.float64,
    v_out: wp.array(dtype=wp.vec3d),
    change: wp.array(dtype=wp.vec3d),
):
    """Friction velocity change of node i (mm/s; 0 unless free and running): wall and
    device with the wall's coefficient, their slip fractions as applied (:func:`node_fraction_caps`),
    coil pairs its shares of edges i and i − 1."""
    i = wp.tid()
    dv = wp.vec3d(F64_0, F64_0, F64_0)
    if running[world_of[i]] != 0 and free_out[i] != 0:
        v = v_out[i]
        if mu_wall > F64_0:
            dv = obstacle_change(wall_force[i], v, mu_wall, v_reg, inv_mass[i], fraction_scale, fraction_cap, i,
                                 dt) + \
                obstacle_change(device_force[i], v, mu_wall, v_reg, inv_mass[i], fraction_scale, fraction_cap, i, dt)
        if with_coil_terms != 0:
            dv = add_edge_shares(dv, dv_start, dv_end, has_next, i)
    change[i] = dv


GUARD_PASSES = 16  # Jacobi passes of the normal guard (each restores 1/K of every remaining shortfall), at most
# the guard's pass loop (an int32 array; its first entry is the loop's condition, wp.capture_while): another pass,
# whether the last pass changed a friction change, the passes done
GUARD_MOVING = wp.constant(0)
GUARD_CHANGED = wp.constant(1)
GUARD_DONE = wp.constant(2)
GUARD_PAIRS = 8  # touching partners an edge records for the guard's passes (more: it searches each pass)
GUARD_SEARCH = wp.constant(-1)  # an edge's record overflowed


@wp.func
def guard_touching(x: wp.array(dtype=wp.vec3d), rest_x: wp.array(dtype=wp.vec3d), coil_of: wp.array(dtype=wp.int32),
                   free: wp.array(dtype=wp.int32), has_next: wp.array(dtype=wp.int32),
                   fixed: wp.array(dtype=wp.int32), node_radius: wp.array(dtype=wp.float64), a: int, b: int,
                   c0: wp.float64) -> wp.vec2d:
    """The closest-point parameters (s, t) of edges a and b when the guard watches
    the pair (b can be touched, the law's segment gap < c0 — a same-coil pair near in the
    rest shape counted from its rest clearance, as contact.pair_forces counts it, so a
    watched pair is a contact of both edges and both watch it — axes apart), else (−1, −1)."""
    if edge_is_obstacle(free, has_next, fixed, b):
        pa0 = x[a]
        pa1 = x[a + 1]
        pb0 = x[b]
        pb1 = x[b + 1]
        st = segment_closest_params(pa0, pa1, pb0, pb1)
        dist = wp.length(pa0 + st[0] * (pa1 - pa0) - pb0 - st[1] * (pb1 - pb0))
        gap = dist - node_radius[a] - node_radius[b]
        if coil_of[a] == coil_of[b] and not rest_apart(rest_x, node_radius, a, b, c0):
            gap = rest_clearance_gap(rest_x, node_radius, a, b, gap, c0)
        if gap < c0 and dist > wp.float64(1.0e-9):
            return st
    return wp.vec2d(-F64_1, -F64_1)


@wp.func
def pair_guard(x: wp.array(dtype=wp.vec3d), change: wp.array(dtype=wp.vec3d), free: wp.array(dtype=wp.int32),
               has_next: wp.array(dtype=wp.int32), inv_mass: wp.array(dtype=wp.float64),
               contacts: wp.array(dtype=wp.int32), wall_force: wp.array(dtype=wp.vec3d),
               device_force: wp.array(dtype=wp.vec3d), a: int, b: int, st: wp.vec2d):
    """Normal guard of the watched coil pair (a, b) (closest-point parameters ``st``,
    :func:`guard_touching`) seen from a: if the friction changes ``change`` lower the
    rate at which the segments' closest points separate along their axes' normal n,
    the impulse J n (J ≥ 0, equal and opposite on b) that restores 1/K of the
    shortfall, K the most contacts of the pair's nodes: the velocity changes of a's
    start and end node (mm/s)."""
    zero = wp.vec3d(F64_0, F64_0, F64_0)
    dv_start = zero
    dv_end = zero
    s = st[0]
    t = st[1]
    n = contact_normal(x[a], x[a + 1], x[b], x[b + 1], s, t, zero)  # the axes are apart (guard_touching)
    rate = wp.dot((F64_1 - s) * change[a] + s * change[a + 1] - (F64_1 - t) * change[b] - t * change[b + 1], n)
    if rate < F64_0:
        w_a, w_b = pair_weights(free, inv_mass, a, b, s, t)
        k = pair_contacts(free, has_next, contacts, wall_force, device_force, a, b)
        impulse = (-rate / (wp.float64(wp.max(k, 1)) * (w_a + w_b))) * n  # on a's contact point, g·mm/s
        dv_start = ((F64_1 - s) * inv_mass[a]) * impulse
        dv_end = (s * inv_mass[a + 1]) * impulse
    return dv_start, dv_end


@wp.kernel(enable_backward=False)
def record_guard_pairs(
    x: wp.array(dtype=wp.vec3d),
    rest_x: wp.array(dtype=wp.vec3d),
    free: wp.array(dtype=wp.int32),
    has_next: wp.array(dtype=wp.int32),
    coil_of: wp.array(dtype=wp.int32),
    world_of: wp.array(dtype=wp.int32),
    running: wp.array(dtype=wp.int32),
    fixed: wp.array(dtype=wp.int32),
    node_radius: wp.array(dtype=wp.float64),
    contacts: wp.array(dtype=wp.int32),
    grid: wp.uint64,
    neighbours: wp.array2d(dtype=wp.int32),
    neighbour_count: wp.array(dtype=wp.int32),
    mid: wp.array(dtype=wp.vec3d),
    grid_radius: wp.float64,
    exclusion: int,
    c0: wp.float64,
    pair_b: wp.array2d(dtype=wp.int32),
    pair_st: wp.array2d(dtype=wp.vec2d),
    pair_count: wp.array(dtype=wp.int32),
):
    """Edge a's coil pairs the guard watches (:func:`guard_touching`), found as
    :func:`edge_friction` finds them: up to GUARD_PAIRS, else GUARD_SEARCH (the
    passes then search again, so the result never depends on the order found)."""
    a = wp.tid()
    count = int(0)
    w = world_of[a]
    if edge_in_contact_pass(free, has_next, a) and running[w] != 0 and contacts[a] > 0:
        listed = neighbour_count[a]
        if listed == NO_LIST:  # the grid (built only here: next_partner reads it only then)
            query = wp.hash_grid_query(grid, mid[a], grid_radius, w)
        k = int(0)
        b = int(0)
        while next_partner(query, k, b, a, neighbours, listed, coil_of, exclusion):
            st = guard_touching(x, rest_x, coil_of, free, has_next, fixed, node_radius, a, b, c0)
            if st[0] >= F64_0 and count != GUARD_SEARCH:
                if count < GUARD_PAIRS:
                    pair_b[a, count] = b
                    pair_st[a, count] = st
                    count += 1
                else:
                    count = GUARD_SEARCH
    pair_count[a] = count


@wp.kernel(enable_backward=False)
def edge_normal_guard(
    x: wp.array(dtype=wp.vec3d),
    rest_x: wp.array(dtype=wp.vec3d),
    change: wp.array(dtype=wp.vec3d),
    free: wp.array(dtype=wp.int32),
    has_next: wp.array(dtype=wp.int32),
    coil_of: wp.array(dtype=wp.int32),
    world_of: wp.array(dtype=wp.int32),
    fixed: wp.array(dtype=wp.int32),
    node_radius: wp.array(dtype=wp.float64),
    inv_mass: wp.array(dtype=wp.float64),
    contacts: wp.array(dtype=wp.int32),
    wall_force: wp.array(dtype=wp.vec3d),
    device_force: wp.array(dtype=wp.vec3d),
    grid: wp.uint64,
    neighbours: wp.array2d(dtype=wp.int32),
    neighbour_count: wp.array(dtype=wp.int32),
    mid: wp.array(dtype=wp.vec3d),
    grid_radius: wp.float64,
    exclusion: int,
    c0: wp.float64,
    pair_b: wp.array2d(dtype=wp.int32),
    pair_st: wp.array2d(dtype=wp.vec2d),
    pair_count: wp.array(dtype=wp.int32),
    dv_start: wp.array(dtype=wp.vec3d),
    dv_end: wp.array(dtype=wp.vec3d),
):
    """One Jacobi pass of the normal guard (:func:`pair_guard`) over edge a's watched
    coil pairs (its record, or a search when that overflowed): the corrections of
    a's nodes (mm/s), fixed-point sums."""
    a = wp.tid()
    sum_start = vec3l()
    sum_end = vec3l()
    count = pair_count[a]
    if count == GUARD_SEARCH:
        listed = neighbour_count[a]
        if listed == NO_LIST:  # the grid (built only here: next_partner reads it only then)
            query = wp.hash_grid_query(grid, mid[a], grid_radius, world_of[a])
        k = int(0)
        b = int(0)
        while next_partner(query, k, b, a, neighbours, listed, coil_of, exclusion):
            st = guard_touching(x, rest_x, coil_of, free, has_next, fixed, node_radius, a, b, c0)
            if st[0] >= F64_0:
                d0, d1 = pair_guard(x, change, free, has_next, inv_mass, contacts, wall_force, device_force, a, b, st)
                sum_start = sum_start + to_fixed(d0)
                sum_end = sum_end + to_fixed(d1)
    for j in range(count):
        d0, d1 = pair_guard(x, change, free, has_next, inv_mass, contacts, wall_force, device_force, a, pair_b[a, j],
                            pair_st[a, j])
        sum_start = sum_start + to_fixed(d0)
        sum_end = sum_end + to_fixed(d1)
    dv_start[a] = from_fixed(sum_start)
    dv_end[a] = from_fixed(sum_end)


@wp.func
def obstacle_guard(dv: wp.vec3d, f: wp.vec3d) -> wp.vec3d:
    """``dv`` less its component into a fixed obstacle pushing with force f."""
    load = wp.length(f)
    if load > F64_0:
        n = f / load
        rate = wp.dot(dv, n)
        if rate < F64_0:
            return dv - rate * n
    return dv


@wp.kernel
def add_guard(free_out: wp.array(dtype=wp.int32), has_next: wp.array(dtype=wp.int32),
              world_of: wp.array(dtype=wp.int32), running: wp.array(dtype=wp.int32),
              wall_force: wp.array(dtype=wp.vec3d), device_force: wp.array(dtype=wp.vec3d),
              dv_start: wp.array(dtype=wp.vec3d), dv_end: wp.array(dtype=wp.vec3d), with_coil_terms: int,
              change: wp.array(dtype=wp.vec3d), loop: wp.array(dtype=wp.int32)):
    """Adds node i's normal-guard corrections (edges i and i − 1; ``with_coil_terms``)
    to its friction change, then takes out any component of it into the wall or a
    device that touches the node (so friction never drives a node into them).
    ``loop[GUARD_CHANGED]`` is set where a change moved (in any bit)."""
    i = wp.tid()
    if running[world_of[i]] == 0 or free_out[i] == 0:
        return
    old = change[i]
    dv = old
    if with_coil_terms != 0:
        dv = add_edge_shares(dv, dv_start, dv_end, has_next, i)
    dv = obstacle_guard(obstacle_guard(dv, wall_force[i]), device_force[i])
    change[i] = dv
    if dv[0] != old[0] or dv[1] != old[1] or dv[2] != old[2]:  # (a NaN too: it never compares equal)
        loop[GUARD_CHANGED] = 1


@wp.kernel
def start_guard(loop: wp.array(dtype=wp.int32)):
    """The guard's pass loop before its first pass: running, nothing changed, no pass done."""
    loop[GUARD_MOVING] = 1
    loop[GUARD_CHANGED] = 0
    loop[GUARD_DONE] = 0


@wp.kernel
def finish_guard_pass(loop: wp.array(dtype=wp.int32), passes: int):
    """After a pass: another one while the pass changed some friction change and fewer than
    ``passes`` are done. A pass that changed nothing left a fixed point of the pass (a function
    of the changes alone, the contacts fixed), which every later pass would leave as it is: stopping
    there is bit-identical to running all ``passes``."""
    loop[GUARD_DONE] = loop[GUARD_DONE] + 1
    loop[GUARD_MOVING] = wp.where(loop[GUARD_CHANGED] != 0 and loop[GUARD_DONE] < passes, 1, 0)
    loop[GUARD_CHANGED] = 0


@wp.kernel
def apply_friction(
    x_in: wp.array(dtype=wp.vec3d),
    free_out: wp.array(dtype=wp.int32),
    world_of: wp.array(dtype=wp.int32),
    running: wp.array(dtype=wp.int32),
    change: wp.array(dtype=wp.vec3d),
    dt: wp.float64,
    v_out: wp.array(dtype=wp.vec3d),
    x_out: wp.array(dtype=wp.vec3d),
):
    """v' = v* + node i's friction change, then x' = x + dt v'."""
    i = wp.tid()
    if running[world_of[i]] == 0 or free_out[i] == 0:
        return
    v_new = v_out[i] + change[i]
    v_out[i] = v_new
    x_out[i] = x_in[i] + dt * v_new
