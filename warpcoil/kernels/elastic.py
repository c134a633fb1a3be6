"""Elastic pass: stretching, bending and twisting, in gather form.

Energies (µN·mm = nJ), per edge i and vertex j (see ``rod.py`` for κ, K, τ)::

    W_s = ½ k_s,i (|e_i| − l̄_i)²                       k_s = EA / l̄_i
    W_b = ¼ k_b,j (|K_j^(j-1) − K̄_j^(j-1)|² + |K_j^(j) − K̄_j^(j)|²)   k_b = EI / l̄_j
    W_t = ½ k_t,j (τ_j − τ̄_j)²                          k_t = GJ / l̄_j

with K^(a) = κ in the material frame of edge a, so W_b = ½ k_b (φ − φ0)² in a
plane. Material frames are carried in time by parallel transport (as in DER),
so the gradient holds the frame drag: it vanishes for W_b because κ ⊥ t, and
gives DER's reference-twist term ``∂τ/∂e = κb / (2|e|)``, κb = 2 t0×t1/(1+t0·t1),
for W_t.

Pass 1 (``vertex_gradients``) writes, per vertex, the energy gradient with
respect to its three nodes and two edge angles; pass 2 (``gather_forces``)
sums, per node, the contributions of its own stencils, stretching, external
and contact forces. Each thread writes only its own entries: no atomics,
identical results on CPU and CUDA.
"""

import warp as wp

from .contact import contact_force_magnitude
from .rod import (
    F64_0,
    F64_1,
    angle_factors,
    clamp_vertex,
    edge_valid,
    material_curvature,
    previous_edge,
    vertex_twist,
    vertex_valid,
)


@wp.func
def project_out(g: wp.vec3d, t: wp.vec3d) -> wp.vec3d:
    return g - wp.dot(g, t) * t


@wp.func
def vertex_needed(free: wp.array(dtype=wp.int32), j: int) -> bool:
    """A stencil matters when a node within reach is free: its own three, or
    node j-2, whose release makes node j-1 the next to leave the catheter."""
    needed = free[j - 1] != 0 or free[j] != 0 or free[j + 1] != 0
    if j >= 2:
        needed = needed or free[j - 2] != 0
    return needed


@wp.func
def has_vertex(has_next: wp.array(dtype=wp.int32), clamp_tangent: wp.array(dtype=wp.vec3d), j: int) -> bool:
    """Vertex j bends: an interior node, or a coil's first node clamped with its tangent."""
    return vertex_valid(has_next, j) or clamp_vertex(clamp_tangent, j)


@wp.func
def vertex_strains(x: wp.array(dtype=wp.vec3d), m1: wp.array(dtype=wp.vec3d),
                   clamp_tangent: wp.array(dtype=wp.vec3d), clamp_director: wp.array(dtype=wp.vec3d), j: int):
    """Material curvatures (in the frames of edges j-1 and j) and twist at vertex j."""
    t0, len0, a0 = previous_edge(x, m1, clamp_tangent, clamp_director, j)
    t1 = wp.normalize(x[j + 1] - x[j])
    w = wp.cross(t0, t1)
    phi, psi, chi = angle_factors(wp.length(w), wp.dot(t0, t1))
    kappa = psi * w
    return (material_curvature(kappa, t0, a0), material_curvature(kappa, t1, m1[j]),
            vertex_twist(t0, a0, t1, m1[j]))


@wp.kernel
def vertex_gradients(
    x: wp.array(dtype=wp.vec3d),
    m1: wp.array(dtype=wp.vec3d),
    free: wp.array(dtype=wp.int32),
    has_next: wp.array(dtype=wp.int32),
    clamp_tangent: wp.array(dtype=wp.vec3d),
    clamp_director: wp.array(dtype=wp.vec3d),
    k_bend: wp.array(dtype=wp.float64),
    k_twist: wp.array(dtype=wp.float64),
    rest_K0: wp.array(dtype=wp.vec2d),
    rest_K1: wp.array(dtype=wp.vec2d),
    rest_twist: wp.array(dtype=wp.float64),
    grad_prev: wp.array(dtype=wp.vec3d),
    grad_mid: wp.array(dtype=wp.vec3d),
    grad_next: wp.array(dtype=wp.vec3d),
    grad_theta: wp.array(dtype=wp.vec2d),
):
    """∂(W_b + W_t)/∂(x_{j-1}, x_j, x_{j+1}) and ∂/∂(θ_{j-1}, θ_j) at vertex j
    (at a clamp vertex the virtual edge j-1 is fixed: its gradients are zero)."""
    j = wp.tid()
    zero = wp.vec3d(F64_0, F64_0, F64_0)
    clamped = clamp_vertex(clamp_tangent, j)
    active = vertex_valid(has_next, j)
    if active:
        active = vertex_needed(free, j)
    if clamped:
        active = free[j + 1] != 0
    if not active:
        grad_prev[j] = zero
        grad_mid[j] = zero
        grad_next[j] = zero
        grad_theta[j] = wp.vec2d(F64_0, F64_0)
        return
    t0, len0, a0 = previous_edge(x, m1, clamp_tangent, clamp_director, j)
    e1 = x[j + 1] - x[j]
    len1 = wp.length(e1)
    t1 = e1 / len1
    a1 = m1[j]
    w = wp.cross(t0, t1)
    c = wp.dot(t0, t1)
    phi, psi, chi = angle_factors(wp.length(w), c)
    kappa = psi * w
    K0 = material_curvature(kappa, t0, a0)
    K1 = material_curvature(kappa, t1, a1)
    dK0 = K0 - rest_K0[j]
    dK1 = K1 - rest_K1[j]
    half_kb = wp.float64(0.5) * k_bend[j]
    g = half_kb * (dK0[0] * a0 + dK0[1] * wp.cross(t0, a0) + dK1[0] * a1 + dK1[1] * wp.cross(t1, a1))
    gw = wp.dot(g, w)
    dE_dt0 = psi * wp.cross(t1, g) - chi * gw * t1
    dE_dt1 = psi * wp.cross(g, t0) - chi * gw * t0

    kt_dtau = k_twist[j] * (vertex_twist(t0, a0, t1, a1) - rest_twist[j])
    kb_der = (wp.float64(2.0) / (F64_1 + c)) * w
    dE_de0 = project_out(dE_dt0, t0) / len0 + (wp.float64(0.5) * kt_dtau / len0) * kb_der
    dE_de1 = project_out(dE_dt1, t1) / len1 + (wp.float64(0.5) * kt_dtau / len1) * kb_der

    if clamped:  # the virtual edge moves with node j: only edge j's gradient acts
        dE_de0 = zero
    grad_prev[j] = -dE_de0
    grad_mid[j] = dE_de0 - dE_de1
    grad_next[j] = dE_de1
    grad_theta[j] = wp.vec2d(
        half_kb * (dK0[0] * K0[1] - dK0[1] * K0[0]) - kt_dtau,
        half_kb * (dK1[0] * K1[1] - dK1[1] * K1[0]) + kt_dtau,
    )


@wp.kernel
def vertex_theta_gradients(
    x: wp.array(dtype=wp.vec3d),
    m1: wp.array(dtype=wp.vec3d),
    free: wp.array(dtype=wp.int32),
    has_next: wp.array(dtype=wp.int32),
    clamp_tangent: wp.array(dtype=wp.vec3d),
    clamp_director: wp.array(dtype=wp.vec3d),
    k_bend: wp.array(dtype=wp.float64),
    k_twist: wp.array(dtype=wp.float64),
    rest_K0: wp.array(dtype=wp.vec2d),
    rest_K1: wp.array(dtype=wp.vec2d),
    rest_twist: wp.array(dtype=wp.float64),
    grad_theta: wp.array(dtype=wp.vec2d),
):
    """∂(W_b + W_t)/∂(θ_{j-1}, θ_j) at vertex j alone (µN·mm), as
    :func:`vertex_gradients` has it, for a twist update at new positions."""
    j = wp.tid()
    active = vertex_valid(has_next, j)
    if active:
        active = vertex_needed(free, j)
    if clamp_vertex(clamp_tangent, j):
        active = free[j + 1] != 0
    if not active:
        grad_theta[j] = wp.vec2d(F64_0, F64_0)
        return
    K0, K1, tau = vertex_strains(x, m1, clamp_tangent, clamp_director, j)
    dK0 = K0 - rest_K0[j]
    dK1 = K1 - rest_K1[j]
    half_kb = wp.float64(0.5) * k_bend[j]
    kt_dtau = k_twist[j] * (tau - rest_twist[j])
    grad_theta[j] = wp.vec2d(
        half_kb * (dK0[0] * K0[1] - dK0[1] * K0[0]) - kt_dtau,
        half_kb * (dK1[0] * K1[1] - dK1[1] * K1[0]) + kt_dtau,
    )


@wp.func
def edge_torque(has_next: wp.array(dtype=wp.int32), clamp_tangent: wp.array(dtype=wp.vec3d),
                grad_theta: wp.array(dtype=wp.vec2d), i: int) -> wp.float64:
    """Twisting torque on edge i (µN·mm): −∂W/∂θ_i from its two vertices."""
    tq = F64_0
    if has_vertex(has_next, clamp_tangent, i):
        tq = tq - grad_theta[i][1]
    if i + 1 < has_next.shape[0]:
        if vertex_valid(has_next, i + 1):
            tq = tq - grad_theta[i + 1][0]
    return tq


@wp.func
def stretch_force(x: wp.array(dtype=wp.vec3d), k_stretch: wp.array(dtype=wp.float64),
                  rest_length: wp.array(dtype=wp.float64), i: int) -> wp.vec3d:
    """Force of edge i's stretching spring on its node i (−force on node i+1)."""
    e = x[i + 1] - x[i]
    length = wp.length(e)
    return (k_stretch[i] * (length - rest_length[i]) / length) * e


@wp.func
def bonded_span(has_next: wp.array(dtype=wp.int32), i: int, span: int) -> bool:
    """Nodes i and i + span are joined by ``span`` edges of one coil."""
    if i < 0 or i + span >= has_next.shape[0]:
        return False
    joined = bool(True)
    for k in range(span):
        if has_next[i + k] == 0:
            joined = False
    return joined


@wp.func
def fold_force(x: wp.array(dtype=wp.vec3d), has_next: wp.array(dtype=wp.int32),
               node_radius: wp.array(dtype=wp.float64), contact_share: wp.array(dtype=wp.float64), i: int, span: int,
               p0: wp.float64, c0: wp.float64, u_linear: wp.float64) -> wp.vec3d:
    """Neighbouring windings: node i against nodes i ± 2·span along its coil with
    the contact law of the gap |x_i − x_j| − d, weighted by the smaller contact
    share of the two (½ when one is a free end: its half patch). At rest they are about 2d apart
    (no force); the force appears only when the coil folds sharply (over ~113° at
    l0 = d), so a vertex cannot fold back onto itself, where the curvature of the
    angle form is singular. Bonded neighbours are otherwise out of contact."""
    f = wp.vec3d(F64_0, F64_0, F64_0)
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
                gap = dist - node_radius[i] - node_radius[j]
                weight = wp.min(contact_share[i], contact_share[j])
                f = f + (weight * contact_force_magnitude(gap, p0, c0, u_linear) / dist) * delta
    return f


@wp.kernel
def gather_forces(
    x: wp.array(dtype=wp.vec3d),
    free: wp.array(dtype=wp.int32),
    has_next: wp.array(dtype=wp.int32),
    clamp_tangent: wp.array(dtype=wp.vec3d),
    k_stretch: wp.array(dtype=wp.float64),
    rest_length: wp.array(dtype=wp.float64),
    grad_prev: wp.array(dtype=wp.vec3d),
    grad_mid: wp.array(dtype=wp.vec3d),
    grad_next: wp.array(dtype=wp.vec3d),
    grad_theta: wp.array(dtype=wp.vec2d),
    external: wp.array(dtype=wp.vec3d),
    contact: wp.array(dtype=wp.vec3d),
    node_radius: wp.array(dtype=wp.float64),
    contact_share: wp.array(dtype=wp.float64),
    fold_span: int,
    p0: wp.float64,
    c0: wp.float64,
    u_linear: wp.float64,
    world_of: wp.array(dtype=wp.int32),
    push_axis: wp.array(dtype=wp.vec3d),
    force: wp.array(dtype=wp.vec3d),
    torque: wp.array(dtype=wp.float64),
    push_share: wp.array(dtype=wp.float64),
):
    """Total force on node i (µN), twisting torque on edge i (µN·mm), and node i's
    share of the push force (its internal force along the catheter axis)."""
    i = wp.tid()
    n = x.shape[0]
    f = wp.vec3d(F64_0, F64_0, F64_0)
    if has_vertex(has_next, clamp_tangent, i):
        f = f - grad_mid[i]
    if i >= 1:
        if has_vertex(has_next, clamp_tangent, i - 1):
            f = f - grad_next[i - 1]
        if edge_valid(has_next, i - 1):
            f = f - stretch_force(x, k_stretch, rest_length, i - 1)
    if i + 1 < n:
        if vertex_valid(has_next, i + 1):
            f = f - grad_prev[i + 1]
        if edge_valid(has_next, i):
            f = f + stretch_force(x, k_stretch, rest_length, i)
    share = F64_0
    fold = wp.vec3d(F64_0, F64_0, F64_0)
    if free[i] != 0:
        share = wp.dot(f, push_axis[world_of[i]])
        fold = fold_force(x, has_next, node_radius, contact_share, i, fold_span, p0, c0, u_linear)
    push_share[i] = share
    force[i] = f + external[i] + contact[i] + fold
    torque[i] = edge_torque(has_next, clamp_tangent, grad_theta, i)


@wp.kernel
def elastic_energies(
    x: wp.array(dtype=wp.vec3d),
    m1: wp.array(dtype=wp.vec3d),
    has_next: wp.array(dtype=wp.int32),
    clamp_tangent: wp.array(dtype=wp.vec3d),
    clamp_director: wp.array(dtype=wp.vec3d),
    k_stretch: wp.array(dtype=wp.float64),
    rest_length: wp.array(dtype=wp.float64),
    k_bend: wp.array(dtype=wp.float64),
    k_twist: wp.array(dtype=wp.float64),
    rest_K0: wp.array(dtype=wp.vec2d),
    rest_K1: wp.array(dtype=wp.vec2d),
    rest_twist: wp.array(dtype=wp.float64),
    stretch_energy: wp.array(dtype=wp.float64),
    bend_energy: wp.array(dtype=wp.float64),
    twist_energy: wp.array(dtype=wp.float64),
):
    """Per-edge stretching and per-vertex bending and twisting energy, nJ."""
    i = wp.tid()
    ws = F64_0
    wb = F64_0
    wt = F64_0
    if edge_valid(has_next, i):
        stretch = wp.length(x[i + 1] - x[i]) - rest_length[i]
        ws = wp.float64(0.5) * k_stretch[i] * stretch * stretch
    if has_vertex(has_next, clamp_tangent, i):
        K0, K1, tau = vertex_strains(x, m1, clamp_tangent, clamp_director, i)
        dK0 = K0 - rest_K0[i]
        dK1 = K1 - rest_K1[i]
        wb = wp.float64(0.25) * k_bend[i] * (wp.dot(dK0, dK0) + wp.dot(dK1, dK1))
        dtau = tau - rest_twist[i]
        wt = wp.float64(0.5) * k_twist[i] * dtau * dtau
    stretch_energy[i] = ws
    bend_energy[i] = wb
    twist_energy[i] = wt


@wp.kernel
def rest_strains(
    x: wp.array(dtype=wp.vec3d),
    m1: wp.array(dtype=wp.vec3d),
    has_next: wp.array(dtype=wp.int32),
    clamp_tangent: wp.array(dtype=wp.vec3d),
    clamp_director: wp.array(dtype=wp.vec3d),
    rest_K0: wp.array(dtype=wp.vec2d),
    rest_K1: wp.array(dtype=wp.vec2d),
    rest_twist: wp.array(dtype=wp.float64),
):
    """Rest curvature (in both edges' frames) and rest twist of the pre-shape; zero
    at a clamp vertex (the pre-shape leaves its clamp straight and untwisted)."""
    j = wp.tid()
    if not vertex_valid(has_next, j):
        rest_K0[j] = wp.vec2d(F64_0, F64_0)
        rest_K1[j] = wp.vec2d(F64_0, F64_0)
        rest_twist[j] = F64_0
        return
    K0, K1, tau = vertex_strains(x, m1, clamp_tangent, clamp_director, j)
    rest_K0[j] = K0
    rest_K1[j] = K1
    rest_twist[j] = tau
