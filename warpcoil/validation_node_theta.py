"""`warpcoil validate node-theta`: the implicit θ-method with the proximity-gated θ
(``near_theta``, kernels/node_theta.py; docs/FORMULATION.md "Implicit step: proximity-gated θ").

- In free space no node is gated: the lowest cantilever mode loses the θ-method's
  1 − |R|^(2π/w), |R|² = (1 + (1−θ)² w²)/(1 + θ² w²) per period (w = ω dt).
- Every node gated (θ_i = 1, the elastic force still at x + θ Δx, x' = x + dt v'):
  |R|² = 1/(1 + θ w²) — between the θ-method and Euler's 1/(1 + w²).
- Every node gated converges to the reference integrator as dt shrinks (first order).
- The free release (60 mm helix pushed into free space at 100 and 150 mm/s, catheter
  turned 0.01°) comes to rest in the helix, where linearly implicit Euler tangles.
"""

from __future__ import annotations

import math

import numpy as np

from .coil import CoilSpec
from .implicit import implicit_step_s, make_solver
from .model import ModelBuilder
from .settings import SimulationSettings
from .solver import Control, Solver, Stepper
from .state import state_from_positions
from .validation import (CaseResult, _positions_at, _relaxing_helix, _row, free_release, loss_per_period,
                         tilted_catheter)

THETA = 0.7
GATED = {"theta": THETA, "near_theta": 1.0}
EVERY_NODE = {**GATED, "proximity_margin_c0": 1.0e12}  # a reach beyond any distance: every node at θ_i = 1


def cantilever_loss(options: dict, periods: int = 3, samples_per_period: int = 100) -> tuple[float, float, float]:
    """(amplitude lost per period, ω rad/s, dt s) of the undamped 20 mm cantilever
    (40 segments) started in its static tip-load shape, at the default implicit step."""
    length, segments = 20.0, 40
    l0 = length / segments
    spec = CoilSpec(length_mm=length, segment_length_mm=l0)
    rest = np.zeros((segments + 1, 3))
    rest[:, 0] = np.arange(segments + 1) * l0
    xi = rest[:, 0] / length
    start = rest.copy()
    start[:, 1] = 0.02 * length * xi**2 * (3.0 - xi) / 2.0
    builder = ModelBuilder(settings=SimulationSettings(damping_uN_per_mm=0.0))
    builder.add_coil(spec, rest)
    builder.clamp(0, node=0)
    model = builder.finalize()
    dt = implicit_step_s(model, SimulationSettings().push_speed_mm_s)
    solver = make_solver(model, "implicit", dt, coil_contact=False, **options)
    omega_ref = 3.516 * math.sqrt(spec.EI / (spec.rho * length**4))
    chunk = 2 * max(1, round(2.0 * math.pi / omega_ref / dt / samples_per_period / 2))
    stepper = Stepper(solver, state_from_positions(model, start), Control.create(model), chunk=chunk)
    count = (periods + 1) * samples_per_period + samples_per_period // 2
    tip = np.array([stepper.run_chunk().x.numpy()[-1, 1] for _ in range(count)])
    loss, omega = loss_per_period(tip, chunk * dt)
    return loss, omega, dt


def damping_rows() -> list[CaseResult]:
    rows = []
    for label, options, gated in (("free space (no node gated)", GATED, False), ("every node gated", EVERY_NODE, True)):
        loss, omega, dt = cantilever_loss(options)
        w = omega * dt
        r2 = 1.0 / (1.0 + THETA * w * w) if gated else (1.0 + ((1.0 - THETA) * w) ** 2) / (1.0 + (THETA * w) ** 2)
        rows.append(_row(f"gated θ {THETA:g}, {label}: amplitude lost per period of the lowest cantilever mode at "
                         f"dt {dt:.3g} s", 1.0 - r2 ** (math.pi / w), loss, 0.25))
    return rows


def convergence_rows(time_s: float = 1.0e-3, factors=(0.4, 0.2, 0.1, 0.05, 0.025)) -> list[CaseResult]:
    """Every node gated against the reference (symplectic Euler at 0.005 × its bound) on
    the relaxing helix: relative RMS node distance at ``time_s`` and the observed order."""
    model, start = _relaxing_helix()
    reference = Solver(model, coil_contact=False, dt_safety=0.005)
    x_ref = _positions_at(model, start, reference, time_s)
    scale = float(np.sqrt(((x_ref - start) ** 2).sum(axis=1).mean()))
    bound = reference.bound.dt_s
    errors = []
    for f in factors:
        x = _positions_at(model, start, make_solver(model, "implicit", f * bound, coil_contact=False, **EVERY_NODE),
                          time_s)
        errors.append(float(np.sqrt(((x - x_ref) ** 2).sum(axis=1).mean())) / scale)
    orders = [math.log2(a / b) for a, b in zip(errors, errors[1:])]
    rows = [CaseResult(f"gated θ {THETA:g}, every node gated, vs reference at 1 ms, dt {f:g}× bound (rel. RMS)",
                       0.0, e, e, 5e-2) for f, e in zip(factors, errors)]
    return rows + [_row(f"gated θ {THETA:g}, every node gated: observed order, finest pair (→ 1)", 1.0, orders[-1],
                        0.25)]


def release_rows() -> list[CaseResult]:
    rows = []
    for speed in (100.0, 150.0):
        rows += free_release(push_speed_mm_s=speed, integrator="implicit", catheter=tilted_catheter(0.01, 90.0),
                             solver_options=GATED,
                             label=f"free release at {speed:g} mm/s, gated θ {THETA:g}, catheter turned 0.01°")
    return rows


def node_theta_cases() -> list[CaseResult]:
    return damping_rows() + convergence_rows() + release_rows()
