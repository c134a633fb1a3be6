"""Regularised Coulomb friction, applied implicitly at the velocity level.

Every contact k of a node (wall, another coil, a coil edge in the catheter
standing in for the catheter) has a normal load N_k (µN, from the contact law,
the node's barycentric share for coil contacts), a unit normal n_k, a friction
coefficient μ_k and a target velocity ū_k: 0 for the wall and the catheter, the
pair's mass-weighted common velocity for two coil edges (the velocity both would
share if they stuck). After the conservative forces and the damping have given
the predicted velocity v*, friction is a tangential damper, solved implicitly::

    (m I + dt D) v' = m v* + dt Σ_k c_k P_k ū_k,   D = Σ_k c_k P_k,   P_k = I − n_k n_kᵀ

    c_k = μ_k N_k / max(|w_k| − a_k, v_reg)   (× (m_A + m_B)/m_B for two coils)

with w_k the tangential relative velocity at v* and a_k = dt μ_k N_k / m_red the
speed one step of Coulomb friction can remove. For a single contact this is
exact Coulomb friction: sliding (|w| > a + v_reg) loses exactly a per step
(|F_t| = μ N), and below that the contact sticks as a linear damper μN/v_reg,
so a tangential load F_t < μN creeps at v_reg F_t/(μN) < v_reg at most
(``v_reg`` = ``friction_speed_mm_s``, the stated regularisation velocity).
D is symmetric positive semi-definite, so against the wall and the catheter
(ū = 0) |v'| ≤ |v*|: friction never adds kinetic energy and, being implicit,
sets no step limit. Coil pairs are coupled node by node (Jacobi): an isolated
pair is exact and conserves momentum; a node with several coil contacts relaxes
towards their weighted mean.

Sums over partners are fixed-point (int64), as for the contact forces, so the
result does not depend on the order partners are found (CPU = CUDA, an
ensemble member = its single run).
"""

import warp as wp

from .contact import (NO_LIST, bonded, contact_force_magnitude, edge_in_contact_pass, edge_is_obstacle, from_fixed,
                      segment_closest_params, to_fixed, vec3l)
from .rod import F64_0, F64_1

mat33d = wp.types.matrix(shape=(3, 3), dtype=wp.float64)


@wp.func
def tangential(v: wp.vec3d, n: wp.vec3d) -> wp.vec3d:
    return v - wp.dot(v, n) * n


@wp.func
def friction_coefficient(mu: wp.float64, load: wp.float64, slip: wp.float64, step_loss: wp.float64,
                         v_reg: wp.float64) -> wp.float64:
    """c = μN / max(|w| − a, v_reg) (µN·s/mm): the damper that gives exact Coulomb
    friction for one contact (see the module docstring)."""
    return mu * load / wp.max(slip - step_loss, v_reg)


@wp.func
def pair_friction(x: wp.array(dtype=wp.vec3d), v: wp.array(dtype=wp.vec3d), free: wp.array(dtype=wp.int32),
                  has_next: wp.array(dtype=wp.int32), fixed: wp.array(dtype=wp.int32),
                  node_radius: wp.array(dtype=wp.float64), inv_mass: wp.array(dtype=wp.float64),
                  mid: wp.array(dtype=wp.vec3d), a: int, b: int, far: wp.float64, p0: wp.float64, c0: wp.float64,
                  u_linear: wp.float64, mu_coil: wp.float64, mu_catheter: wp.float64, v_reg: wp.float64,
                  dt: wp.float64):
    """Friction terms of edge b on edge a (the same pair geometry and cutoff as
    contact.pair_contact): the damper coefficient c (µN·s/mm), its normal n and
    target velocity ū (mm/s), and a's barycentric weight s of its end node."""
    c = F64_0
    n = wp.vec3d(F64_0, F64_0, F64_0)
    target = n
    s = F64_0
    if edge_is_obstacle(free, has_next, fixed, b):
        pa0 = x[a]
        pa1 = x[a + 1]
        pb0 = x[b]
        pb1 = x[b + 1]
        reach_a = wp.float64(0.5) * wp.length(pa1 - pa0) + node_radius[a] + c0
        apart = wp.length(mid[a] - mid[b])
        if apart <= far and apart < reach_a + wp.float64(0.5) * wp.length(pb1 - pb0) + node_radius[b]:
            st = segment_closest_params(pa0, pa1, pb0, pb1)
            delta = pa0 + st[0] * (pa1 - pa0) - pb0 - st[1] * (pb1 - pb0)
            dist = wp.length(delta)
            gap = dist - node_radius[a] - node_radius[b]
            if gap < c0 and dist > wp.float64(1.0e-12):
                load = contact_force_magnitude(gap, p0, c0, u_linear)
                n = delta / dist
                s = st[0]
                va = (F64_1 - s) * v[a] + s * v[a + 1]
                inv_ma = (F64_1 - s) * inv_mass[a] + s * inv_mass[a + 1]
                mu = mu_catheter
                inv_mb = F64_0  # the catheter does not move
                vb = wp.vec3d(F64_0, F64_0, F64_0)
                if free[b] != 0 or free[b + 1] != 0:
                    mu = mu_coil
                    t = st[1]
                    vb = (F64_1 - t) * v[b] + t * v[b + 1]
                    inv_mb = (F64_1 - t) * inv_mass[b] + t * inv_mass[b + 1]
                if mu > F64_0:
                    inv_red = inv_ma + inv_mb
                    slip = wp.length(tangential(va - vb, n))
                    c = friction_coefficient(mu, load, slip, dt * mu * load * inv_red, v_reg) * inv_red / inv_ma
                    target = (inv_mb * va + inv_ma * vb) / inv_red  # (m_A va + m_B vb)/(m_A + m_B)
    return c, n, target, s


@wp.func
def outer_fixed(c: wp.float64, n: wp.vec3d):
    """Fixed-point c·n nᵀ: its diagonal and (xy, xz, yz)."""
    return to_fixed(c * wp.cw_mul(n, n)), to_fixed(c * wp.vec3d(n[0] * n[1], n[0] * n[2], n[1] * n[2]))


@wp.kernel
def edge_friction(
    x: wp.array(dtype=wp.vec3d),
    v: wp.array(dtype=wp.vec3d),
    free: wp.array(dtype=wp.int32),
    has_next: wp.array(dtype=wp.int32),
    coil_of: wp.array(dtype=wp.int32),
    world_of: wp.array(dtype=wp.int32),
    running: wp.array(dtype=wp.int32),
    fixed: wp.array(dtype=wp.int32),
    node_radius: wp.array(dtype=wp.float64),
    inv_mass: wp.array(dtype=wp.float64),
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
    terms: wp.array2d(dtype=wp.vec3d),
):
    """Friction terms of edge a's coil contacts, found exactly as contact.edge_contact
    finds them (positions ``x`` at the start of the step, velocities ``v`` predicted):
    per end node (row 0: start, 1: end) the sums Σ c (as a vector's x),
    Σ c diag(n nᵀ), Σ c offdiag(n nᵀ) and Σ c P ū, in columns 0–3."""
    a = wp.tid()
    sums = vec3l()
    diag0 = vec3l()
    off0 = vec3l()
    rhs0 = vec3l()
    sum1 = vec3l()
    diag1 = vec3l()
    off1 = vec3l()
    rhs1 = vec3l()
    w = world_of[a]
    radius = query_radius[w]
    if edge_in_contact_pass(free, has_next, a) and running[w] != 0:
        listed = neighbour_count[a]
        count = listed
        query = wp.hash_grid_query(grid, mid[a], grid_radius, w)
        if listed == NO_LIST:
            count = 1 << 30
        k = int(0)
        b = int(0)
        while k < count:
            if listed != NO_LIST:
                b = neighbours[a, k]
            elif not wp.hash_grid_query_next(query, b):
                break
            k += 1
            if bonded(coil_of, exclusion, a, b):
                continue
            c, n, target, s = pair_friction(x, v, free, has_next, fixed, node_radius, inv_mass, mid, a, b, radius,
                                            p0, c0, u_linear, mu_coil, mu_catheter, v_reg, dt)
            if c > F64_0:
                rhs = c * tangential(target, n)
                c_start = (F64_1 - s) * c
                c_end = s * c
                sums = sums + to_fixed(wp.vec3d(c_start, F64_0, F64_0))
                sum1 = sum1 + to_fixed(wp.vec3d(c_end, F64_0, F64_0))
                d, o = outer_fixed(c_start, n)
                diag0 = diag0 + d
                off0 = off0 + o
                d, o = outer_fixed(c_end, n)
                diag1 = diag1 + d
                off1 = off1 + o
                rhs0 = rhs0 + to_fixed((F64_1 - s) * rhs)
                rhs1 = rhs1 + to_fixed(s * rhs)
    terms[a, 0] = from_fixed(sums)
    terms[a, 1] = from_fixed(diag0)
    terms[a, 2] = from_fixed(off0)
    terms[a, 3] = from_fixed(rhs0)
    terms[a, 4] = from_fixed(sum1)
    terms[a, 5] = from_fixed(diag1)
    terms[a, 6] = from_fixed(off1)
    terms[a, 7] = from_fixed(rhs1)


@wp.func
def add_terms(terms: wp.array2d(dtype=wp.vec3d), e: int, row: int, D: mat33d, rhs: wp.vec3d):
    c = terms[e, row][0]
    d = terms[e, row + 1]
    o = terms[e, row + 2]
    D = D + mat33d(c - d[0], -o[0], -o[1], -o[0], c - d[1], -o[2], -o[1], -o[2], c - d[2])
    return D, rhs + terms[e, row + 3]


@wp.func
def obstacle_damper(f: wp.vec3d, v: wp.vec3d, mu: wp.float64, v_reg: wp.float64, dt_inv_m: wp.float64) -> mat33d:
    """c P of a fixed obstacle pushing with force f (its load and normal)."""
    load = wp.length(f)
    if load > F64_0:
        n = f / load
        c = friction_coefficient(mu, load, wp.length(tangential(v, n)), dt_inv_m * mu * load, v_reg)
        return c * (wp.identity(n=3, dtype=wp.float64) - wp.outer(n, n))
    return mat33d()


@wp.kernel
def apply_friction(
    x_in: wp.array(dtype=wp.vec3d),
    free_out: wp.array(dtype=wp.int32),
    has_next: wp.array(dtype=wp.int32),
    world_of: wp.array(dtype=wp.int32),
    running: wp.array(dtype=wp.int32),
    inv_mass: wp.array(dtype=wp.float64),
    wall_force: wp.array(dtype=wp.vec3d),
    device_force: wp.array(dtype=wp.vec3d),
    mu_wall: wp.float64,
    v_reg: wp.float64,
    coil_terms: wp.array2d(dtype=wp.vec3d),
    with_coil_terms: int,
    dt: wp.float64,
    v_out: wp.array(dtype=wp.vec3d),
    x_out: wp.array(dtype=wp.vec3d),
):
    """v' = (I + dt/m D)⁻¹ (v* + dt/m Σ c P ū) for each free node (v* = ``v_out`` as
    the integrator left it), then x' = x + dt v'. Wall and balloon (``device_force``,
    with the wall's coefficient): the load and normal are the force's magnitude and
    direction, target 0. Coil terms: the node's
    shares of edges i (start) and i − 1 (end)."""
    i = wp.tid()
    if running[world_of[i]] == 0 or free_out[i] == 0:
        return
    v = v_out[i]
    D = mat33d()
    rhs = wp.vec3d(F64_0, F64_0, F64_0)
    inv_m = inv_mass[i]
    if mu_wall > F64_0:
        D = D + obstacle_damper(wall_force[i], v, mu_wall, v_reg, dt * inv_m)
        D = D + obstacle_damper(device_force[i], v, mu_wall, v_reg, dt * inv_m)
    if with_coil_terms != 0:
        if has_next[i] != 0:
            D, rhs = add_terms(coil_terms, i, 0, D, rhs)
        if i >= 1:
            if has_next[i - 1] != 0:
                D, rhs = add_terms(coil_terms, i - 1, 4, D, rhs)
    A = wp.identity(n=3, dtype=wp.float64) + (dt * inv_m) * D
    v_new = wp.inverse(A) * (v + (dt * inv_m) * rhs)
    v_out[i] = v_new
    x_out[i] = x_in[i] + dt * v_new
