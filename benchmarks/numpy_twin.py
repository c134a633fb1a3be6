"""NumPy twin of warpcoil's model: the same equations, discretisation and
integrator as the Warp kernels, written plainly with NumPy array operations.

This is the "as the method was first written in MATLAB" peer for benchmarks
and the reference a reviewer reads side by side with the kernels. Every
function names the kernel (or ``wp.func``) it mirrors. All node, edge, vertex
and contact-pair work is vectorised over whole arrays; the only Python loop
is over time steps (plus a loop over the few segments of the catheter
polyline and over chunks of contact pairs / wall faces when they are many).

The static data come from a finalised :class:`warpcoil.Model` and the initial
state from a :class:`warpcoil.State` (``.numpy()`` copies), so the twin and
the Warp solver simulate the same thing; after that everything is NumPy
float64. Summation order differs from Warp, so results agree to rounding,
not bit for bit.

Differences in *method* (not in the model):

* Coil–coil contact: brute force over all pairs of contact-pass edges (the
  Warp kernel takes its candidates from a ``wp.HashGrid`` of edge midpoints
  and rejects most by bounding spheres; both filters keep every pair within
  c0, so the set of pairs that exert a force is the same).
* Coil–wall contact: brute force closest point over all wall triangles
  (Ericson's closest-point-on-triangle, as Warp's
  ``closest_point_to_triangle``), in float64. Warp's BVH query runs in
  float32 and returns float32 barycentrics that the kernel then evaluates
  in float64, so the two closest points differ by ~1e-7 of the mesh size.
  ``trimesh.proximity.closest_point`` would do the same job but needs
  ``rtree``, which is not a warpcoil dependency.
  Inside/outside: the sign of ``(p − closest) · n̂`` with n̂ the
  angle-weighted pseudo-normal (Bærentzen & Aanæs 2005) of the feature that
  holds the closest point: the face normal inside a face, the sum of the two
  adjacent face normals on an edge, the angle-weighted vertex normal at a
  vertex (not ``trimesh.Trimesh.contains``, which also needs ``rtree``).
  Warp's query applies the same rule, with the feature decided to within
  1e-3 of the mean edge length. The twin always computes the exact distance
  but then applies the kernel's search window (``wall_search_mm`` beyond the
  contact range, with the per-node side cache), because that window decides
  which nodes feel a force. A node in the lumen within its contact range then
  gets the feature sum over *every* face, edge and vertex (Warp: those in a
  ``wp.mesh_query_aabb`` box around the node; the others contribute zero).

Units: mm, g, s; forces µN, torques µN·mm, energies nJ.
"""

from __future__ import annotations

import numpy as np

from warpcoil.solver import WALL_SEARCH_MM, contact_linear_onset

# --- constants, identical to the kernels -----------------------------------------
SMALL_ANGLE = 1.0e-4  # rod.py: SMALL_ANGLE (series for φ/sin φ below this)
ANTIPARALLEL_COS = -0.999999999  # rod.py: transport's half-turn branch
E_MINUS_1 = 1.718281828459045  # contact.py
FAR_MM = 1.0e6  # contact.py: FAR_MM
DAMPING_NEWTON_ITERATIONS = 6  # integrate.py: damped_speed
PAIR_CHUNK = 1 << 18  # edge–edge / node–face pairs evaluated at once (bounds the memory)
# features of a triangle abc that can hold a closest point (closest_point_to_triangle)
VERTEX_A, VERTEX_B, VERTEX_C, EDGE_BC, EDGE_AC, EDGE_AB, FACE = range(7)


# --- small vector helpers (row-wise over (..., 3) arrays) ---------------------------
def dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("...i,...i->...", a, b)


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.cross(a, b)


def length(a: np.ndarray) -> np.ndarray:
    return np.sqrt(dot(a, a))


def normalize(a: np.ndarray) -> np.ndarray:
    return a / length(a)[..., None]


def col(s: np.ndarray) -> np.ndarray:
    """A per-row scalar as a column, to scale rows of (..., 3) arrays."""
    return np.asarray(s)[..., None]


# --- rod geometry (kernels/rod.py) -------------------------------------------------
def transport(v: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """rod.py ``transport``: parallel transport of v from unit tangent a to b
    (the smallest rotation taking a to b; a half turn about an axis normal to a
    when b ≈ −a)."""
    k = cross(a, b)
    c = dot(a, b)
    flip = c < ANTIPARALLEL_COS
    denom = np.where(flip, 1.0, 1.0 + c)
    out = v + cross(k, v) + cross(k, cross(k, v)) / col(denom)
    if np.any(flip):
        af, vf = a[flip], v[flip]
        axis = cross(af, np.array([1.0, 0.0, 0.0]))
        near_x = dot(axis, axis) < 1.0e-12
        axis[near_x] = cross(af[near_x], np.array([0.0, 1.0, 0.0]))
        axis = normalize(axis)
        out[flip] = 2.0 * col(dot(axis, vf)) * axis - vf
    return out


def rotate_about(v: np.ndarray, axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """rod.py ``rotate_about``: rotate v about the unit axis by angle (rad)."""
    c = np.cos(angle)
    s = np.sin(angle)
    return v * col(c) + cross(axis, v) * col(s) + axis * col(dot(axis, v) * (1.0 - c))


def director_normal(m1: np.ndarray, t: np.ndarray) -> np.ndarray:
    """rod.py ``director_normal``: m1 made exactly unit and normal to t."""
    return normalize(m1 - col(dot(m1, t)) * t)


def angle_factors(s: np.ndarray, c: np.ndarray):
    """rod.py ``angle_factors``: φ = atan2(s, c), ψ = φ/sin φ and
    χ = (sin φ − φ cos φ)/sin³ φ, with their series below SMALL_ANGLE."""
    phi = np.arctan2(s, c)
    small = phi < SMALL_ANGLE
    p2 = phi * phi
    s_safe = np.where(small, 1.0, s)
    psi = np.where(small, 1.0 + p2 / 6.0, phi / s_safe)
    chi = np.where(small, 1.0 / 3.0 + 2.0 * p2 / 15.0, (s_safe - phi * c) / (s_safe * s_safe * s_safe))
    return phi, psi, chi


def material_curvature(kappa: np.ndarray, t: np.ndarray, m1: np.ndarray) -> np.ndarray:
    """rod.py ``material_curvature``: (κ·m1, κ·m2), m2 = t × m1; shape (..., 2)."""
    return np.stack([dot(kappa, m1), dot(kappa, cross(t, m1))], axis=-1)


def vertex_twist(t0: np.ndarray, m1_0: np.ndarray, t1: np.ndarray, m1_1: np.ndarray) -> np.ndarray:
    """rod.py ``vertex_twist``: signed angle about t1 from the transported m1_0 to m1_1."""
    p = transport(m1_0, t0, t1)
    return np.arctan2(dot(cross(p, m1_1), t1), dot(p, m1_1))


# --- contact law and geometry (kernels/contact.py) -----------------------------------
def contact_force_magnitude(h: np.ndarray, p0: float, c0: float, u_linear: float = 7.0) -> np.ndarray:
    """contact.py ``contact_force_magnitude``: |F| (µN) at clearance h (mm), the
    exponential turning into its tangent line at ``u_linear``."""
    h = np.asarray(h, dtype=np.float64)
    u = 1.0 - h / c0
    exponential = p0 / E_MINUS_1 * u * (np.exp(np.minimum(u, u_linear)) - 1.0)
    e = np.exp(u_linear)
    linear = p0 / E_MINUS_1 * (u_linear * (e - 1.0) + (e * (1.0 + u_linear) - 1.0) * (u - u_linear))
    return np.where(h >= c0, 0.0, np.where(u < u_linear, exponential, linear))


def segment_closest_params(p1, q1, p2, q2):
    """contact.py ``segment_closest_params``: (s, t) ∈ [0, 1]² of the closest
    points of segments p1q1 and p2q2 (Ericson §5.1.9), row-wise."""
    d1 = q1 - p1
    d2 = q2 - p2
    r = p1 - p2
    a = dot(d1, d1)
    e = dot(d2, d2)
    f = dot(d2, r)
    c = dot(d1, r)
    b = dot(d1, d2)
    denom = a * e - b * b
    not_parallel = denom > 1.0e-14 * a * e
    s = np.where(not_parallel, np.clip((b * f - c * e) / np.where(not_parallel, denom, 1.0), 0.0, 1.0), 0.0)
    t = (b * s + f) / e
    below, above = t < 0.0, t > 1.0
    s = np.where(below, np.clip(-c / a, 0.0, 1.0), np.where(above, np.clip((b - c) / a, 0.0, 1.0), s))
    t = np.clip(t, 0.0, 1.0)
    return s, t


def closest_point_to_triangle(a, b, c, p):
    """Warp's native ``closest_point_to_triangle`` (Ericson §5.1.5), row-wise in
    float64: barycentric weights (u, v, w) of a, b, c of the point of triangle
    abc closest to p, and the feature that holds it (VERTEX_A … FACE)."""
    ab, ac, ap = b - a, c - a, p - a
    bp, cp = p - b, p - c
    d1, d2 = dot(ab, ap), dot(ac, ap)
    d3, d4 = dot(ab, bp), dot(ac, bp)
    d5, d6 = dot(ab, cp), dot(ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        # the Voronoi regions in Ericson's order; the first that applies wins
        regions = [
            (d1 <= 0.0) & (d2 <= 0.0),  # vertex a
            (d3 >= 0.0) & (d4 <= d3),  # vertex b
            (vc <= 0.0) & (d1 >= 0.0) & (d3 <= 0.0),  # edge ab
            (d6 >= 0.0) & (d5 <= d6),  # vertex c
            (vb <= 0.0) & (d2 >= 0.0) & (d6 <= 0.0),  # edge ac
            (va <= 0.0) & (d4 - d3 >= 0.0) & (d5 - d6 >= 0.0),  # edge bc
        ]
        zero, one = np.zeros_like(d1), np.ones_like(d1)
        v_ab = d1 / (d1 - d3)
        w_ac = d2 / (d2 - d6)
        w_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        inv = 1.0 / (va + vb + vc)
        v = np.select(regions, [zero, one, v_ab, zero, zero, 1.0 - w_bc], vb * inv)
        w = np.select(regions, [zero, zero, zero, one, w_ac, w_bc], vc * inv)
    feature = np.select(regions, [VERTEX_A, VERTEX_B, EDGE_AB, VERTEX_C, EDGE_AC, EDGE_BC], FACE)
    u = 1.0 - v - w
    return u, v, w, feature


# --- the twin ---------------------------------------------------------------------
class NumpyTwin:
    """Semi-implicit Euler of warpcoil's coil model, in NumPy float64.

    Mirrors :meth:`warpcoil.Solver.step` (and the :class:`~warpcoil.Control`
    it is given: ``active_coil``, ``push_speed_mm_s``). State arrays (NumPy):
    ``x`` (N, 3) mm, ``v`` (N, 3) mm/s, ``m1`` (N, 3) edge directors,
    ``omega`` (N,) rad/s, ``free`` (N,) int32, ``advance`` (coils,) mm, ``time_s``.
    """

    def __init__(self, model, state, dt_s: float, push_speed_mm_s: float = 0.0, active_coil: int = -1,
                 coil_contact: bool = True, wall_search_mm: float = WALL_SEARCH_MM):
        self.dt = float(dt_s)
        self.push_speed = float(push_speed_mm_s)
        self.active_coil = int(active_coil)
        self.coil_contact = bool(coil_contact)
        self.wall_search_mm = float(wall_search_mm)

        # static data, straight from the finalised Model
        self.n = model.node_count
        self.coil_count = model.coil_count
        self.has_next = model.has_next.numpy() != 0
        self.coil_of = model.coil_of.numpy().astype(np.int64)
        self.arc_s = model.arc_s.numpy()
        self.fixed = model.fixed.numpy() != 0
        if np.any(model.clamp_tangent.numpy() != 0.0):
            raise NotImplementedError("the numpy twin has no clamp vertex (ModelBuilder.clamp with tangent): "
                                      "compare it on models without one")
        self.inv_mass = model.inv_mass.numpy()
        self.contact_share = model.contact_share.numpy()
        if np.any(model.contact_samples.numpy() != 1):
            raise NotImplementedError("the numpy twin has no contact samples between nodes (segments above 1.5 d): "
                                      "compare it on coils with segment_length_mm ≤ 1.5 d")
        self.damping_c = model.damping_c.numpy()
        self.damping_k = float(model.damping_k)
        self.external = model.external.numpy()
        self.rest_length = model.rest_length.numpy()
        self.k_stretch = model.k_stretch.numpy()
        self.inv_inertia = model.inv_inertia.numpy()
        self.twist_damping = model.twist_damping.numpy()
        self.k_bend = model.k_bend.numpy()
        self.k_twist = model.k_twist.numpy()
        self.rest_K0 = model.rest_K0.numpy()
        self.rest_K1 = model.rest_K1.numpy()
        self.rest_twist = model.rest_twist.numpy()
        self.catheter_path = model.catheter_path.numpy()
        self.catheter_axis = np.asarray(model.catheter_axis, dtype=np.float64)
        self.node_radius = model.node_radius.numpy()
        self.rest_x = model.rest_positions.astype(np.float64)
        c = model.contact
        self.p0, self.c0, self.exclusion = float(c.p0_uN), float(c.c0_mm), int(c.exclusion_edges)
        self.u_linear = contact_linear_onset(model, self.dt)  # solver.py: the law's linear onset for this step
        self.fold_span = int(c.fold_span)

        # topology: edge i joins nodes i, i+1; vertex j joins edges j-1, j (rod.py edge_valid/vertex_valid)
        self.edges = np.flatnonzero(self.has_next)
        vertex_valid = np.zeros(self.n, bool)
        vertex_valid[1:] = self.has_next[1:] & self.has_next[:-1]
        self.vertices = np.flatnonzero(vertex_valid)

        self.wall = None if model.wall is None else _WallTwin(model.wall)
        self.wall_side = np.full(self.n, -1, np.int32)  # Solver._wall_side: 1 lumen, 0 outside, −1 unknown

        # state, copied once
        self.x = state.x.numpy().astype(np.float64)
        self.v = state.v.numpy().astype(np.float64)
        self.m1 = state.m1.numpy().astype(np.float64)
        self.omega = state.omega.numpy().astype(np.float64)
        self.free = state.free.numpy().astype(np.int32)
        self.advance = state.advance.numpy().astype(np.float64)
        self.time_s = float(state.time_s)

        # per-step outputs, kept for inspection (Solver's buffers of the same names)
        self.contact_force = np.zeros((self.n, 3))
        self.wall_force = np.zeros((self.n, 3))
        self.wall_distance = np.full(self.n, FAR_MM)
        self.coil_contacts = np.zeros(self.n, np.int32)  # touching pairs per edge (counted from both edges)
        self.force = np.zeros((self.n, 3))
        self.torque = np.zeros(self.n)
        self.push_share = np.zeros(self.n)
        self.push_accumulator = np.zeros(2)  # Σ and max of the step push force

    # --- forces ----------------------------------------------------------------
    def wall_contact(self, x: np.ndarray, free: np.ndarray) -> np.ndarray:
        """contact.py ``wall_contact``: the law of the gap (signed centre distance
        − d/2) along the inward wall normal, on each free node whose closest face
        lies within the search reach r + c0 + wall_search_mm (any distance while
        the node's side is unknown). Updates the side cache; the reported centre
        distance is ± the reach when no face is that close, +FAR in the catheter."""
        force = np.zeros((self.n, 3))
        self.wall_distance = np.full(self.n, FAR_MM)
        self.wall_side[free == 0] = -1
        nodes = np.flatnonzero(free != 0)
        if nodes.size == 0:
            return force
        side = self.wall_side[nodes]
        reach = np.where(side < 0, FAR_MM, self.node_radius[nodes] + self.c0 + self.wall_search_mm)
        signed, inward = self.wall.query(x[nodes])
        found = np.abs(signed) < reach  # the BVH query finds faces strictly within its max_dist
        radius = self.node_radius[nodes]
        magnitude = contact_force_magnitude(signed - radius, self.p0, self.c0, self.u_linear)
        outside = found & (signed <= 0.0)  # pushed back along the closest face's normal
        force[nodes] = np.where(col(outside), col(magnitude) * inward, 0.0)
        near = found & (signed > 0.0) & (signed < radius + self.c0)
        force[nodes[near]] = self.wall.feature_sum(x[nodes[near]], radius[near], self.p0, self.c0, self.u_linear)
        self.wall_side[nodes] = np.where(found, (signed > 0.0).astype(np.int32), side)
        self.wall_distance[nodes] = np.where(found, signed, np.where(side == 0, -reach, reach))
        return col(self.contact_share) * force

    def candidate_pairs(self, x: np.ndarray, edges: np.ndarray, others: np.ndarray):
        """Every ordered pair (a, b), a from ``edges`` and b from ``others``, that are
        not bonded neighbours (same coil, |a − b| ≤ exclusion) and whose bounding
        spheres overlap: |mid_a − mid_b| < (½|e_a| + r_a + c0) + ½|e_b| + r_b, the
        rejection test of contact.py ``edge_contact``, which keeps every pair
        within c0. Brute force over all pairs (in chunks of rows); Warp first
        narrows them with its hash grid of midpoints."""
        mid = 0.5 * (x[:-1] + x[1:])  # contact.py edge_midpoints (edge e: mid[e])
        half = 0.5 * length(x[1:] - x[:-1])
        pairs_a, pairs_b = [edges[:0]], [edges[:0]]
        rows_per_chunk = max(1, PAIR_CHUNK // max(others.size, 1))
        for first in range(0, edges.size, rows_per_chunk):
            rows = edges[first:first + rows_per_chunk]
            a, b = rows[:, None], others[None, :]
            bonded = (self.coil_of[a] == self.coil_of[b]) & (np.abs(b - a) <= self.exclusion)
            reach_a = half[a] + self.node_radius[a] + self.c0
            near = length(mid[a] - mid[b]) < reach_a + half[b] + self.node_radius[b]
            ia, ib = np.nonzero(near & ~bonded)
            pairs_a.append(rows[ia])
            pairs_b.append(others[ib])
        return np.concatenate(pairs_a), np.concatenate(pairs_b)

    def counted(self, free: np.ndarray, e: np.ndarray, other: np.ndarray) -> np.ndarray:
        """contact.py ``counted``: edge e (−1: none) is an obstacle, not bonded to ``other``."""
        ok = e >= 0
        e_ = np.where(ok, e, 0)
        free_next = np.append(free[1:], 0)
        fixed_next = np.append(self.fixed[1:], True)
        obstacle = self.has_next & (((free != 0) | (free_next != 0)) | (~self.fixed & ~fixed_next))
        bonded = (self.coil_of[e_] == self.coil_of[other]) & (np.abs(e_ - other) <= self.exclusion)
        return ok & obstacle[e_] & ~bonded

    def joint(self, free: np.ndarray, k: np.ndarray, other: np.ndarray) -> np.ndarray:
        """contact.py ``joint``: 1.0 where node k joins edges k − 1 and k that ``other`` touches."""
        inner = (k >= 1) & self.has_next[k] & self.has_next[np.maximum(k - 1, 0)]
        both = self.counted(free, np.where(inner, k - 1, -1), other) & self.counted(free, np.where(inner, k, -1),
                                                                                    other)
        return (inner & both).astype(np.float64)

    def offset_gap(self, gap: np.ndarray, same: np.ndarray, rest_gap: np.ndarray) -> np.ndarray:
        """contact.py ``rest_offset`` added to the gaps of same-coil terms."""
        return gap + np.where(same, np.clip(self.c0 - rest_gap, 0.0, self.c0), 0.0)

    def node_segment(self, x: np.ndarray, j: np.ndarray, b: np.ndarray):
        """contact.py ``node_segment_term``: ½ s_j × the law between node j and capsule b
        (force on j; s_j its contact share) and the parameter t of the closest point on b."""
        def closest(points, p0, p1):
            e = p1 - p0
            t = np.clip(dot(points - p0, e) / np.maximum(dot(e, e), 1e-300), 0.0, 1.0)
            return p0 + col(t) * e, t
        cp, t = closest(x[j], x[b], x[b + 1])
        delta = x[j] - cp
        dist = length(delta)
        r = self.node_radius[j] + self.node_radius[b]
        rest_cp, _ = closest(self.rest_x[j], self.rest_x[b], self.rest_x[b + 1])
        gap = self.offset_gap(dist - r, self.coil_of[j] == self.coil_of[b], length(self.rest_x[j] - rest_cp) - r)
        on = (gap < self.c0) & (dist > 1.0e-12)
        f = col(np.where(on, 0.5 * self.contact_share[j] * contact_force_magnitude(gap, self.p0, self.c0, self.u_linear)
                         / np.where(on, dist, 1.0), 0.0)) * delta
        return f, t

    def node_node(self, x: np.ndarray, j: np.ndarray, k: np.ndarray) -> np.ndarray:
        """contact.py ``node_node_term``: the law between node spheres j and k (force on j)."""
        delta = x[j] - x[k]
        dist = length(delta)
        r = self.node_radius[j] + self.node_radius[k]
        gap = self.offset_gap(dist - r, self.coil_of[j] == self.coil_of[k], length(self.rest_x[j] - self.rest_x[k]) - r)
        on = (gap < self.c0) & (dist > 1.0e-12)
        return col(np.where(on, contact_force_magnitude(gap, self.p0, self.c0, self.u_linear)
                            / np.where(on, dist, 1.0), 0.0)) * delta

    def edge_contact(self, x: np.ndarray, free: np.ndarray):
        """contact.py ``edge_contact`` / ``pair_contact``: for every edge a in the
        contact pass (it exists and has a free node) and every other edge b near it
        (:meth:`candidate_pairs`), the forces on a's nodes of the coil–coil terms
        joining a's and b's nodes: ½ the law between each node a owns (its start,
        and its end at a coil's end) and capsule b, minus the joint corrections
        with b's nodes, and the reactions of b's nodes against capsule a, split by
        the closest point's parameter. Returns the per-edge (start, end) forces;
        counts each edge's touching pairs (segment gap < c0; a same-coil pair's
        counted from its rest clearance). Edges in the catheter are obstacles
        (they take no force)."""
        force_start, force_end = np.zeros((self.n, 3)), np.zeros((self.n, 3))
        self.coil_contacts = np.zeros(self.n, np.int32)
        free_next = np.append(free[1:], 0)
        fixed_next = np.append(self.fixed[1:], True)
        in_pass = self.has_next & ((free != 0) | (free_next != 0))  # edge_in_contact_pass
        obstacle = in_pass | (self.has_next & ~self.fixed & ~fixed_next)  # edge_is_obstacle: also in the catheter
        a, b = self.candidate_pairs(x, np.flatnonzero(in_pass), np.flatnonzero(obstacle))
        s, t = segment_closest_params(x[a], x[a + 1], x[b], x[b + 1])
        r = self.node_radius[a] + self.node_radius[b]
        gap = length(x[a] + col(s) * (x[a + 1] - x[a]) - x[b] - col(t) * (x[b + 1] - x[b])) - r
        rx = self.rest_x
        rs, rt = segment_closest_params(rx[a], rx[a + 1], rx[b], rx[b + 1])
        rest_gap = length(rx[a] + col(rs) * (rx[a + 1] - rx[a]) - rx[b] - col(rt) * (rx[b + 1] - rx[b])) - r
        gap = np.where(gap < self.c0, self.offset_gap(gap, self.coil_of[a] == self.coil_of[b], rest_gap), gap)
        np.add.at(self.coil_contacts, a, (gap < self.c0).astype(np.int32))
        last = lambda e: ~self.has_next[e + 1]  # noqa: E731  the edge also owns its coil's last node
        f_start, f_end = np.zeros((len(a), 3)), np.zeros((len(a), 3))
        for m in (0, 1):  # a's nodes against capsule b and b's joints
            on = np.ones(len(a), bool) if m == 0 else last(a)
            j = a + m
            f, _ = self.node_segment(x, j, b)
            joint_j = self.joint(free, j, b)
            for q in (0, 1):
                k = b + q
                k_in = np.minimum(k, self.n - 1)
                weight = 0.5 * (self.contact_share[j] * self.joint(free, k, a) + self.contact_share[k_in] * joint_j)
                if q == 1:
                    weight = np.where(last(b), weight, 0.0)
                f = f - col(weight) * self.node_node(x, j, np.minimum(k, self.n - 1))
            f = np.where(col(on), f, 0.0)
            if m == 0:
                f_start += f
            else:
                f_end += f
        for q in (0, 1):  # b's nodes against capsule a: the reaction on a's nodes
            on = np.ones(len(a), bool) if q == 0 else last(b)
            f, t_a = self.node_segment(x, np.minimum(b + q, self.n - 1), a)
            f = np.where(col(on), f, 0.0)
            f_start -= col(1.0 - t_a) * f
            f_end -= col(t_a) * f
        np.add.at(force_start, a, f_start)
        np.add.at(force_end, a, f_end)
        return force_start, force_end

    def gather_contact(self, free: np.ndarray, wall_force: np.ndarray, force_start: np.ndarray,
                       force_end: np.ndarray) -> np.ndarray:
        """contact.py ``gather_contact``: contact force on node i = wall force + (if
        free) the start share of edge i and the end share of edge i − 1."""
        f = wall_force.copy()
        takes_start = (free != 0) & self.has_next
        f[takes_start] += force_start[takes_start]
        takes_end = np.zeros(self.n, bool)
        takes_end[1:] = (free[1:] != 0) & self.has_next[:-1]
        f[takes_end] += force_end[np.flatnonzero(takes_end) - 1]
        return f

    def compute_contacts(self, x: np.ndarray, free: np.ndarray) -> np.ndarray:
        """Solver.compute_contacts: wall force + coil–coil force per node (µN)."""
        self.wall_force = self.wall_contact(x, free) if self.wall is not None else np.zeros((self.n, 3))
        if not self.coil_contact:
            return self.wall_force.copy()
        force_start, force_end = self.edge_contact(x, free)
        return self.gather_contact(free, self.wall_force, force_start, force_end)

    def vertex_gradients(self, x: np.ndarray, m1: np.ndarray, free: np.ndarray):
        """elastic.py ``vertex_gradients``: ∂(W_b + W_t)/∂(x_{j−1}, x_j, x_{j+1})
        and ∂/∂(θ_{j−1}, θ_j) at every valid vertex j that a free node can reach
        (zero elsewhere)."""
        grad_prev, grad_mid, grad_next = np.zeros((self.n, 3)), np.zeros((self.n, 3)), np.zeros((self.n, 3))
        grad_theta = np.zeros((self.n, 2))
        j = self.vertices
        fr = free != 0
        needed = fr[j - 1] | fr[j] | fr[j + 1] | ((j >= 2) & fr[np.maximum(j - 2, 0)])  # vertex_needed
        j = j[needed]
        if j.size == 0:
            return grad_prev, grad_mid, grad_next, grad_theta
        e0 = x[j] - x[j - 1]
        e1 = x[j + 1] - x[j]
        len0, len1 = length(e0), length(e1)
        t0, t1 = e0 / col(len0), e1 / col(len1)
        a0, a1 = m1[j - 1], m1[j]
        w = cross(t0, t1)
        c = dot(t0, t1)
        phi, psi, chi = angle_factors(length(w), c)
        kappa = col(psi) * w
        K0 = material_curvature(kappa, t0, a0)
        K1 = material_curvature(kappa, t1, a1)
        dK0 = K0 - self.rest_K0[j]
        dK1 = K1 - self.rest_K1[j]
        half_kb = 0.5 * self.k_bend[j]
        # g = ∂W_b/∂κ
        g = col(half_kb) * (col(dK0[:, 0]) * a0 + col(dK0[:, 1]) * cross(t0, a0)
                            + col(dK1[:, 0]) * a1 + col(dK1[:, 1]) * cross(t1, a1))
        gw = dot(g, w)
        dE_dt0 = col(psi) * cross(t1, g) - col(chi * gw) * t1
        dE_dt1 = col(psi) * cross(g, t0) - col(chi * gw) * t0

        kt_dtau = self.k_twist[j] * (vertex_twist(t0, a0, t1, a1) - self.rest_twist[j])
        kb_der = col(2.0 / (1.0 + c)) * w  # DER's curvature binormal: the reference-twist drag
        dE_de0 = (dE_dt0 - col(dot(dE_dt0, t0)) * t0) / col(len0) + col(0.5 * kt_dtau / len0) * kb_der
        dE_de1 = (dE_dt1 - col(dot(dE_dt1, t1)) * t1) / col(len1) + col(0.5 * kt_dtau / len1) * kb_der

        grad_prev[j] = -dE_de0
        grad_mid[j] = dE_de0 - dE_de1
        grad_next[j] = dE_de1
        grad_theta[j, 0] = half_kb * (dK0[:, 0] * K0[:, 1] - dK0[:, 1] * K0[:, 0]) - kt_dtau
        grad_theta[j, 1] = half_kb * (dK1[:, 0] * K1[:, 1] - dK1[:, 1] * K1[:, 0]) + kt_dtau
        return grad_prev, grad_mid, grad_next, grad_theta

    def stretch_forces(self, x: np.ndarray) -> np.ndarray:
        """elastic.py ``stretch_force`` for every edge: force of edge i's spring
        on node i (its negative on node i+1); zero for non-edges."""
        f = np.zeros((self.n, 3))
        i = self.edges
        e = x[i + 1] - x[i]
        edge_len = length(e)
        f[i] = col(self.k_stretch[i] * (edge_len - self.rest_length[i]) / edge_len) * e
        return f

    def gather_forces(self, x: np.ndarray, free: np.ndarray, grads, contact_force: np.ndarray):
        """elastic.py ``gather_forces``: total force per node, twisting torque per
        edge and each free node's push share, summed in the kernel's order.
        (Gradients of invalid vertices and forces of non-edges are zero, so the
        kernel's validity tests reduce to plain shifts here.)"""
        grad_prev, grad_mid, grad_next, grad_theta = grads
        stretch = self.stretch_forces(x)
        f = -grad_mid
        f[1:] -= grad_next[:-1]
        f[1:] -= stretch[:-1]
        f[:-1] -= grad_prev[1:]
        f[:-1] += stretch[:-1]
        tq = -grad_theta[:, 1]
        tq[:-1] -= grad_theta[1:, 0]
        push_share = np.where(free != 0, dot(f, self.catheter_axis), 0.0)
        return f + self.external + contact_force + self.fold_forces(x, free), tq, push_share

    def fold_forces(self, x: np.ndarray, free: np.ndarray) -> np.ndarray:
        """elastic.py ``fold_force``: free node i against nodes i ± 2·span of its coil
        (joined by 2·span edges), the contact law of |x_i − x_j| − d times the
        smaller contact share of the two."""
        span = 2 * self.fold_span
        f = np.zeros_like(x)
        i = np.arange(self.n - span)
        joined = np.ones(i.size, bool)
        for k in range(span):
            joined &= self.has_next[i + k]
        i = i[joined]
        j = i + span
        delta = x[i] - x[j]
        dist = length(delta)
        gap = dist - self.node_radius[i] - self.node_radius[j]
        weight = np.minimum(self.contact_share[i], self.contact_share[j])
        pair = col(weight * contact_force_magnitude(gap, self.p0, self.c0, self.u_linear) / np.maximum(dist, 1e-300)) \
            * delta
        np.add.at(f, i, pair)
        np.add.at(f, j, -pair)
        return np.where(col(free != 0), f, 0.0)

    def compute_forces(self) -> None:
        """Solver.compute_forces at the current state."""
        self.contact_force = self.compute_contacts(self.x, self.free)
        grads = self.vertex_gradients(self.x, self.m1, self.free)
        self.force, self.torque, self.push_share = self.gather_forces(self.x, self.free, grads, self.contact_force)

    # --- integration -------------------------------------------------------------
    def catheter_point(self, depth: np.ndarray):
        """integrate.py ``catheter_point``: points and unit directions (towards the
        tip) on the catheter centerline at arc distance ``depth`` ≥ 0 behind the
        tip; beyond the proximal end the first segment is extended. Walks the
        polyline from the tip, all depths at once."""
        path = self.catheter_path
        remaining = depth.copy()
        point = np.zeros((depth.size, 3))
        direction = np.zeros((depth.size, 3))
        pending = np.ones(depth.size, bool)
        for k in range(path.shape[0] - 1, 0, -1):
            seg = path[k] - path[k - 1]
            seg_len = float(np.sqrt(seg @ seg))
            unit = seg / seg_len
            here = pending & ((remaining <= seg_len) | (k == 1))
            point[here] = path[k] - col(remaining[here]) * unit
            direction[here] = unit
            pending &= ~here
            remaining = np.where(pending, remaining - seg_len, remaining)
        return point, direction

    def damped_speed(self, speed: np.ndarray, a: np.ndarray) -> np.ndarray:
        """integrate.py ``damped_speed``: root s ≥ 0 of s + a (1 − e^(−s/k)) = speed,
        by monotone Newton from the linearised root (6 iterations)."""
        k = self.damping_k
        s = speed / (1.0 + a / k)
        for _ in range(DAMPING_NEWTON_ITERATIONS):
            e = np.exp(-s / k)
            s = s - (s + a * (1.0 - e) - speed) / (1.0 + a / k * e)
        return np.where((a <= 0.0) | (speed <= 0.0), speed, np.maximum(s, 0.0))

    def integrate_nodes(self, force: np.ndarray):
        """integrate.py ``integrate_nodes``: advance the pusher, place nodes behind
        the catheter tip on the centerline (moving with the pusher), hold clamped
        nodes, and step the free ones: v* = v + dt F/m, implicit nonlinear damping
        along v*, x' = x + dt v'."""
        dt = self.dt
        push_step = self.push_speed * dt
        pushed_coils = (self.active_coil >= 0) & (np.arange(self.coil_count) >= self.active_coil)
        advance = self.advance + np.where(pushed_coils, push_step, 0.0)  # integrate.py coil_advance
        sigma = advance[self.coil_of] - self.arc_s
        in_catheter = ~self.fixed & (sigma < 0.0)
        dynamic = ~self.fixed & ~in_catheter

        x = self.x.copy()  # clamped nodes stay put
        v = np.zeros((self.n, 3))
        free = dynamic.astype(np.int32)

        inside = np.flatnonzero(in_catheter)
        point, direction = self.catheter_point(-sigma[inside])
        x[inside] = point
        pushed = pushed_coils[self.coil_of[inside]]
        v[inside] = np.where(col(pushed), self.push_speed * direction, 0.0)

        d = np.flatnonzero(dynamic)
        v_star = self.v[d] + col(dt * self.inv_mass[d]) * force[d]
        speed = length(v_star)
        moving = speed > 0.0
        damped = self.damped_speed(speed, dt * self.damping_c[d] * self.inv_mass[d])
        v_new = np.where(col(moving), v_star * col(damped / np.where(moving, speed, 1.0)), v_star)
        v[d] = v_new
        x[d] = self.x[d] + dt * v_new
        return x, v, free, advance

    def update_frames(self, x_new: np.ndarray, free_new: np.ndarray):
        """integrate.py ``update_frames``: transport each edge's director to its new
        tangent, spin free edges (both nodes free) by their twist rate with linear
        implicit twist damping ω' = (ω + dt T/J)/(1 + dt b/J), re-orthonormalise."""
        dt = self.dt
        m1 = self.m1.copy()  # non-edges keep their director
        omega = np.zeros(self.n)
        i = self.edges
        t_old = normalize(self.x[i + 1] - self.x[i])
        t_new = normalize(x_new[i + 1] - x_new[i])
        m = transport(self.m1[i], t_old, t_new)
        held0, held1 = self.fixed[i], self.fixed[i + 1]
        spins = ((free_new[i] != 0) | held0) & ((free_new[i + 1] != 0) | held1) & ~(held0 & held1)
        inv_j = self.inv_inertia[i]
        w = (self.omega[i] + dt * self.torque[i] * inv_j) / (1.0 + dt * self.twist_damping[i] * inv_j)
        w = np.where(spins, w, 0.0)
        m = np.where(col(spins), rotate_about(m, t_new, w * dt), m)
        m1[i] = director_normal(m, t_new)
        omega[i] = w
        return m1, omega

    def step(self) -> None:
        """Solver.step: forces at the current state, integrate_nodes,
        update_frames, accumulate_push_force, time += dt."""
        self.compute_forces()
        x, v, free, advance = self.integrate_nodes(self.force)
        m1, omega = self.update_frames(x, free)
        total = float(np.sum(self.push_share))
        self.push_accumulator[0] += total
        self.push_accumulator[1] = max(self.push_accumulator[1], total)
        self.x, self.v, self.free, self.advance, self.m1, self.omega = x, v, free, advance, m1, omega
        self.time_s += self.dt

    def run(self, steps: int) -> None:
        for _ in range(int(steps)):
            self.step()

    def take_push_force(self, steps: int) -> tuple[float, float]:
        """Solver.take_push_force: mean and largest step push force (µN) since the last call."""
        total, largest = self.push_accumulator
        self.push_accumulator[:] = 0.0
        return float(total) / max(steps, 1), float(largest)

    # --- measurements ------------------------------------------------------------
    def elastic_energies(self):
        """elastic.py ``elastic_energies``: per-edge stretching, per-vertex bending
        and twisting energy (nJ), every edge/vertex whether free or not."""
        x, m1 = self.x, self.m1
        ws, wb, wt = np.zeros(self.n), np.zeros(self.n), np.zeros(self.n)
        i = self.edges
        stretch = length(x[i + 1] - x[i]) - self.rest_length[i]
        ws[i] = 0.5 * self.k_stretch[i] * stretch * stretch
        j = self.vertices
        t0 = normalize(x[j] - x[j - 1])
        t1 = normalize(x[j + 1] - x[j])
        w = cross(t0, t1)
        phi, psi, chi = angle_factors(length(w), dot(t0, t1))
        kappa = col(psi) * w
        dK0 = material_curvature(kappa, t0, m1[j - 1]) - self.rest_K0[j]
        dK1 = material_curvature(kappa, t1, m1[j]) - self.rest_K1[j]
        wb[j] = 0.25 * self.k_bend[j] * (np.sum(dK0 * dK0, axis=1) + np.sum(dK1 * dK1, axis=1))
        dtau = vertex_twist(t0, m1[j - 1], t1, m1[j]) - self.rest_twist[j]
        wt[j] = 0.5 * self.k_twist[j] * dtau * dtau
        return ws, wb, wt

    def energies(self) -> dict[str, float]:
        """Solver.energies: kinetic (free nodes, translation + edge spin),
        stretching, bending and twisting energy, nJ."""
        fr = self.free != 0
        kinetic = np.where(fr, 0.5 * dot(self.v, self.v) / self.inv_mass, 0.0) \
            + 0.5 * self.omega * self.omega / self.inv_inertia
        ws, wb, wt = self.elastic_energies()
        return {"kinetic_nJ": float(kinetic.sum()), "stretch_nJ": float(ws.sum()),
                "bend_nJ": float(wb.sum()), "twist_nJ": float(wt.sum())}


class _WallTwin:
    """The closed wall in float64 (relative to the model's wall origin, as the
    kernel stores it) with the pseudo-normals of its faces, edges and vertices."""

    def __init__(self, wall):
        self.origin = np.asarray(wall.origin, dtype=np.float64)
        self.vertices = wall.vertices.numpy().astype(np.float64)  # relative to origin
        self.faces = wall.faces.numpy().reshape(-1, 3).astype(np.int64)
        self.owners = np.asarray(wall.owners)
        tri = self.vertices[self.faces]  # (F, 3 corners, 3)
        e0, e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0], tri[:, 2] - tri[:, 1]
        normal = cross(e0, e1)
        # Warp's mesh query skips sliver faces with this test
        sliver = length(normal) / (dot(e0, e0) + dot(e1, e1) + dot(e2, e2)) < 1.0e-6
        self.candidates = np.flatnonzero(~sliver)
        self.face_normal = normalize(normal)  # outward (faces wound with outward normals)
        # angle-weighted vertex pseudo-normals: Σ over incident faces of corner angle × face normal
        angle = np.zeros((len(self.faces), 3))
        for corner in range(3):
            to_next = normalize(tri[:, (corner + 1) % 3] - tri[:, corner])
            to_prev = normalize(tri[:, (corner + 2) % 3] - tri[:, corner])
            angle[:, corner] = np.arccos(np.clip(dot(to_next, to_prev), -1.0, 1.0))
        self.vertex_normal = np.zeros_like(self.vertices)
        np.add.at(self.vertex_normal, self.faces.ravel(),
                  (angle[:, :, None] * self.face_normal[:, None, :]).reshape(-1, 3))
        # edge pseudo-normals: sum of the two adjacent face normals; edge k of a face
        # is the one opposite its corner k
        opposite = np.stack([self.faces[:, [1, 2]], self.faces[:, [2, 0]], self.faces[:, [0, 1]]], axis=1)
        keys = np.sort(opposite.reshape(-1, 2), axis=1)
        _, edge_id = np.unique(keys, axis=0, return_inverse=True)
        edge_id = edge_id.ravel()
        edge_sum = np.zeros((edge_id.max() + 1, 3))
        np.add.at(edge_sum, edge_id, np.repeat(self.face_normal, 3, axis=0))
        self.edge_normal = edge_sum[edge_id].reshape(-1, 3, 3)  # (F, opposite corner, 3)

    def closest(self, p: np.ndarray):
        """Closest face, barycentric weights and feature for each point (brute
        force over all candidate faces, in chunks of points)."""
        faces = self.candidates
        tri = self.vertices[self.faces[faces]]
        face = np.zeros(len(p), np.int64)
        bary = np.zeros((len(p), 3))
        feature = np.zeros(len(p), np.int64)
        rows = max(1, PAIR_CHUNK // max(faces.size, 1))
        for first in range(0, len(p), rows):
            q = p[first:first + rows, None, :]
            u, v, w, feat = closest_point_to_triangle(tri[None, :, 0], tri[None, :, 1], tri[None, :, 2], q)
            c = col(u) * tri[None, :, 0] + col(v) * tri[None, :, 1] + col(w) * tri[None, :, 2]
            best = np.argmin(dot(q - c, q - c), axis=1)
            k = np.arange(len(best))
            face[first:first + rows] = faces[best]
            bary[first:first + rows] = np.stack([u[k, best], v[k, best], w[k, best]], axis=1)
            feature[first:first + rows] = feat[k, best]
        return face, bary, feature

    def pseudo_normal(self, face: np.ndarray, feature: np.ndarray) -> np.ndarray:
        """Angle-weighted pseudo-normal (outward) of the feature of ``face`` that
        holds the closest point: a vertex, an edge, or the face interior."""
        n = self.face_normal[face].copy()
        corner_of_vertex = {VERTEX_A: 0, VERTEX_B: 1, VERTEX_C: 2}
        corner_opposite_edge = {EDGE_BC: 0, EDGE_AC: 1, EDGE_AB: 2}
        for feat, corner in corner_of_vertex.items():
            k = feature == feat
            n[k] = self.vertex_normal[self.faces[face[k], corner]]
        for feat, corner in corner_opposite_edge.items():
            k = feature == feat
            n[k] = self.edge_normal[face[k], corner]
        return n

    def feature_sum(self, p_abs: np.ndarray, radius: np.ndarray, p0: float, c0: float, u_linear: float) -> np.ndarray:
        """contact.py ``wall_feature_sum``: Σ_faces − Σ_edges + Σ_vertices of the law of
        the distance to each closed face, edge and vertex (each edge and vertex once)."""
        p = p_abs - self.origin
        tri = self.vertices[self.faces]  # (F, 3, 3)
        force = np.zeros_like(p)

        def add(closest, sign):  # closest: (points, features, 3)
            delta = p[:, None, :] - closest
            dist = length(delta)
            on = (dist < (radius + c0)[:, None]) & (dist > 1.0e-12)
            gap = dist - radius[:, None]
            magnitude = np.where(on, contact_force_magnitude(gap, p0, c0, u_linear) / np.where(on, dist, 1.0), 0.0)
            return sign * (magnitude[..., None] * delta).sum(axis=1)

        u, v, w, _ = closest_point_to_triangle(tri[None, :, 0], tri[None, :, 1], tri[None, :, 2], p[:, None, :])
        force += add(col(u) * tri[None, :, 0] + col(v) * tri[None, :, 1] + col(w) * tri[None, :, 2], 1.0)
        edges = np.concatenate([self.faces[self.owners & flag != 0][:, pair]
                                for flag, pair in ((1, [0, 1]), (2, [1, 2]), (4, [2, 0]))])
        e0, e1 = self.vertices[edges[:, 0]][None], self.vertices[edges[:, 1]][None]
        seg = e1 - e0
        t = np.clip(dot(p[:, None, :] - e0, seg) / dot(seg, seg), 0.0, 1.0)
        force += add(e0 + col(t) * seg, -1.0)
        corners = np.concatenate([self.faces[self.owners & flag != 0][:, k] for k, flag in enumerate((8, 16, 32))])
        force += add(np.broadcast_to(self.vertices[corners][None], (len(p), len(corners), 3)), 1.0)
        return force

    def query(self, p_abs: np.ndarray):
        """contact.py ``wall_query``: signed distance (mm, > 0 inside the lumen) of
        each point to the wall and the unit normal pointing into the lumen."""
        p = p_abs - self.origin
        face, bary, feature = self.closest(p)
        tri = self.vertices[self.faces[face]]
        closest = col(bary[:, 0]) * tri[:, 0] + col(bary[:, 1]) * tri[:, 1] + col(bary[:, 2]) * tri[:, 2]
        delta = p - closest
        dist = length(delta)
        inside = dot(delta, self.pseudo_normal(face, feature)) <= 0.0  # not in front of the outward normal
        apart = dist > 1.0e-12
        unit = delta / col(np.where(apart, dist, 1.0))
        inward = np.where(col(apart), np.where(col(inside), unit, -unit), -self.face_normal[face])
        return np.where(inside, dist, -dist), inward


# --- timing ------------------------------------------------------------------------
def time_reference_helix(steps: int = 1000, warp_steps: int = 20000, repeats: int = 3) -> list[dict]:
    """Seconds per step of the twin and of the Warp Stepper (graph capture, chunks
    of 100) on MODEL.md's reference helix (60 mm, 3 mm loops, pitch 0.6 mm)
    released from straight, with and without coil contact (best of ``repeats``)."""
    import time

    import warpcoil as wc

    builder = wc.ModelBuilder()
    builder.add_coil(wc.CoilSpec(length_mm=60.0, loop_diameter_mm=3.0, pitch_mm=0.6))
    model = builder.finalize()
    straight = np.zeros((model.node_count, 3))
    straight[:, 0] = model.arc_s.numpy()
    rows = []
    for coil_contact in (False, True):
        solver = wc.Solver(model, coil_contact=coil_contact)
        stepper = wc.Stepper(solver, wc.state_from_positions(model, straight), wc.Control.create(model), chunk=100)
        stepper.run_chunk()  # compile, capture
        warp_s = np.inf
        for _ in range(repeats):
            wc_state = stepper.run_chunk()
            wc_state.x.numpy()  # synchronise
            start = time.perf_counter()
            for _ in range(warp_steps // stepper.chunk):
                stepper.run_chunk()
            stepper.state.x.numpy()
            warp_s = min(warp_s, (time.perf_counter() - start) / warp_steps)
        twin_s = np.inf
        for _ in range(repeats):
            twin = NumpyTwin(model, wc.state_from_positions(model, straight), solver.dt_s, coil_contact=coil_contact)
            start = time.perf_counter()
            twin.run(steps)
            twin_s = min(twin_s, (time.perf_counter() - start) / steps)
        rows.append({"coil_contact": coil_contact, "nodes": model.node_count, "device": str(model.device),
                     "warp_us_per_step": 1e6 * warp_s, "twin_us_per_step": 1e6 * twin_s})
    return rows


if __name__ == "__main__":
    for row in time_reference_helix():
        print(f"coil contact {'on ' if row['coil_contact'] else 'off'} ({row['nodes']} nodes): "
              f"Warp {row['device']} {row['warp_us_per_step']:8.1f} µs/step, "
              f"NumPy twin {row['twin_us_per_step']:8.1f} µs/step, "
              f"ratio {row['twin_us_per_step'] / row['warp_us_per_step']:5.1f}×")
