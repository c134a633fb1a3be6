"""Validation of the linearly implicit BDF2 step (``warpcoil validate bdf2``):
its numerical damping of the lowest bending mode at the default step, the decay
of a stiff mode (L-stability: it decays, it does not ring), and its convergence
to the reference integrator as dt shrinks. Units mm, g, s, µN.

The slow mode is started in the discrete lowest mode itself (the generalised
eigenvector of the elastic Hessian, by central differences of the forces), so
no higher mode rides on the tip signal: BDF2 barely damps them, unlike Euler.
"""

from __future__ import annotations

import math

import numpy as np

from .coil import CoilSpec
from .implicit import EULER, implicit_step_s, make_solver
from .model import ModelBuilder
from .settings import SimulationSettings
from .solver import Control, Solver, Stepper
from .state import new_state_like, state_from_positions
from .validation import (CaseResult, _row, bdf2_principal_root, euler_loss_per_period, implicit_convergence,
                         loss_per_period)

CANTILEVER_MM, CANTILEVER_SEGMENTS = 20.0, 40
TIP_AMPLITUDE = 0.02  # of the length


def _cantilever():
    """A straight 20 mm coil (40 segments) clamped at node 0, undamped: (model, rest, spec)."""
    l0 = CANTILEVER_MM / CANTILEVER_SEGMENTS
    spec = CoilSpec(length_mm=CANTILEVER_MM, segment_length_mm=l0)
    rest = np.zeros((CANTILEVER_SEGMENTS + 1, 3))
    rest[:, 0] = np.arange(CANTILEVER_SEGMENTS + 1) * l0
    builder = ModelBuilder(settings=SimulationSettings(damping_uN_per_mm=0.0))
    builder.add_coil(spec, rest)
    builder.clamp(0, node=0)
    return builder.finalize(), rest, spec


def lowest_mode(model, rest: np.ndarray, eps_mm: float = 1e-6) -> tuple[np.ndarray, float]:
    """The lowest transverse (y) mode of the straight clamped coil: its shape (tip 1)
    and ω (rad/s), from −∂F_y/∂y by central differences and the lumped masses."""
    solver = Solver(model, coil_contact=False)
    state = state_from_positions(model, rest)
    unknowns = np.flatnonzero(model.fixed.numpy() == 0)
    stiffness = np.zeros((unknowns.size, unknowns.size))
    for col, node in enumerate(unknowns):
        forces = []
        for sign in (1.0, -1.0):
            x = rest.copy()
            x[node, 1] += sign * eps_mm
            state.x.assign(x)
            solver.compute_forces(state)
            forces.append(solver.force.numpy()[unknowns, 1].copy())
        stiffness[:, col] = -(forces[0] - forces[1]) / (2.0 * eps_mm)
    inv_sqrt_m = np.sqrt(model.inv_mass.numpy()[unknowns])
    values, vectors = np.linalg.eigh(0.5 * (stiffness + stiffness.T) * np.outer(inv_sqrt_m, inv_sqrt_m))
    shape = np.zeros(len(rest))
    shape[unknowns] = vectors[:, 0] * inv_sqrt_m
    return shape / shape[-1], math.sqrt(values[0])


def mode_loss_per_period(method: str, periods: int = 3, samples_per_period: int = 100) -> tuple[float, float, float]:
    """Undamped free vibration of the cantilever started in its lowest mode (tip
    TIP_AMPLITUDE × L), at the implicit default step: (amplitude lost per period
    between tip maxima, ω measured, ω dt); "theta": linearly implicit Euler (implicit.EULER)."""
    model, rest, _ = _cantilever()
    shape, omega_mode = lowest_mode(model, rest)
    start = rest.copy()
    start[:, 1] = TIP_AMPLITUDE * CANTILEVER_MM * shape
    dt = implicit_step_s(model, SimulationSettings().push_speed_mm_s)
    options = EULER if method == "theta" else {"method": method}
    solver = make_solver(model, "implicit", dt, coil_contact=False, **options)
    chunk = 2 * max(1, round(2.0 * math.pi / omega_mode / dt / samples_per_period / 2))
    stepper = Stepper(solver, state_from_positions(model, start), Control.create(model), chunk=chunk)
    count = periods * samples_per_period + samples_per_period // 2
    tip = np.array([stepper.run_chunk().x.numpy()[-1, 1] for _ in range(count)])
    loss, omega = loss_per_period(tip, chunk * dt)
    return loss, omega, omega * dt


def stiff_mode_history(method: str, theta: float = 1.0, steps: int = 6) -> tuple[np.ndarray, float]:
    """Two 0.5 mm segments held at both ends, the middle node pulled 1 µm along them
    (a single stretching mode, stiffness 2 k_s), undamped, stepped at the implicit
    default step: (the middle node's axial offset from rest (mm) after each step,
    the mode's ω dt); "theta": the plain θ-method at ``theta`` (no gate, tangent stiffness)."""
    spec = CoilSpec(length_mm=1.0, segment_length_mm=0.5)
    rest = np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [1.0, 0.0, 0.0]])
    builder = ModelBuilder(settings=SimulationSettings(damping_uN_per_mm=0.0))
    builder.add_coil(spec, rest)
    builder.clamp(0, node=0, tangent=False)
    builder.clamp(0, node=-1, tangent=False)
    model = builder.finalize()
    start = rest.copy()
    start[1, 0] += 1e-3
    dt = implicit_step_s(model, SimulationSettings().push_speed_mm_s)
    plain = {**EULER, "theta": theta} if method == "theta" else {"method": method, "theta": theta}
    solver = make_solver(model, "implicit", dt, coil_contact=False, **plain)
    a, b, control = state_from_positions(model, start), new_state_like(model), Control.create(model)
    offsets = []
    for _ in range(steps):
        solver.step(a, b, control)
        a, b = b, a
        offsets.append(a.x.numpy()[1, 0] - rest[1, 0])
    w = math.sqrt(2.0 * model.k_stretch.numpy()[0] * model.inv_mass.numpy()[1]) * dt
    return np.array(offsets), w


def bdf2_cases() -> list[CaseResult]:
    rows = []
    for method in ("bdf2", "theta"):
        loss, omega, w = mode_loss_per_period(method)
        theory = (1.0 - abs(bdf2_principal_root(w)) ** (2.0 * math.pi / w)) if method == "bdf2" else \
            euler_loss_per_period(w)
        label = "implicit BDF2" if method == "bdf2" else "implicit θ 1"
        # BDF2's loss is ≈ π (ω dt)³/2 ≈ 1e-6, below what three periods can resolve: an absolute tolerance
        rows.append(CaseResult(f"{label}: lowest mode (clean start) amplitude lost per period, ω dt {w:.2g}",
                               theory, loss, abs(loss - theory), 2e-4 if method == "bdf2" else 0.1 * theory))
    offsets, w = stiff_mode_history("bdf2")
    # after the Euler start, each step multiplies a stiff mode by BDF2's |r(ω dt)| ≈ (2 ω dt)^(−1/2) (L-stable:
    # → 0); the θ-method at θ 0.7 keeps (1 − θ)/θ = 0.43 of it per step
    ratio = float(abs(offsets[-1] / offsets[-3]) ** 0.5)
    rows.append(_row(f"implicit BDF2: stiff stretching mode (ω dt {w:.3g}): decay per step vs |r|",
                     abs(bdf2_principal_root(w)), ratio, 0.1))
    return rows + implicit_convergence(method="bdf2")

