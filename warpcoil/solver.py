"""Solver: advances a State by semi-implicit Euler steps of the model's forces.

``solver.step(state_in, state_out, control, dt)`` is one step (a fixed list of
kernel launches, so whole chunks of steps are captured as one graph and
replayed: :class:`Stepper`). The step size is checked against the explicit
stability bound of the stiffest term (:func:`stable_step_bound`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import warp as wp

from .kernels import contact, elastic, integrate
from .model import Model
from .settings import DEFAULT_DT_SAFETY
from .state import State, new_state_like

SPEED_LIMIT_MM_S = 1.0e5  # 100 m/s: far beyond any whip of a released coil end; a node this fast has gone unstable
WALL_SEARCH_MM = 0.1  # wall search beyond the contact range; a step moves a node ~1e-3 mm
CONTACTS_PER_NODE = 4  # contacts a node may press on at once, for the contact term of the step bound
CONTACTS_AT_ONSET = 8  # ... and in a dense pack, for where the contact law turns linear


class UnstableStepError(ValueError):
    """A step size above the explicit stability bound was asked for."""


class SimulationUnstable(RuntimeError):
    """The run produced non-finite or runaway values; ``reason`` says which and why."""

    def __init__(self, reason: str):
        super().__init__(reason)
        self.reason = reason


@dataclass(frozen=True)
class StepBound:
    """Explicit stability bound dt < 2/ω_max, and the term that sets it."""

    dt_s: float
    limiting_term: str
    omega_rad_s: dict = field(default_factory=dict)


def stable_step_bound(model: Model, contact_stiffness_uN_mm: float = 0.0) -> StepBound:
    """Gershgorin bounds of the highest angular frequency of each term, per node:

    * stretching: 2 (k_s,i-1 + k_s,i) / m_i (4 k_s/m for a uniform chain)
    * bending: 16 k_b / (m l̄²) (the squared second difference of a straight chain)
    * twisting: (4 k_t + k_b |K̄|²) / J
    * contact: the contact law's slope at the design overlap (u = 3, h = −2 c0),
      times CONTACTS_PER_NODE, / m (when given)
    """
    inv_m = model.inv_mass.numpy()
    has_next = model.has_next.numpy() == 1
    ks = model.k_stretch.numpy()
    kb = model.k_bend.numpy()
    kt = model.k_twist.numpy()
    rest_len = model.rest_length.numpy()
    l_edge = np.where(has_next, rest_len, np.inf)
    ks_prev = np.concatenate([[0.0], ks[:-1]])
    kbar = np.maximum(np.linalg.norm(model.rest_K0.numpy(), axis=1), np.linalg.norm(model.rest_K1.numpy(), axis=1))
    kb_max = np.max(np.stack([kb, np.roll(kb, 1), np.roll(kb, -1)]), axis=0)
    kt_max = np.max(np.stack([kt, np.roll(kt, -1)]), axis=0)
    l_min = np.minimum(l_edge, np.concatenate([[np.inf], l_edge[:-1]]))
    inv_j = model.inv_inertia.numpy()
    omega_sq = {
        "stretching (coil axial_stiffness_uN)": np.max(2.0 * (ks_prev + ks) * inv_m),
        "bending (coil bending_stiffness_uN_mm2)": np.max(16.0 * kb_max * inv_m / l_min**2),
        "twisting (coil twist_stiffness_uN_mm2)": np.max((4.0 * kt_max + kb_max * kbar**2) * inv_j),
    }
    if contact_stiffness_uN_mm > 0.0:
        omega_sq["contact (contact P0_uN / c0_mm)"] = contact_stiffness_uN_mm * np.max(inv_m)
    omega = {k: math.sqrt(v) for k, v in omega_sq.items()}
    name = max(omega, key=omega.get)
    return StepBound(dt_s=2.0 / omega[name], limiting_term=name, omega_rad_s=omega)


def contact_linear_onset(model: Model, dt_s: float) -> float:
    """Overlap u (= 1 − h/c0) where the contact law turns linear for this step:
    MODEL.md's 7, or earlier, where the law's stiffness reaches what an explicit
    step dt can integrate for the lightest node pressed from CONTACTS_AT_ONSET
    sides (k_max = m (2/dt)² / CONTACTS_AT_ONSET); never below u = 2 (h = −c0).
    Up to it the law is exact; past it the force keeps growing along the law's
    tangent, so deep overlaps in an overpacked sac stay stable instead of blowing
    up. For the default coil and step it is u ≈ 2.8 (|F| ≈ 24 P0)."""
    m_min = 1.0 / float(model.inv_mass.numpy().max())
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


@dataclass
class Control:
    """What drives the model from outside: which coil the pusher moves, how fast."""

    active_coil: wp.array  # int32[1]; −1 when nobody pushes
    push_speed_mm_s: float = 0.0

    @staticmethod
    def create(model: Model, active_coil: int = -1, push_speed_mm_s: float = 0.0) -> "Control":
        return Control(wp.array([active_coil], dtype=wp.int32, device=model.device), push_speed_mm_s)

    def set_active_coil(self, coil: int) -> None:
        self.active_coil.fill_(coil)


class Solver:
    """Elastic forces, catheter kinematics and time integration for one Model.

    ``dt_s`` None → ``dt_safety`` (default 0.9) × the stable bound. A larger dt than the bound
    raises :class:`UnstableStepError` unless ``allow_unstable_dt``.
    """

    def __init__(self, model: Model, dt_s: float | None = None, dt_safety: float = DEFAULT_DT_SAFETY,
                 allow_unstable_dt: bool = False, coil_contact: bool = True,
                 wall_search_mm: float = WALL_SEARCH_MM):
        self.model = model
        self.coil_contact = coil_contact
        self.wall_search_mm = wall_search_mm
        with_contact = coil_contact or model.wall is not None
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
        zeros = lambda dtype: wp.zeros(n, dtype=dtype, device=dev)  # noqa: E731
        self.grad_prev, self.grad_mid, self.grad_next = zeros(wp.vec3d), zeros(wp.vec3d), zeros(wp.vec3d)
        self.grad_theta = zeros(wp.vec2d)
        self.force, self.contact_force = zeros(wp.vec3d), zeros(wp.vec3d)
        self.torque, self.push_share = zeros(wp.float64), zeros(wp.float64)
        self._kinetic, self._unhealthy = zeros(wp.float64), zeros(wp.int32)
        self._stretch_e, self._bend_e, self._twist_e = zeros(wp.float64), zeros(wp.float64), zeros(wp.float64)
        self.wall_force, self.wall_distance = zeros(wp.vec3d), zeros(wp.float64)
        self.wall_distance.fill_(float(contact.FAR_MM))
        self._wall_side = zeros(wp.int32)
        self._wall_side.fill_(-1)
        self.coil_gap, self.coil_contacts = zeros(wp.float64), zeros(wp.int32)
        self._midpoints = zeros(wp.vec3d)
        self._edge_force_start, self._edge_force_end = zeros(wp.vec3d), zeros(wp.vec3d)
        self.push_accumulator = wp.zeros(2, dtype=wp.float64, device=dev)  # Σ and max of the step push force
        cells = int(min(128, max(8, 2 * round(n ** (1.0 / 3.0)))))  # hashed grid: ~8 cells per edge
        self._grid = wp.HashGrid(cells, cells, cells, device=dev, dtype=wp.float64) if coil_contact else None

    # --- one step ----------------------------------------------------------
    def compute_contacts(self, state: State, wall_search_mm: float | None = None) -> None:
        """Wall and coil–coil contact forces into ``contact_force`` (µN), with the
        per-node wall distance and the per-edge smallest coil gap and touching pairs
        (each pair counted from both edges). ``wall_search_mm``: how far beyond the
        contact range the wall is searched (default the solver's; a large value
        gives exact distances for every node, for measurements)."""
        m, dev, n = self.model, self.model.device, self.model.node_count
        c = m.contact
        if m.wall is not None:
            w = m.wall
            wp.launch(contact.wall_contact, n, device=dev, inputs=[
                state.x, state.free, m.node_radius, w.mesh.id, w.vertices, w.faces, wp.vec3d(*w.origin),
                c.p0_uN, c.c0_mm, self.contact_u_linear,
                self.wall_search_mm if wall_search_mm is None else wall_search_mm, self._wall_side,
                self.wall_force, self.wall_distance])
        if self.coil_contact:
            wp.launch(contact.edge_midpoints, n, device=dev, inputs=[state.x, m.has_next, self._midpoints])
            self._grid.build(self._midpoints, c.query_radius_mm)
            wp.launch(contact.edge_contact, n, device=dev, inputs=[
                state.x, state.free, m.has_next, m.coil_of, m.fixed, m.node_radius, self._grid.id, self._midpoints,
                c.query_radius_mm, c.exclusion_edges, c.p0_uN, c.c0_mm, self.contact_u_linear, self._edge_force_start,
                self._edge_force_end, self.coil_gap, self.coil_contacts])
            wp.launch(contact.gather_contact, n, device=dev, inputs=[
                state.free, m.has_next, self.wall_force, self._edge_force_start, self._edge_force_end,
                self.contact_force])
        elif m.wall is not None:
            wp.copy(self.contact_force, self.wall_force)

    def compute_forces(self, state: State) -> None:
        """Node forces (µN), edge torques (µN·mm) and push shares at ``state``."""
        m, dev, n = self.model, self.model.device, self.model.node_count
        self.compute_contacts(state)
        wp.launch(elastic.vertex_gradients, n, device=dev, inputs=[
            state.x, state.m1, state.free, m.has_next, m.k_bend, m.k_twist, m.rest_K0, m.rest_K1,
            m.rest_twist, self.grad_prev, self.grad_mid, self.grad_next, self.grad_theta])
        wp.launch(elastic.gather_forces, n, device=dev, inputs=[
            state.x, state.free, m.has_next, m.k_stretch, m.rest_length, self.grad_prev, self.grad_mid,
            self.grad_next, self.grad_theta, m.external, self.contact_force, m.node_radius, m.contact.fold_span,
            m.contact.p0_uN, m.contact.c0_mm, self.contact_u_linear, wp.vec3d(*m.catheter_axis),
            self.force, self.torque, self.push_share])

    def step(self, state_in: State, state_out: State, control: Control, dt: float | None = None) -> None:
        """Advance ``state_in`` by dt into ``state_out`` (distinct buffers)."""
        m, dev, n = self.model, self.model.device, self.model.node_count
        dt = self.dt_s if dt is None else dt
        self.compute_forces(state_in)
        wp.launch(integrate.integrate_nodes, n, device=dev, inputs=[
            state_in.x, state_in.v, state_in.advance, self.force, m.fixed, m.coil_of, m.arc_s, m.inv_mass,
            m.damping_c, m.damping_k, m.catheter_path, control.active_coil, control.push_speed_mm_s, dt,
            state_out.x, state_out.v, state_out.free, state_out.advance])
        wp.launch(integrate.update_frames, n, device=dev, inputs=[
            state_in.x, state_out.x, state_in.m1, state_in.omega, self.torque, state_out.free, m.has_next,
            m.inv_inertia, m.twist_damping, dt, state_out.m1, state_out.omega])
        wp.launch(integrate.accumulate_push_force, 1, device=dev, inputs=[self.push_share, self.push_accumulator])
        state_out.time_s = state_in.time_s + dt

    # --- measurements ------------------------------------------------------
    def _launch_elastic_energies(self, state: State) -> None:
        m = self.model
        wp.launch(elastic.elastic_energies, m.node_count, device=m.device, inputs=[
            state.x, state.m1, m.has_next, m.k_stretch, m.rest_length, m.k_bend, m.k_twist, m.rest_K0,
            m.rest_K1, m.rest_twist, self._stretch_e, self._bend_e, self._twist_e])

    def elastic_energy_per_node(self, state: State) -> np.ndarray:
        """Stretching (edge i) + bending and twisting (vertex i) energy at index i, nJ."""
        self._launch_elastic_energies(state)
        return self._stretch_e.numpy() + self._bend_e.numpy() + self._twist_e.numpy()

    def energies(self, state: State) -> dict[str, float]:
        """Kinetic (free nodes, translation + spin), stretching, bending and twisting energy, nJ."""
        m = self.model
        wp.launch(integrate.kinetic_energies, m.node_count, device=m.device, inputs=[
            state.v, state.omega, state.free, m.inv_mass, m.inv_inertia, self._kinetic, self._unhealthy,
            SPEED_LIMIT_MM_S])
        self._launch_elastic_energies(state)
        return {
            "kinetic_nJ": float(self._kinetic.numpy().sum()),
            "stretch_nJ": float(self._stretch_e.numpy().sum()),
            "bend_nJ": float(self._bend_e.numpy().sum()),
            "twist_nJ": float(self._twist_e.numpy().sum()),
        }

    def take_push_force(self, steps: int) -> tuple[float, float]:
        """Mean and largest push force (µN, compressive > 0) over the last ``steps``
        steps, and restart the accumulation."""
        total, largest = self.push_accumulator.numpy()
        self.push_accumulator.zero_()
        return float(total) / max(steps, 1), float(largest)

    def check_health(self, state: State, energy_budget_nJ: float | None = None) -> dict[str, float]:
        """Energies of ``state``; raises SimulationUnstable on NaN, a runaway speed, or
        (with ``energy_budget_nJ``: the energy put in so far, by packing and pushing)
        kinetic + elastic energy above twice that budget — damping only removes
        energy, so more than was put in means the integration is unstable."""
        e = self.energies(state)
        bad = int(self._unhealthy.numpy().sum())
        x = state.x.numpy()
        problem = None
        if bad or not np.isfinite(x).all() or not all(math.isfinite(v) for v in e.values()):
            problem = f"{bad} node(s) non-finite or faster than {SPEED_LIMIT_MM_S:.0e} mm/s"
        elif energy_budget_nJ is not None and sum(e.values()) > 2.0 * energy_budget_nJ:
            problem = (f"energy blow-up: kinetic + elastic {sum(e.values()):.4g} nJ > twice the energy put in "
                       f"({energy_budget_nJ:.4g} nJ)")
        if problem:
            raise SimulationUnstable(
                f"{problem} at t = {state.time_s:.6f} s (dt = {self.dt_s:.3e} s, bound {self.bound.dt_s:.3e} s set "
                f"by {self.bound.limiting_term}): reduce simulation.dt_s / dt_safety, or soften the contact "
                f"(contact.P0_uN, larger contact.c0_mm)")
        return e


class Stepper:
    """Runs a Solver in chunks of ``chunk`` steps over two ping-pong states,
    replaying a captured graph of the chunk (CPU and CUDA) after the first.

    The current state is always ``self.state``; between chunks the host may
    read it, change the control arrays' contents, or stop.
    """

    def __init__(self, solver: Solver, state: State, control: Control, chunk: int = 100,
                 use_graph: bool = True):
        if chunk < 2 or chunk % 2:
            raise ValueError("chunk must be an even number of steps ≥ 2")
        self.solver, self.control, self.chunk = solver, control, chunk
        self._a, self._b = state, new_state_like(solver.model)
        self._b.copy_from(state)
        self.steps = 0
        self._graph = None
        self._use_graph = use_graph and (solver.model.device.is_cpu or solver.model.device.is_cuda)

    @property
    def state(self) -> State:
        return self._a

    def _launch_chunk(self) -> None:
        for _ in range(self.chunk // 2):
            self.solver.step(self._a, self._b, self.control)
            self.solver.step(self._b, self._a, self.control)

    def run_chunk(self) -> State:
        """Advance by ``chunk`` steps; returns the current state."""
        start = self._a.time_s
        if self._use_graph and self._graph is None:
            for module in (elastic, integrate):
                wp.load_module(module, device=self.solver.model.device)
            with wp.ScopedCapture(device=self.solver.model.device) as capture:
                self._launch_chunk()
            self._graph = capture.graph
        if self._graph is not None:
            wp.capture_launch(self._graph)
        else:
            self._launch_chunk()
        self.steps += self.chunk
        self._a.time_s = start + self.chunk * self.solver.dt_s
        return self._a

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
