"""Validation of a wall impact (``warpcoil validate impact``): a straight, undamped coil thrown
at a flat face bounces back. The contact law is a conservative spring, so the reference step
returns all of the normal speed (restitution e = 1); the implicit step's numerical damping of the
stiff contact mode takes part of it: at its push step (0.8 c0 of push) the impact is inelastic
(e ≈ 0), and 1 − e falls to first order as the step shrinks (docs/FORMULATION.md, "Implicit step:
impacts are inelastic"). Units mm, g, s, µN.
"""

from __future__ import annotations

import math

import numpy as np

from .implicit import ImplicitSolver, implicit_step_s
from .model import Model
from .settings import SimulationSettings
from .solver import Control, Solver, Stepper
from .state import state_from_positions
from .validation import CaseResult, _row
from .validation_chord import straight_coil_at_face

IMPACT_SPEED_MM_S = 50.0  # the default push speed: a coil's loops meet the wall at it and faster
IMPACT_START_GAP_MM = 0.1  # clearance at the start (> c0: the coil flies in)
REFINEMENTS = (16, 64, 256)  # the implicit step's push step / these, for the observed order


def impact_model() -> tuple[Model, np.ndarray]:
    """The straight coil of :func:`validation_chord.straight_coil_at_face`, IMPACT_START_GAP_MM
    from the box's face, no damping: (model, start positions mm)."""
    return straight_coil_at_face(IMPACT_START_GAP_MM, SimulationSettings(damping_uN_per_mm=0.0))


def restitution(model: Model, start: np.ndarray, solver: Solver) -> float:
    """−v_z / v₀ of the coil's mean velocity after it met the face at v₀ = IMPACT_SPEED_MM_S
    (at twice the flight time to the face + 2 ms: the contact is over)."""
    state = state_from_positions(model, start)
    v = np.zeros_like(start)
    v[:, 2] = IMPACT_SPEED_MM_S
    state.v.assign(v)
    stepper = Stepper(solver, state, Control.create(model), chunk=2)
    steps = math.ceil((2.0 * IMPACT_START_GAP_MM / IMPACT_SPEED_MM_S + 2e-3) / solver.dt_s / 2.0) * 2
    stepper.run_steps(steps, check_every_chunk=False)
    return -float(stepper.state.v.numpy()[:, 2].mean()) / IMPACT_SPEED_MM_S


def impact_cases() -> list[CaseResult]:
    """The reference step's restitution (1: the law is conservative) and the implicit step's
    (default scheme): e at its push step stated, 1 − e converging at first order."""
    model, start = impact_model()
    reference = restitution(model, start, Solver(model, coil_contact=False))
    push_dt = implicit_step_s(model, IMPACT_SPEED_MM_S)
    implicit = lambda k: restitution(model, start, ImplicitSolver(model, dt_s=push_dt / k, coil_contact=False))  # noqa: E731
    at_push, at_quarter = implicit(1), implicit(4)
    loss = [1.0 - implicit(k) for k in REFINEMENTS]
    where = f"implicit wall impact at {IMPACT_SPEED_MM_S:g} mm/s"
    stated = f"e {at_push:.3f} at the {push_dt * 1e3:.2f} ms push step, {at_quarter:.2f} at 1/4"
    rows = [_row(f"wall impact at {IMPACT_SPEED_MM_S:g} mm/s, no damping, reference step: restitution e", 1.0,
                 reference, 1e-2)]
    for (k0, k1), (l0, l1) in zip(zip(REFINEMENTS, REFINEMENTS[1:]), zip(loss, loss[1:])):
        # (a 1 − e at or below 0, an implicit step that gains energy, has no order: the row fails)
        order = math.log(l0 / l1) / math.log(k1 / k0) if l0 > 0.0 and l1 > 0.0 else math.nan
        rows.append(_row(f"{where}: observed order of 1 − e, push step /{k0} → /{k1} ({stated}; 1 − e "
                         f"{l0:.3f} → {l1:.3f})", 1.0, order, 0.25))
    return rows
