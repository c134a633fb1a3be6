"""Model: the static, device-ready description of the coils (and later the wall).

Built once by :class:`ModelBuilder` from :class:`~warpcoil.coil.CoilSpec` s
and their rest centerlines; holds no time-dependent data (that is
:class:`~warpcoil.state.State`). Nodes of all coils are stored back to back;
edge i joins nodes i and i+1 when ``has_next[i]`` (the last node of a coil
has no edge), vertex j is an interior node of a coil.

Per-node mass is ``ρ l̄ · mass_scale`` with l̄ the coil's mean segment length;
stiffnesses follow the coil: k_s = EA/l̄_i per edge, k_b = EI/l̄_j and
k_t = GJ/l̄_j per vertex (l̄_j the mean of its two edges, so W_b → ∫ EI κ²/2 ds).
Twist inertia per edge: ``m r²`` with r the winding radius (d − d_w)/2.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import warp as wp


from .coil import CoilSpec
from .kernels import elastic, integrate
from .settings import CatheterSpec, ContactSettings, SimulationSettings

CONTACT_DESIGN_OVERLAP_U = 3.0  # u = 1 − h/c0 at which the step bound takes the contact stiffness (h = −2 c0)


@dataclass
class WallModel:
    """The wall on the device: a Warp BVH mesh (float32, stored relative to
    ``origin``) and float64 copies of its vertices and faces for exact distances."""

    mesh: wp.Mesh
    vertices: wp.array  # vec3d, mm, relative to origin
    faces: wp.array  # int32, flat (3 per triangle), wound with outward normals
    origin: np.ndarray  # mm
    volume_mm3: float
    vertices_mm: np.ndarray  # absolute, for output
    faces_np: np.ndarray

    @staticmethod
    def create(vertices_mm: np.ndarray, faces: np.ndarray, volume_mm3: float, device) -> "WallModel":
        vertices_mm = np.asarray(vertices_mm, dtype=np.float64)
        faces = np.asarray(faces, dtype=np.int32)
        origin = 0.5 * (vertices_mm.min(axis=0) + vertices_mm.max(axis=0))
        local = vertices_mm - origin
        mesh = wp.Mesh(points=wp.array(local.astype(np.float32), dtype=wp.vec3, device=device),
                       indices=wp.array(faces.ravel(), dtype=wp.int32, device=device))
        return WallModel(mesh=mesh, vertices=wp.array(local, dtype=wp.vec3d, device=device),
                         faces=wp.array(faces.ravel(), dtype=wp.int32, device=device), origin=origin,
                         volume_mm3=float(volume_mm3), vertices_mm=vertices_mm, faces_np=faces)


@dataclass(frozen=True)
class ContactModel:
    """Contact parameters resolved for the model's coils."""

    p0_uN: float
    c0_mm: float
    exclusion_edges: int  # same-coil edges this close along the coil never touch (bonded neighbours)
    fold_span: int  # nodes i and i ± 2·fold_span repel when a coil folds sharply (about 2d apart at rest)
    query_radius_mm: float  # edge-midpoint search radius that finds every pair within c0

    def stiffness_uN_mm(self, u: float = CONTACT_DESIGN_OVERLAP_U) -> float:
        """−d|F|/dh of the contact law at u (µN/mm)."""
        return self.p0_uN / ((math.e - 1.0) * self.c0_mm) * (math.exp(u) * (1.0 + u) - 1.0)


def _default_director(t: np.ndarray) -> np.ndarray:
    """A unit vector normal to ``t``, chosen deterministically."""
    axis = np.eye(3)[int(np.argmin(np.abs(t)))]
    d = np.cross(t, axis)
    return d / np.linalg.norm(d)


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
    # topology and per-node data
    has_next: wp.array
    coil_of: wp.array
    arc_s: wp.array  # rest arc length from the coil's distal end, mm
    fixed: wp.array
    inv_mass: wp.array  # 1/g
    damping_c: wp.array  # µN (high-speed limit of the damping force per node)
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
    catheter_path: wp.array
    catheter_axis: np.ndarray  # unit, towards the tip at the tip
    mass_scale: float
    node_radius: wp.array  # d/2 of the node's coil, mm
    contact: ContactModel
    wall: WallModel | None = None

    @property
    def node_count(self) -> int:
        return int(self.rest_positions.shape[0])

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
                _default_director(_unit(positions[f + 1] - positions[f])) for f in self.coil_first
            ])
        m1 = wp.zeros(self.node_count, dtype=wp.vec3d, device=self.device)
        wp.launch(integrate.transported_directors, self.coil_count, device=self.device, inputs=[
            self.array(positions, wp.vec3d), self.array(self.coil_first, wp.int32),
            self.array(self.coil_last, wp.int32), self.array(first_directors, wp.vec3d), m1])
        return m1.numpy()


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


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
        self._forces: list[tuple[int, np.ndarray]] = []

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

    def clamp(self, coil: int, nodes: int = 2) -> None:
        """Clamp the first ``nodes`` nodes of a coil (2 clamps position and direction)."""
        self._fixed.extend(self._node(coil, k) for k in range(nodes))

    def apply_force(self, coil: int, node: int, force_uN) -> None:
        """A constant force (µN) on one node; node −1 is the coil's last node."""
        self._forces.append((self._node(coil, node), np.asarray(force_uN, np.float64)))

    def finalize(self, device: str | wp.context.Device | None = None) -> Model:
        device = wp.get_device(device)
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
        mean_len = np.repeat([edge_len[first[c]:last[c]].mean() for c in range(len(counts))], counts)
        mass = per_coil(lambda c: c.rho) * mean_len * s.mass_scale
        winding_r = per_coil(lambda c: 0.5 * (c.d - c.primary_wire_diameter_mm))
        inertia = mass * winding_r**2
        damping_c = s.damping_uN_per_mm * mean_len * s.mass_scale  # same damping rate c/(m k) when mass-scaled
        vertex_len = np.zeros(n)
        interior = np.zeros(n, bool)
        interior[1:-1] = (has_next[1:-1] == 1) & (has_next[:-2] == 1)
        vertex_len[interior] = 0.5 * (edge_len[1:-1] + edge_len[:-2])[interior[1:-1]]
        with np.errstate(divide="ignore", invalid="ignore"):
            k_stretch = np.where(has_next == 1, per_coil(lambda c: c.EA) / edge_len, 0.0)
            k_bend = np.where(interior, per_coil(lambda c: c.EI) / vertex_len, 0.0)
            k_twist = np.where(interior, per_coil(lambda c: c.GJ) / vertex_len, 0.0)
        fixed = np.zeros(n, np.int32)
        fixed[self._fixed] = 1
        external = np.zeros((n, 3))
        for node, f in self._forces:
            external[node] += f
        path = catheter_path(self.catheter)
        d = per_coil(lambda c: c.d)
        c0 = self.contact.c0_mm if self.contact.c0_mm is not None else 0.1 * float(d.min())
        longest = float(edge_len.max())
        contact_model = ContactModel(
            p0_uN=float(self.contact.P0_uN), c0_mm=float(c0),
            exclusion_edges=int(math.ceil((float(d.max()) + c0) / float(edge_len[has_next == 1].min()))),
            fold_span=max(1, int(math.ceil(float(d.max()) / float(edge_len[has_next == 1].mean()) - 1e-6))),
            query_radius_mm=longest + float(d.max()) + c0)

        arr = lambda v, t: wp.array(v, dtype=t, device=device)  # noqa: E731
        model = Model(
            device=device, coils=tuple(self._coils), coil_first=first, coil_last=last, rest_positions=rest,
            has_next=arr(has_next, wp.int32), coil_of=arr(coil_of, wp.int32), arc_s=arr(arc_s, wp.float64),
            fixed=arr(fixed, wp.int32), inv_mass=arr(1.0 / mass, wp.float64),
            damping_c=arr(damping_c, wp.float64), damping_k=float(s.damping_speed_mm_s),
            external=arr(external, wp.vec3d),
            rest_length=arr(edge_len, wp.float64), k_stretch=arr(k_stretch, wp.float64),
            inv_inertia=arr(1.0 / inertia, wp.float64),
            twist_damping=arr(damping_c / s.damping_speed_mm_s * winding_r**2, wp.float64),
            k_bend=arr(k_bend, wp.float64), k_twist=arr(k_twist, wp.float64),
            rest_K0=wp.zeros(n, dtype=wp.vec2d, device=device), rest_K1=wp.zeros(n, dtype=wp.vec2d, device=device),
            rest_twist=wp.zeros(n, dtype=wp.float64, device=device),
            catheter_path=arr(path, wp.vec3d), catheter_axis=_unit(path[-1] - path[-2]),
            mass_scale=float(s.mass_scale), node_radius=arr(0.5 * d, wp.float64), contact=contact_model,
            wall=None if self.wall is None else WallModel.create(
                self.wall.vertices_mm, self.wall.faces, self.wall.volume_mm3, device),
        )
        rest_m1 = model.directors_along(rest)
        wp.launch(elastic.rest_strains, n, device=device, inputs=[
            model.array(rest, wp.vec3d), model.array(rest_m1, wp.vec3d), model.has_next,
            model.rest_K0, model.rest_K1, model.rest_twist])
        return model
