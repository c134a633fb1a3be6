"""Chord (secant) contact stiffness for the implicit step (``contact_stiffness="chord"``).

The linearly implicit step takes each contact's stiffness at the step start x. A
contact out of range at x (zero force, zero stiffness) that the step moves into is
then met with no push-back, and the convex law's tangent underestimates the force
on the way deeper. Here, per contact along its normal, the stiffness is the chord of
the law between the gap at the step start h and at a predicted end h̃ (the damped
free flight x̃, ``predict_positions``):

    k = max(k(h), (|F|(h̃) − |F|(h)) / (h − h̃))   where the gap closes (h̃ < h)
    k = k(h)                                      where it opens

For a convex law the chord lies above the tangent at h, so the linear model pushes
back at least as hard as the law on the way from h to h̃ (conservative), and it sees
contacts that enter during the step. As x̃ → x it is the tangent.
"""

import warp as wp

from .contact import (
    BOX_MARGIN_MM,
    FEATURE_SKIP_MM,
    OWN_EDGE_AB,
    OWN_EDGE_BC,
    OWN_EDGE_CA,
    OWN_VERTEX_A,
    OWN_VERTEX_B,
    OWN_VERTEX_C,
    closest_on_segment,
    closest_on_triangle,
    contact_force_magnitude,
    contact_law,
    field_sample,
    fixed_outer,
    from_fixed,
    vec3l,
)
from .rod import F64_0, F64_1

# below this gap change (mm) the chord is the tangent (its quotient would be rounding)
CHORD_MIN_CLOSING_MM = wp.constant(wp.float64(1.0e-9))
# a node pressed on the wall at the step start whose predicted end closes by less than this share of c0 along
# its wall force keeps the tangent (the chord would add ≈ ½ k'/k · closing ≲ 2 % to it): a node sliding along
# the wall is not searched a second time
CHORD_WALL_SKIP_C0 = wp.constant(wp.float64(0.02))


@wp.func
def chord_and_tangent(h: wp.float64, h_end: wp.float64, p0: wp.float64, c0: wp.float64, u_linear: wp.float64):
    """Contact stiffness (µN/mm) between gap ``h`` (mm, step start) and ``h_end``
    (predicted end) — the law's chord where the gap closes and the chord is steeper
    than the tangent at h, else the tangent k(h) — and the tangent k(h)."""
    f, k = contact_law(h, p0, c0, u_linear)
    chord = k
    closing = h - h_end
    if h_end < c0 and closing > CHORD_MIN_CLOSING_MM:
        chord = wp.max(k, (contact_force_magnitude(h_end, p0, c0, u_linear) - f) / closing)
    return chord, k


@wp.func
def chord_stiffness(h: wp.float64, h_end: wp.float64, p0: wp.float64, c0: wp.float64,
                    u_linear: wp.float64) -> wp.float64:
    """Contact stiffness (µN/mm) between gap ``h`` (mm, step start) and ``h_end``
    (predicted end): :func:`chord_and_tangent`'s chord."""
    chord, k = chord_and_tangent(h, h_end, p0, c0, u_linear)
    return chord


@wp.func
def chord_excess(h: wp.float64, h_end: wp.float64, p0: wp.float64, c0: wp.float64, u_linear: wp.float64) -> wp.float64:
    """What the chord adds to the tangent k(h) (µN/mm, ≥ 0)."""
    chord, k = chord_and_tangent(h, h_end, p0, c0, u_linear)
    return chord - k


@wp.func
def feature_excess(p_end: wp.vec3d, closest: wp.vec3d, p: wp.vec3d, radius: wp.float64, p0: wp.float64,
                   c0: wp.float64, u_linear: wp.float64):
    """One wall feature's chord excess along its normal ñ at the predicted end, fixed point
    (diagonal, upper): gap h̃ = |p̃ − closest| − r there, and at the step start the gap
    along that normal, h = h̃ − ñ·(p̃ − p) (exact for a flat face; a function of (p̃,
    closest) alone, so the feature sum's repeated terms cancel as in the force). None
    where the gap opens along ñ (ñ·(p̃ − p) ≥ 0: h ≤ h̃ is no closing, the excess is 0)."""
    delta = p_end - closest
    dist = wp.length(delta)
    diagonal = vec3l()
    upper = vec3l()
    if dist < radius + c0 and dist > wp.float64(1.0e-12):
        n = delta / dist
        opening = wp.dot(n, p_end - p)
        if opening < F64_0:
            h_end = dist - radius
            k = chord_excess(h_end - opening, h_end, p0, c0, u_linear)
            if k > F64_0:
                diagonal, upper = fixed_outer(k, n)
    return diagonal, upper


@wp.func
def wall_excess_sum(mesh: wp.uint64, vertices: wp.array(dtype=wp.vec3d), faces: wp.array(dtype=wp.int32),
                    owners: wp.array(dtype=wp.int32), face_first: int, p_end: wp.vec3d, p: wp.vec3d,
                    radius: wp.float64, p0: wp.float64, c0: wp.float64, u_linear: wp.float64) -> wp.mat33d:
    """The chord excess (µN/mm) of the wall's feature sum at the predicted end ``p_end``
    (mesh frame; ``p`` the step start): Σ_faces − Σ_edges + Σ_vertices, as
    contact.wall_feature_sum sums the force, in fixed point."""
    reach = radius + c0 + BOX_MARGIN_MM
    centre = wp.vec3f(wp.float32(p_end[0]), wp.float32(p_end[1]), wp.float32(p_end[2]))
    query = wp.mesh_query_sphere(mesh, centre, wp.float32(reach))
    f = int(0)
    diagonal = vec3l()
    off = vec3l()
    while wp.mesh_query_next(query, f):
        k = face_first + f
        a = vertices[faces[3 * k]]
        b = vertices[faces[3 * k + 1]]
        c = vertices[faces[3 * k + 2]]
        closest = closest_on_triangle(p_end, a, b, c)
        if wp.length(p_end - closest) >= radius + c0 + FEATURE_SKIP_MM:
            continue
        own = owners[k]
        d, o = feature_excess(p_end, closest, p, radius, p0, c0, u_linear)
        diagonal, off = diagonal + d, off + o
        if own & OWN_EDGE_AB:
            d, o = feature_excess(p_end, closest_on_segment(p_end, a, b), p, radius, p0, c0, u_linear)
            diagonal, off = diagonal - d, off - o
        if own & OWN_EDGE_BC:
            d, o = feature_excess(p_end, closest_on_segment(p_end, b, c), p, radius, p0, c0, u_linear)
            diagonal, off = diagonal - d, off - o
        if own & OWN_EDGE_CA:
            d, o = feature_excess(p_end, closest_on_segment(p_end, c, a), p, radius, p0, c0, u_linear)
            diagonal, off = diagonal - d, off - o
        if own & OWN_VERTEX_A:
            d, o = feature_excess(p_end, a, p, radius, p0, c0, u_linear)
            diagonal, off = diagonal + d, off + o
        if own & OWN_VERTEX_B:
            d, o = feature_excess(p_end, b, p, radius, p0, c0, u_linear)
            diagonal, off = diagonal + d, off + o
        if own & OWN_VERTEX_C:
            d, o = feature_excess(p_end, c, p, radius, p0, c0, u_linear)
            diagonal, off = diagonal + d, off + o
    dd = from_fixed(diagonal)
    oo = from_fixed(off)
    return wp.mat33d(dd[0], oo[0], oo[1], oo[0], dd[1], oo[2], oo[1], oo[2], dd[2])


@wp.kernel
def wall_chord_stiffness(
    x: wp.array(dtype=wp.vec3d),
    x_end: wp.array(dtype=wp.vec3d),
    free: wp.array(dtype=wp.int32),
    world_of: wp.array(dtype=wp.int32),
    running: wp.array(dtype=wp.int32),
    node_radius: wp.array(dtype=wp.float64),
    meshes: wp.array(dtype=wp.uint64),
    face_first: wp.array(dtype=wp.int32),
    origins: wp.array(dtype=wp.vec3d),
    vertices: wp.array(dtype=wp.vec3d),
    faces: wp.array(dtype=wp.int32),
    owners: wp.array(dtype=wp.int32),
    fields: wp.array(dtype=wp.uint64),
    grad_tolerance: wp.float64,
    inside: wp.array(dtype=wp.int32),
    centre_distance: wp.array(dtype=wp.float64),
    wall_force: wp.array(dtype=wp.vec3d),
    p0: wp.float64,
    c0: wp.float64,
    u_linear: wp.float64,
    stiffness: wp.array(dtype=wp.mat33d),
):
    """Add the wall's chord excess (µN/mm) between x and the predicted end ``x_end`` to
    each free node's wall ``stiffness`` (the tangent at x, from contact.wall_contact), for
    a node in the lumen (``inside``) whose end may be in range: its centre distance at x
    (exact, or the lower bound it was anchored with) less the step is within the
    contact range (the distance is 1-Lipschitz), unless it is pressed on the wall at x and
    its end closes by less than CHORD_WALL_SKIP_C0 · c0 along the wall's force (sliding).
    From the world's field where it is trusted at x_end, else from the wall's feature sum
    there. A node outside the lumen keeps the tangent."""
    i = wp.tid()
    w = world_of[i]
    mesh = meshes[w]
    if free[i] == 0 or running[w] == 0 or mesh == wp.uint64(0) or inside[i] != 1:
        return
    step = x_end[i] - x[i]
    moved = wp.length(step)
    radius = node_radius[i]
    if moved == F64_0 or centre_distance[i] - moved >= radius + c0 + BOX_MARGIN_MM:
        return
    pressed = wp.length(wall_force[i])
    if pressed > F64_0 and -wp.dot(wall_force[i], step) < CHORD_WALL_SKIP_C0 * c0 * pressed:
        return
    if fields[w] != wp.uint64(0):
        trusted, sampled, n = field_sample(fields[w], x_end[i] - origins[w], grad_tolerance)
        if trusted:
            if sampled > F64_0:
                h_end = sampled - radius
                k = chord_excess(h_end - wp.dot(n, step), h_end, p0, c0, u_linear)
                stiffness[i] = stiffness[i] + k * wp.outer(n, n)
            return
    stiffness[i] = stiffness[i] + wall_excess_sum(mesh, vertices, faces, owners, face_first[w], x_end[i] - origins[w],
                                                  x[i] - origins[w], radius, p0, c0, u_linear)
