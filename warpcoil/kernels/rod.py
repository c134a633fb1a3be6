"""Discrete-rod geometry shared by every pass: parallel transport, curvature, twist.

All in float64 (mm). A coil is a chain of nodes; edge i joins nodes i and
i+1 and carries a material director ``m1`` (unit, normal to the edge
tangent; ``m2 = t × m1``). Vertex j (an interior node) joins edges j-1 and j.

Curvature at a vertex (the bending strain) is the rotation vector that turns
``t0`` into ``t1``::

    κ = φ (t0 × t1) / |t0 × t1|,   φ = atan2(|t0 × t1|, t0 · t1)

It is smooth through the straight state (κ → t0 × t1 as φ → 0), its length
is the turning angle φ exactly, so the bending energy reduces to
``½ k_b (φ - φ0)²`` in a plane (MODEL.md), and it is expressed in the two
edges' material frames, which makes it hold a 3D rest shape (Discrete Elastic
Rods, Bergou et al. 2008, with the angle in place of 2·tan(φ/2)).
Twist at a vertex: the signed angle, about ``t1``, from the parallel
transport of ``m1`` of edge j-1 to ``m1`` of edge j.
"""

import warp as wp

F64_0 = wp.constant(wp.float64(0.0))
F64_1 = wp.constant(wp.float64(1.0))
SMALL_ANGLE = wp.constant(wp.float64(1.0e-4))


@wp.func
def transport(v: wp.vec3d, a: wp.vec3d, b: wp.vec3d) -> wp.vec3d:
    """Parallel transport of ``v`` from unit tangent ``a`` to unit tangent ``b``:
    the smallest rotation that takes a to b (undefined for b = -a; a half turn
    about an axis normal to a is used there)."""
    k = wp.cross(a, b)
    c = wp.dot(a, b)
    if c < wp.float64(-0.999999999):
        axis = wp.cross(a, wp.vec3d(F64_1, F64_0, F64_0))
        if wp.length_sq(axis) < wp.float64(1.0e-12):
            axis = wp.cross(a, wp.vec3d(F64_0, F64_1, F64_0))
        axis = wp.normalize(axis)
        return wp.float64(2.0) * wp.dot(axis, v) * axis - v
    return v + wp.cross(k, v) + wp.cross(k, wp.cross(k, v)) / (F64_1 + c)


@wp.func
def rotate_about(v: wp.vec3d, axis: wp.vec3d, angle: wp.float64) -> wp.vec3d:
    """Rotate ``v`` about the unit ``axis`` by ``angle`` (rad), right-handed."""
    c = wp.cos(angle)
    s = wp.sin(angle)
    return v * c + wp.cross(axis, v) * s + axis * (wp.dot(axis, v) * (F64_1 - c))


@wp.func
def director_normal(m1: wp.vec3d, t: wp.vec3d) -> wp.vec3d:
    """``m1`` made exactly unit and normal to the unit tangent ``t``."""
    return wp.normalize(m1 - wp.dot(m1, t) * t)


@wp.func
def angle_factors(s: wp.float64, c: wp.float64):
    """For φ = atan2(s, c): ψ = φ / sin φ and χ = (sin φ − φ cos φ) / sin³ φ,
    both smooth at φ = 0 (series below SMALL_ANGLE)."""
    phi = wp.atan2(s, c)
    if phi < SMALL_ANGLE:
        p2 = phi * phi
        return phi, F64_1 + p2 / wp.float64(6.0), F64_1 / wp.float64(3.0) + wp.float64(2.0) * p2 / wp.float64(15.0)
    return phi, phi / s, (s - phi * c) / (s * s * s)


@wp.func
def material_curvature(kappa: wp.vec3d, t: wp.vec3d, m1: wp.vec3d) -> wp.vec2d:
    """Components of κ in the material frame (m1, m2 = t × m1) of one edge."""
    return wp.vec2d(wp.dot(kappa, m1), wp.dot(kappa, wp.cross(t, m1)))


@wp.func
def vertex_twist(t0: wp.vec3d, m1_0: wp.vec3d, t1: wp.vec3d, m1_1: wp.vec3d) -> wp.float64:
    """Signed angle (rad) about t1 from the transported m1 of edge j-1 to m1 of edge j."""
    p = transport(m1_0, t0, t1)
    return wp.atan2(wp.dot(wp.cross(p, m1_1), t1), wp.dot(p, m1_1))


@wp.func
def edge_valid(has_next: wp.array(dtype=wp.int32), i: int) -> bool:
    return has_next[i] != 0


@wp.func
def clamp_vertex(clamp_tangent: wp.array(dtype=wp.vec3d), j: int) -> bool:
    """Node j is a coil's first node clamped with its tangent: vertex j bends
    between a virtual, fixed edge along ``clamp_tangent[j]`` and edge j."""
    return wp.length_sq(clamp_tangent[j]) > F64_0


@wp.func
def previous_edge(x: wp.array(dtype=wp.vec3d), m1: wp.array(dtype=wp.vec3d),
                  clamp_tangent: wp.array(dtype=wp.vec3d), clamp_director: wp.array(dtype=wp.vec3d), j: int):
    """Unit tangent, length (mm) and director of vertex j's first edge: edge j-1,
    or the clamp's virtual edge (length 1, unused: nothing moves it)."""
    if clamp_vertex(clamp_tangent, j):
        return clamp_tangent[j], F64_1, clamp_director[j]
    e = x[j] - x[j - 1]
    length = wp.length(e)
    return e / length, length, m1[j - 1]


@wp.func
def vertex_valid(has_next: wp.array(dtype=wp.int32), j: int) -> bool:
    if j < 1:
        return False
    return has_next[j] != 0 and has_next[j - 1] != 0
