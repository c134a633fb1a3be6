"""Proximity-gated θ of the implicit θ-method: θ_i = ``near_theta`` (1: the position update
x' = x + dt v', backward Euler) for every node that could reach an obstacle within the
step, or whose edges turn fast (the turn gate), θ elsewhere (docs/FORMULATION.md
"Implicit step: proximity-gated θ", "Implicit step: the turn gate").

With the elastic forces linearised at x + θ Δx (global θ) and node i's position update
Δx_i = dt ((1 − θ_i) v_i + θ_i v'_i), the unknown u = Δx/(θ dt) − (1 − θ)/θ v (= v' where
θ_i = θ) solves the θ-method's symmetric system with node i's mass diagonal M_i θ/θ_i in
place of M_i and M_i (θ/θ_i − 1) v_i added to its right side (:func:`shift_rows`); then
v'_i = u_i + (θ_i − θ)/θ_i (v_i − u_i) and x'_i = x_i + dt ((1 − θ_i) v_i + θ_i v'_i)
(:func:`finish_nodes`). Rows with θ_i = θ are not touched: the θ-method bit for bit.
"""

from __future__ import annotations

import warp as wp

from .contact import edge_in_contact_pass, sample_point
from .devices import balloon_gap, strut_gap
from .implicit import solving
from .rod import F64_0, F64_1


@wp.func
def gate(gap: wp.float64, reach: wp.float64) -> bool:
    """An obstacle at surface gap ``gap`` (mm; NaN: unknown) is within ``reach`` (mm)."""
    return not (gap >= reach)


@wp.func
def edge_turn(x: wp.array(dtype=wp.vec3d), v: wp.array(dtype=wp.vec3d), a: int, dt: wp.float64) -> wp.float64:
    """Angle (rad) edge a turns through in a step dt at its nodes' velocities: the part of
    their relative velocity normal to the edge, times dt, over its length."""
    d = x[a + 1] - x[a]
    length = wp.max(wp.length(d), wp.float64(1.0e-12))  # a collapsed edge: gated (any turn counts)
    t = d / length
    dv = v[a + 1] - v[a]
    return wp.length(dv - wp.dot(dv, t) * t) * dt / length


@wp.kernel
def proximity_theta(
    x: wp.array(dtype=wp.vec3d),
    v: wp.array(dtype=wp.vec3d),
    free: wp.array(dtype=wp.int32),
    has_next: wp.array(dtype=wp.int32),
    node_radius: wp.array(dtype=wp.float64),
    wall_distance: wp.array(dtype=wp.float64),
    coil_gap: wp.array(dtype=wp.float64),
    coil_contact: int,
    contact_samples: wp.array(dtype=wp.int32),
    reach_mm: wp.float64,
    turn_rad: wp.float64,
    dt: wp.float64,
    theta: wp.float64,
    near_theta: wp.float64,
    node_theta: wp.array(dtype=wp.float64),
):
    """θ_i of node i: ``near_theta`` where the wall (its centre's signed distance less
    its radius; a certified lower bound where not searched; on a segment longer than 1.5 d also
    at its contact samples, bounded from its nodes') or another coil edge
    (the smallest gap of edges i − 1 and i) lies within ``reach_mm`` + |v_i| dt
    (mm) at the step start, or where edge i − 1 or i turns by more than ``turn_rad``
    (rad) in the step at the start's velocities (``turn_rad`` ≤ 0: no turn gate);
    ``theta`` elsewhere."""
    i = wp.tid()
    reach = reach_mm + wp.length(v[i]) * dt
    near = bool(False)
    if free[i] != 0:
        near = gate(wall_distance[i] - node_radius[i], reach)
        for e in range(i - 1, i + 1):  # the node's edges i − 1 and i, where they exist
            if e >= 0:
                if has_next[e] != 0:
                    if free[e] != 0 and free[e + 1] != 0:  # its wall contact samples (kernels/contact.py)
                        for m in range(1, contact_samples[e]):
                            p, radius, bound = sample_point(x, node_radius, wall_distance, e,
                                                            wp.float64(m) / wp.float64(contact_samples[e]))
                            near = near or gate(bound - radius, reach)
                    if coil_contact != 0:
                        near = near or gate(coil_gap[e], reach)
                    if turn_rad > F64_0:
                        near = near or edge_turn(x, v, e, dt) > turn_rad
    node_theta[i] = wp.where(near, near_theta, theta)


@wp.func
def strut_near(x: wp.array(dtype=wp.vec3d), free: wp.array(dtype=wp.int32), has_next: wp.array(dtype=wp.int32),
               node_radius: wp.array(dtype=wp.float64), grid: wp.uint64, strut_start: wp.array(dtype=wp.vec3d),
               strut_end: wp.array(dtype=wp.vec3d), strut_radius: wp.float64, query_radius: wp.float64, w: int,
               a: int, reach: wp.float64) -> bool:
    """Whether a stent strut lies within ``reach`` (mm) of coil edge a."""
    near = int(0)
    if a >= 0 and edge_in_contact_pass(free, has_next, a):
        query = wp.hash_grid_query(grid, wp.float64(0.5) * (x[a] + x[a + 1]), query_radius, w)
        s = int(0)
        while wp.hash_grid_query_next(query, s):
            along, gap, delta, dist = strut_gap(x[a], x[a + 1], strut_start[s], strut_end[s], node_radius[a],
                                                strut_radius)
            if gate(gap, reach):
                near = 1
    return near != 0


@wp.kernel
def strut_proximity(
    x: wp.array(dtype=wp.vec3d),
    v: wp.array(dtype=wp.vec3d),
    free: wp.array(dtype=wp.int32),
    has_next: wp.array(dtype=wp.int32),
    world_of: wp.array(dtype=wp.int32),
    node_radius: wp.array(dtype=wp.float64),
    grid: wp.uint64,
    strut_start: wp.array(dtype=wp.vec3d),
    strut_end: wp.array(dtype=wp.vec3d),
    strut_radius: wp.float64,
    query_radius: wp.float64,
    reach_mm: wp.float64,
    dt: wp.float64,
    near_theta: wp.float64,
    node_theta: wp.array(dtype=wp.float64),
):
    """θ_i = ``near_theta`` where a strut lies within ``reach_mm`` + |v_i| dt of edge
    i − 1 or i (``query_radius``: the strut grid's search radius, widened by the reach)."""
    i = wp.tid()
    if free[i] == 0:
        return
    reach = reach_mm + wp.length(v[i]) * dt
    w = world_of[i]
    args_near = strut_near(x, free, has_next, node_radius, grid, strut_start, strut_end, strut_radius,
                           query_radius + reach, w, i, reach)
    if i >= 1:
        args_near = args_near or strut_near(x, free, has_next, node_radius, grid, strut_start, strut_end,
                                            strut_radius, query_radius + reach, w, i - 1, reach)
    if args_near:
        node_theta[i] = near_theta


@wp.kernel
def balloon_proximity(
    x: wp.array(dtype=wp.vec3d),
    v: wp.array(dtype=wp.vec3d),
    free: wp.array(dtype=wp.int32),
    world_of: wp.array(dtype=wp.int32),
    node_radius: wp.array(dtype=wp.float64),
    stations: wp.array(dtype=wp.vec3d),
    cap_radius: wp.array(dtype=wp.float64),
    station_first: wp.array(dtype=wp.int32),
    station_count: wp.array(dtype=wp.int32),
    inflation: wp.array(dtype=wp.float64),
    reach_mm: wp.float64,
    dt: wp.float64,
    near_theta: wp.float64,
    node_theta: wp.array(dtype=wp.float64),
):
    """θ_i = ``near_theta`` where the balloon lies within ``reach_mm`` + |v_i| dt of node i."""
    i = wp.tid()
    w = world_of[i]
    if free[i] == 0 or station_count[w] < 2:
        return
    gap, normal = balloon_gap(x[i], node_radius[i], stations, cap_radius, station_first[w], station_count[w],
                              inflation[w])
    if gate(gap, reach_mm + wp.length(v[i]) * dt):
        node_theta[i] = near_theta


@wp.kernel
def shift_rows(
    v: wp.array(dtype=wp.vec3d),
    free: wp.array(dtype=wp.int32),
    fixed: wp.array(dtype=wp.int32),
    world_of: wp.array(dtype=wp.int32),
    running: wp.array(dtype=wp.int32),
    inv_mass: wp.array(dtype=wp.float64),
    node_theta: wp.array(dtype=wp.float64),
    theta: wp.float64,
    diag: wp.array(dtype=wp.mat33d),
    diag_exact: wp.array(dtype=wp.mat33d),
    rhs: wp.array(dtype=wp.vec3d),
):
    """Row i with θ_i ≠ θ: M_i (θ/θ_i − 1) added to its diagonal blocks (g) and times v_i
    to its right side (g·mm/s)."""
    i = wp.tid()
    if not solving(free, fixed, world_of, running, i) or node_theta[i] == theta:
        return
    s = (theta / node_theta[i] - F64_1) / inv_mass[i]
    shift = s * wp.identity(n=3, dtype=wp.float64)
    diag[i] = diag[i] + shift
    diag_exact[i] = diag_exact[i] + shift
    rhs[i] = rhs[i] + s * v[i]


@wp.kernel
def finish_nodes(
    x_in: wp.array(dtype=wp.vec3d),
    v_in: wp.array(dtype=wp.vec3d),
    solved: wp.array(dtype=wp.vec3d),
    solved_is_u: int,
    free: wp.array(dtype=wp.int32),
    fixed: wp.array(dtype=wp.int32),
    world_of: wp.array(dtype=wp.int32),
    running: wp.array(dtype=wp.int32),
    dt: wp.float64,
    theta: wp.float64,
    node_theta: wp.array(dtype=wp.float64),
    x_out: wp.array(dtype=wp.vec3d),
    v_out: wp.array(dtype=wp.vec3d),
):
    """Unknown node i: v'_i (from the solve's u, with ``solved_is_u``; else ``solved`` is
    v' already, e.g. after friction) and x'_i = x_i + dt ((1 − θ_i) v_i + θ_i v'_i).
    Held nodes keep what hold_nodes gave them."""
    i = wp.tid()
    if not solving(free, fixed, world_of, running, i):
        return
    th = node_theta[i]
    v_new = solved[i]
    if solved_is_u != 0 and th != theta:
        v_new = v_new + ((th - theta) / th) * (v_in[i] - v_new)
    v_out[i] = v_new
    x_out[i] = x_in[i] + dt * ((F64_1 - th) * v_in[i] + th * v_new)
