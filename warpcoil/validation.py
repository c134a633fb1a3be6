"""Validation cases with analytic references (``warpcoil validate``; the tests run
the same functions).

Each case returns :class:`CaseResult` rows: reference, result, relative error
and tolerance. Units mm, g, s, µN.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import warp as wp

from . import preshape
from .coil import CoilSpec
from .kernels import contact, integrate
from .metrics import fit_helix
from .model import ModelBuilder
from .settings import DEFAULT_DT_SAFETY, UNDAMPED_DT_SAFETY, CatheterSpec, ContactSettings, SimulationSettings
from .implicit import EULER, IMPLICIT_SETTLE_THETA, IMPLICIT_THETA, implicit_step_s, make_solver
from .solver import Control, Solver, Stepper
from .state import packed_state, state_from_positions

REFERENCE_D_MM = 0.2921  # the abstract's coil: secondary radius 0.014605 cm


@dataclass(frozen=True)
class CaseResult:
    case: str
    reference: float
    result: float
    error: float  # relative, or absolute where the reference is 0
    tolerance: float

    @property
    def passed(self) -> bool:
        return bool(self.error <= self.tolerance)


def _rel(result: float, reference: float) -> float:
    return abs(result - reference) / abs(reference) if reference != 0.0 else abs(result)


def _row(case: str, reference: float, result: float, tolerance: float) -> CaseResult:
    return CaseResult(case, float(reference), float(result), _rel(result, reference), tolerance)


# --- contact law ------------------------------------------------------------
def contact_law(p0_uN: float = 1.0e3, c0_mm: float = 0.1 * REFERENCE_D_MM) -> list[CaseResult]:
    """F(0) = P0, F(−6 c0) = 4463.43 P0, value and slope continuous at u = 7, zero for h ≥ c0."""
    eps = 1e-9 * c0_mm
    h = np.array([0.0, -6.0 * c0_mm, -6.0 * c0_mm - eps, -6.0 * c0_mm + eps, c0_mm, 2.0 * c0_mm, c0_mm - eps])
    f = wp.zeros(len(h), dtype=wp.float64)
    k = wp.zeros(len(h), dtype=wp.float64)
    wp.launch(contact.evaluate_law, len(h), inputs=[wp.array(h, dtype=wp.float64), p0_uN, c0_mm,
                                                    float(contact.U_LINEAR), f, k])
    f, k = f.numpy(), k.numpy()
    jump = abs(f[2] - f[3]) / f[1]
    kink = abs(k[2] - k[3]) / k[1]
    return [
        _row("contact: F(0)/P0", 1.0, f[0] / p0_uN, 1e-12),
        _row("contact: F(-6 c0)/P0", 4463.43, f[1] / p0_uN, 1e-6),
        CaseResult("contact: value jump at u=7 (rel.)", 0.0, jump, jump, 1e-6),
        CaseResult("contact: slope jump at u=7 (rel.)", 0.0, kink, kink, 1e-6),
        CaseResult("contact: F at h = c0, 2 c0, c0-", 0.0, f[4] + f[5] + f[6], f[4] + f[5] + f[6], 1e-9),
    ]


# --- gradient -----------------------------------------------------------------
def _rotate(v: np.ndarray, axis: np.ndarray, angle: float | np.ndarray) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    c, s = np.atleast_1d(c)[:, None], np.atleast_1d(s)[:, None]
    return v * c + np.cross(axis, v) * s + axis * np.sum(axis * v, axis=1, keepdims=True) * (1.0 - c)


def gradient_check(positions: np.ndarray, directors: np.ndarray, rest: np.ndarray, spec: CoilSpec,
                   eps: float = 1e-6, clamp_direction=None) -> tuple[float, float]:
    """Relative error of forces and twisting torques against central differences of
    the energy, with directors dragged by parallel transport (as the solver does).
    ``clamp_direction``: clamp node 0 with this tangent (its vertex is checked too).

    All 6N + 2(N−1) perturbed copies are evaluated in one batch model."""
    n = len(positions)
    dofs = 3 * n

    def add(builder: ModelBuilder) -> None:
        coil = builder.add_coil(spec, rest)
        if clamp_direction is not None:
            builder.clamp(coil, node=0, direction=clamp_direction)

    builder = ModelBuilder()
    add(builder)
    model = builder.finalize()
    state = state_from_positions(model, positions)
    state.m1.assign(directors)
    state.free.fill_(1)  # forces on every node, the clamped one included
    solver = Solver(model)
    solver.compute_forces(state)
    force, torque = solver.force.numpy(), solver.torque.numpy()[: n - 1]

    signs = np.array([1.0, -1.0])
    shift = np.einsum("s,kd->skd", signs * eps, np.eye(dofs)).reshape(2 * dofs, n, 3)
    moved = positions[None] + shift  # (2·3N, n, 3)
    copies = 2 * dofs + 2 * (n - 1)
    batch = ModelBuilder()
    for _ in range(copies):
        add(batch)
    batch_model = batch.finalize()
    x_old = np.tile(positions, (copies, 1))
    x_new = np.concatenate([moved.reshape(-1, 3), np.tile(positions, (2 * (n - 1), 1))])
    m1 = wp.zeros(copies * n, dtype=wp.vec3d)
    zeros_f = wp.zeros(copies * n, dtype=wp.float64)
    wp.launch(integrate.update_frames, copies * n, inputs=[
        wp.array(x_old, dtype=wp.vec3d), wp.array(x_new, dtype=wp.vec3d), wp.array(np.tile(directors, (copies, 1)),
        dtype=wp.vec3d), zeros_f, zeros_f, wp.zeros(copies * n, dtype=wp.int32), batch_model.fixed, batch_model.has_next,
        batch_model.inv_inertia, zeros_f, batch_model.world_of, wp.ones(1, dtype=wp.int32), 0.0, m1,
        wp.zeros(copies * n, dtype=wp.float64)])
    m1 = m1.numpy().reshape(copies, n, 3)
    tangents = np.diff(positions, axis=0)
    tangents /= np.linalg.norm(tangents, axis=1)[:, None]
    for sign_index, sign in enumerate(signs):  # twist perturbations, all edges at once
        rows = 2 * dofs + sign_index * (n - 1) + np.arange(n - 1)
        m1[rows, np.arange(n - 1)] = _rotate(directors[:-1], tangents, sign * eps)
    twisted = state_from_positions(batch_model, x_new)
    twisted.m1.assign(m1.reshape(-1, 3))
    batch_solver = Solver(batch_model)
    energy = batch_solver.elastic_energy_per_node(twisted).reshape(copies, n).sum(axis=1)
    grad_x = ((energy[:dofs] - energy[dofs:2 * dofs]) / (2 * eps)).reshape(n, 3)
    grad_theta = (energy[2 * dofs:2 * dofs + n - 1] - energy[2 * dofs + n - 1:]) / (2 * eps)
    force_err = np.abs(grad_x + force).max() / np.abs(force).max()
    torque_err = np.abs(grad_theta + torque).max() / max(np.abs(torque).max(), 1e-300)
    return float(force_err), float(torque_err)


def gradient_cases(seed: int = 0) -> list[CaseResult]:
    """Forces = −∇W on a random 3D configuration and on an exactly straight one."""
    rng = np.random.default_rng(seed)
    spec = CoilSpec(length_mm=4.0, loop_diameter_mm=2.0, axial_stiffness_uN=2.0e4)
    rest = preshape.helix(2.0, 0.8, 4.0, spec.l0)
    n = len(rest)
    curved = rest + 0.03 * rng.standard_normal(rest.shape)
    tangents = np.diff(curved, axis=0)
    tangents /= np.linalg.norm(tangents, axis=1)[:, None]
    model_builder = ModelBuilder()
    model_builder.add_coil(spec, rest)
    model = model_builder.finalize()
    bishop = model.directors_along(curved)
    twisted = bishop.copy()
    twisted[:-1] = _rotate(bishop[:-1], tangents, rng.uniform(-0.5, 0.5, n - 1))
    straight = np.zeros_like(rest)
    straight[:, 2] = np.arange(n) * spec.l0 * 1.001
    straight_dirs = model.directors_along(straight)
    straight_dirs[:-1] = _rotate(straight_dirs[:-1], np.array([0.0, 0.0, 1.0]), rng.uniform(-0.5, 0.5, n - 1))
    rows = []
    tilted = _rotate(tangents[:1], np.array([[0.0, 0.6, 0.8]]), 0.3)[0]  # clamp direction 0.3 rad off edge 0
    for label, x, m1, clamp in (("random 3D", curved, twisted, None), ("straight", straight, straight_dirs, None),
                                ("random 3D, clamped at node 0", curved, twisted, tilted)):
        f_err, t_err = gradient_check(x, m1, rest, spec, clamp_direction=clamp)
        rows.append(CaseResult(f"gradient: force vs FD, {label}", 0.0, f_err, f_err, 1e-5))
        rows.append(CaseResult(f"gradient: torque vs FD, {label}", 0.0, t_err, t_err, 1e-5))
    return rows


# --- cantilever ---------------------------------------------------------------
def extensible_elastica(load_parameter: float, axial_ratio: float, steps: int = 4000) -> float:
    """Tip deflection δ/L of the extensible elastica (Kirchhoff rod, no shear),
    clamped at s = 0 along +x, under a transverse dead load P at s = L.

    With s̃ = s/L, p = P L²/EI and ε = P/EA (``axial_ratio``), θ the tangent
    angle and λ = 1 − ε sin θ the axial stretch (tension N = −P sin θ)::

        θ'' = p λ cos θ,   y' = λ sin θ,   θ(0) = 0,   θ'(1) = 0

    shot on θ'(0) (bisection, classical RK4 in s̃): δ/L = −y(1). ε = 0 gives the
    Euler elastica (p = 5: 0.713792)."""

    def shoot(curvature0: float) -> tuple[float, float]:
        h = 1.0 / steps

        def rhs(u: np.ndarray) -> np.ndarray:
            theta, dtheta, _ = u
            stretch = 1.0 - axial_ratio * math.sin(theta)
            return np.array([dtheta, load_parameter * stretch * math.cos(theta), stretch * math.sin(theta)])

        u = np.array([0.0, curvature0, 0.0])
        for _ in range(steps):
            k1 = rhs(u)
            k2 = rhs(u + 0.5 * h * k1)
            k3 = rhs(u + 0.5 * h * k2)
            k4 = rhs(u + h * k3)
            u = u + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        return u[1], -u[2]

    low, high = -load_parameter, 0.0  # θ'(0) lies between −p (rigid lever arm) and 0
    for _ in range(60):
        mid = 0.5 * (low + high)
        low, high = (low, mid) if shoot(mid)[0] > 0.0 else (mid, high)
    return shoot(0.5 * (low + high))[1]


def _solver(model, integrator: str, dt_safety: float = DEFAULT_DT_SAFETY, **kwargs) -> Solver:
    """The reference solver, or the implicit one at its default step (pusher at the default speed)."""
    dt = implicit_step_s(model, SimulationSettings().push_speed_mm_s) if integrator == "implicit" else None
    return make_solver(model, integrator, dt, dt_safety=dt_safety, **kwargs)


def _relaxing(integrator: str) -> dict:
    """Solver options of a relaxation with nothing pushed: the implicit default as a deployment
    settles (θ IMPLICIT_SETTLE_THETA; the gate a no-op, the chord on)."""
    return {"theta": IMPLICIT_SETTLE_THETA} if integrator == "implicit" else {}


def cantilever_deflection(segments: int, load_parameter: float, length_mm: float = 20.0,
                          dt_safety: float = DEFAULT_DT_SAFETY, integrator: str = "symplectic") -> tuple[float, float]:
    """Tip deflection δ/L of a straight coil clamped at node 0 (x = 0, along +x)
    under a transverse dead load P = load_parameter · EI / L² at its free end,
    damped to rest; returns (result, the extensible elastica's δ/L for its EA).
    Nodes sit at x = k L/n (:meth:`ModelBuilder.clamp`: position and tangent at
    node 0). ``integrator`` "implicit": at its default step, as a deployment settles (θ 1)."""
    l0 = length_mm / segments
    spec = CoilSpec(length_mm=length_mm, segment_length_mm=l0)
    rest = np.zeros((segments + 1, 3))
    rest[:, 0] = np.arange(segments + 1) * l0
    omega1 = 3.516 * math.sqrt(spec.EI / (spec.rho * length_mm**4))  # first mode, rad/s
    speed_scale = 1.0e3  # mm/s: keep the damping in its linear range
    damping = 2.0 * spec.rho * omega1 * speed_scale  # critical for mode 1, per mm
    builder = ModelBuilder(settings=SimulationSettings(damping_uN_per_mm=damping, damping_speed_mm_s=speed_scale))
    builder.add_coil(spec, rest)
    builder.clamp(0, node=0)
    load = load_parameter * spec.EI / length_mm**2
    builder.apply_force(0, -1, (0.0, -load, 0.0))
    model = builder.finalize()
    solver = _solver(model, integrator, dt_safety, coil_contact=False,  # a bending straight beam cannot touch itself
                     **_relaxing(integrator))
    stepper = Stepper(solver, state_from_positions(model, rest), Control.create(model), chunk=1000)
    min_steps = 20_000 if integrator == "symplectic" else 2_000
    state, rested = stepper.run_to_rest(1e-14 * load * length_mm, max_steps=4_000_000, min_steps=min_steps)
    if not rested:
        raise RuntimeError("cantilever did not come to rest")
    return float(-state.x.numpy()[-1, 1] / length_mm), extensible_elastica(load_parameter, load / spec.EA)


def observed_order(errors: list[float], ratio: float = 2.0) -> float:
    """Convergence order from the last two of errors at steps refined by ``ratio``."""
    return math.log(errors[-2] / errors[-1]) / math.log(ratio)


def cantilever_cases(resolutions=(25, 50, 100, 200)) -> list[CaseResult]:
    """Clamped at node 0, tip dead load P L²/EI = 5, against the extensible elastica
    (the coil's own EA): error ≤ 5e-3 from 50 segments, second order."""
    rows = []
    errors = []
    for segments in resolutions:
        result, reference = cantilever_deflection(segments, 5.0)
        row = _row(f"cantilever PL²/EI=5, {segments} segments: δ/L", reference, result,
                   5e-3 if segments >= 50 else 2e-2)
        rows.append(row)
        errors.append(row.error)
    order = observed_order(errors)
    rows.append(CaseResult(f"cantilever: observed order {resolutions[-2]}→{resolutions[-1]} segments", 2.0, order,
                           abs(order - 2.0) / 2.0, 0.25))
    result, reference = cantilever_deflection(50, 0.05)
    rows.append(_row("cantilever PL²/EI=0.05, 50 segments: δ/L vs elastica (≈ PL²/(3EI))", reference, result, 5e-3))
    return rows


# --- bending frequencies -----------------------------------------------------------
EULER_BERNOULLI_BETA_L = {"clamped-free": 1.875104068711961, "free-free": 4.730040744862704}


def _mode_shape(support: str, s: np.ndarray) -> np.ndarray:
    """Lowest Euler–Bernoulli bending mode of a rod of length 1 at s ∈ [0, 1]."""
    b = EULER_BERNOULLI_BETA_L[support]
    if support == "clamped-free":
        sigma = (math.cosh(b) + math.cos(b)) / (math.sinh(b) + math.sin(b))
        return np.cosh(b * s) - np.cos(b * s) - sigma * (np.sinh(b * s) - np.sin(b * s))
    sigma = (math.cosh(b) - math.cos(b)) / (math.sinh(b) - math.sin(b))
    return np.cosh(b * s) + np.cos(b * s) - sigma * (np.sinh(b * s) + np.sin(b * s))


def bending_frequency(support: str, segments: int, length_mm: float = 20.0,
                      dt_safety: float = DEFAULT_DT_SAFETY) -> tuple[float, float]:
    """Lowest bending frequency (rad/s) of a straight coil, clamped at node 0 or
    free at both ends, by the reference integrator: undamped free vibration from
    the Euler–Bernoulli mode shape (amplitude 1e-3 L), period from the zero
    crossings of its mass-weighted modal coordinate over about 1¼ periods.
    Returns (result, Euler–Bernoulli β² √(EI/ρ))."""
    spec = CoilSpec(length_mm=length_mm, segment_length_mm=length_mm / segments)
    s = np.linspace(0.0, 1.0, segments + 1)
    rest = np.zeros((segments + 1, 3))
    rest[:, 0] = s * length_mm
    shape = _mode_shape(support, s)
    shape /= np.abs(shape).max()
    start = rest.copy()
    start[:, 1] = 1e-3 * length_mm * shape
    builder = ModelBuilder(settings=SimulationSettings(damping_uN_per_mm=0.0))
    builder.add_coil(spec, rest)
    if support == "clamped-free":
        builder.clamp(0, node=0)
    model = builder.finalize()
    reference = (EULER_BERNOULLI_BETA_L[support] / length_mm) ** 2 * math.sqrt(spec.EI / spec.rho)
    solver = Solver(model, coil_contact=False, dt_safety=dt_safety)
    samples_per_period = 400
    chunk = max(2, 2 * round(2.0 * math.pi / reference / solver.dt_s / samples_per_period / 2))
    stepper = Stepper(solver, state_from_positions(model, start), Control.create(model), chunk=chunk)
    weight = shape / model.inv_mass.numpy()
    t, q = [0.0], [1.0]
    while t[-1] < 1.6 * 2.0 * math.pi / reference:  # three zero crossings, even 20 % slow
        state = stepper.run_chunk()
        t.append(state.time_s)
        q.append(float(weight @ state.x.numpy()[:, 1]) / float(weight @ start[:, 1]))
    t, q = np.array(t), np.array(q)
    k = np.flatnonzero(np.sign(q[:-1]) != np.sign(q[1:]))[:3]
    if len(k) < 3:
        raise RuntimeError(f"{support} rod: fewer than three zero crossings in 1.6 periods")
    crossings = t[k] - q[k] * (t[k + 1] - t[k]) / (q[k + 1] - q[k])
    return 2.0 * math.pi / (crossings[2] - crossings[0]), reference


def frequency_cases(resolutions=(25, 50, 100), length_mm: float = 20.0) -> list[CaseResult]:
    """Lowest bending frequency, clamped-free and free-free, against Euler–Bernoulli:
    ≤ 0.5 % from 50 segments, second order (lumped masses: half a segment at a free end)."""
    rows = []
    for support in ("clamped-free", "free-free"):
        errors = []
        for segments in resolutions:
            result, reference = bending_frequency(support, segments, length_mm)
            row = _row(f"frequency {support}, {segments} segments: ω1 (rad/s)", reference, result,
                       5e-3 if segments >= 50 else 2e-2)
            rows.append(row)
            errors.append(row.error)
        order = observed_order(errors)
        rows.append(CaseResult(f"frequency {support}: observed order {resolutions[-2]}→{resolutions[-1]}", 2.0,
                               order, abs(order - 2.0) / 2.0, 0.25))
    return rows


# --- helix recovery and free release -----------------------------------------
HELIX = dict(length_mm=60.0, loop_diameter_mm=3.0, pitch_mm=0.6)
TIGHT_HELIX = dict(length_mm=30.0, loop_diameter_mm=3.0, pitch_mm=REFERENCE_D_MM + 0.01)  # turns 10 µm apart


def _helix_spec(segment_length_mm: float | None = None, helix: dict = HELIX) -> CoilSpec:
    return CoilSpec(wire_diameter_mm=REFERENCE_D_MM, shape="helix", segment_length_mm=segment_length_mm, **helix)


def _helix_rows(label: str, points: np.ndarray, helix: dict = HELIX, pitch_tolerance: float = 3e-2
                ) -> list[CaseResult]:
    fit = fit_helix(points)
    return [
        _row(f"{label}: loop diameter (mm)", helix["loop_diameter_mm"], fit.loop_diameter_mm, 1e-2),
        _row(f"{label}: pitch (mm)", helix["pitch_mm"], fit.pitch_mm, pitch_tolerance),
    ]


def _settle(stepper: Stepper, max_steps: int) -> np.ndarray:
    state, rested = stepper.run_to_rest(1e-5, max_steps=max_steps)
    if not rested:
        raise RuntimeError("the coil did not come to rest")
    return state.x.numpy()


def _recovered(segment_length_mm: float | None, dt_safety: float, helix: dict, coil_contact: bool,
               damping_uN_per_mm: float = 5.0, integrator: str = "symplectic",
               stretch: float | None = None) -> np.ndarray:
    """Rest positions of a helical coil released with free ends and damped to rest:
    started straight, or (``stretch``) from its pre-shape stretched along its axis
    to ``stretch`` × its pitch (same loop diameter, arc length and segments). Implicit: at
    its default step, as a deployment settles (θ 1: :func:`_relaxing`)."""
    spec = _helix_spec(segment_length_mm, helix)
    builder = ModelBuilder(settings=SimulationSettings(damping_uN_per_mm=damping_uN_per_mm))
    builder.add_coil(spec)
    model = builder.finalize()
    if stretch is None:
        start = np.zeros((model.node_count, 3))
        start[:, 0] = model.arc_s.numpy()
    else:
        start = preshape.helix(spec.loop_diameter_mm, stretch * spec.helix_pitch_mm, spec.length_mm, spec.l0)
    stepper = Stepper(_solver(model, integrator, dt_safety, coil_contact=coil_contact, **_relaxing(integrator)),
                      state_from_positions(model, start), Control.create(model), chunk=1000)
    return _settle(stepper, max_steps=4_000_000)


def helix_recovery(segment_length_mm: float | None = None, dt_safety: float = DEFAULT_DT_SAFETY,
                   integrator: str = "symplectic") -> list[CaseResult]:
    """A 60 mm helical coil started straight, free ends, damped to rest (elastic only:
    a straight start is no physical state; ``tight_pitch`` runs it with contact)."""
    label = "helix recovery" if integrator == "symplectic" else f"helix recovery, {integrator} default step (settling θ)"
    return _helix_rows(label, _recovered(segment_length_mm, dt_safety, HELIX, coil_contact=False,
                                         integrator=integrator))


def tilted_catheter(tilt_deg: float = 0.0, azimuth_deg: float = 0.0) -> CatheterSpec:
    """The straight catheter at the origin, its direction turned from +z by ``tilt_deg``
    towards the azimuth ``azimuth_deg`` (from +x, about z): in free space a rigid rotation
    of the problem, so a tiny tilt changes only round-off (a perturbation of the path)."""
    tilt, azimuth = math.radians(tilt_deg), math.radians(azimuth_deg)
    return CatheterSpec(direction=(math.sin(tilt) * math.cos(azimuth), math.sin(tilt) * math.sin(azimuth),
                                   math.cos(tilt)))


def _released(push_speed_mm_s: float, dt_safety: float, segment_length_mm: float | None, mass_scale: float,
              helix: dict, damping_uN_per_mm: float = 5.0, integrator: str = "symplectic",
              catheter: CatheterSpec | None = None, advance_per_c0: float | None = None,
              solver_options: dict | None = None) -> np.ndarray:
    """Rest positions of a helical coil packed in a straight catheter and pushed out into
    empty space (``integrator`` "implicit": at its default step for this push speed, or at
    the step that advances the pusher ``advance_per_c0`` × the contact onset c0;
    ``solver_options``: the implicit solver's)."""
    spec = _helix_spec(segment_length_mm, helix)
    settings = SimulationSettings(damping_uN_per_mm=damping_uN_per_mm, push_speed_mm_s=push_speed_mm_s,
                                  mass_scale=mass_scale)
    builder = ModelBuilder(catheter=catheter or CatheterSpec(), settings=settings)
    builder.add_coil(spec)
    model = builder.finalize()
    control = Control.create(model, active_coil=0, push_speed_mm_s=push_speed_mm_s)
    dt = implicit_step_s(model, push_speed_mm_s) if integrator == "implicit" else None
    if integrator == "implicit" and advance_per_c0 is not None:
        dt = advance_per_c0 * model.contact.c0_mm / push_speed_mm_s
    stepper = Stepper(make_solver(model, integrator, dt, dt_safety=dt_safety, **(solver_options or {})),
                      packed_state(model), control, chunk=1000 if integrator == "symplectic" else 20)
    coil_length = float(model.arc_s.numpy()[-1])
    while stepper.state.advance.numpy()[0] < coil_length:
        stepper.run_steps(stepper.chunk)
    control.set_active_coil(-1)  # detached: the pusher stops
    return _settle(stepper, max_steps=stepper.steps + 4_000_000)


def free_release(push_speed_mm_s: float = 100.0, dt_safety: float = DEFAULT_DT_SAFETY,
                 segment_length_mm: float | None = None, mass_scale: float = 1.0,
                 integrator: str = "symplectic", catheter: CatheterSpec | None = None,
                 advance_per_c0: float | None = None, solver_options: dict | None = None,
                 label: str | None = None) -> list[CaseResult]:
    """The helical coil packed in a straight catheter (``catheter``: default along +z;
    :func:`tilted_catheter` perturbs it) and pushed out into empty space (implicit:
    ``advance_per_c0`` sets its push step, default the integrator's default;
    ``solver_options``: the implicit solver's)."""
    if label is None:
        label = "free release" if integrator == "symplectic" else f"free release, {integrator} default step"
    return _helix_rows(label, _released(push_speed_mm_s, dt_safety, segment_length_mm, mass_scale, HELIX,
                                        integrator=integrator, catheter=catheter, advance_per_c0=advance_per_c0,
                                        solver_options=solver_options))


TIGHT_STRETCH = 2.0  # the tight helix is released from twice its pitch: turns 0.31 mm apart, in order


def tight_pitch(length_mm: float = TIGHT_HELIX["length_mm"]) -> list[CaseResult]:
    """A helix whose turns are 10 µm apart (pitch d + 10 µm, below the default
    contact onset c0 = 0.1 d = 29 µm), with coil contact on: pushed into free space,
    and released from its pre-shape stretched to twice its pitch (its turns close
    in order onto their rest clearance). Both must come to rest in the pre-shape
    (loop diameter and pitch within 1 %): neighbouring turns of the rest shape do
    not repel each other at rest (docs/FORMULATION.md, rest clearance).

    Not from straight: a straight start forms every turn at once in a whip of
    1.6e4 nJ, and a close-wound helix so formed comes to rest tangled, its turns
    stacked out of order and held by contact — at every step tried (0.3–0.9 of
    the bound: 72–118 nJ left), also with c0 = 5 µm below the turn gap (no rest
    offset involved), while no segment passes through another and the total
    energy (kinetic + elastic + contact) never rises: a physical trapped state,
    not a numerical one (docs/FORMULATION.md, "Tight pitch from straight")."""
    damping = SimulationSettings().damping_uN_per_mm
    helix = dict(TIGHT_HELIX, length_mm=length_mm)
    push = _released(100.0, DEFAULT_DT_SAFETY, None, 1.0, helix, damping)
    recovery = _recovered(None, DEFAULT_DT_SAFETY, helix, True, damping, stretch=TIGHT_STRETCH)
    return (_helix_rows("tight pitch, pushed out (contact)", push, helix, 1e-2)
            + _helix_rows(f"tight pitch, released from {TIGHT_STRETCH:g}x its pitch (contact)", recovery, helix,
                          1e-2))


# --- dense packs come to rest ------------------------------------------------------
DENSE_PACKS = ((0.20, 4.0), (0.30, 3.5))  # packing density, helix loop diameter (mm): wider than the sac


def dense_pack_ensemble(packing: float, loop_diameter_mm: float, integrator: str, length_mm: float = 60.0,
                        seed: int = 1, wall_query: str = "bvh"):
    """A helical coil (d 0.2921 mm, pitch 2d) to be pushed at default settings on ``integrator``
    into an irregular, faceted, non-convex sac (:func:`warpcoil.faceted_sac.lobulated_sac`,
    1280 faces, volume π (d/2)² L / packing), the wall queried by ``wall_query``: its Ensemble,
    not yet run (with "sdf", its wall field built or loaded)."""
    from .deploy import Anatomy, Ensemble
    from .faceted_sac import catheter_tip, lobulated_sac
    from .settings import OutputSettings, Scene

    coil = CoilSpec(wire_diameter_mm=REFERENCE_D_MM, length_mm=length_mm, loop_diameter_mm=loop_diameter_mm)
    wall = lobulated_sac(math.pi * (REFERENCE_D_MM / 2.0) ** 2 * length_mm / packing, seed=seed)
    catheter = CatheterSpec(tip_mm=catheter_tip(wall, seed), direction=(0.0, 0.0, 1.0))
    scene = Scene(coils=(coil,), catheter=catheter, output=OutputSettings(usd=False),
                  simulation=SimulationSettings(integrator=integrator), contact=ContactSettings(wall_query=wall_query))
    return Ensemble([scene], anatomies=[Anatomy(wall=wall, sac=None, catheter=catheter)])


def dense_packs() -> list[CaseResult]:
    """60 mm coils into faceted sacs at 20 % and 30 % packing come to rest: the run
    completes (kinetic energy below the rest tolerance, ½ M (0.25 mm/s)² ≈ 1.2e-3 nJ)
    within its 2 s after detachment, at default settings, on the reference step (symplectic
    Euler) and on the default implicit step."""
    rows = []
    for integrator in ("symplectic", "implicit"):
        for packing, loop in DENSE_PACKS:
            result = dense_pack_ensemble(packing, loop, integrator).run()[0]
            label = f"dense pack {packing:.0%}, faceted sac" + ("" if integrator == "symplectic" else ", implicit")
            rows.append(_row(f"{label}: packing density", packing, result.packing_density, 1e-2))
            done = result.status == "completed"
            rows.append(CaseResult(f"{label}: completed (at rest after {result.simulated_time_s:.2f} s)", 1.0,
                                   float(done), 0.0 if done else 1.0, 0.0))
    return rows


# --- energy ---------------------------------------------------------------------
def energy_conservation(steps: int = 100_000) -> list[CaseResult]:
    """Undamped free vibration of a straight-rest coil started bent into an arc."""
    length, segments, bend_angle = 20.0, 40, 1.0
    spec = CoilSpec(length_mm=length, segment_length_mm=length / segments)
    s = np.linspace(0.0, length, segments + 1)
    rest = np.stack([s, np.zeros_like(s), np.zeros_like(s)], axis=1)
    radius = length / bend_angle
    arc = np.stack([radius * np.sin(s / radius), radius * (1.0 - np.cos(s / radius)), np.zeros_like(s)], axis=1)
    builder = ModelBuilder(settings=SimulationSettings(damping_uN_per_mm=0.0))
    builder.add_coil(spec, rest)
    model = builder.finalize()
    solver = Solver(model, coil_contact=False)  # a gently bent rod does not touch itself
    stepper = Stepper(solver, state_from_positions(model, arc), Control.create(model), chunk=1000)
    total = lambda e: sum(e.values())  # noqa: E731
    e0 = total(solver.energies(stepper.state))
    drift = 0.0
    for _ in range(steps // stepper.chunk):
        stepper.run_steps(stepper.chunk)
        drift = max(drift, abs(total(solver.energies(stepper.state)) - e0) / e0)
    return [CaseResult(f"energy: undamped, {steps} steps, max |ΔE|/E", 0.0, drift, drift, 1e-2)]


def implicit_devices() -> list[CaseResult]:
    """The implicit step with a balloon or a stent: rest under load, convergence (validation_devices.py)."""
    from .validation_devices import implicit_device_cases
    return implicit_device_cases()


def impact() -> list[CaseResult]:
    """A wall impact: the reference's restitution 1, the implicit step's converging (validation_impact.py)."""
    from .validation_impact import impact_cases
    return impact_cases()


def implicit_wall() -> list[CaseResult]:
    """The implicit step's wall stiffness: the force's Jacobian, rest in a groove (validation_implicit_wall.py)."""
    from .validation_implicit_wall import implicit_wall_cases
    return implicit_wall_cases()


def friction() -> list[CaseResult]:
    """Regularised Coulomb friction: incline, capstan, energy (validation_friction.py)."""
    from .validation_friction import friction_cases
    return friction_cases()


def bdf2() -> list[CaseResult]:
    """The linearly implicit BDF2 step: slow-mode damping, stiff-mode decay, convergence (validation_bdf2.py)."""
    from .validation_bdf2 import bdf2_cases
    return bdf2_cases()


def push_force() -> list[CaseResult]:
    """The push force where it is known: a straight coil into free space (damping) and
    at rest on a wall (the wall's reaction), both integrators (validation_push.py)."""
    from .validation_push import push_force_cases
    return push_force_cases()


def settle() -> list[CaseResult]:
    """The settling step set by the fastest node against the finest step (validation_settle.py)."""
    from .validation_settle import settle_cases
    return settle_cases()


def detach() -> list[CaseResult]:
    """The detachment step (a coil's tail leaving the catheter at push step / k) against k = 16
    (validation_detach.py)."""
    from .validation_detach import detach_cases
    return detach_cases()


def dissipation() -> list[CaseResult]:
    """The numerical-dissipation ledger run on the solver: a linear chain's analytic loss and
    ratio order, and a free coil's order in dt (validation_dissipation.py)."""
    from .validation_dissipation import dissipation_cases
    return dissipation_cases()


def contact_share() -> list[CaseResult]:
    """Contact weighted by each node's share of the coil: a coil on a floor presses evenly (validation_contact.py)."""
    from .validation_contact import contact_share_cases
    return contact_share_cases()


def contact_samples() -> list[CaseResult]:
    """Contact samples between the nodes of segments above 1.5 d: pressure per length kept, the
    crossing force converging to its integral as the samples grow, the wall at them (a coarse edge
    across a ridge; a coarse coil resting on a floor) (validation_contact.py)."""
    from .validation_contact import contact_sample_cases, wall_sample_cases
    return contact_sample_cases() + wall_sample_cases()


def regions() -> list[CaseResult]:
    """Regional packing densities on a cut sphere with analytic regions (validation_regions.py)."""
    from .validation_regions import region_cases
    return region_cases()


# --- wall field -------------------------------------------------------------
def wall_field_cases(diameter_mm: float = 3.5, voxels_mm: tuple[float, float] = (0.08, 0.04),
                     c0_mm: float = 0.1 * REFERENCE_D_MM, points: int = 20000) -> list[CaseResult]:
    """The narrow-band field of the seed sphere against the exact BVH at random
    points of the contact band (0–0.25 mm inside the wall), where the field is
    trusted: largest distance error (≤ 0.05 c0 at the default voxel), its
    observed order as the voxel halves (≈ 1: the faceted wall's creases; ≥ 2
    on a smooth wall), RMS normal error (≤ 2°), share of points trusted."""
    from .model import WallModel
    from .wall import sphere_wall
    from .wall_field import band_points, build_wall_field, field_error

    mesh = sphere_wall(diameter_mm)
    wall = WallModel.create(mesh.vertices_mm, mesh.faces, mesh.volume_mm3, wp.get_device())
    pts = band_points(wall, (0.0, 0.25), points)
    coarse, fine = (field_error(wall, build_wall_field(wall, 0.3, h), pts) for h in voxels_mm)
    order = math.log(coarse.distance_max_mm / fine.distance_max_mm) / math.log(voxels_mm[0] / voxels_mm[1])
    h = voxels_mm[1]
    return [
        CaseResult(f"wall field h={h} mm: max |d − d_BVH| / c0", 0.0, fine.distance_max_mm / c0_mm,
                   fine.distance_max_mm / c0_mm, 0.05),
        _row(f"wall field: observed order of the distance error, h {voxels_mm[0]} → {h} mm", 1.0, order, 0.6),
        CaseResult(f"wall field h={h} mm: RMS normal error (deg)", 0.0, fine.normal_rms_deg, fine.normal_rms_deg, 2.0),
        CaseResult(f"wall field h={h} mm: share of band points untrusted", 0.0, 1.0 - fine.trusted / fine.points,
                   1.0 - fine.trusted / fine.points, 0.05),
    ]


# --- porous field ------------------------------------------------------------------
def porous_cases(d_mm: float = 0.3) -> list[CaseResult]:
    """Sampled coil volume of one oblique capsule against π r² L + 4/3 π r³ as the voxel shrinks
    (d/2 → d/8); an aligned array of rods: its mean solid fraction, and the tensor of one of its
    voxels along and across the rods against Happel's K∥, K⊥ at that voxel's solid fraction."""
    import trimesh

    from .porous import happel_permeabilities_mm2, porous_field

    box = trimesh.creation.box(extents=[3.0] * 3)
    vertices, faces = np.asarray(box.vertices), np.asarray(box.faces)
    r = 0.5 * d_mm
    piece = np.array([[-1.0, 0.1234, -0.0771], [1.0, -0.0567, 0.0913]])
    exact = math.pi * r**2 * float(np.linalg.norm(piece[1] - piece[0])) + 4.0 / 3.0 * math.pi * r**3
    rows = []
    for divisor, tolerance in ((2, 0.05), (4, 0.01), (8, 0.005)):
        h = d_mm / divisor
        field = porous_field(vertices, faces, [piece], [d_mm], h)
        volume = float(((1.0 - field.porosity) * field.sac_fraction).sum() * h**3)
        rows.append(_row(f"porous: capsule volume, voxel d/{divisor} (mm3)", exact, volume, tolerance))
    offsets = np.arange(-2, 3) * 0.57 + 0.137  # 5 × 5 rods along z, 0.57 mm apart (off the sample lattice), in the box
    rods = [np.array([[x, y, -2.0], [x, y, 2.0]]) for x in offsets for y in offsets]
    field = porous_field(vertices, faces, rods, [d_mm] * len(rods), 0.5 * d_mm)
    solid = float(((1.0 - field.porosity) * field.sac_fraction).sum() / field.sac_fraction.sum())
    voxel = np.unravel_index(np.argmax((field.porosity < 1.0) & (field.sac_fraction == 1.0)), field.shape)
    parallel, transverse = happel_permeabilities_mm2(np.array(1.0 - field.porosity[voxel]), np.array(r))
    tensor = field.permeability_tensor_mm2()[voxel]
    rows += [_row("porous: aligned rods, mean solid fraction", len(rods) * math.pi * r**2 / 9.0, solid, 0.01),
             _row("porous: aligned rods, K along = Happel K∥ (mm2)", float(parallel), tensor[2, 2], 1e-12),
             _row("porous: aligned rods, K across = Happel K⊥ (mm2)", float(transverse), tensor[0, 0], 1e-12)]
    return rows


# --- 3D dynamics of the reference integrator (symplectic Euler) ----------------------
OPENED_HELIX = dict(wire_diameter_mm=REFERENCE_D_MM, length_mm=60.0, loop_diameter_mm=3.0, pitch_mm=0.6,
                    segment_length_mm=0.3, bending_stiffness_uN_mm2=3.0e3, twist_stiffness_uN_mm2=2.0e3,
                    linear_density_g_mm=6.5e-4, axial_stiffness_uN=5.71e5)
OPENED_DIAMETER_MM = 4.0  # released from its helix opened to this loop diameter


def _opened_helix(dt_safety: float, damping_uN_per_mm: float, chunk: int) -> tuple[Solver, Stepper]:
    """The 60 mm helix (D 3 mm, pitch 0.6 mm) released, elastic only, from its
    shape opened to D = 4 mm (same pitch and arc length), at rest."""
    spec = CoilSpec(shape="helix", **OPENED_HELIX)
    builder = ModelBuilder(settings=SimulationSettings(damping_uN_per_mm=damping_uN_per_mm))
    builder.add_coil(spec)
    model = builder.finalize()
    start = preshape.helix(OPENED_DIAMETER_MM, spec.helix_pitch_mm, spec.length_mm, spec.l0)
    solver = Solver(model, coil_contact=False, dt_safety=dt_safety)
    return solver, Stepper(solver, state_from_positions(model, start), Control.create(model), chunk=chunk)


def helix_energy_error(steps: int, dt_safety: float = DEFAULT_DT_SAFETY, samples: int = 500) -> np.ndarray:
    """Rows (naive, synchronous) of ΔE/E0 of the undamped opened helix (:func:`_opened_helix`),
    sampled ``samples`` times over ``steps`` steps: the total of ``Solver.energies``
    (x_n with v_{n−½}) and of ``Solver.synchronous_energies`` (time-centred velocities)."""
    chunk = max(2, 2 * (steps // samples // 2))
    solver, stepper = _opened_helix(dt_safety, 0.0, chunk)
    totals = lambda: (sum(solver.energies(stepper.state).values()),  # noqa: E731
                      sum(solver.synchronous_energies(stepper.state).values()))
    e0 = np.array(totals())
    drift = []
    for _ in range(steps // chunk):
        stepper.run_chunk()
        drift.append(np.array(totals()) / e0 - 1.0)
    return np.array(drift).T


def energy_3d_cases(steps: int = 1_000_000, dt_safety: float = UNDAMPED_DT_SAFETY) -> list[CaseResult]:
    """The undamped 3D helix by symplectic Euler at the step for undamped dynamics
    (``UNDAMPED_DT_SAFETY``, a quarter of the default) and at half of it (issue 10:
    max |ΔE|/E0 ≤ 1 % at both). E is the energy of the state at t_n, its kinetic
    part from the time-centred velocity (``Solver.synchronous_energies``), held in an
    O(h²) band, so log2 of the two errors' ratio ≥ 1.5 is checked. Reported, not
    checked: the naive total (x_n with v_{n−½}, an O(h) band). At the default step
    the stiff axial modes (h ω up to 1.8) take the error to 4.4 % (docs/FORMULATION.md, "Energy")."""
    rows = []
    largest = []
    for safety in (dt_safety, 0.5 * dt_safety):
        naive, synchronous = helix_energy_error(steps, safety)
        largest.append(np.abs(synchronous).max())
        label = f"energy 3D: {steps} steps at {safety / DEFAULT_DT_SAFETY:g} × default dt"
        rows.append(CaseResult(f"{label}, max |ΔE|/E0", 0.0, largest[-1], largest[-1], 1e-2))
        naive_max = np.abs(naive).max()
        rows.append(CaseResult(f"{label}, naive E (not checked)", 0.0, naive_max, naive_max, math.inf))
    order = math.log2(largest[0] / largest[1])
    rows.append(CaseResult("energy 3D: order, log2 of the errors' ratio (≥ 1.5)",
                           2.0, order, max(0.0, 1.5 - order), 0.0))
    return rows


def tip_trajectory(dt_safety: float, duration_s: float, sample_steps_at_default: int) -> np.ndarray:
    """Distal tip positions (mm) of the opened helix released with the default
    damping, sampled every ``sample_steps_at_default`` default steps' worth of time."""
    refine = DEFAULT_DT_SAFETY / dt_safety
    solver, stepper = _opened_helix(dt_safety, SimulationSettings().damping_uN_per_mm,
                                    chunk=int(round(sample_steps_at_default * refine)))
    samples = int(round(duration_s / (solver.dt_s * stepper.chunk)))
    tips = [stepper.state.x.numpy()[0].copy()]
    for _ in range(samples):
        tips.append(stepper.run_chunk().x.numpy()[0].copy())
    return np.array(tips)


def timestep_convergence(duration_s: float = 0.05, refinements=(1, 2, 4, 8), reference_refinement: int = 64,
                         sample_steps_at_default: int = 50) -> list[CaseResult]:
    """Tip trajectory of the released helix over its first ``duration_s`` at 1, ½, ¼, ⅛
    of the default step, against a run at 1/64 of it (largest distance over the
    trajectory, relative to the tip's largest excursion); observed order from
    successive differences ≥ 1 (symplectic Euler with implicit damping is first order)."""
    runs = {r: tip_trajectory(DEFAULT_DT_SAFETY / r, duration_s, sample_steps_at_default)
            for r in (*refinements, reference_refinement)}
    reference = runs[reference_refinement]
    scale = np.linalg.norm(reference - reference[0], axis=1).max()
    rows = []
    for r in refinements:
        error = np.linalg.norm(runs[r] - reference, axis=1).max() / scale
        rows.append(CaseResult(f"time step: tip trajectory {duration_s * 1e3:g} ms at 1/{r} default step vs 1/"
                               f"{reference_refinement}", 0.0, error, error, 5e-2 if r == 1 else 2e-2))
    differences = [np.linalg.norm(runs[a] - runs[b], axis=1).max() for a, b in zip(refinements, refinements[1:])]
    order = observed_order(differences)
    rows.append(CaseResult(f"time step: observed order from successive differences (1/{refinements[-3]}, "
                           f"1/{refinements[-2]}, 1/{refinements[-1]})", 1.0, order, max(0.0, 1.0 - order), 0.0))
    return rows


# --- implicit step ------------------------------------------------------------------
def _relaxing_helix() -> tuple:
    """A 10 mm helical coil (l0 = d) started as a helix of 20 % wider loops (same
    segment lengths), damped: model and start positions (a 3D motion with
    bending and twist)."""
    spec = CoilSpec(wire_diameter_mm=REFERENCE_D_MM, shape="helix", length_mm=10.0, loop_diameter_mm=3.0,
                    pitch_mm=0.6)
    builder = ModelBuilder(settings=SimulationSettings(damping_uN_per_mm=5.0))
    builder.add_coil(spec)
    model = builder.finalize()
    start = preshape.helix(1.2 * spec.loop_diameter_mm, spec.pitch_mm, spec.length_mm, spec.l0)
    return model, start


def _positions_at(model, start: np.ndarray, solver: Solver, time_s: float) -> np.ndarray:
    """Positions at ``time_s`` (the solver's dt adjusted to an even number of steps)."""
    steps = 2 * max(1, round(time_s / solver.dt_s / 2))
    solver.dt_s = time_s / steps
    stepper = Stepper(solver, state_from_positions(model, start), Control.create(model), chunk=steps)
    return stepper.run_chunk().x.numpy()


def implicit_convergence(time_s: float = 1.0e-3, factors=(0.4, 0.2, 0.1, 0.05, 0.025),
                         theta: float | None = None, method: str | None = None,
                         labelled_options: tuple[str, dict] | None = None) -> list[CaseResult]:
    """The implicit step against the reference integrator (symplectic Euler at
    0.005 × its bound) as dt shrinks: RMS node distance at ``time_s`` over the
    reference's RMS displacement, for dt = factor × the explicit bound, and the
    observed order log2(e(2 dt)/e(dt)) of the finest pair. Both steps are first
    order; the implicit one reaches its asymptotic order only once dt resolves
    the stiffest modes (ω_max dt ≪ 1): the observed order rises towards 1
    as dt shrinks (0.697, 0.697, 0.73, 0.80 on these pairs). ``labelled_options``: (row label,
    solver options) of another implicit variant, in place of ``theta`` / ``method``."""
    model, start = _relaxing_helix()
    reference = Solver(model, coil_contact=False, dt_safety=0.005)
    x_ref = _positions_at(model, start, reference, time_s)
    scale = float(np.sqrt(((x_ref - start) ** 2).sum(axis=1).mean()))
    bound = reference.bound.dt_s
    errors = []
    label, options = labelled_options or _implicit_label(theta, method)
    for f in factors:
        x = _positions_at(model, start, make_solver(model, "implicit", f * bound, coil_contact=False, **options),
                          time_s)
        errors.append(float(np.sqrt(((x - x_ref) ** 2).sum(axis=1).mean())) / scale)
    orders = [math.log2(a / b) for a, b in zip(errors, errors[1:])]
    rows = [CaseResult(f"{label} vs reference at 1 ms, dt {f:g}× bound (rel. RMS)", 0.0, e, e, 5e-2)
            for f, e in zip(factors, errors)]
    rows.append(_row(f"{label}: observed order, finest pair (→ 1)", 1.0, orders[-1], 0.25))
    if method == "bdf2":  # first order here, not 2: the damping's secant at the old speed, the Jacobian at the
        # step start (Gauss–Newton bending) and the backward-Euler twist are each first order (docs/FORMULATION.md)
        euler = _theta_errors(model, start, x_ref, scale, bound, factors, time_s)
        below = all(e <= r for e, r in zip(errors, euler))
        return rows + [CaseResult(f"{label}: below linearly implicit Euler's error at every dt", 1.0, float(below),
                                  0.0 if below else 1.0, 0.0)]
    # rising towards 1: no pair falls back by more than 0.01 (the two coarsest sit on a plateau, equal to
    # ~1e-4) and the finest is clearly above the coarsest
    rising = all(b > a - 0.01 for a, b in zip(orders, orders[1:])) and orders[-1] > orders[0] + 0.05
    rows.append(CaseResult(f"{label}: observed order rises as dt shrinks", 1.0, float(rising),
                           0.0 if rising else 1.0, 0.0))
    return rows


def bdf2_principal_root(w: float) -> complex:
    """BDF2's amplification of an undamped mode at ω dt = w: the root of
    (1 − 2/3 i w) r² − 4/3 r + 1/3 = 0 that tends to 1 as w → 0 (the other, the
    start-up's parasite, tends to 1/3 and to 0 for stiff modes: L-stable)."""
    a = 1.0 - 2.0j * w / 3.0
    disc = np.sqrt(complex(16.0 / 9.0 - 4.0 * a / 3.0))
    return max(((4.0 / 3.0 + disc) / (2.0 * a), (4.0 / 3.0 - disc) / (2.0 * a)), key=lambda r: abs(r))


def euler_loss_per_period(w: float) -> float:
    """Linearly implicit Euler's amplitude lost per period of an undamped mode at ω dt = w."""
    return 1.0 - (1.0 + w * w) ** (-math.pi / w)


def _implicit_label(theta: float | None, method: str | None) -> tuple[str, dict]:
    """A validation row's label and the solver options: the default scheme (``theta`` None:
    gated_chord), the plain θ-method at ``theta`` (no gate, tangent stiffness) or BDF2."""
    if method == "bdf2":
        return "implicit BDF2", {"method": "bdf2"}
    if theta is None:
        return f"implicit default (gated_chord, θ {IMPLICIT_THETA:g} gated, chord)", {}
    return f"implicit θ {theta:g}", {**EULER, "theta": theta}


# the named scheme "euler" (linearly implicit Euler, tangent) as implicit_convergence / implicit_damping's labelled_options
EULER_LABELLED = ("implicit Euler (θ 1, tangent)", EULER)


def _theta_errors(model, start, x_ref, scale, bound, factors, time_s) -> list[float]:
    """The linearly implicit Euler step's errors in :func:`implicit_convergence`."""
    return [float(np.sqrt(((_positions_at(model, start, make_solver(model, "implicit", f * bound, coil_contact=False,
                                                                      **EULER),
                                          time_s) - x_ref) ** 2).sum(axis=1).mean())) / scale for f in factors]


def loss_per_period(tip: np.ndarray, sample_s: float) -> tuple[float, float]:
    """A decaying oscillation sampled every ``sample_s``: (amplitude lost per period
    between its first and last maxima above half the largest, each refined by a
    parabola through three samples; ω in rad/s)."""
    peaks = []
    for k in range(1, len(tip) - 1):
        if tip[k] >= tip[k - 1] and tip[k] > tip[k + 1] and tip[k] > 0.5 * tip.max():
            a, b, c = tip[k - 1], tip[k], tip[k + 1]
            shift = 0.5 * (a - c) / (a - 2.0 * b + c)
            peaks.append((k + shift, b - 0.25 * (a - c) * shift))
    (t0, a0), (t1, a1) = peaks[0], peaks[-1]
    cycles = len(peaks) - 1
    return 1.0 - (a1 / a0) ** (1.0 / cycles), 2.0 * math.pi * cycles / ((t1 - t0) * sample_s)


def cantilever_vibration_loss(solver_options: dict, periods: int = 3, samples_per_period: int = 100
                              ) -> tuple[float, float, float, float]:
    """Undamped free vibration of a 20 mm cantilever (40 segments) started in its static
    tip-load shape, on the implicit step at its default dt with ``solver_options``:
    (amplitude lost per period between tip maxima after the first period, when the higher
    modes the start excites have died out; ω measured, rad/s; dt s; the reference ω
    3.516 √(EI/ρL⁴), rad/s)."""
    length, segments = 20.0, 40
    l0 = length / segments
    spec = CoilSpec(length_mm=length, segment_length_mm=l0)
    rest = np.zeros((segments + 1, 3))
    rest[:, 0] = np.arange(segments + 1) * l0
    xi = rest[:, 0] / length
    start = rest.copy()
    start[:, 1] = 0.02 * length * xi**2 * (3.0 - xi) / 2.0  # the static tip-load shape, tip 2 % of L
    builder = ModelBuilder(settings=SimulationSettings(damping_uN_per_mm=0.0))
    builder.add_coil(spec, rest)
    builder.clamp(0, node=0)
    model = builder.finalize()
    solver = _solver(model, "implicit", coil_contact=False, **solver_options)
    dt = solver.dt_s
    omega_ref = 3.516 * math.sqrt(spec.EI / (spec.rho * length**4))
    chunk = 2 * max(1, round(2.0 * math.pi / omega_ref / dt / samples_per_period / 2))
    stepper = Stepper(solver, state_from_positions(model, start), Control.create(model), chunk=chunk)
    count = (periods + 1) * samples_per_period + samples_per_period // 2
    tip = np.array([stepper.run_chunk().x.numpy()[-1, 1] for _ in range(count)])
    loss, omega = loss_per_period(tip, chunk * dt)
    return loss, omega, dt, omega_ref


def implicit_damping(theta: float | None = None, labelled_options: tuple[str, dict] | None = None
                     ) -> list[CaseResult]:
    """Numerical damping of the implicit step at its default dt (:func:`cantilever_vibration_loss`)
    against the linear theory of the θ-method, 1 − |R|^(2π/(ω dt)) with
    |R|² = (1 + (1−θ)² ω²dt²)/(1 + θ² ω²dt²) (θ = 1: 1 − (1 + ω² dt²)^(−π/(ω dt)) ≈ π ω dt),
    ω measured (BDF2: validation_bdf2). ``theta`` None: the default scheme (gated_chord); else the
    plain θ-method at ``theta``; ``labelled_options``: (row label, solver options) of another
    θ-method variant (the default gated_chord: no node is gated in free space, so the θ-method at its θ)."""
    label, options = labelled_options or _implicit_label(theta, None)
    loss, omega, dt, omega_ref = cantilever_vibration_loss(options)
    w = omega * dt
    th = options.get("theta", IMPLICIT_THETA if theta is None else theta)
    theory = 1.0 - ((1.0 + ((1.0 - th) * w) ** 2) / (1.0 + (th * w) ** 2)) ** (math.pi / w)
    return [_row(f"{label}: lowest bending mode ω (rad/s) vs 3.516 √(EI/ρL⁴)", omega_ref, omega, 5e-2),
            _row(f"{label}: amplitude lost per period at dt {dt:.3g} s", theory, loss, 0.25)]


def node_theta() -> list[CaseResult]:
    """The proximity-gated θ: numerical damping, convergence, free release (validation_node_theta.py)."""
    from .validation_node_theta import node_theta_cases
    return node_theta_cases()


def chord() -> list[CaseResult]:
    """The implicit step's chord contact stiffness: the law's secant, a thrown coil (validation_chord.py)."""
    from .validation_chord import chord_cases
    return chord_cases()


def implicit_cases() -> list[CaseResult]:
    """The implicit step: convergence to the reference, numerical damping, and the
    cantilever and helix recovery at its default step."""
    rows = (implicit_convergence() + implicit_convergence(labelled_options=EULER_LABELLED)
            + implicit_convergence(theta=0.7) + implicit_damping()
            + implicit_damping(labelled_options=EULER_LABELLED) + implicit_damping(theta=0.7))
    result, reference = cantilever_deflection(50, 5.0, integrator="implicit")
    rows.append(_row("implicit default step (settling θ): cantilever PL²/EI=5, 50 segments: δ/L", reference, result,
                     5e-3))
    return rows + helix_recovery(integrator="implicit")


CASES = {
    "contact": contact_law,
    "gradient": gradient_cases,
    "cantilever": cantilever_cases,
    "frequency": frequency_cases,
    "helix": helix_recovery,
    "release": free_release,
    "tight-pitch": tight_pitch,
    "dense-pack": dense_packs,
    "energy": energy_conservation,
    "friction": friction,
    "contact-share": contact_share,
    "contact-samples": contact_samples,
    "regions": regions,
    "wall-field": wall_field_cases,
    "porous": porous_cases,
    "energy3d": energy_3d_cases,
    "timestep": timestep_convergence,
    "implicit": implicit_cases,
    "implicit-devices": implicit_devices,
    "push-force": push_force,
    "implicit-wall": implicit_wall,
    "impact": impact,
    "bdf2": bdf2,
    "settle": settle,
    "detach": detach,
    "chord": chord,
    "dissipation": dissipation,
    "node-theta": node_theta,
}


DEFAULT_CASES = list(CASES)


def case_name(name: str) -> str:
    """A case's name in CASES as a user may spell it (wall_field: wall-field)."""
    return name.replace("_", "-")


def run(names: list[str] | None = None) -> list[CaseResult]:
    """The named cases (default: DEFAULT_CASES), each once."""
    rows: list[CaseResult] = []
    for name in dict.fromkeys(case_name(n) for n in names or DEFAULT_CASES):
        rows.extend(CASES[name]())
    return rows


def format_table(rows: list[CaseResult]) -> str:
    header = f"{'case':58s} {'reference':>12s} {'result':>12s} {'error':>10s} {'tolerance':>10s}  ok"
    lines = [header, "-" * len(header)]
    for r in rows:
        lines.append(f"{r.case:58s} {r.reference:12.6g} {r.result:12.6g} {r.error:10.2e} {r.tolerance:10.1e}  "
                     f"{'yes' if r.passed else 'NO'}")
    return "\n".join(lines)
