"""Solver: advances a State by semi-implicit Euler steps of the model's forces.

``solver.step(state_in, state_out, control, dt)`` is one step (a fixed list of
kernel launches, so whole chunks of steps are captured as one graph and
replayed: :class:`Stepper`). The step size is checked against the explicit
stability bound of the stiffest term (:func:`stable_step_bound`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
import warp as wp

from .kernels import contact, devices, elastic, friction, integrate, wall_measure
from .model import Model
from .settings import DEFAULT_DT_SAFETY
from .state import State, new_state_like
from .wall_field import DEFAULT_VOXEL_MM, GRAD_TOLERANCE, field_error_bound_mm, wall_field_for

SPEED_LIMIT_MM_S = 1.0e5  # 100 m/s: far beyond any whip of a released coil end; a node this fast has gone unstable
WALL_SEARCH_MM = 0.1  # wall search beyond the contact range; a step moves a node ~1e-3 mm
CONTACTS_PER_NODE = 4  # contacts a node may press on at once, for the contact term of the step bound
CONTACTS_AT_ONSET = 8  # ... and in a dense pack, for where the contact law turns linear
WALL_QUERIES = ("sdf", "bvh")  # wall distance from the narrow-band field (BVH where untrusted), or the BVH only
FIELD_REGION_MM = 1.0  # the wall field covers the loop diameter + this around the catheter tip (BVH beyond)
NEIGHBOUR_SKIN_MM = 0.2  # coil–coil neighbour grid rebuilt when a midpoint moved half this (seed case: 0.2 beats 0.05 by ~8 %, bit-identical)
NEIGHBOUR_CAPACITY = 64  # edges per neighbour list; an edge with more searches the grid instead
TOUCHING_PER_EDGE = 16  # touching partners an edge's record holds (more: the implicit step searches its list)
WALL_GUARD_STEPS = 1000  # a node anchored away from the wall is searched again at least this often
NEIGHBOUR_BUILDS = ("auto", "grid", "walk")  # how the neighbour lists are built (Solver's neighbour_build)
# "auto" walks the edges (contact.walk_neighbours) on the CPU for a single world of at most this many nodes (an
# ensemble keeps the grid: one sort for all its worlds against a walk per world, not measured), else builds the hash
# grid (Warp's CPU build sorts 65 536 buckets whatever the point count). Measured, one
# world packed dense (a coil at its pre-shape): walk / grid 68 / 143 µs at 206 nodes, 153 / 186 at 309, 267 / 236 at
# 412; in the push (most edges strung along the catheter) the walk is cheaper still (docs/FORMULATION.md "Implicit
# step: the neighbour lists without the hash grid")
NEIGHBOUR_WALK_MAX_NODES = 360


def wall_field_extent(model: Model, wall_search_mm: float = WALL_SEARCH_MM) -> list[tuple[float, tuple]]:
    """Per world, the wall field's band (mm: the largest node radius + c0 + the wall search) and region
    ((centre, radius) mm: the coil's loops around the catheter tip, where the coil can reach)."""
    radius = model.node_radius.numpy()
    path, last = model.catheter_path.numpy(), model.catheter_first.numpy() + model.catheter_count.numpy() - 1
    return [(float(radius[model.world_nodes(w)].max()) + model.contact.c0_mm + min(wall_search_mm, WALL_SEARCH_MM),
             (path[last[w]], max(model.coils[c].loop_diameter_mm for c in model.world_coils(w)) + FIELD_REGION_MM))
            for w in range(model.world_count)]

class UnstableStepError(ValueError):
    """A step size above the explicit stability bound was asked for."""


class SimulationUnstable(RuntimeError):
    """The run produced non-finite or runaway values; ``reason`` says which and why."""

    def __init__(self, reason: str):
        super().__init__(reason)
        self.reason = reason


class PushForce(NamedTuple):
    """The pusher's force over some steps, per world (µN, compressive > 0): the
    push force of a step is the coil's internal force along the catheter axis
    at the tip (MODEL.md), P_n at the step's start; for the θ-method with θ < 1 the step's
    reading is (1 − θ) P_{n−1} + θ P_n (docs/FORMULATION.md "Implicit step: the θ-method's push
    force reading"). ``mean_uN``: signed mean over the steps;
    ``peak_uN``: largest compressive step value (≥ 0); ``rms_uN``: root mean
    square over the steps."""

    mean_uN: np.ndarray
    peak_uN: np.ndarray
    rms_uN: np.ndarray


@dataclass(frozen=True)
class StepBound:
    """Explicit stability bound dt < 2/ω_max, and the term that sets it."""

    dt_s: float
    limiting_term: str
    omega_rad_s: dict = field(default_factory=dict)


def _contact_inv_mass(model: Model, nodes: slice) -> np.ndarray:
    """Contact share per gram (1/g) of each node: its contact law (wall, device, its
    node–capsule terms) is weighted by its share of the coil, as its mass is, so an
    end node of half mass meets half the law and has an interior node's contact
    frequency."""
    return model.host("contact_share")[nodes] * model.host("inv_mass")[nodes]


def stable_step_bound(model: Model, contact_stiffness_uN_mm: float = 0.0, nodes: slice = slice(None)) -> StepBound:
    """Gershgorin bounds of the highest angular frequency of each term: the largest
    absolute row sum of M⁻¹K over the nodes (edges for twist), K the term's
    Hessian at the straight rest state (exact for a uniform chain):

    * stretching: 2 (k_s,i-1 + k_s,i) / m_i (4 k_s/m in a chain; also 4 k_s/m at a
      free end, whose node has half the mass and one spring)
    * bending: Σ_j 4 |a_ij| k_b,j / l_j² / m_i over the vertices j that hold node i,
      a = (1, 2, 1) its second-difference stencil (16 k_b/(m l²) inside a chain,
      8 at a free end of half mass)
    * twisting: (4 k_t + k_b |K̄|²) / J
    * contact: the contact law's slope at the design overlap (u = 3, h = −2 c0),
      times CONTACTS_PER_NODE and each node's contact share, / its mass (when given;
      :func:`_contact_inv_mass`: the same for every node of a coil, its end nodes too)

    ``nodes``: one world's nodes (default: every world, the smallest bound).
    """
    inv_m = model.host("inv_mass")[nodes]
    has_next = model.host("has_next")[nodes] == 1
    ks = model.host("k_stretch")[nodes]
    kb = model.host("k_bend")[nodes]
    kt = model.host("k_twist")[nodes]
    rest_len = model.host("rest_length")[nodes]
    l_edge = np.where(has_next, rest_len, np.inf)
    ks_prev = np.concatenate([[0.0], ks[:-1]])
    kbar = np.maximum(np.linalg.norm(model.host("rest_K0")[nodes], axis=1),
                      np.linalg.norm(model.host("rest_K1")[nodes], axis=1))
    kt_max = np.max(np.stack([kt, np.roll(kt, -1)]), axis=0)
    kb_max = np.max(np.stack([kb, np.roll(kb, -1)]), axis=0)
    l_min = np.minimum(l_edge, np.concatenate([[np.inf], l_edge[:-1]]))  # vertex j: its shorter edge
    clamped = np.linalg.norm(model.host("clamp_tangent")[nodes], axis=1) > 0.0
    l_min = np.where(clamped, l_edge, l_min)  # a clamp vertex's virtual edge has no length
    c = 4.0 * kb / l_min**2  # per vertex (k_b = 0 where there is none)
    bend_row = np.concatenate([[0.0], c[:-1]]) + 2.0 * c + np.concatenate([c[1:], [0.0]])
    inv_j = model.host("inv_inertia")[nodes]
    omega_sq = {
        "stretching (coil axial_stiffness_uN)": np.max(2.0 * (ks_prev + ks) * inv_m),
        "bending (coil bending_stiffness_uN_mm2)": np.max(bend_row * inv_m),
        "twisting (coil twist_stiffness_uN_mm2)": np.max(np.where(has_next, (4.0 * kt_max + kb_max * kbar**2) * inv_j,
                                                                  0.0)),
    }
    if contact_stiffness_uN_mm > 0.0:
        omega_sq["contact (contact P0_uN / c0_mm)"] = contact_stiffness_uN_mm * np.max(_contact_inv_mass(model, nodes))
    omega = {k: math.sqrt(v) for k, v in omega_sq.items()}
    name = max(omega, key=omega.get)
    return StepBound(dt_s=2.0 / omega[name], limiting_term=name, omega_rad_s=omega)


def contact_linear_onset(model: Model, dt_s: float, nodes: slice = slice(None)) -> float:
    """Overlap u (= 1 − h/c0) where the contact law turns linear for this step:
    MODEL.md's 7, or earlier, where the law's stiffness reaches what an explicit
    step dt can integrate for the lightest node pressed from CONTACTS_AT_ONSET
    sides (k_max = m (2/dt)² / CONTACTS_AT_ONSET, m the lightest node's mass per
    unit of contact share: :func:`_contact_inv_mass`); never below u = 2 (h = −c0).
    Up to it the law is exact; past it the force keeps growing along the law's
    tangent, so deep overlaps in an overpacked sac stay stable instead of blowing
    up. For the default coil and step it is u ≈ 2.8 (|F| ≈ 24 P0)."""
    m_min = 1.0 / float(_contact_inv_mass(model, nodes).max())
    k_max = m_min * (2.0 / dt_s) ** 2 / CONTACTS_AT_ONSET
    low, high = 2.0, 7.0
    if model.contact.stiffness_uN_mm(high) <= k_max:
        return high
    if model.contact.stiffness_uN_mm(low) >= k_max:
        return low
    for _ in range(60):
        mid = 0.5 * (low + high)
        low, high = (mid, high) if model.contact.stiffness_uN_mm(mid) <= k_max else (low, mid)
    return low


def uninstantiated(graph) -> bool:
    """A CUDA graph whose launch failed before it was instantiated (so before any of its work ran)."""
    return graph.device.is_cuda and graph.graph_exec is None


@dataclass
class Control:
    """What drives the model from outside, per world: which coil its pusher moves
    (a global coil index, −1 when nobody pushes), how fast (mm/s), and whether
    the world is still running (a stopped world keeps its state)."""

    active_coil: wp.array  # int32 per world
    push_speed_mm_s: wp.array  # float64 per world
    running: wp.array  # int32 per world
    model: Model

    @staticmethod
    def create(model: Model, active_coil: int | Sequence[int] = -1,
               push_speed_mm_s: float | Sequence[float] = 0.0) -> "Control":
        """``active_coil``: per world, the index of the pushed coil among that world's
        coils (−1: none); a single value applies to every world."""
        worlds = model.world_count
        local = np.broadcast_to(np.asarray(active_coil, dtype=np.int64), (worlds,))
        speeds = np.broadcast_to(np.asarray(push_speed_mm_s, dtype=np.float64), (worlds,))
        control = Control(wp.full(worlds, -1, dtype=wp.int32, device=model.device),
                          wp.array(speeds, dtype=wp.float64, device=model.device),
                          wp.ones(worlds, dtype=wp.int32, device=model.device), model)
        for w, coil in enumerate(local):
            control.set_active_coil(int(coil), world=w)
        return control

    def set_active_coil(self, coil: int, world: int = 0) -> None:
        """Hand world ``world``'s pusher to its coil ``coil`` (local index; −1: none)."""
        first = int(self.model.world_first_coil[world])
        self.active_coil[world:world + 1].fill_(-1 if coil < 0 else first + coil)

    def set_push_speed(self, speed_mm_s: float, world: int | None = None) -> None:
        """Pusher speed (mm/s) of world ``world`` (None: every world); 0 stops the pusher
        (the coil stays where it is in the catheter; its deployed part moves freely)."""
        if world is None:
            self.push_speed_mm_s.fill_(float(speed_mm_s))
        else:
            self.push_speed_mm_s[world:world + 1].fill_(float(speed_mm_s))

    def stop(self, world: int) -> None:
        """Freeze a world: from the next step on it keeps its state."""
        self.running[world:world + 1].fill_(0)


class Solver:
    """Elastic forces, catheter kinematics and time integration for one Model
    (one or many worlds).

    ``dt_s`` None → ``dt_safety`` (default 0.9) × the stable bound. A larger dt than the bound
    raises :class:`UnstableStepError` unless ``allow_unstable_dt``.

    ``neighbour_skin_mm``: the coil–coil neighbour grid is rebuilt only when an
    edge midpoint has moved more than half this since the last build (0: every
    step); every pair within the contact range is found either way, and the
    fixed-point contact sums make the forces bit-identical. At each build every
    edge lists the edges within query radius + skin (up to ``neighbour_capacity``;
    an edge with more searches the grid each step instead).
    ``wall_guard_steps``: a node anchored away from the wall's contact range is
    searched again at least this often (0: every step).
    ``wall_query``: "sdf" samples wall distance and normal from a narrow-band
    field of voxel ``wall_voxel_mm`` (wall_field.py) over the contact range +
    ``wall_search_mm`` (at most WALL_SEARCH_MM), within the largest loop diameter + FIELD_REGION_MM of the
    catheter tip, falling back to the BVH where the field is untrusted or absent;
    "bvh" (default) queries the BVH only (exact).
    ``wall_sided_skip``: a node in wall contact that cannot have left the lumen
    since its last search skips the signed BVH query (kernels/contact.wall_contact;
    bit-identical to the full search, which False forces).
    ``guard_fixed_point``: friction's normal guard stops its passes at a fixed point
    (kernels/friction.py; bit-identical to all GUARD_PASSES passes, which False forces).
    ``neighbour_build``: "grid" builds the neighbour lists from Warp's hash grid, "walk"
    by each edge walking its world's edges (contact.walk_neighbours: the same lists; the
    grid is built only when a list overflows), "auto" (default) walks on the CPU for a
    single world of at most NEIGHBOUR_WALK_MAX_NODES nodes (an ensemble sorts the grid once
    for all its worlds but would walk each: not measured, so it keeps the grid).
    """

    integrator = "symplectic"
    record_touching = False  # note each edge's touching partners in the contact pass (the implicit step reads them)
    kernel_modules = (contact, devices, elastic, friction, integrate, wall_measure)  # loaded before a graph capture

    def __init__(self, model: Model, dt_s: float | None = None, dt_safety: float = DEFAULT_DT_SAFETY,
                 allow_unstable_dt: bool = False, coil_contact: bool = True,
                 wall_search_mm: float = WALL_SEARCH_MM, neighbour_skin_mm: float = NEIGHBOUR_SKIN_MM,
                 wall_guard_steps: int = WALL_GUARD_STEPS, neighbour_capacity: int = NEIGHBOUR_CAPACITY,
                 wall_query: str = "bvh", wall_voxel_mm: float = DEFAULT_VOXEL_MM, wall_sided_skip: bool = True,
                 neighbour_build: str = "auto", guard_fixed_point: bool = True):
        if wall_query not in WALL_QUERIES:
            raise ValueError(f"wall_query must be one of {WALL_QUERIES}, got {wall_query!r}")
        if neighbour_build not in NEIGHBOUR_BUILDS:
            raise ValueError(f"neighbour_build must be one of {NEIGHBOUR_BUILDS}, got {neighbour_build!r}")
        self.model = model
        self.scheme = {"integrator": self.integrator}  # result.json's "scheme" (ImplicitSolver: its settings)
        self.coil_contact = coil_contact
        self.wall_search_mm = wall_search_mm
        self.wall_sided_skip = bool(wall_sided_skip)
        self.guard_fixed_point = bool(guard_fixed_point)
        self.neighbour_skin_mm = float(neighbour_skin_mm)
        self.wall_guard_steps = int(wall_guard_steps)
        self.has_wall = any(w is not None for w in model.world_walls)
        with_contact = coil_contact or self.has_wall
        # a node pressed from up to four sides (wall and coil), Gershgorin over its contacts
        contact_k = CONTACTS_PER_NODE * model.contact.stiffness_uN_mm() if with_contact else 0.0
        self.bound = stable_step_bound(model, contact_k)
        self.dt_s = dt_safety * self.bound.dt_s if dt_s is None else float(dt_s)
        if self.dt_s > self.bound.dt_s and not allow_unstable_dt:
            raise UnstableStepError(
                f"dt = {self.dt_s:.3e} s exceeds the stable bound {self.bound.dt_s:.3e} s set by "
                f"{self.bound.limiting_term}; use a smaller simulation.dt_s (or leave it unset for "
                f"dt_safety × bound), a larger simulation.mass_scale, or set allow_unstable_dt")
        self.contact_u_linear = contact_linear_onset(model, self.dt_s)
        n, dev = model.node_count, model.device
        self.wall_query = wall_query
        extents = wall_field_extent(model, wall_search_mm)
        self.wall_fields = [None if wall is None or wall_query == "bvh" else
                            wall_field_for(wall, band, wall_voxel_mm, region)
                            for wall, (band, region) in zip(model.world_walls, extents)]
        self._field_ids = wp.array([0 if f is None else f.id for f in self.wall_fields], dtype=wp.uint64, device=dev)
        self._no_fields = wp.zeros(model.world_count, dtype=wp.uint64, device=dev)
        self._exact_worlds: set[int] = set()  # worlds whose wall fields gave way to the BVH (use_exact_wall)
        # an anchored node must be beyond contact for the field too: its error is ≤ h √3/2 (1-Lipschitz, trilinear)
        self._anchor_margin = max([float(contact.ANCHOR_MARGIN_MM)] + [
            field_error_bound_mm(f.voxel_mm) + float(contact.ANCHOR_MARGIN_MM) for f in self.wall_fields if f])
        zeros = lambda dtype: wp.zeros(n, dtype=dtype, device=dev)  # noqa: E731
        self.grad_prev, self.grad_mid, self.grad_next = zeros(wp.vec3d), zeros(wp.vec3d), zeros(wp.vec3d)
        self.grad_theta = zeros(wp.vec2d)
        self.force, self.contact_force = zeros(wp.vec3d), zeros(wp.vec3d)
        self.torque, self.push_share = zeros(wp.float64), zeros(wp.float64)
        self._kinetic, self._unhealthy = zeros(wp.float64), zeros(wp.int32)
        self._stretch_e, self._bend_e, self._twist_e = zeros(wp.float64), zeros(wp.float64), zeros(wp.float64)
        self.wall_force, self.wall_distance = zeros(wp.vec3d), zeros(wp.float64)
        self.has_balloon = model.has_balloon
        self.device_force = zeros(wp.vec3d)  # balloon or stent contact (µN)
        self.has_stent = model.has_stent and coil_contact
        if self.has_stent:  # a static grid of strut midpoints, grouped by world
            starts, ends, _ = model.strut_host
            mids = model.array(0.5 * (starts + ends), wp.vec3d)
            half_strut = 0.5 * float(np.linalg.norm(ends - starts, axis=1).max())
            # every strut whose closest point can be within c0 of an edge stretched up to 10 %
            self._strut_query_mm = (0.55 * float(model.rest_length.numpy().max()) + float(
                model.node_radius.numpy().max()) + model.contact.c0_mm + half_strut + model.strut_radius_mm)
            strut_cells = int(min(64, max(4, 2 * round(len(starts) ** (1.0 / 3.0)))))
            self._strut_grid = wp.HashGrid(strut_cells, strut_cells, strut_cells, device=dev, dtype=wp.float64)
            self._strut_grid.build(mids, self._strut_query_mm, groups=model.strut_world)
            self._strut_force_start, self._strut_force_end = zeros(wp.vec3d), zeros(wp.vec3d)
        self.wall_distance.fill_(float(contact.FAR_MM))
        self._wall_side, self._wall_anchor, self._wall_quiet = zeros(wp.int32), zeros(wp.vec3d), zeros(wp.int32)
        self._wall_slack = zeros(wp.float64)
        self._wall_seen_x, self._wall_seen_mm = zeros(wp.vec3d), zeros(wp.float64)  # last full search in the lumen
        self._wall_side.fill_(-1)
        # per node, 1 where the frame measurement's wall_distance is exact, 0 where a bound (measure_contacts)
        self.wall_distance_exact = wp.ones(n, dtype=wp.int32, device=dev)
        # per node, the frame measurement's own last search in the lumen: at x_ref the signed
        # distance is ≥ the value (mm; ≤ 0: none) — its bounds never rest on the steps' anchors
        self._measure_ref_x, self._measure_ref_mm = zeros(wp.vec3d), zeros(wp.float64)
        # mm, per world: the smallest exact wall gap and the smallest bound of the others (measure_contacts)
        self._smallest_wall_gap = wp.zeros(model.world_count, dtype=wp.float64, device=dev)
        self._smallest_bound_gap = wp.zeros(model.world_count, dtype=wp.float64, device=dev)
        # mm, per edge with contact samples: the smallest wall gap of its samples (wall_measure.sample_wall_gaps)
        self.sample_wall_gap = zeros(wp.float64)
        self.sample_wall_gap.fill_(float(contact.FAR_MM))
        self._has_samples = int(model.host("contact_samples").max()) > 1
        # the wall's weight on each node (µN per law): its contact share, over its coil's contact samples per edge
        # where they share the law (kernels/contact.wall_sample_contact); the share itself where none has any
        self._wall_share = (model.array(model.host("contact_share") / model.host("contact_samples"), wp.float64)
                            if self._has_samples else model.contact_share)
        # the implicit step's wall stiffness, taken in the wall pass (None: not wanted)
        self.wall_stiffness: wp.array | None = None
        self._no_stiffness = wp.zeros(1, dtype=wp.mat33d, device=dev)
        self.wall_searches = zeros(wp.int32)  # per node, its signed BVH queries so far (for tests and benchmarks)
        self._wall_quiet.fill_(-1)
        self.coil_gap, self.coil_contacts = zeros(wp.float64), zeros(wp.int32)
        self._midpoints, self._built_midpoints = zeros(wp.vec3d), zeros(wp.vec3d)
        self._neighbours = wp.zeros((n, neighbour_capacity), dtype=wp.int32, device=dev)
        self._neighbour_count = zeros(wp.int32)
        self._rebuild = wp.ones(1, dtype=wp.int32, device=dev)
        self.grid_builds = 0  # neighbour-grid builds launched outside a captured graph (for tests)
        self._edge_force_start, self._edge_force_end = zeros(wp.vec3d), zeros(wp.vec3d)
        self._edge_sum_start, self._edge_sum_end = zeros(contact.vec3l), zeros(contact.vec3l)  # fixed point
        self._edge_bad = zeros(wp.int32)
        # per edge, its partners within a hair of touching (noted by the contact pass for the implicit step)
        self._touch_count = zeros(wp.int32)
        self._touch_b = wp.zeros((n, TOUCHING_PER_EDGE if self.record_touching else 1), dtype=wp.int32, device=dev)
        # per edge, how many chord candidates the implicit step's contact pass noted (while _note_chord is set),
        # and the contact pass's other chord inputs: the predicted end's per-edge values and the record
        # (implicit.ImplicitSolver's; one-element placeholders here)
        self._note_chord = False
        self._chord_count = zeros(wp.int32)
        one = {"dtype": wp.float64, "device": dev}
        self._end_mid = wp.zeros(1, dtype=wp.vec3d, device=dev)
        self._end_half, self._end_move, self._sweep = wp.zeros(1, **one), wp.zeros(1, **one), wp.zeros(1, **one)
        self._node_move = wp.zeros(1, dtype=wp.vec3d, device=dev)
        self._chord_b = wp.zeros((1, 1), dtype=wp.int32, device=dev)
        self._chord_st = wp.zeros((1, 1), dtype=wp.vec2d, device=dev)
        c = model.contact
        self.coil_friction = coil_contact and max(c.friction_coil, c.friction_catheter) > 0.0
        self.friction = self.coil_friction or (
            (self.has_wall or self.has_balloon or self.has_stent) and c.friction_wall > 0.0)
        self._friction_start, self._friction_end = zeros(wp.vec3d), zeros(wp.vec3d)  # per edge, mm/s
        # per node: the scale and cap on its contacts' slip fractions (friction.node_fraction_caps); per edge: its
        # coil pairs' slip fractions (up to FRICTION_PAIRS), their count (−1: more) and their sum
        self._fraction_scale, self._fraction_cap, self._phi_sum = (zeros(wp.float64) for _ in range(3))
        recorded = (n, friction.FRICTION_PAIRS) if self.coil_friction else (1, 1)
        self._pair_phi = wp.zeros(recorded, dtype=wp.float64, device=dev)
        self._pair_phi_count = wp.zeros(recorded[0], dtype=wp.int32, device=dev)
        self._guard_start, self._guard_end = zeros(wp.vec3d), zeros(wp.vec3d)  # per edge, mm/s
        self._friction_change = zeros(wp.vec3d)  # per node, mm/s
        guarded = (n, friction.GUARD_PAIRS) if self.friction and coil_contact else (1, 1)  # the guard's pair record
        self._guard_b = wp.zeros(guarded, dtype=wp.int32, device=dev)
        self._guard_st = wp.zeros(guarded, dtype=wp.vec2d, device=dev)
        self._guard_count = zeros(wp.int32)
        self._guard_loop = wp.zeros(3, dtype=wp.int32, device=dev)  # the guard's pass loop (friction.GUARD_MOVING …)
        # per world: Σ, max, Σ² of the step push force, and the steps counted
        self.push_accumulator = wp.zeros((model.world_count, 4), dtype=wp.float64, device=dev)
        # per world: the previous step's push force (µN) and whether there is one (θ-method reading, θ < 1)
        self._push_previous = wp.zeros((model.world_count, 2), dtype=wp.float64, device=dev)
        self._running_all = wp.ones(model.world_count, dtype=wp.int32, device=dev)
        cells = int(min(128, max(8, 2 * round(n ** (1.0 / 3.0)))))  # hashed grid: ~8 cells per edge
        self._grid_radius = model.contact.query_radius_mm + 0.5 * self.neighbour_skin_mm
        self._list_radius = model.contact.query_radius_mm + self.neighbour_skin_mm
        self._grid = wp.HashGrid(cells, cells, cells, device=dev, dtype=wp.float64) if coil_contact else None
        self.walk_neighbours = neighbour_build == "walk" or (
            neighbour_build == "auto" and dev.is_cpu and model.world_count == 1 and n <= NEIGHBOUR_WALK_MAX_NODES)
        self._coil_first = wp.array(model.coil_first, dtype=wp.int32, device=dev)
        self._coil_last = wp.array(model.coil_last, dtype=wp.int32, device=dev)
        self._coil_step = wp.zeros(model.coil_count, dtype=wp.float64, device=dev)  # mm, per coil (walk_neighbours)
        self._list_overflow = wp.zeros(1, dtype=wp.int32, device=dev)  # a walked list overflowed: build the grid
        # CUDA graphs need conditional nodes (CUDA 12.4+) to skip builds and stop friction's guard passes;
        # without them, build every step and run every pass
        self._conditional_graphs = dev.is_cpu or wp.is_conditional_graph_supported()
        self._conditional_rebuild = self._conditional_graphs
        self._graphs: dict = {}  # (name, id(state), id(extra)) → (state, extra, graph): _replayed
        self._views: dict = {}  # id(array) → (array, its numpy view): host()
        self._world_slices = [model.world_nodes(w) for w in range(model.world_count)]

    # --- one step ----------------------------------------------------------
    def _launch_midpoints(self, state: State) -> None:
        """Edge midpoints of ``state``, raising the rebuild flag when one moved half the skin."""
        m = self.model
        wp.launch(contact.edge_midpoints, m.node_count, device=m.device, inputs=[
            state.x, m.has_next, self._built_midpoints, 0.5 * self.neighbour_skin_mm, self._midpoints, self._rebuild])

    def _build_neighbour_lists(self, allocate: bool = False) -> None:
        """Neighbour lists at the current midpoints: from the hash grid, or walked
        (``walk_neighbours``; the grid then built only when a list overflowed, or to
        size its buffers: ``allocate``)."""
        m = self.model
        wp.launch(contact.mark_built, m.node_count, device=m.device, inputs=[
            self._midpoints, self._built_midpoints, self._rebuild, self._list_overflow])
        if self.walk_neighbours:
            wp.launch(contact.coil_midpoint_steps, m.coil_count, device=m.device, inputs=[
                self._built_midpoints, self._coil_first, self._coil_last, self._coil_step])
            wp.launch(contact.walk_neighbours, m.node_count, device=m.device, inputs=[
                self._built_midpoints, m.has_next, m.coil_of, m.world_of, m.world_node_range, self._coil_last,
                self._coil_step, m.contact.exclusion_edges, self._list_radius, self._neighbours,
                self._neighbour_count, self._list_overflow])
            if self._conditional_rebuild and not allocate:
                wp.capture_if(self._list_overflow, on_true=self._build_hash_grid)
            else:
                self._build_hash_grid()
        else:
            self._build_hash_grid()
            wp.launch(contact.build_neighbours, m.node_count, device=m.device, inputs=[
                self._grid.id, self._built_midpoints, m.has_next, m.coil_of, m.world_of, m.contact.exclusion_edges,
                self._list_radius, self._neighbours, self._neighbour_count])
        self.grid_builds += 1

    def _build_hash_grid(self) -> None:
        m = self.model
        # one world: no groups (its grouped queries see every point, in the same order; Warp's CPU build
        # sorts 32- instead of 64-bit keys then)
        self._grid.build(self._built_midpoints, self._list_radius, groups=m.world_of if m.world_count > 1 else None)

    def compute_contacts(self, state: State, wall_search_mm: float | None = None,
                         running: wp.array | None = None, wall_measure: bool = False) -> None:
        """Wall and coil–coil contact forces into ``contact_force`` (µN), with the
        per-node wall distance and the per-edge smallest coil gap and touching pairs
        (each pair counted from both edges). ``wall_search_mm``: how far beyond the
        contact range the wall is searched (default the solver's; a large value
        gives exact distances for every node). ``running``: the worlds to compute
        (default all). ``wall_measure``: the wall part is a frame's measurement
        (:meth:`_launch_wall_measure`) instead."""
        m, dev, n = self.model, self.model.device, self.model.node_count
        c = m.contact
        running = self._running_all if running is None else running
        if self.has_wall and wall_measure:
            self._launch_wall_measure(state, running)
        elif self.has_wall:
            wp.launch(contact.wall_contact, n, device=dev, inputs=[
                state.x, state.free, m.world_of, running, m.node_radius, self._wall_share, m.wall_mesh, m.wall_face_first,
                m.wall_origin, m.wall_vertices, m.wall_faces, m.wall_owners, c.p0_uN, c.c0_mm, self.contact_u_linear,
                self.wall_search_mm if wall_search_mm is None else wall_search_mm,
                self.wall_guard_steps if wall_search_mm is None else 0,  # exact distances: search every node
                self._field_ids if wall_search_mm is None else self._no_fields, GRAD_TOLERANCE, self._anchor_margin,
                int(self.wall_sided_skip), self._wall_side, self._wall_anchor, self._wall_slack, self._wall_quiet,
                self._wall_seen_x, self._wall_seen_mm, self.wall_force, self.wall_distance, self.wall_searches,
                int(self.wall_stiffness is not None and wall_search_mm is None),
                self.wall_stiffness if self.wall_stiffness is not None else self._no_stiffness])
            if self._has_samples:  # segments longer than 1.5 d: the wall at their points between the nodes too
                self._launch_sample_contact(
                    state, running, self.wall_search_mm if wall_search_mm is None else wall_search_mm,
                    self._field_ids if wall_search_mm is None else self._no_fields,
                    int(self.wall_stiffness is not None and wall_search_mm is None))
        if self.coil_contact:
            self._launch_midpoints(state)
            if self._conditional_rebuild:
                wp.capture_if(self._rebuild, on_true=self._build_neighbour_lists)
            else:
                self._build_neighbour_lists()
            sums = (self._edge_sum_start, self._edge_sum_end)
            wp.launch(contact.clear_edge_sums, n, device=dev, inputs=[
                m.world_of, m.query_radius_of, *sums, self.coil_gap, self.coil_contacts, self._edge_bad,
                self._touch_count, self._chord_count])
            pass_args = [
                state.x, m.rest_x, state.free, m.has_next, m.coil_of, m.world_of, running, m.fixed,
                m.node_radius, m.contact_share, m.contact_samples, self._grid.id, self._neighbours,
                self._neighbour_count, self._midpoints, m.query_radius_of, self._grid_radius, c.exclusion_edges,
                c.p0_uN, c.c0_mm, self.contact_u_linear,
                *sums, self.coil_gap, self.coil_contacts, self._edge_bad, int(self.record_touching),
                self._touch_count, self._touch_b,
                # the implicit step's chord candidates too, while its predicted end is known
                self._end_mid, self._end_half, self._end_move, self._sweep, self._chord_count, self._chord_b,
                self._chord_st, int(self._note_chord), self._node_move]
            wp.launch(contact.edge_contact, n, device=dev, inputs=pass_args)
            wp.launch(contact.finish_edge_contact, n, device=dev, inputs=[
                *sums, self._edge_bad, self._edge_force_start, self._edge_force_end, self.coil_gap])
            wp.launch(contact.gather_contact, n, device=dev, inputs=[
                state.free, m.has_next, self.wall_force, self._edge_force_start, self._edge_force_end,
                self.contact_force])
        elif self.has_wall:
            wp.copy(self.contact_force, self.wall_force)
        if self.has_stent:
            wp.launch(devices.strut_contact, n, device=dev, inputs=[
                state.x, state.free, m.has_next, m.world_of, running, m.node_radius, self._strut_grid.id,
                m.strut_start, m.strut_end, m.strut_radius_mm, self._strut_query_mm, c.p0_uN, c.c0_mm,
                self.contact_u_linear, self._strut_force_start, self._strut_force_end])
            wp.launch(devices.gather_edge_forces, n, device=dev, inputs=[
                state.free, m.has_next, self._strut_force_start, self._strut_force_end, self.device_force])
            wp.launch(devices.add_forces, n, device=dev, inputs=[self.device_force, self.contact_force])
        if self.has_balloon:
            wp.launch(devices.balloon_contact, n, device=dev, inputs=[
                state.x, state.free, m.world_of, running, m.node_radius, m.contact_share, m.balloon_stations, m.balloon_cap_radius,
                m.balloon_first, m.balloon_count, m.balloon_inflation, c.p0_uN, c.c0_mm, self.contact_u_linear,
                self.device_force])
            if self.coil_contact or self.has_wall:
                wp.launch(devices.add_forces, n, device=dev, inputs=[self.device_force, self.contact_force])
            else:
                wp.copy(self.contact_force, self.device_force)

    def _launch_sample_contact(self, state: State, running: wp.array, search_mm: float, fields: wp.array,
                               with_stiffness: int) -> None:
        """The wall at the contact samples of segments longer than 1.5 d, added to ``wall_force`` (and, with
        ``with_stiffness``, lumped into ``wall_stiffness``): kernels/contact.wall_sample_contact."""
        m, c = self.model, self.model.contact
        wp.launch(contact.wall_sample_contact, m.node_count, device=m.device, inputs=[
            state.x, state.free, m.has_next, m.world_of, running, m.node_radius, m.contact_samples, m.wall_mesh,
            m.wall_face_first, m.wall_origin, m.wall_vertices, m.wall_faces, m.wall_owners, c.p0_uN, c.c0_mm,
            self.contact_u_linear, search_mm, fields, GRAD_TOLERANCE, self._anchor_margin, self.wall_distance,
            self.wall_force, with_stiffness, self.wall_stiffness if self.wall_stiffness is not None else self._no_stiffness])

    def _launch_wall_measure(self, state: State, running: wp.array) -> None:
        """The frame measurement's wall pass (kernels/wall_measure.py): force and signed
        centre distance of every free node, exact where the node may be in contact or
        outside the lumen and for each world's smallest gap, elsewhere a certified lower
        bound above the contact range (``wall_distance_exact`` 0). It writes nothing the steps
        read, so frames do not change the run (docs/FORMULATION.md, "The frame's wall measurement")."""
        m, dev, n = self.model, self.model.device, self.model.node_count
        c = m.contact

        def measure(stage: int) -> None:
            wp.launch(wall_measure.measure_wall, n, device=dev, inputs=[
                state.x, state.free, m.world_of, running, m.node_radius, self._wall_share, m.wall_mesh,
                m.wall_face_first, m.wall_origin, m.wall_vertices, m.wall_faces, m.wall_owners, c.p0_uN, c.c0_mm,
                self.contact_u_linear, self._field_ids, GRAD_TOLERANCE, self._anchor_margin, int(self.wall_sided_skip),
                self._measure_ref_x, self._measure_ref_mm, stage, *smallest, self.wall_force,
                self.wall_distance, self.wall_distance_exact])

        def reduce() -> None:
            wp.launch(wall_measure.smallest_gaps, n, device=dev, inputs=[
                state.free, m.world_of, m.node_radius, self.wall_distance, self.wall_distance_exact, *smallest])

        smallest = (self._smallest_wall_gap, self._smallest_bound_gap)
        measure(wall_measure.FIRST)
        wp.launch(wall_measure.reset_smallest_gaps, m.world_count, device=dev, inputs=[*smallest])
        reduce()
        measure(wall_measure.SEED)  # a world with bounds only: its smallest bound's node, exactly
        reduce()
        measure(wall_measure.FIX_UP)
        if self._has_samples:  # segments longer than 1.5 d: their points between the nodes too (force, gap)
            self._launch_sample_contact(state, running, self.wall_search_mm, self._field_ids, 0)
            wp.launch(wall_measure.sample_wall_gaps, n, device=dev, inputs=[
                state.x, state.free, m.has_next, m.world_of, running, m.node_radius, m.contact_samples, m.wall_mesh,
                m.wall_face_first, m.wall_origin, m.wall_vertices, m.wall_faces, self.wall_distance,
                self._smallest_wall_gap, self.sample_wall_gap])

    def measure_contacts(self, state: State, running: wp.array) -> None:
        """:meth:`compute_contacts` as a frame's measurement (replayed, :meth:`_replayed`):
        the coil–coil pass as a step has it, the wall by :meth:`_launch_wall_measure`."""
        if ("contacts", id(state), id(running)) not in self._graphs:
            self.allocate_neighbour_grid(state)  # no allocation inside the capture
            wp.load_module(wall_measure, device=self.model.device)
        self._replayed("contacts", state, running,
                       lambda: self.compute_contacts(state, running=running, wall_measure=True))

    def _replayed(self, name: str, state: State, extra, launches) -> None:
        """Run ``launches()`` (kernel launches on ``state`` and ``extra``) from a graph
        captured at its first call for this (name, state, extra): a frame's
        measurements launch ~12 kernels, ~0.5 ms from Python on the CPU. The last
        MEASURE_GRAPHS graphs are kept (each holding its state and extra, so their
        ids stay theirs); a device that cannot capture them launches them as they are, and one that
        cannot instantiate a graph with conditionals at its first launch (a GPU, before anything
        runs) captures it again without them (:meth:`drop_conditionals`)."""
        dev = self.model.device
        key = (name, id(state), id(extra))
        if key not in self._graphs:
            if not (dev.is_cpu or dev.is_cuda):
                launches()
                return
            try:
                with wp.ScopedCapture(device=dev) as capture:
                    launches()
            except RuntimeError:
                launches()
                return
            if len(self._graphs) >= MEASURE_GRAPHS:
                self._graphs.pop(next(iter(self._graphs)))
            self._graphs[key] = (state, extra, capture.graph, self._conditional_rebuild)
        graph = self._graphs[key][2]
        try:
            wp.capture_launch(graph)
        except RuntimeError:
            if not (uninstantiated(graph) and self._graphs[key][3]):
                raise
            del self._graphs[key]
            self.drop_conditionals()
            self._replayed(name, state, extra, launches)  # captured again, without them

    def drop_conditionals(self) -> None:
        """This driver cannot branch in a graph: graphs captured from now on build the neighbour grid
        every step and run every friction guard pass (the same forces, bit for bit)."""
        self._conditional_rebuild = self._conditional_graphs = False

    def host(self, array: wp.array) -> np.ndarray:
        """``array.numpy()``: on the CPU a view of the array's memory, kept per array
        (a frame reads ~20 arrays; making each view costs a few µs), elsewhere a copy.
        Read it before the array changes; copy what must outlive that."""
        if not array.device.is_cpu:
            return array.numpy()
        held = self._views.get(id(array))
        if held is None or held[0] is not array:
            held = self._views[id(array)] = (array, array.numpy())
        return held[1]

    def field_in_use(self, world: int) -> bool:
        """Whether the world's wall distances come from its wall field (where trusted), not all from the BVH."""
        return self.wall_fields[world] is not None and world not in self._exact_worlds

    def use_exact_wall(self, world: int) -> None:
        """From now on every wall distance of ``world`` from the exact BVH query, none from its wall field (in
        place: the captured graphs see it). A coil at rest against the wall must feel one potential: where a
        node sits at the edge of a field's trusted region its force switches between the field's and the BVH's
        distance, which kept packed coils' wall contacts jittering instead of letting them come to rest."""
        self._exact_worlds.add(world)
        self._field_ids.assign(np.array([0 if f is None or w in self._exact_worlds else f.id
                                         for w, f in enumerate(self.wall_fields)], dtype=np.uint64))

    def copy_state(self, target: State, source: State) -> None:
        """``target.copy_from(source)`` replayed from a captured graph (:meth:`_replayed`;
        eight copies each frame, ~6 µs each from Python on the CPU)."""
        self._replayed("copy", target, source, lambda: target.copy_from(source))
        target.time_s, target.history_dt_s = source.time_s, source.history_dt_s

    def compute_forces(self, state: State, running: wp.array | None = None) -> None:
        """Node forces (µN), edge torques (µN·mm) and push shares at ``state``."""
        m, dev, n = self.model, self.model.device, self.model.node_count
        self.compute_contacts(state, running=running)
        wp.launch(elastic.vertex_gradients, n, device=dev, inputs=[
            state.x, state.m1, state.free, m.has_next, m.clamp_tangent, m.clamp_director, m.k_bend, m.k_twist, m.rest_K0, m.rest_K1,
            m.rest_twist, self.grad_prev, self.grad_mid, self.grad_next, self.grad_theta])
        wp.launch(elastic.gather_forces, n, device=dev, inputs=[
            state.x, state.free, m.has_next, m.clamp_tangent, m.k_stretch, m.rest_length, self.grad_prev, self.grad_mid,
            self.grad_next, self.grad_theta, m.external, self.contact_force, m.node_radius, m.contact_share, m.contact.fold_span,
            m.contact.p0_uN, m.contact.c0_mm, self.contact_u_linear, m.world_of, m.catheter_axis_of,
            self.force, self.torque, self.push_share])

    def needs_start(self, state: State) -> bool:
        """Whether the next step from ``state`` is a multistep scheme's start (not the
        step a captured graph replays): never for a one-step scheme."""
        return False

    def step(self, state_in: State, state_out: State, control: Control, dt: float | None = None) -> None:
        """Advance ``state_in`` by dt into ``state_out`` (distinct buffers)."""
        m, dev, n = self.model, self.model.device, self.model.node_count
        dt = self.dt_s if dt is None else dt
        self.compute_forces(state_in, control.running)
        wp.launch(integrate.integrate_nodes, n, device=dev, inputs=[
            state_in.x, state_in.v, state_in.free, state_in.advance, self.force, m.fixed, m.coil_of, m.world_of,
            m.coil_world, m.arc_s, m.inv_mass, m.damping_c, m.damping_k, m.catheter_path, m.catheter_first,
            m.catheter_count, control.active_coil, control.push_speed_mm_s, control.running, dt,
            state_out.x, state_out.v, state_out.free, state_out.advance])
        if self.friction:
            self._apply_friction(state_in, state_out, control.running, dt)
        wp.launch(integrate.update_frames, n, device=dev, inputs=[
            state_in.x, state_out.x, state_in.m1, state_in.omega, self.torque, state_out.free, m.fixed, m.has_next,
            m.inv_inertia, m.twist_damping, m.world_of, control.running, dt, state_out.m1, state_out.omega])
        self._accumulate_push_force(control)
        state_out.time_s = state_in.time_s + dt

    def _accumulate_push_force(self, control: Control, theta: float = 1.0) -> None:
        """Adds this step's push force reading per running world to ``push_accumulator``:
        P_n, the push force at the step's start (θ = 1: the reference and linearly implicit
        Euler), or, for the θ-method with θ < 1, (1 − θ) P_{n−1} + θ P_n
        (kernels/integrate.accumulate_blended_push_force)."""
        m = self.model
        if theta == 1.0:
            wp.launch(integrate.accumulate_push_force, m.world_count, device=m.device, inputs=[
                self.push_share, m.world_node_range, control.running, self.push_accumulator])
            return
        wp.launch(integrate.accumulate_blended_push_force, m.world_count, device=m.device, inputs=[
            self.push_share, m.world_node_range, control.running, theta, self._push_previous, self.push_accumulator])

    def _apply_friction(self, state_in: State, state_out: State, running: wp.array, dt: float) -> None:
        """Implicit Coulomb friction on the velocities the integrator predicted
        (kernels/friction.py), with the contacts found at ``state_in``."""
        self._friction_law(state_in, state_out, running, dt)
        self._friction_guard(state_in, state_out, running)
        self._launch_friction_apply(state_in, state_out, running, dt)

    def _launch_friction_apply(self, state_in: State, state_out: State, running: wp.array, dt: float) -> None:
        """v' = v* + the friction change, x' = x + dt v'."""
        m = self.model
        wp.launch(friction.apply_friction, m.node_count, device=m.device, inputs=[
            state_in.x, state_out.free, m.world_of, running, self._friction_change, dt, state_out.v, state_out.x])

    def _friction_law(self, state_in: State, state_out: State, running: wp.array, dt: float,
                      with_obstacles: bool = True) -> None:
        """Each node's friction velocity change (mm/s) by the law, into ``_friction_change``: a first
        pass records each edge's pairs' slip fractions φ, a second caps each node's (the largest t with
        Σ min(φ, t) ≤ 1), a third applies each contact's φ within its nodes' caps (kernels/friction.py;
        without ``with_obstacles``: coil pairs alone, no wall or device contact in the caps;
        ``_no_obstacle_force``, zeros, stands in for those forces)."""
        m, dev, n = self.model, self.model.device, self.model.node_count
        c = m.contact
        wall_force, device_force = ((self.wall_force, self.device_force) if with_obstacles
                                    else (self._no_obstacle_force, self._no_obstacle_force))
        mu_wall = c.friction_wall if with_obstacles else 0.0
        caps = (self._fraction_scale, self._fraction_cap)
        if self.coil_friction:  # each edge's pairs' slip fractions
            pairs = [
                state_in.x, m.rest_x, state_out.v, state_in.free, m.has_next, m.coil_of, m.world_of, running, m.fixed,
                m.node_radius, m.contact_share, m.contact_samples, m.inv_mass, self.coil_contacts, *caps,
                self._grid.id, self._neighbours, self._neighbour_count, self._midpoints, m.query_radius_of,
                self._grid_radius, c.exclusion_edges, c.p0_uN, c.c0_mm, self.contact_u_linear, c.friction_coil,
                c.friction_catheter, c.friction_speed_mm_s, dt]
            records = [self._pair_phi, self._pair_phi_count, self._phi_sum, self._friction_start, self._friction_end]
            wp.launch(friction.edge_friction, n, device=dev, inputs=pairs + [0] + records)
        wp.launch(friction.node_fraction_caps, n, device=dev, inputs=[
            state_out.free, m.has_next, m.inv_mass, wall_force, device_force, mu_wall, c.friction_speed_mm_s,
            self._phi_sum, self._pair_phi, self._pair_phi_count, int(self.coil_friction), dt, state_out.v, *caps])
        if self.coil_friction:
            wp.launch(friction.edge_friction, n, device=dev, inputs=pairs + [1] + records)
        wp.launch(friction.friction_change, n, device=dev, inputs=[
            state_out.free, m.has_next, m.world_of, running, m.inv_mass, *caps, wall_force, device_force,
            mu_wall, c.friction_speed_mm_s, self._friction_start, self._friction_end, int(self.coil_friction), dt,
            state_out.v, self._friction_change])

    def _friction_guard(self, state_in: State, state_out: State, running: wp.array) -> None:
        """The normal guard on ``_friction_change``: no contact's normal separation rate lowered
        by it (kernels/friction.py)."""
        m, dev, n = self.model, self.model.device, self.model.node_count
        c = m.contact
        if self.coil_contact:
            wp.launch(friction.record_guard_pairs, n, device=dev, inputs=[
                state_in.x, m.rest_x, state_in.free, m.has_next, m.coil_of, m.world_of, running, m.fixed, m.node_radius,
                self.coil_contacts, self._grid.id, self._neighbours, self._neighbour_count, self._midpoints,
                self._grid_radius, c.exclusion_edges, c.c0_mm, self._guard_b, self._guard_st, self._guard_count])
        else:  # the wall and devices alone: one pass
            self._launch_add_guard(state_out, running, with_coil_terms=False)
            return

        def guard_pass() -> None:  # one Jacobi pass over the watched coil pairs, then its loop's bookkeeping
            wp.launch(friction.edge_normal_guard, n, device=dev, inputs=[
                state_in.x, m.rest_x, self._friction_change, state_in.free, m.has_next, m.coil_of, m.world_of, m.fixed,
                m.node_radius, m.inv_mass, self.coil_contacts, self.wall_force, self.device_force, self._grid.id,
                self._neighbours, self._neighbour_count, self._midpoints, self._grid_radius, c.exclusion_edges,
                c.c0_mm, self._guard_b, self._guard_st, self._guard_count, self._guard_start, self._guard_end])
            self._launch_add_guard(state_out, running, with_coil_terms=True)
            wp.launch(friction.finish_guard_pass, 1, device=dev, inputs=[self._guard_loop, friction.GUARD_PASSES])

        # every pass: asked for (the stop is tested against it), no conditional graphs, or a CUDA step outside a
        # graph (capture_while would copy its flag to the host after every pass)
        if not (self.guard_fixed_point and self._conditional_graphs) or (dev.is_cuda and not dev.is_capturing):
            for _ in range(friction.GUARD_PASSES):
                guard_pass()
            return
        wp.launch(friction.start_guard, 1, device=dev, inputs=[self._guard_loop])
        wp.capture_while(self._guard_loop, guard_pass)

    def _launch_add_guard(self, state_out: State, running: wp.array, with_coil_terms: bool) -> None:
        """The friction changes less any part into the wall or a device (kernels/friction.add_guard;
        ``with_coil_terms``: plus the last guard pass's coil-pair corrections)."""
        m = self.model
        wp.launch(friction.add_guard, m.node_count, device=m.device, inputs=[
            state_out.free, m.has_next, m.world_of, running, self.wall_force, self.device_force, self._guard_start,
            self._guard_end, int(with_coil_terms), self._friction_change, self._guard_loop])

    def allocate_neighbour_grid(self, state: State) -> None:
        """Build the neighbour grid once (sizing its buffers) and flag a rebuild."""
        if self.coil_contact:
            self._launch_midpoints(state)
            self._build_neighbour_lists(allocate=True)
            self._rebuild.fill_(1)

    # --- measurements ------------------------------------------------------
    def _launch_elastic_energies(self, state: State) -> None:
        m = self.model
        wp.launch(elastic.elastic_energies, m.node_count, device=m.device, inputs=[
            state.x, state.m1, m.has_next, m.clamp_tangent, m.clamp_director, m.k_stretch, m.rest_length, m.k_bend, m.k_twist, m.rest_K0,
            m.rest_K1, m.rest_twist, self._stretch_e, self._bend_e, self._twist_e])

    def elastic_energy_per_node(self, state: State) -> np.ndarray:
        """Stretching (edge i) + bending and twisting (vertex i) energy at index i, nJ."""
        self._launch_elastic_energies(state)
        return self._stretch_e.numpy() + self._bend_e.numpy() + self._twist_e.numpy()

    def world_energies(self, state: State) -> tuple[dict[str, np.ndarray], np.ndarray]:
        """Per world: kinetic (free nodes, translation + spin), stretching, bending and
        twisting energy (nJ), and the count of non-finite or runaway nodes."""
        m = self.model

        def launches():
            wp.launch(integrate.kinetic_energies, m.node_count, device=m.device, inputs=[
                state.v, state.omega, state.free, m.inv_mass, m.inv_inertia, self._kinetic, self._unhealthy,
                SPEED_LIMIT_MM_S])
            self._launch_elastic_energies(state)

        self._replayed("energies", state, None, launches)
        host = self.host
        per_node = {"kinetic_nJ": host(self._kinetic), "stretch_nJ": host(self._stretch_e),
                    "bend_nJ": host(self._bend_e), "twist_nJ": host(self._twist_e)}
        worlds = self._world_slices
        energies = {k: np.array([v[sl].sum() for sl in worlds]) for k, v in per_node.items()}
        x = host(state.x)
        unhealthy = host(self._unhealthy)
        if not unhealthy.any() and np.isfinite(x).all():  # (every frame of a healthy run: the counts are 0)
            return energies, np.zeros(len(worlds), dtype=np.int64)
        bad = np.array([unhealthy[sl].sum() + (~np.isfinite(x[sl])).any(axis=1).sum() for sl in worlds])
        return energies, bad

    def energies(self, state: State) -> dict[str, float]:
        """Kinetic (free nodes, translation + spin), stretching, bending and twisting energy, nJ (all worlds)."""
        return {k: float(v.sum()) for k, v in self.world_energies(state)[0].items()}

    def synchronous_energies(self, state: State) -> dict[str, float]:
        """Energies (nJ, all worlds) with the kinetic energy of the velocities *at* t_n.

        The state pairs x_n with v_{n−½} (symplectic Euler: the velocity that
        carried x_{n−1} to x_n), so ``energies`` pairs quantities half a step
        apart and its total carries an O(h) error band. Here the translational and
        spin velocities are time-centred, ½ (v_{n−½} + v_{n+½}), with v_{n+½} the
        conservative kick of the next step (no damping: a measure for undamped
        runs), as velocity Verlet reports them; the total's error is O(h²)
        (docs/FORMULATION.md, "Energy"). Evaluates the forces at ``state``."""
        m = self.model
        energies = self.energies(state)
        self.compute_forces(state)
        h = self.dt_s
        inv_mass, inv_inertia = m.inv_mass.numpy(), m.inv_inertia.numpy()
        free = state.free.numpy() != 0
        v = state.v.numpy()
        v_mid = v + 0.5 * h * inv_mass[:, None] * self.force.numpy()
        fixed = m.fixed.numpy() != 0
        held = free | fixed
        spins = np.zeros(m.node_count, dtype=bool)
        spins[:-1] = (m.has_next.numpy()[:-1] != 0) & held[:-1] & held[1:] & ~(fixed[:-1] & fixed[1:])
        omega = state.omega.numpy()
        omega_mid = omega + np.where(spins, 0.5 * h * inv_inertia * self.torque.numpy(), 0.0)
        energies["kinetic_nJ"] = float(0.5 * ((v_mid**2).sum(axis=1)[free] / inv_mass[free]).sum()
                                       + 0.5 * (omega_mid**2 / inv_inertia).sum())
        return energies

    def forget_push_reading(self, world: int) -> None:
        """The θ-method's push reading of ``world`` restarts at its next step (a new coil is pushed:
        the previous coil's last reading is not blended into it)."""
        previous = self._push_previous.numpy()
        previous[world] = 0.0
        self._push_previous.assign(previous)

    def take_push_force(self) -> PushForce:
        """Per world, over the steps since the last call (the solver counts them):
        the push force's signed mean, peak compressive value and RMS (µN,
        compressive > 0); restarts the accumulation."""
        view = self.host(self.push_accumulator)
        acc = view.copy()
        if self.model.device.is_cpu:
            view.fill(0.0)  # (the view is the array)
        else:
            self.push_accumulator.zero_()
        steps = np.maximum(acc[:, 3], 1.0)
        return PushForce(acc[:, 0] / steps, acc[:, 1], np.sqrt(acc[:, 2] / steps))

    def world_health(self, state: State, energy_budget_nJ: np.ndarray | None = None,
                     wall_distance_mm: np.ndarray | None = None) -> tuple[dict[str, np.ndarray], list[str | None]]:
        """Per-world energies (as :meth:`world_energies`) and, per world, None or why
        it is unstable: NaN, a runaway speed, (with ``energy_budget_nJ``: the
        energy put in so far, by packing and pushing) kinetic + elastic energy
        above twice that budget — damping only removes energy, so more than was
        put in means the integration is unstable — or (with ``wall_distance_mm``:
        every node's signed centre distance to its wall, > 0 in the lumen, as
        ``take_snapshot`` measures it: exact where it is below the contact range, a
        lower bound above it elsewhere) a free node's centre past the wall: the
        contact law stops every node at a gap above −d/2 long before, so a centre
        outside means a step moved the node through the contact range c0 without
        feeling it (a step too long for its speed)."""
        energies, bad = self.world_energies(state)
        total = sum(energies.values())
        escaped = self._escaped_nodes(state, wall_distance_mm)
        problems: list[str | None] = []
        for w in range(self.model.world_count):
            problem = None
            if bad[w] or not all(math.isfinite(v[w]) for v in energies.values()):
                problem = f"{bad[w]} node(s) non-finite or faster than {SPEED_LIMIT_MM_S:.0e} mm/s"
            elif energy_budget_nJ is not None and total[w] > 2.0 * energy_budget_nJ[w]:
                problem = (f"energy blow-up: kinetic + elastic {total[w]:.4g} nJ > twice the energy put in "
                           f"({energy_budget_nJ[w]:.4g} nJ)")
            elif escaped[w] is not None:
                count, deepest = escaped[w]
                problem = (f"{count} free node centre(s) past the wall (deepest {deepest:.3g} mm outside the "
                           f"lumen): a step carried them through the contact range c0 = "
                           f"{self.model.contact.c0_mm:.3g} mm unseen")
            problems.append(None if problem is None else self.unstable_reason(problem, state.time_s))
        return energies, problems

    def _escaped_nodes(self, state: State, wall_distance_mm: np.ndarray | None) -> list[tuple[int, float] | None]:
        """Per world: (count, deepest mm) of its free nodes whose centre lies past the wall, or None."""
        m = self.model
        if wall_distance_mm is None or not self.has_wall:
            return [None] * m.world_count
        outside = (self.host(state.free) == 1) & (wall_distance_mm < 0.0)
        escaped: list[tuple[int, float] | None] = []
        for w in range(m.world_count):
            sl = m.world_nodes(w)
            count = int(outside[sl].sum())
            escaped.append((count, float(-wall_distance_mm[sl][outside[sl]].min())) if count else None)
        return escaped

    def unstable_reason(self, problem: str, time_s: float) -> str:
        return (f"{problem} at t = {time_s:.6f} s (dt = {self.dt_s:.3e} s, bound {self.bound.dt_s:.3e} s set "
                f"by {self.bound.limiting_term}): reduce simulation.dt_s / dt_safety, or soften the contact "
                f"(contact.P0_uN, larger contact.c0_mm)")

    def check_health(self, state: State, energy_budget_nJ: float | None = None) -> dict[str, float]:
        """Energies of ``state`` (all worlds, nJ); raises SimulationUnstable when any
        world is unstable (see :meth:`world_health`)."""
        budget = None if energy_budget_nJ is None else np.full(self.model.world_count, energy_budget_nJ)
        energies, problems = self.world_health(state, budget)
        for problem in problems:
            if problem is not None:
                raise SimulationUnstable(problem)
        return {k: float(v.sum()) for k, v in energies.items()}


# steps per captured graph: capturing one implicit step (34 launches) costs ~5 ms on the CPU, a replay
# ~7 µs per graph; 8 keeps replays under 1 µs a step and a capture short (the seed case's 22-step
# frames: 2-step graphs, first frame 128 → 13 ms)
GRAPH_STEPS_MAX = 8
MEASURE_GRAPHS = 8  # captured measurement graphs a solver keeps (Solver._replayed)


def graph_steps(chunk: int, most: int = GRAPH_STEPS_MAX) -> int:
    """Steps per captured graph: the largest even divisor of ``chunk`` up to ``most``
    (a chunk replays its graph chunk / that many times); 0 for a chunk under 2 steps."""
    return max((g for g in range(2, min(chunk, most) + 1, 2) if chunk % g == 0), default=0)


class Stepper:
    """Runs a Solver in chunks of ``chunk`` steps over two ping-pong states,
    replaying a captured graph of a few steps (CPU and CUDA; :func:`graph_steps`)
    as often as the chunk needs.

    The current state is always ``self.state``; between chunks the host may
    read it, change the control arrays' contents, or stop. A chunk may have any
    number of steps ≥ 1: an odd one ends with one more step and a copy back.
    """

    def __init__(self, solver: Solver, state: State, control: Control, chunk: int = 100,
                 use_graph: bool = True, graph_steps_max: int = GRAPH_STEPS_MAX):
        """``graph_steps_max``: the most steps one captured graph holds (capture costs
        milliseconds a step on the CPU, GRAPH_STEPS_MAX's note; 2 for a stepper that runs few chunks)."""
        if chunk < 1:
            raise ValueError(f"chunk must be 1 or more steps, got {chunk}")
        self.solver, self.control, self.chunk = solver, control, chunk
        self._graph_steps_max = graph_steps_max
        self._a, self._b = state, new_state_like(solver.model)
        self._b.copy_from(state)
        self.steps = 0
        self._graph = None
        self._graph_conditional = False  # whether that graph holds conditionals (_capture)
        self._use_graph = use_graph and (solver.model.device.is_cpu or solver.model.device.is_cuda)

    @property
    def state(self) -> State:
        return self._a

    def forget_graph(self) -> None:
        """Drop the captured graph: the solver's settings changed (θ, method), which a graph
        holds as they were at its capture; the next chunk captures it again."""
        self._graph = None

    def _launch_steps(self, steps: int) -> None:
        for _ in range(steps // 2):
            self.solver.step(self._a, self._b, self.control)
            self.solver.step(self._b, self._a, self.control)

    def run_chunk(self, between: Callable[[float], None] | None = None) -> State:
        """Advance by ``chunk`` steps; returns the current state. A multistep solver's
        start (Solver.needs_start) is launched directly, before the graph, which
        always captures the solver's steady step. ``between(t_mid_s)``: called before each
        graph replay (at most GRAPH_STEPS_MAX steps, or ``graph_steps_max``) and each group of
        direct launches with the middle of the time they advance, for control arrays that
        follow the clock within a chunk (a deflating balloon)."""
        start = self._a.time_s
        dt = self.solver.dt_s
        done = 0  # steps advanced so far in this chunk

        def at(steps: int) -> None:  # ``between`` for the next ``steps`` steps
            nonlocal done
            if between is not None and steps:
                between(start + (done + 0.5 * steps) * dt)
            done += steps

        even = self.chunk - self.chunk % 2
        per_graph = graph_steps(even, self._graph_steps_max)
        if even and self.solver.needs_start(self._a):
            at(2)
            self._launch_steps(2)
            even -= 2
        if self._use_graph and self._graph is None and per_graph:
            for module in self.solver.kernel_modules:
                wp.load_module(module, device=self.solver.model.device)
            self.solver.allocate_neighbour_grid(self._a)  # no allocation inside the capture
            try:
                self._graph = self._capture(per_graph)
            except RuntimeError:
                if not self.solver._conditional_rebuild:
                    raise
                self.solver.drop_conditionals()
                self._graph = self._capture(per_graph)
        if self._graph is not None:
            for _ in range(even // per_graph):
                at(per_graph)
                self._replay(per_graph)
            at(even % per_graph)
            self._launch_steps(even % per_graph)  # (after a start: the steps short of a whole graph)
        else:
            at(even)
            self._launch_steps(even)
        if self.chunk % 2:  # the odd step, into the other buffer and back
            at(1)
            self.solver.step(self._a, self._b, self.control)
            self._a.copy_from(self._b)
        self.steps += self.chunk
        self._a.time_s = start + self.chunk * self.solver.dt_s
        return self._a

    def _capture(self, steps: int):
        """A graph of ``steps`` steps from the current buffers (noting whether it holds conditionals)."""
        self._graph_conditional = self.solver._conditional_rebuild
        with wp.ScopedCapture(device=self.solver.model.device) as capture:
            self._launch_steps(steps)
        return capture.graph

    def _replay(self, steps: int) -> None:
        """Launch the captured graph (``steps`` steps). On a GPU the first launch instantiates it,
        before any step runs; a driver that captured the conditional neighbour-grid rebuild but cannot
        instantiate it (the build's host-to-device copy inside a conditional body) fails there, and
        the graph is captured again without conditionals."""
        try:
            wp.capture_launch(self._graph)
        except RuntimeError:
            if not (uninstantiated(self._graph) and self._graph_conditional):
                raise
            self.solver.drop_conditionals()
            self._graph = self._capture(steps)
            wp.capture_launch(self._graph)

    def run_steps(self, steps: int, check_every_chunk: bool = True) -> State:
        """Advance by at least ``steps`` (rounded up to whole chunks)."""
        for _ in range(-(-steps // self.chunk)):
            self.run_chunk()
            if check_every_chunk:
                self.solver.check_health(self._a)
        return self._a

    def run_to_rest(self, kinetic_tolerance_nJ: float, max_steps: int, min_steps: int = 0) -> tuple[State, bool]:
        """Advance until kinetic energy < tolerance (after ``min_steps``); returns
        (state, reached_rest)."""
        while self.steps < max_steps:
            self.run_chunk()
            e = self.solver.check_health(self._a)
            if self.steps >= min_steps and e["kinetic_nJ"] < kinetic_tolerance_nJ:
                return self._a, True
        return self._a, False
