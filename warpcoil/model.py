"""Model: the static, device-ready description of the coils, catheter and wall.

Built once by :class:`ModelBuilder` from :class:`~warpcoil.coil.CoilSpec` s
and their rest centerlines; holds no time-dependent data (that is
:class:`~warpcoil.state.State`). Nodes of all coils are stored back to back;
edge i joins nodes i and i+1 when ``has_next[i]`` (the last node of a coil
has no edge), vertex j is an interior node of a coil.

A model may hold several independent *worlds* (ensemble members, each its own
coils, catheter and wall, :func:`finalize_ensemble`): one set of launches
advances them all, and nothing couples one world to another.

Masses are lumped on each node's share of the coil (its Voronoi length, half of
each adjacent rest edge): ``ρ (l̄_i−1 + l̄_i)/2 · mass_scale``, so an end node
carries half a segment; the node damping follows the same length (not mass-scaled), and so does
each node's contact (``contact_share`` = l̄_i / the coil's segment length: the
contact law acts per node patch d·l̄_i, ½ P0 at an end node's half patch). Per edge:
twist inertia ``ρ l̄_i r² · mass_scale`` (r the winding radius (d − d_w)/2) and
its damping. Stiffnesses follow the coil: k_s = EA/l̄_i per edge, k_b = EI/l̄_j
and k_t = GJ/l̄_j per vertex (l̄_j the mean of its two edges, so W_b → ∫ EI κ²/2 ds).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
import warp as wp


from .coil import CoilSpec
from .kernels import elastic, integrate
from .settings import CatheterSpec, ContactSettings, SimulationSettings

EDGE_STRETCH_MARGIN = 1.1  # the coil–coil search holds for edges stretched up to 10 % past the longest rest edge
# coil–coil contact at the nodes alone holds two segments crossing at their middles apart up to l0 = 1.5 d (each
# node, l0/2 from the other's axis, inside the other's wire; tests/test_contact.py); a coarser coil adds contact
# samples between its nodes, K − 1 evenly spaced per edge with K = ⌈l0 / d⌉: samples a diameter apart hold
# crossing segments of 2–4.5 d apart at 500 mm/s with their centre lines ≥ 0.66 d apart, where 1.5 d spacing let
# them come to 0.41 d (each sample weighs 1/K; docs/FORMULATION.md "Segments longer than 1.5 d")
NODE_CONTACT_MAX_SEGMENT_D = 1.5
CONTACT_SAMPLE_SPACING_D = 1.0
CONTACT_DESIGN_OVERLAP_U = 3.0  # u = 1 − h/c0 at which the step bound takes the contact stiffness (h = −2 c0)


@dataclass
class WallModel:
    """The wall on the device: a Warp BVH mesh (float32, stored relative to
    ``origin``) and float64 copies of its vertices and faces for exact distances."""

    mesh: wp.Mesh
    vertices: wp.array  # vec3d, mm, relative to origin
    faces: wp.array  # int32, flat (3 per triangle), wound with outward normals
    owners: np.ndarray  # int32 per triangle: the edges and vertices it counts in the wall's feature sum
    origin: np.ndarray  # mm
    volume_mm3: float
    vertices_mm: np.ndarray  # absolute, for output
    faces_np: np.ndarray
    fields: dict = field(default_factory=dict, repr=False, compare=False)  # narrow-band SDFs built (wall_field.py)

    @staticmethod
    def create(vertices_mm: np.ndarray, faces: np.ndarray, volume_mm3: float, device) -> "WallModel":
        vertices_mm = np.asarray(vertices_mm, dtype=np.float64)
        faces = np.asarray(faces, dtype=np.int32)
        origin = 0.5 * (vertices_mm.min(axis=0) + vertices_mm.max(axis=0))
        local = vertices_mm - origin
        mesh = wp.Mesh(points=wp.array(local.astype(np.float32), dtype=wp.vec3, device=device),
                       indices=wp.array(faces.ravel(), dtype=wp.int32, device=device),
                       support_winding_number=True)  # contact.wall_query confirms "outside" by it
        return WallModel(mesh=mesh, vertices=wp.array(local, dtype=wp.vec3d, device=device),
                         faces=wp.array(faces.ravel(), dtype=wp.int32, device=device),
                         owners=feature_owners(faces), origin=origin,
                         volume_mm3=float(volume_mm3), vertices_mm=vertices_mm, faces_np=faces)


def feature_owners(faces: np.ndarray) -> np.ndarray:
    """Per triangle abc, the flags (contact.OWN_EDGE_AB … OWN_VERTEX_C) of the edges
    and vertices it counts in the wall's feature sum: each edge and each vertex
    is counted once, by the lowest-numbered triangle that holds it."""
    faces = np.asarray(faces, dtype=np.int64)
    count = len(faces)
    owners = np.zeros(count, np.int32)
    index = np.repeat(np.arange(count), 3)
    edges = np.sort(np.stack([faces.ravel(), np.roll(faces, -1, axis=1).ravel()], axis=1), axis=1)  # ab, bc, ca
    _, first, edge_id = np.unique(edges, axis=0, return_index=True, return_inverse=True)
    owns_edge = (index[first][edge_id.ravel()] == index).reshape(count, 3)
    owners |= (owns_edge * np.array([1, 2, 4])).sum(axis=1).astype(np.int32)
    first_face = np.full(int(faces.max()) + 1, count)
    np.minimum.at(first_face, faces.ravel(), index)
    for k, flag in enumerate((8, 16, 32)):  # vertices a, b, c
        owners[first_face[faces[:, k]] == np.arange(count)] |= flag
    return owners


@dataclass(frozen=True)
class ContactModel:
    """Contact parameters resolved for the model's coils."""

    p0_uN: float
    c0_mm: float
    exclusion_edges: int  # same-coil edges this close along the coil never touch (bonded neighbours)
    fold_span: int  # nodes i and i ± 2·fold_span repel when a coil folds sharply (about 2d apart at rest)
    query_radius_mm: float  # edge-midpoint search radius that finds every pair within c0 (largest of the worlds')
    friction_wall: float = 0.0  # Coulomb coefficients per pair type (kernels/friction.py)
    friction_coil: float = 0.0
    friction_catheter: float = 0.0
    friction_speed_mm_s: float = 0.01  # regularisation velocity: the fastest a stuck contact creeps

    @property
    def frictional(self) -> bool:
        return max(self.friction_wall, self.friction_coil, self.friction_catheter) > 0.0

    def stiffness_uN_mm(self, u: float = CONTACT_DESIGN_OVERLAP_U) -> float:
        """−d|F|/dh of the contact law at u (µN/mm)."""
        return self.p0_uN / ((math.e - 1.0) * self.c0_mm) * (math.exp(u) * (1.0 + u) - 1.0)


def default_director(t: np.ndarray) -> np.ndarray:
    """A unit vector normal to ``t``, chosen deterministically."""
    axis = np.eye(3)[int(np.argmin(np.abs(t)))]
    d = np.cross(t, axis)
    return d / np.linalg.norm(d)


def voronoi_lengths(edge_len_mm: np.ndarray) -> np.ndarray:
    """Each node's Voronoi length (mm): half of each edge it ends, from per-node edge lengths (the edge from
    node i to i + 1 at i, 0 at a coil's last node, as Model.rest_length holds them), so a coil's nodes sum
    to its length and an end node counts half an edge."""
    edge = np.asarray(edge_len_mm, dtype=np.float64)
    edge_prev = np.concatenate([[0.0], edge[:-1]])  # (a coil's first node: the last node's 0 before it)
    return 0.5 * (edge_prev + edge)


def contact_samples_per_edge(segment_mm: np.ndarray, d_mm: np.ndarray) -> np.ndarray:
    """Coil–coil contact samples per edge (int32, ≥ 1) of coils with segment length
    ``segment_mm`` and wire diameter ``d_mm`` (mm): 1 (the nodes) up to
    NODE_CONTACT_MAX_SEGMENT_D · d, else the fewest K with l0 / K ≤ CONTACT_SAMPLE_SPACING_D · d."""
    ratio = np.asarray(segment_mm, float) / np.asarray(d_mm, float)
    samples = np.ceil(ratio / CONTACT_SAMPLE_SPACING_D * (1.0 - 1e-9))
    return np.where(ratio <= NODE_CONTACT_MAX_SEGMENT_D * (1.0 + 1e-9), 1, samples).astype(np.int32)


def catheter_path(spec: CatheterSpec) -> np.ndarray:
    """Catheter centerline from proximal end to tip, mm (straight: 2 points)."""
    tip = np.asarray(spec.tip_mm, dtype=np.float64)
    if spec.centerline_mm is not None:
        return np.asarray(spec.centerline_mm, dtype=np.float64)
    direction = np.asarray(spec.direction, dtype=np.float64)
    direction = direction / np.linalg.norm(direction)
    return np.stack([tip - 100.0 * direction, tip])


@dataclass
class Model:
    """Device arrays (float64, mm·g·s) and the host-side facts about them."""

    device: wp.context.Device
    coils: tuple[CoilSpec, ...]
    coil_first: np.ndarray  # first node of each coil
    coil_last: np.ndarray  # last node of each coil
    rest_positions: np.ndarray  # (N, 3) pre-shapes, back to back
    rest_x: wp.array  # the same on the device (vec3d, mm): rest clearances of coil–coil pairs
    # topology and per-node data
    has_next: wp.array
    coil_of: wp.array
    arc_s: wp.array  # rest arc length from the coil's distal end, mm
    fixed: wp.array
    clamp_tangent: wp.array  # vec3d per node: unit clamp direction at a coil's clamped first node, else 0
    clamp_director: wp.array  # vec3d per node: the clamp's material director (normal to clamp_tangent), else 0
    inv_mass: wp.array  # 1/g
    damping_c: wp.array  # µN (high-speed limit of the damping force per node)
    contact_share: wp.array  # per node: weight of its contact law, l̄_i / its coil's segment length (½ at a free end)
    contact_samples: wp.array  # per node: its coil's coil–coil contact samples per edge K (1: the nodes alone)
    damping_k: float  # mm/s
    external: wp.array  # µN, constant applied forces
    # per edge
    rest_length: wp.array
    k_stretch: wp.array  # µN/mm
    inv_inertia: wp.array  # 1/(g·mm²)
    twist_damping: wp.array  # µN·mm·s
    # per vertex
    k_bend: wp.array  # µN·mm
    k_twist: wp.array  # µN·mm
    rest_K0: wp.array
    rest_K1: wp.array
    rest_twist: wp.array
    catheter_path: wp.array  # every world's catheter centerline, proximal → tip, back to back
    catheter_first: wp.array  # per world: its first catheter point
    catheter_count: wp.array  # per world: its number of catheter points
    catheter_axes: np.ndarray  # (worlds, 3) unit, towards the tip at the tip
    catheter_axis_of: wp.array  # the same, on the device
    mass_scale: float
    node_radius: wp.array  # d/2 of the node's coil, mm
    contact: ContactModel
    # worlds (ensemble members)
    world_of: wp.array  # per node
    coil_world: wp.array  # per coil
    world_first_node: np.ndarray
    world_last_node: np.ndarray
    world_first_coil: np.ndarray  # (worlds + 1,): world w owns coils [first[w], first[w + 1])
    world_node_range: wp.array  # (worlds, 2) int32: first and last node
    query_radius_of: wp.array  # per world: its own coil–coil search radius (mm), as a single run has it
    world_walls: list  # per world: its WallModel or None
    wall_mesh: wp.array  # uint64 per world (0: no wall)
    wall_face_first: wp.array  # per world: its first triangle in wall_faces
    wall_origin: wp.array  # vec3d per world
    wall_vertices: wp.array  # every distinct wall's vertices (float64, relative to its origin), back to back
    wall_faces: wp.array  # ... and faces (indices into wall_vertices), flat
    wall_owners: wp.array  # ... and per face the edges and vertices it counts (contact.wall_feature_sum)


    # balloon (kernels/devices.py): per world its axis stations, back to back, and their capped radii (mm)
    balloon_stations: wp.array | None = None
    balloon_cap_radius: wp.array | None = None
    balloon_first: wp.array | None = None
    balloon_count: wp.array | None = None
    balloon_inflation: wp.array | None = None  # per world, 0..1, set by the host between frames

    # stent struts (fixed rods), every world's back to back
    strut_start: wp.array | None = None
    strut_end: wp.array | None = None
    strut_world: wp.array | None = None
    strut_radius_mm: float = 0.0
    strut_host: tuple | None = None  # (starts, ends, world) numpy, for output
    _host: dict = field(default_factory=dict, init=False, repr=False, compare=False)  # host(): copies kept

    def host(self, name: str) -> np.ndarray:
        """The static array ``name`` on the host, copied once and kept (on a GPU each ``.numpy()``
        copies the whole array: per-world loops over an ensemble of B members would copy it B
        times). For arrays that stay fixed after :meth:`ModelBuilder.finalize`; one that is
        changed later (a retracted coil's topology) is :meth:`forget_host`-ed."""
        if name not in self._host:
            self._host[name] = getattr(self, name).numpy()
        return self._host[name]

    def forget_host(self, *names: str) -> None:
        """Drop the kept host copies of ``names`` (arrays just changed on the device)."""
        for name in names:
            self._host.pop(name, None)

    @property
    def has_stent(self) -> bool:
        return self.strut_host is not None and len(self.strut_host[0]) > 0

    @property
    def has_balloon(self) -> bool:
        return self.balloon_count is not None and int(self.host("balloon_count").max()) >= 2

    def set_inflation(self, world: int, fraction: float) -> None:
        self.balloon_inflation[world:world + 1].fill_(float(fraction))

    @property
    def node_count(self) -> int:
        return int(self.rest_positions.shape[0])

    @property
    def world_count(self) -> int:
        return len(self.world_first_node)

    @property
    def catheter_axis(self) -> np.ndarray:
        """The catheter axis at the tip of world 0 (unit)."""
        return self.catheter_axes[0]

    @property
    def wall(self) -> "WallModel | None":
        """World 0's wall."""
        return self.world_walls[0]

    def world_nodes(self, world: int) -> slice:
        return slice(int(self.world_first_node[world]), int(self.world_last_node[world]) + 1)

    def world_coils(self, world: int) -> range:
        return range(int(self.world_first_coil[world]), int(self.world_first_coil[world + 1]))

    @property
    def coil_count(self) -> int:
        return len(self.coils)

    def node_slice(self, coil: int) -> slice:
        return slice(int(self.coil_first[coil]), int(self.coil_last[coil]) + 1)

    def array(self, values, dtype) -> wp.array:
        return wp.array(values, dtype=dtype, device=self.device)

    def directors_along(self, positions: np.ndarray, first_directors: np.ndarray | None = None) -> np.ndarray:
        """Twist-free (Bishop) directors along each coil of ``positions``."""
        if first_directors is None:
            first_directors = np.stack([
                default_director(_unit(positions[f + 1] - positions[f])) for f in self.coil_first
            ])
            clamp_t, clamp_d = self.clamp_tangent.numpy(), self.clamp_director.numpy()
            for c, f in enumerate(self.coil_first):  # a clamped coil starts untwisted at its clamp
                if np.any(clamp_t[f] != 0.0) and np.any(clamp_d[f] != 0.0):
                    t0 = _unit(positions[f + 1] - positions[f])[None]
                    first_directors[c] = transport(clamp_d[f][None], clamp_t[f][None], t0)[0]
        m1 = wp.zeros(self.node_count, dtype=wp.vec3d, device=self.device)
        wp.launch(integrate.transported_directors, self.coil_count, device=self.device, inputs=[
            self.array(positions, wp.vec3d), self.array(self.coil_first, wp.int32),
            self.array(self.coil_last, wp.int32), self.array(first_directors, wp.vec3d), m1])
        return m1.numpy()


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def transport(v: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rows of ``v`` carried by the smallest rotation from unit ``a`` to unit ``b``
    (rod.py ``transport``), made unit and normal to ``b``."""
    k = np.cross(a, b)
    c = np.sum(a * b, axis=1, keepdims=True)
    if np.any(c < -0.999999999):
        raise ValueError("clamp: the clamp direction reverses the coil's first edge")
    out = v + np.cross(k, v) + np.cross(k, np.cross(k, v)) / (1.0 + c)
    out -= np.sum(out * b, axis=1, keepdims=True) * b
    return out / np.linalg.norm(out, axis=1)[:, None]


class ModelBuilder:
    """Collects coils and boundary conditions, then :meth:`finalize` s a Model."""

    def __init__(self, catheter: CatheterSpec | None = None, settings: SimulationSettings | None = None,
                 contact: ContactSettings | None = None, wall=None):
        """``wall``: a :class:`warpcoil.wall.WallMesh` (closed, outward normals) or None."""
        self.catheter = catheter or CatheterSpec()
        self.settings = settings or SimulationSettings()
        self.contact = contact or ContactSettings()
        self.wall = wall
        self._coils: list[CoilSpec] = []
        self._rest: list[np.ndarray] = []
        self._fixed: list[int] = []
        self._clamps: dict[int, np.ndarray | None] = {}  # coil → clamp direction at its node 0 (None: rest)
        self._forces: list[tuple[int, np.ndarray]] = []
        self._body_acceleration = np.zeros(3)
        self.balloon: tuple[np.ndarray, np.ndarray] | None = None  # (stations mm, capped radii mm)
        self.stent: tuple[np.ndarray, np.ndarray, float] | None = None  # (strut starts, ends mm, strut radius mm)

    def add_coil(self, spec: CoilSpec, rest_centerline: np.ndarray | None = None) -> int:
        """Add a coil (rest centerline from its pre-shape unless given, mm); returns its index."""
        if rest_centerline is None:
            from . import preshape
            rest = preshape.rest_centerline(spec)
        else:
            rest = np.asarray(rest_centerline, np.float64)
        if rest.ndim != 2 or rest.shape[1] != 3 or rest.shape[0] < 3:
            raise ValueError("a rest centerline needs at least 3 points (two segments) of x, y, z")
        self._coils.append(spec)
        self._rest.append(rest)
        return len(self._coils) - 1

    def _node(self, coil: int, node: int) -> int:
        offset = sum(len(r) for r in self._rest[:coil])
        return offset + (node % len(self._rest[coil]))

    def clamp(self, coil: int, node: int = 0, tangent: bool = True, direction=None) -> None:
        """Clamp a coil at ``node`` (−1: its last node): the node's position is held.

        With ``tangent`` (only at node 0) the coil's tangent *at the node* and its
        material frame there are held too: the clamped section is node 0 itself.
        The tangent is ``direction`` (unit or not; default the rest direction of the
        first edge), and the pre-shape leaves the clamp straight and untwisted.
        Discretely, vertex 0 gets a virtual, fixed previous edge along the clamp
        direction and the half Voronoi cell l̄_0/2 of a boundary node, so it bends
        with k_b = EI/(l̄_0/2) and twists with k_t = GJ/(l̄_0/2) — the half of a
        mirror-symmetric rod, second order like the interior (docs/FORMULATION.md)."""
        index = self._node(coil, node)
        self._fixed.append(index)
        if not tangent:
            return
        if index != self._node(coil, 0):
            raise ValueError(f"clamp: a tangent can be held only at node 0 of a coil, not node {node}: "
                             f"put the clamped end first, or clamp the position alone (tangent=False)")
        if direction is not None:
            direction = np.asarray(direction, np.float64)
            if direction.shape != (3,) or not np.isfinite(direction).all() or np.linalg.norm(direction) == 0.0:
                raise ValueError(f"clamp: direction must be a non-zero 3-vector, got {direction}")
            direction = direction / np.linalg.norm(direction)
        self._clamps[coil] = direction

    def apply_force(self, coil: int, node: int, force_uN) -> None:
        """A constant force (µN) on one node; node −1 is the coil's last node."""
        self._forces.append((self._node(coil, node), np.asarray(force_uN, np.float64)))

    def body_acceleration(self, acceleration_mm_s2) -> None:
        """A uniform body force m·g (µN) on every node, g in mm/s² (m the scaled node mass,
        so the acceleration it causes does not depend on mass_scale)."""
        self._body_acceleration = np.asarray(acceleration_mm_s2, np.float64)

    def finalize(self, device: str | wp.context.Device | None = None) -> Model:
        """The device-ready Model of this builder's one world."""
        return finalize_ensemble([self], device)

    def world_arrays(self) -> dict:
        """Host arrays of this builder's world (numpy, node/coil indices local to it)."""
        if not self._coils:
            raise ValueError("a model needs at least one coil")
        s = self.settings
        counts = np.array([len(r) for r in self._rest])
        first = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int32)
        last = (first + counts - 1).astype(np.int32)
        n = int(counts.sum())
        rest = np.concatenate(self._rest)
        has_next = np.ones(n, np.int32)
        has_next[last] = 0
        coil_of = np.repeat(np.arange(len(counts), dtype=np.int32), counts)

        edge_len = np.zeros(n)
        edge_len[has_next == 1] = np.linalg.norm(rest[1:] - rest[:-1], axis=1)[has_next[:-1] == 1]
        arc_s = np.zeros(n)
        for c in range(len(counts)):  # per coil, not per node
            sl = slice(first[c], last[c] + 1)
            arc_s[sl] = np.concatenate([[0.0], np.cumsum(edge_len[first[c]:last[c]])])

        per_coil = lambda f: np.repeat([f(c) for c in self._coils], counts)  # noqa: E731
        node_len = voronoi_lengths(edge_len)  # half a segment at a coil end
        rho = per_coil(lambda c: c.rho)
        mass = rho * node_len * s.mass_scale
        winding_r = per_coil(lambda c: 0.5 * (c.d - c.primary_wire_diameter_mm))
        edge_prev = np.concatenate([[0.0], edge_len[:-1]])
        spin_len = np.where(has_next == 1, edge_len, edge_prev)  # per edge; a coil's last index repeats its edge
        inertia = rho * spin_len * s.mass_scale * winding_r**2
        damping_c = s.damping_uN_per_mm * node_len  # not mass-scaled: the creeping motion c·v ≈ F stays the true one
        segment = np.repeat([edge_len[f:l].mean() for f, l in zip(first, last)], counts)  # the coil's l0
        contact_share = node_len / segment  # its contact per unit mass is every node's of its coil
        contact_samples = contact_samples_per_edge(segment, per_coil(lambda c: c.d))
        twist_damping = s.damping_uN_per_mm * spin_len / s.damping_speed_mm_s * winding_r**2
        vertex_len = np.zeros(n)
        interior = np.zeros(n, bool)
        interior[1:-1] = (has_next[1:-1] == 1) & (has_next[:-2] == 1)
        vertex_len[interior] = 0.5 * (edge_len[1:-1] + edge_len[:-2])[interior[1:-1]]
        clamp_tangent = np.zeros((n, 3))
        for c, direction in self._clamps.items():  # vertex 0 with a virtual edge of length 0: half a cell
            j = first[c]
            clamp_tangent[j] = _unit(rest[j + 1] - rest[j]) if direction is None else direction
            interior[j] = True
            vertex_len[j] = 0.5 * edge_len[j]
        with np.errstate(divide="ignore", invalid="ignore"):
            k_stretch = np.where(has_next == 1, per_coil(lambda c: c.EA) / edge_len, 0.0)
            k_bend = np.where(interior, per_coil(lambda c: c.EI) / vertex_len, 0.0)
            k_twist = np.where(interior, per_coil(lambda c: c.GJ) / vertex_len, 0.0)
        fixed = np.zeros(n, np.int32)
        fixed[self._fixed] = 1
        external = np.zeros((n, 3))
        for node, f in self._forces:
            external[node] += f
        external += mass[:, None] * self._body_acceleration
        d = per_coil(lambda c: c.d)
        c0 = self.contact.c0_mm if self.contact.c0_mm is not None else 0.1 * float(d.min())
        contact_model = ContactModel(
            p0_uN=float(self.contact.P0_uN), c0_mm=float(c0),
            exclusion_edges=int(math.ceil((float(d.max()) + c0) / float(edge_len[has_next == 1].min()))),
            fold_span=max(1, int(math.ceil(float(d.max()) / float(edge_len[has_next == 1].mean()) - 1e-6))),
            query_radius_mm=EDGE_STRETCH_MARGIN * float(edge_len.max()) + float(d.max()) + c0,
            friction_wall=float(self.contact.friction_wall), friction_coil=float(self.contact.friction_coil),
            friction_catheter=float(self.contact.friction_catheter),
            friction_speed_mm_s=float(self.contact.friction_speed_mm_s))
        return dict(
            coils=list(self._coils), coil_first=first, coil_last=last, rest=rest, has_next=has_next,
            coil_of=coil_of, arc_s=arc_s, fixed=fixed, clamp_tangent=clamp_tangent, mass=mass, damping_c=damping_c,
            contact_share=contact_share, contact_samples=contact_samples, external=external,
            edge_len=edge_len, k_stretch=k_stretch, inertia=inertia,
            twist_damping=twist_damping, k_bend=k_bend, k_twist=k_twist,
            radius=0.5 * d, path=catheter_path(self.catheter), contact=contact_model,
            mass_scale=float(s.mass_scale), damping_k=float(s.damping_speed_mm_s), wall=self.wall,
            balloon=self.balloon, stent=self.stent)


class EnsembleError(ValueError):
    """Worlds that cannot share one set of launches (they differ in a scalar the kernels share)."""


def _shared(worlds: list[dict], key: str, what: str):
    values = {w[key] for w in worlds}
    if len(values) > 1:
        raise EnsembleError(f"ensemble members differ in {what} ({sorted(map(str, values))}); "
                            f"run them in separate ensembles")
    return values.pop()


def finalize_ensemble(builders: list[ModelBuilder], device: str | wp.context.Device | None = None) -> Model:
    """One Model holding each builder's world, back to back (world w = builders[w]).

    The worlds must share the contact law (P0, c0, bonded-neighbour and fold
    spans: the contact kernels take them as scalars), the damping speed and the
    mass scale; the neighbour search radius is the largest of theirs. Worlds
    with the same WallMesh object share one BVH."""
    device = wp.get_device(device)
    worlds = [b.world_arrays() for b in builders]
    contacts = [w["contact"] for w in worlds]
    for key, what in (("p0_uN", "contact P0_uN"), ("c0_mm", "contact c0_mm"),
                      ("exclusion_edges", "bonded-neighbour span (wire diameter / segment length)"),
                      ("fold_span", "fold span (wire diameter / segment length)"),
                      ("friction_wall", "contact friction_wall"), ("friction_coil", "contact friction_coil"),
                      ("friction_catheter", "contact friction_catheter"),
                      ("friction_speed_mm_s", "contact friction_speed_mm_s")):
        _shared([{key: getattr(c, key)} for c in contacts], key, what)
    damping_k = _shared(worlds, "damping_k", "simulation.damping_speed_mm_s")
    mass_scale = _shared(worlds, "mass_scale", "simulation.mass_scale")
    contact_model = replace(contacts[0], query_radius_mm=max(c.query_radius_mm for c in contacts))
    query_radius = np.array([c.query_radius_mm for c in contacts])

    node_counts = np.array([len(w["rest"]) for w in worlds])
    coil_counts = np.array([len(w["coils"]) for w in worlds])
    node_base = np.concatenate([[0], np.cumsum(node_counts)[:-1]])
    coil_base = np.concatenate([[0], np.cumsum(coil_counts)])
    cat = lambda key: np.concatenate([w[key] for w in worlds])  # noqa: E731
    coil_first = np.concatenate([w["coil_first"] + b for w, b in zip(worlds, node_base)]).astype(np.int32)
    coil_last = np.concatenate([w["coil_last"] + b for w, b in zip(worlds, node_base)]).astype(np.int32)
    coil_of = np.concatenate([w["coil_of"] + b for w, b in zip(worlds, coil_base)]).astype(np.int32)
    paths = [w["path"] for w in worlds]
    path_counts = np.array([len(p) for p in paths], np.int32)
    axes = np.stack([_unit(p[-1] - p[-2]) for p in paths])

    arr = lambda v, t: wp.array(v, dtype=t, device=device)  # noqa: E731
    walls, wall_models = _ensemble_walls([w["wall"] for w in worlds], device)
    n = int(node_counts.sum())
    model = Model(
        device=device, coils=tuple(c for w in worlds for c in w["coils"]), coil_first=coil_first,
        coil_last=coil_last, rest_positions=cat("rest"), rest_x=arr(cat("rest"), wp.vec3d),
        has_next=arr(cat("has_next"), wp.int32), coil_of=arr(coil_of, wp.int32), arc_s=arr(cat("arc_s"), wp.float64),
        fixed=arr(cat("fixed"), wp.int32), clamp_tangent=arr(cat("clamp_tangent"), wp.vec3d),
        clamp_director=arr(np.zeros((n, 3)), wp.vec3d), inv_mass=arr(1.0 / cat("mass"), wp.float64),
        damping_c=arr(cat("damping_c"), wp.float64), contact_share=arr(cat("contact_share"), wp.float64),
        contact_samples=arr(cat("contact_samples"), wp.int32),
        damping_k=damping_k, external=arr(cat("external"), wp.vec3d),
        rest_length=arr(cat("edge_len"), wp.float64), k_stretch=arr(cat("k_stretch"), wp.float64),
        inv_inertia=arr(1.0 / cat("inertia"), wp.float64), twist_damping=arr(cat("twist_damping"), wp.float64),
        k_bend=arr(cat("k_bend"), wp.float64), k_twist=arr(cat("k_twist"), wp.float64),
        rest_K0=wp.zeros(n, dtype=wp.vec2d, device=device), rest_K1=wp.zeros(n, dtype=wp.vec2d, device=device),
        rest_twist=wp.zeros(n, dtype=wp.float64, device=device),
        catheter_path=arr(np.concatenate(paths), wp.vec3d),
        catheter_first=arr(np.concatenate([[0], np.cumsum(path_counts)[:-1]]).astype(np.int32), wp.int32),
        catheter_count=arr(path_counts, wp.int32), catheter_axes=axes, catheter_axis_of=arr(axes, wp.vec3d),
        mass_scale=mass_scale, node_radius=arr(cat("radius"), wp.float64), contact=contact_model,
        world_of=arr(np.repeat(np.arange(len(worlds), dtype=np.int32), node_counts), wp.int32),
        coil_world=arr(np.repeat(np.arange(len(worlds), dtype=np.int32), coil_counts), wp.int32),
        world_first_node=node_base.astype(np.int64), world_last_node=(node_base + node_counts - 1).astype(np.int64),
        world_first_coil=coil_base.astype(np.int64),
        world_node_range=arr(np.stack([node_base, node_base + node_counts - 1], 1).astype(np.int32), wp.int32),
        query_radius_of=arr(query_radius, wp.float64),
        world_walls=wall_models, **walls)
    balloons = [w["balloon"] or (np.zeros((0, 3)), np.zeros(0)) for w in worlds]
    counts = np.array([len(b[1]) for b in balloons], np.int32)
    model.balloon_stations = arr(np.concatenate([b[0] for b in balloons] + [np.zeros((1, 3))]), wp.vec3d)
    model.balloon_cap_radius = arr(np.concatenate([b[1] for b in balloons] + [np.zeros(1)]), wp.float64)
    model.balloon_first = arr(np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int32), wp.int32)
    model.balloon_count = arr(counts, wp.int32)
    model.balloon_inflation = arr(np.ones(len(worlds)), wp.float64)
    stents = [(w["stent"], k) for k, w in enumerate(worlds) if w["stent"] is not None]
    if stents:
        starts = np.concatenate([s[0] for s, _ in stents])
        ends = np.concatenate([s[1] for s, _ in stents])
        world = np.concatenate([np.full(len(s[0]), k, np.int32) for s, k in stents])
        model.strut_start, model.strut_end = arr(starts, wp.vec3d), arr(ends, wp.vec3d)
        model.strut_world = arr(world, wp.int32)
        model.strut_radius_mm = max(float(s[2]) for s, _ in stents)
        model.strut_host = (starts, ends, world)
    rest_m1 = model.directors_along(model.rest_positions)
    clamp_t = cat("clamp_tangent")
    clamped = np.flatnonzero(np.linalg.norm(clamp_t, axis=1) > 0.0)
    if clamped.size:  # the clamp's director: the rest director of edge 0 carried to the clamp direction
        t0 = model.rest_positions[clamped + 1] - model.rest_positions[clamped]
        t0 /= np.linalg.norm(t0, axis=1)[:, None]
        director = np.zeros((n, 3))
        director[clamped] = transport(rest_m1[clamped], t0, clamp_t[clamped])
        model.clamp_director.assign(director)
    wp.launch(elastic.rest_strains, n, device=device, inputs=[
        model.array(model.rest_positions, wp.vec3d), model.array(rest_m1, wp.vec3d), model.has_next,
        model.clamp_tangent, model.clamp_director, model.rest_K0, model.rest_K1, model.rest_twist])
    return model


def _ensemble_walls(meshes: list, device) -> tuple[dict, list]:
    """Device wall arrays for every world: one BVH per distinct WallMesh object,
    their float64 vertices and faces back to back, per world its mesh id, first
    face and origin (id 0 where a world has no wall)."""
    distinct: dict[int, WallModel] = {}
    face_first: dict[int, int] = {}
    vertices, faces, owners = [], [], []
    vertex_base = face_base = 0
    for mesh in meshes:
        if mesh is None or id(mesh) in distinct:
            continue
        model = WallModel.create(mesh.vertices_mm, mesh.faces, mesh.volume_mm3, device)
        distinct[id(mesh)] = model
        face_first[id(mesh)] = face_base
        vertices.append(model.vertices_mm - model.origin)
        faces.append(model.faces_np.ravel() + vertex_base)
        owners.append(model.owners)
        vertex_base += len(model.vertices_mm)
        face_base += len(model.faces_np)
    models = [None if m is None else distinct[id(m)] for m in meshes]
    arr = lambda v, t: wp.array(v, dtype=t, device=device)  # noqa: E731
    return dict(
        wall_mesh=arr(np.array([0 if m is None else m.mesh.id for m in models], np.uint64), wp.uint64),
        wall_face_first=arr(np.array([0 if m is None else face_first[id(mesh)] for m, mesh in zip(models, meshes)],
                                     np.int32), wp.int32),
        wall_origin=arr(np.array([np.zeros(3) if m is None else m.origin for m in models]), wp.vec3d),
        wall_vertices=arr(np.concatenate(vertices) if vertices else np.zeros((1, 3)), wp.vec3d),
        wall_faces=arr(np.concatenate(faces).astype(np.int32) if faces else np.zeros(3, np.int32), wp.int32),
        wall_owners=arr(np.concatenate(owners).astype(np.int32) if owners else np.zeros(1, np.int32), wp.int32),
    ), models
