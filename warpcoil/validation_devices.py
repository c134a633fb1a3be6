"""Validation of the implicit step with assist devices (``warpcoil validate
implicit-devices``): a straight coil pressed by a uniform load onto a balloon and
across two stent struts comes to rest where the contact law carries the load,
and a coil dropped onto the balloon converges to the reference integrator as dt
shrinks. Units mm, g, s, µN.
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
from .validation import REFERENCE_D_MM, CaseResult, _row
from .validation_friction import _law_uN, _overlap_for

BALLOON_NODES = 41  # a 40-segment straight coil (l0 = d): its middle node 5.8 mm from the half-loaded ends
STENT_NODES = 21
BALLOON_R_MM = 1.0
LOAD_UN = 300.0  # per interior node on the balloon: u ≈ 1.6 on the law, well below its linear extension
STRUT_LOAD_UN = 50.0  # per interior node across the struts (a 4 mm span: sag ≈ 0.05 mm)
STRUT_X_MM = 2.0  # the struts cross the coil at x = ±2 mm
STRUT_R_MM = 0.035
PUSH_MM_S = 100.0  # the implicit default step is the one of a 100 mm/s push


def _coil(device: str, nodes: int) -> tuple:
    """(model, start positions, interior node mass g) of a straight coil of ``nodes`` along z (balloon:
    parallel to its axis, just clear of it) or along x (stent: across two struts along
    y at x = ±STRUT_X_MM), pressed towards −x / −z by a body acceleration giving LOAD_UN per
    interior node (STRUT_LOAD_UN on the struts)."""
    spec = CoilSpec(wire_diameter_mm=REFERENCE_D_MM, length_mm=(nodes - 1) * REFERENCE_D_MM)
    builder = ModelBuilder(settings=SimulationSettings(damping_uN_per_mm=10.0))
    s = (np.arange(nodes) - 0.5 * (nodes - 1)) * spec.l0
    c0 = builder.contact.c0_mm if builder.contact.c0_mm is not None else 0.1 * spec.d
    if device == "balloon":
        start = np.stack([np.full(nodes, BALLOON_R_MM + 0.5 * spec.d + c0), 0 * s, s], axis=1)
        builder.balloon = (np.array([[0.0, 0.0, -10.0], [0.0, 0.0, 10.0]]), np.full(2, BALLOON_R_MM))
        direction = np.array([-1.0, 0.0, 0.0])
    else:
        start = np.stack([s + 0.013, 0 * s, np.full(nodes, 0.5 * spec.d + STRUT_R_MM + c0)], axis=1)
        builder.stent = (np.array([[-STRUT_X_MM, -3.0, 0.0], [STRUT_X_MM, -3.0, 0.0]]),
                         np.array([[-STRUT_X_MM, 3.0, 0.0], [STRUT_X_MM, 3.0, 0.0]]), STRUT_R_MM)
        direction = np.array([0.0, 0.0, -STRUT_LOAD_UN / LOAD_UN])
    builder.add_coil(spec, start)
    mass = spec.rho * spec.l0
    builder.body_acceleration(LOAD_UN / mass * direction)
    return builder.finalize(), start, mass


def _settled(solver: Solver, model, start: np.ndarray, time_s: float = 0.05):
    stepper = Stepper(solver, state_from_positions(model, start), Control.create(model), chunk=50)
    stepper.run_steps(int(round(time_s / solver.dt_s)))
    state = stepper.state
    solver.compute_forces(state)
    return state, solver.device_force.numpy().copy()


def balloon_rest() -> list[CaseResult]:
    """At rest on the balloon: the balloon carries the whole load (Σ reaction = Σ m a),
    and a middle node sits at the clearance h* where the law gives its load."""
    model, start, mass = _coil("balloon", BALLOON_NODES)
    solver = make_solver(model, "implicit", implicit_step_s(model, PUSH_MM_S))
    state, reaction = _settled(solver, model, start)
    c0 = model.contact.c0_mm
    total_load = LOAD_UN / mass * float((1.0 / model.inv_mass.numpy()).sum())
    middle = state.x.numpy()[BALLOON_NODES // 2]
    gap = math.hypot(middle[0], middle[1]) - BALLOON_R_MM - 0.5 * REFERENCE_D_MM
    return [_row("implicit + balloon at rest: Σ reaction / Σ load", 1.0, float(reaction[:, 0].sum()) / total_load,
                 1e-3),
            _row(f"implicit + balloon at rest: middle node clearance (mm), load {LOAD_UN:g} µN",
                 _overlap_for(LOAD_UN, c0), gap, 1e-4)]


def stent_rest() -> list[CaseResult]:
    """At rest across two struts: the struts carry the whole load, half each by
    symmetry, and the law at the clearances of the coil edges near each strut (the
    distance in the xz plane from the strut to the edge, less the radii: the
    segment–segment law of kernels/devices.strut_contact, one term per edge) has a
    vertical component that sums to the load."""
    model, start, mass = _coil("stent", STENT_NODES)
    solver = make_solver(model, "implicit", implicit_step_s(model, PUSH_MM_S))
    state, reaction = _settled(solver, model, start)
    c0 = model.contact.c0_mm
    total_load = STRUT_LOAD_UN / mass * float((1.0 / model.inv_mass.numpy()).sum())
    xz = state.x.numpy()[:, [0, 2]]
    a, b = xz[:-1], xz[1:]
    carried = []
    for strut in (np.array([-STRUT_X_MM, 0.0]), np.array([STRUT_X_MM, 0.0])):
        t = np.clip(((strut - a) * (b - a)).sum(1) / ((b - a) ** 2).sum(1), 0.0, 1.0)
        delta = a + t[:, None] * (b - a) - strut
        dist = np.linalg.norm(delta, axis=1)
        gaps = dist - 0.5 * REFERENCE_D_MM - STRUT_R_MM
        carried.append(float((_law_uN(np.minimum(gaps, c0), c0) * delta[:, 1] / dist).sum()))  # along z
    return [_row("implicit + stent at rest: Σ strut reaction / Σ load", 1.0, float(reaction[:, 2].sum()) / total_load,
                 1e-3),
            _row("implicit + stent at rest: law at the edges' strut clearances / Σ load", 1.0,
                 sum(carried) / total_load, 1e-3),
            _row("implicit + stent at rest: share of the load on one strut (symmetry)", 0.5, carried[0] / sum(carried),
                 1e-3)]


def _wrapping_helix(balloon_radius_mm: float = 1.55) -> tuple:
    """validation._relaxing_helix (a 10 mm helix released from 20 % wider loops, 1.8 mm
    radius, damped) about a balloon on its axis: the loops close onto the balloon
    (contact from loop radius 1.55 + d/2 + c0 ≈ 1.72 mm; at rest they would be 1.5 mm).
    (model, start)."""
    from .validation import _relaxing_helix

    helix_model, start = _relaxing_helix()
    spec = helix_model.coils[0]
    builder = ModelBuilder(settings=SimulationSettings(damping_uN_per_mm=5.0))
    builder.add_coil(spec)
    builder.balloon = (np.array([[0.0, 0.0, -2.0], [0.0, 0.0, 4.0]]), np.full(2, balloon_radius_mm))
    return builder.finalize(), start


def balloon_convergence(time_s: float = 2.0e-3, factors=(0.2, 0.1, 0.05, 0.025)) -> list[CaseResult]:
    """The helix closing onto the balloon (_wrapping_helix): the implicit step at
    factor × the explicit bound against the reference integrator (symplectic Euler at
    0.005 × its bound), RMS node distance at ``time_s`` over the reference's RMS
    displacement; it falls as dt shrinks, at first order."""
    from .validation import _positions_at

    model, start = _wrapping_helix()
    reference = Solver(model, dt_safety=0.005)
    bound = reference.bound.dt_s
    x_ref = _positions_at(model, start, reference, time_s)
    reference.compute_forces(state_from_positions(model, x_ref))
    pressed = int((np.linalg.norm(reference.device_force.numpy(), axis=1) > 0.0).sum())
    scale = float(np.sqrt(((x_ref - start) ** 2).sum(axis=1).mean()))
    errors = [float(np.sqrt(((_positions_at(model, start, make_solver(model, "implicit", f * bound), time_s)
                              - x_ref) ** 2).sum(axis=1).mean())) / scale for f in factors]
    rows = [CaseResult(f"implicit + balloon vs reference at {time_s * 1e3:g} ms, dt {f:g}× bound (rel. RMS)", 0.0, e,
                       e, 5e-2) for f, e in zip(factors, errors)]
    rows.append(_row("implicit + balloon: observed order, finest pair (→ 1)", 1.0, math.log2(errors[-2] / errors[-1]),
                     0.3))
    rows.append(CaseResult("implicit + balloon: nodes pressing on the balloon at the end (> 0)", 1.0,
                           float(pressed), 0.0 if pressed > 0 else 1.0, 0.0))
    return rows


def implicit_device_cases() -> list[CaseResult]:
    return balloon_rest() + stent_rest() + balloon_convergence()
