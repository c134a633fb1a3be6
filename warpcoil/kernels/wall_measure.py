"""A frame's wall measurement: every free node's wall force (µN) and signed centre
distance (mm, > 0 in the lumen), exact wherever a frame reports them, without an
unlimited BVH search from nodes a certificate already puts out of contact.

The exact search is :func:`warpcoil.kernels.contact.wall_search`, wall_contact's full
search, with no search limit: from a node deep
in the sac every face is nearly equidistant and the BVH prunes little, which made
it most of a frame's measurement. Stage FIRST: a node whose lower bound L of its
signed distance (:func:`distance_lower_bound`: the measurement's own last search
in the lumen, or the trusted narrow-band field; each 1-Lipschitz) is above its contact
range d/2 + c0, or that is certified in the lumen with no face within the feature
sum's reach, has exactly zero force, is in the lumen and is no wall contact; its
distance is reported as that bound (``exact`` 0). Only the world's smallest wall gap
needs a bounded node's value: stage FIX_UP searches in full the bounded nodes whose
bound gap lies below the world's smallest exact gap (:func:`smallest_gaps`) and that
have a face that near (:func:`face_distance_within`), after stage SEED has searched
the smallest bound's node of a world with no exact node; so the minimum is exact.
It writes nothing the steps read (their sides, anchors and last searches are
wall_contact's own): a frame's measurement leaves the run as it was, so the run does
not depend on how often frames are taken.
"""

import warp as wp

from .contact import (ANCHOR_MARGIN_MM, BOX_MARGIN_MM, FAR_MM, NO_FACE, field_sample, sample_point,
                      wall_feature_sum, wall_query, wall_search)

FIRST = wp.constant(0)  # measure_wall's stages
SEED = wp.constant(1)
FIX_UP = wp.constant(2)


@wp.func
def face_distance_within(mesh: wp.uint64, vertices: wp.array(dtype=wp.vec3d), faces: wp.array(dtype=wp.int32),
                         face_first: int, origin: wp.vec3d, p: wp.vec3d, reach: wp.float64) -> wp.float64:
    """Distance (mm, float64) from p to the closest face the BVH finds within ``reach``,
    or ``reach`` when it finds none: unsigned and bounded, so cheap even deep in the
    sac, where an unlimited search prunes little. The true distance is at least this
    less ANCHOR_MARGIN_MM (≫ the float32 query's error in picking the face)."""
    local = p - origin
    local32 = wp.vec3f(wp.float32(local[0]), wp.float32(local[1]), wp.float32(local[2]))
    q = wp.mesh_query_point_no_sign(mesh, local32, wp.float32(reach))
    if not q.result:
        return reach
    base = 3 * (face_first + q.face)
    u = wp.float64(q.u)
    v = wp.float64(q.v)
    closest = u * vertices[faces[base]] + v * vertices[faces[base + 1]] + (wp.float64(1.0) - u - v) * vertices[
        faces[base + 2]]
    return wp.min(wp.length(local - closest), reach)


@wp.func
def distance_lower_bound(p: wp.vec3d, reference_x: wp.vec3d, reference_distance: wp.float64, field: wp.uint64,
                         origin: wp.vec3d, grad_tolerance: wp.float64, margin: wp.float64) -> wp.float64:
    """A lower bound (mm) of the signed centre distance at ``p`` (−FAR_MM: none), each
    1-Lipschitz in p and independent of the steps' assumptions: the measurement's own
    last search in the lumen (``reference_x`` at ≥ ``reference_distance`` > 0: the wall
    is fixed, so it stays a fact of the geometry) and the trusted field (within
    ``margin`` of the distance: at least its error bound plus the BVH's float32 margin).
    Not the steps' anchors: a step that throws a node past the wall between two of its
    short searches anchors it in the lumen, which this measurement must not inherit."""
    bound = -FAR_MM
    if reference_distance > wp.float64(0.0):
        bound = reference_distance - wp.length(p - reference_x) - margin
    if field != wp.uint64(0):
        trusted, sampled, normal = field_sample(field, p - origin, grad_tolerance)
        if trusted:
            bound = wp.max(bound, sampled - margin)
    return bound


@wp.kernel
def measure_wall(
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
    fields: wp.array(dtype=wp.uint64),
    grad_tolerance: wp.float64,
    margin: wp.float64,
    sided_skip: int,
    reference_x: wp.array(dtype=wp.vec3d),
    reference_distance: wp.array(dtype=wp.float64),
    stage: int,
    smallest_gap: wp.array(dtype=wp.float64),
    smallest_bound: wp.array(dtype=wp.float64),
    force: wp.array(dtype=wp.vec3d),
    centre_distance: wp.array(dtype=wp.float64),
    exact: wp.array(dtype=wp.int32),
):
    """``stage`` FIRST: every node's force and signed centre distance, exact
    (``exact`` 1) or, above the contact range, its certified lower bound (``exact``
    0, zero force); +FAR in the catheter, in a stopped world or without a wall.
    SEED (in a world with no exact node): the exact search for the nodes of the
    smallest bound gap (``smallest_bound``), so the world has an exact gap.
    FIX_UP: the bounded nodes whose bound gap is below the world's smallest exact
    gap (``smallest_gap``) and that have a face within that gap, searched exactly."""
    i = wp.tid()
    w = world_of[i]
    mesh = meshes[w]
    measured = free[i] != 0 and running[w] != 0 and mesh != wp.uint64(0)
    if stage != FIRST:
        if not measured or exact[i] != 0 or centre_distance[i] - node_radius[i] >= smallest_gap[w]:
            return
        if stage == SEED and (smallest_gap[w] < FAR_MM or centre_distance[i] - node_radius[i] > smallest_bound[w]):
            return
    signed = FAR_MM
    f = wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(0.0))
    is_exact = 1
    if measured:
        p = x[i]
        contact_range = node_radius[i] + c0
        searched = False  # force and distance known without the full search
        if stage == FIRST:
            bound = distance_lower_bound(p, reference_x[i], reference_distance[i], fields[w], origins[w],
                                         grad_tolerance, margin)
            if bound > contact_range:
                signed = bound
                is_exact = 0
                searched = True
            elif bound > wp.float64(0.0) and sided_skip != 0:  # in the lumen: the feature sum may do (wall_contact)
                summed, nearest, k = wall_feature_sum(mesh, vertices, faces, owners, face_first[w], p - origins[w],
                                                      node_radius[i], p0, c0, u_linear, 0)
                # no face within its reach (d/2 + c0 + BOX_MARGIN_MM) was nearer than ``nearest``
                beyond = wp.min(nearest, contact_range + BOX_MARGIN_MM - ANCHOR_MARGIN_MM)
                if nearest < contact_range:
                    signed = nearest
                    f = summed
                    searched = True
                elif beyond > contact_range:
                    signed = beyond
                    is_exact = 0
                    searched = True
                if searched:  # in the lumen (certified by the bound) at that distance or beyond
                    reference_x[i] = p
                    reference_distance[i] = signed
        elif stage == FIX_UP:  # a face nearer than the world's smallest exact gap allows?
            reach = smallest_gap[w] + node_radius[i] + wp.float64(2.0) * ANCHOR_MARGIN_MM
            if face_distance_within(mesh, vertices, faces, face_first[w], origins[w], p, reach) >= reach:
                signed = wp.max(centre_distance[i], reach - ANCHOR_MARGIN_MM)
                is_exact = 0
                searched = True
        if not searched:
            face, dist, signed, f, k_sum, by_sum = wall_search(mesh, vertices, faces, owners, face_first[w],
                                                               origins[w], p, node_radius[i], p0, c0, u_linear,
                                                               margin, FAR_MM, 0)
            reference_x[i] = p
            reference_distance[i] = wp.where(signed > wp.float64(0.0), signed, -FAR_MM)
    force[i] = contact_share[i] * f
    centre_distance[i] = signed
    exact[i] = is_exact


@wp.kernel
def reset_smallest_gaps(smallest_gap: wp.array(dtype=wp.float64), smallest_bound: wp.array(dtype=wp.float64)):
    w = wp.tid()
    smallest_gap[w] = FAR_MM
    smallest_bound[w] = FAR_MM


@wp.kernel
def smallest_gaps(free: wp.array(dtype=wp.int32), world_of: wp.array(dtype=wp.int32),
                  node_radius: wp.array(dtype=wp.float64), centre_distance: wp.array(dtype=wp.float64),
                  exact: wp.array(dtype=wp.int32), smallest_gap: wp.array(dtype=wp.float64),
                  smallest_bound: wp.array(dtype=wp.float64)):
    """Per world, the smallest wall gap (mm) of its free nodes measured exactly, and
    the smallest bound gap of the others (mins: order-free, deterministic)."""
    i = wp.tid()
    if free[i] != 0:
        if exact[i] != 0:
            wp.atomic_min(smallest_gap, world_of[i], centre_distance[i] - node_radius[i])
        else:
            wp.atomic_min(smallest_bound, world_of[i], centre_distance[i] - node_radius[i])


@wp.kernel
def sample_wall_gaps(
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
    centre_distance: wp.array(dtype=wp.float64),
    smallest_gap: wp.array(dtype=wp.float64),
    gap: wp.array(dtype=wp.float64),
):
    """Per edge of a coil with contact samples (segments longer than 1.5 d: K − 1 points between its
    nodes, model.contact_samples_per_edge) whose nodes are both out of the catheter: the smallest wall
    gap (mm: signed centre distance less the interpolated radius, < −radius where the centre line
    crossed the wall) over those points; FAR_MM elsewhere. The wall acts at the nodes only, so a
    segment can straddle a wall feature thinner than itself; this reports it. A point is searched only
    where the nodes' distances (``centre_distance``, exact or a lower bound, each 1-Lipschitz) do not
    already put it above its world's smallest node gap (``smallest_gap``)."""
    e = wp.tid()
    w = world_of[e]
    mesh = meshes[w]
    smallest = FAR_MM
    samples = contact_samples[e]
    out = samples > 1 and has_next[e] != 0  # an edge (e + 1 a node of its coil) with points between its nodes
    if out:
        out = free[e] != 0 and free[e + 1] != 0 and running[w] != 0 and mesh != wp.uint64(0)
    if out:
        for m in range(1, samples):
            p, radius, bound = sample_point(x, node_radius, centre_distance, e, wp.float64(m) / wp.float64(samples))
            if bound - radius < smallest_gap[w]:
                face, signed, inward = wall_query(mesh, vertices, faces, face_first[w], origins[w], p, FAR_MM)
                if face != NO_FACE:
                    smallest = wp.min(smallest, signed - radius)
    gap[e] = smallest
