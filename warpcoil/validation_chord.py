"""Validation of the implicit step's chord contact stiffness (``warpcoil validate chord``;
``contact_stiffness="chord"``, kernels/chord.py): on a flat face and on a crossing coil
pair the stiffness is the contact law's secant between the gap at the step start and at
the predicted end; a straight coil thrown at a face from outside the contact range stops
at the depth where the law's work equals its kinetic energy, and the chord step converges
to that depth as the step shrinks, with a smaller error than the tangent at long steps.
Each on the linearly implicit Euler step (implicit.EULER with the stiffness named: the
stiffness read from the matrix is then the law's, not over θ); the thrown coil also on
the named scheme gated_chord (θ 0.65 gated + chord). Units mm, g, s, µN.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from .coil import CoilSpec
from .implicit import EULER, GATED_CHORD, ImplicitSolver
from .kernels import contact
from .model import ModelBuilder
from .settings import SimulationSettings
from .solver import Control
from .state import new_state_like, state_from_positions
from .validation import REFERENCE_D_MM, CaseResult, _row
from .validation_implicit_wall import HALF_BOX_MM, box_wall

D = REFERENCE_D_MM
C0 = 0.1 * REFERENCE_D_MM
PROBE_DT_S = 1e-3
THROW_MM_S = 300.0  # a straight coil thrown at a face: kinetic energy ≈ 0.6 × the law's work down to contact
THROW_START_C0 = 3.0  # its gap at the start, in c0 (outside the contact range)
THROW_ADVANCES_C0 = (4.0, 1.0, 0.25, 0.125)  # the step, as the throw's advance per step (c0)
THROW_DEEPER_TOLERANCE_C0 = 0.01  # the chord step stops no deeper than the balance (implicit Euler loses energy)
THROW_MIN_ORDER = 0.6  # first order, approached from below (measured 0.77–0.8 at 0.5 → 0.125 c0/step)


def law(solver: ImplicitSolver, h_mm: np.ndarray) -> np.ndarray:
    """The solver's contact law |F|(h) (µN) at clearances ``h_mm`` (mm)."""
    dev, c = solver.model.device, solver.model.contact
    h = wp.array(np.atleast_1d(np.asarray(h_mm, np.float64)), dtype=wp.float64, device=dev)
    force, stiffness = wp.zeros(h.shape[0], dtype=wp.float64, device=dev), wp.zeros(h.shape[0], dtype=wp.float64,
                                                                                        device=dev)
    wp.launch(contact.evaluate_law, h.shape[0], device=dev, inputs=[h, c.p0_uN, c.c0_mm, solver.contact_u_linear,
                                                                      force, stiffness])
    return force.numpy()


def face_gap(position_mm: np.ndarray) -> float:
    """Clearance (mm) of a node at ``position_mm`` to the box's face z = +HALF."""
    return float(HALF_BOX_MM - position_mm[2] - 0.5 * D)


def straight_coil_at_face(gap_mm: float, settings: SimulationSettings | None = None):
    """A 3-node coil along y, ``gap_mm`` from the box's face z = +HALF: (model, positions)."""
    spec = CoilSpec(wire_diameter_mm=D, length_mm=2 * D)
    builder = ModelBuilder(settings=settings or SimulationSettings(), wall=box_wall())
    z = HALF_BOX_MM - 0.5 * D - gap_mm
    start = np.array([[0.3, -spec.l0, z], [0.3, 0.0, z], [0.3, spec.l0, z]])
    builder.add_coil(spec, start)
    return builder.finalize(), start


def wall_probe(gap_mm: float, speed_mm_s: float, stiffness: str, dt_s: float = PROBE_DT_S):
    """The coil of :func:`straight_coil_at_face` moving at ``speed_mm_s`` towards the face
    (negative: away): after one step, its middle node's wall stiffness (µN/mm), the
    gaps (mm) at the step start and at the predicted end, and the solver."""
    model, start = straight_coil_at_face(gap_mm)
    state = state_from_positions(model, start)
    state.v.assign(np.tile([0.0, 0.0, speed_mm_s], (3, 1)))
    solver = ImplicitSolver(model, dt_s=dt_s, coil_contact=False, wall_query="bvh",
                            **{**EULER, "contact_stiffness": stiffness})
    solver.step(state, new_state_like(model), Control.create(model))
    end = solver._x_end.numpy()[1] if solver.chord else start[1]
    return solver.wall_stiffness.numpy()[1].copy(), face_gap(start[1]), face_gap(end), solver


def pair_probe(gap_mm: float, speed_mm_s: float, stiffness: str):
    """Two straight 3-node coils crossing at right angles (along x and z) at their middle
    nodes, ``gap_mm`` apart along y, closing at ``speed_mm_s`` each: after one step, the
    touching pairs recorded per edge, their stiffness (µN/mm), the gaps (mm) at the step
    start and at the predicted end, and the solver."""
    spec = CoilSpec(wire_diameter_mm=D, length_mm=2 * D)
    builder = ModelBuilder()
    s = np.array([-1.0, 0.0, 1.0]) * spec.l0
    y = 0.5 * (D + gap_mm)
    a = np.stack([s, np.full(3, -y), np.zeros(3)], axis=1)
    b = np.stack([np.zeros(3), np.full(3, y), s], axis=1)
    builder.add_coil(spec, a)
    builder.add_coil(spec, b)
    model = builder.finalize()
    start = np.concatenate([a, b])
    state = state_from_positions(model, start)
    state.v.assign(np.array([[0.0, speed_mm_s, 0.0]] * 3 + [[0.0, -speed_mm_s, 0.0]] * 3))
    solver = ImplicitSolver(model, dt_s=PROBE_DT_S, **{**EULER, "contact_stiffness": stiffness})
    solver.step(state, new_state_like(model), Control.create(model))
    ends = solver._x_end.numpy() if solver.chord else start
    gap = lambda x: float(x[4, 1] - x[1, 1] - D)  # noqa: E731 (every edge pair's closest points: the middle nodes)
    return solver._pair_count.numpy(), solver._pair_k.numpy(), gap(start), gap(ends), solver


def throw_depth(stiffness: str | None, advance_c0: float) -> tuple[float, float]:
    """The coil of :func:`straight_coil_at_face` thrown at the face at THROW_MM_S from
    THROW_START_C0 · c0 (near-zero damping), stepped at ``advance_c0`` · c0 per step until
    it has come back out of the contact range: (its smallest gap, the energy balance's, mm).
    The balance: ½ m v² = s ∫_h^c0 |F| dh per node (mass over contact share is the same for
    every node, so the straight coil stays straight and each node obeys it). ``stiffness``
    None: the named scheme gated_chord (implicit.GATED_CHORD), else Euler with that stiffness."""
    settings = SimulationSettings(damping_uN_per_mm=1e-6)
    model, start = straight_coil_at_face(THROW_START_C0 * C0, settings)
    state = state_from_positions(model, start)
    state.v.assign(np.tile([0.0, 0.0, THROW_MM_S], (3, 1)))
    dt = advance_c0 * C0 / THROW_MM_S
    options = GATED_CHORD if stiffness is None else {**EULER, "contact_stiffness": stiffness}
    solver = ImplicitSolver(model, dt_s=dt, coil_contact=False, wall_query="bvh", **options)
    control, out = Control.create(model), new_state_like(model)
    smallest = np.inf
    for _ in range(int(np.ceil(6.0 * THROW_START_C0 * C0 / THROW_MM_S / dt)) + 4):
        solver.step(state, out, control)
        state, out = out, state
        smallest = min(smallest, face_gap(state.x.numpy()[1]))
    mass = 1.0 / float(model.inv_mass.numpy()[1])
    kinetic = 0.5 * mass * THROW_MM_S**2  # nJ, the middle node (contact share 1)
    h = np.linspace(C0, -2.0 * C0, 30001)
    f = law(solver, h)
    work = np.concatenate([[0.0], np.cumsum(0.5 * (f[1:] + f[:-1]) * (h[:-1] - h[1:]))])
    return smallest, float(np.interp(kinetic, work, h))


def chord_cases() -> list[CaseResult]:
    rows = []
    k, h, h_end, solver = wall_probe(1.5 * C0, 60.0, "chord")
    secant = float((law(solver, h_end) - law(solver, h))[0] / (h - h_end))
    rows.append(_row("chord stiffness, face, entering the range: k vs the law's secant (µN/mm)", secant, k[2, 2],
                     1e-9))
    count, pair_k, h, h_end, solver = pair_probe(1.5 * C0, 30.0, "chord")
    secant = float((law(solver, h_end) - law(solver, h))[0] / (h - h_end))
    rows.append(_row("chord stiffness, crossing coil pair, entering: k vs the law's secant", secant, pair_k[0, 0],
                     1e-9))
    depth, reference = {}, 0.0
    for advance in THROW_ADVANCES_C0:
        for stiffness in ("tangent", "chord"):
            depth[stiffness, advance], reference = throw_depth(stiffness, advance)
    for advance in THROW_ADVANCES_C0:  # error: how much deeper than the balance (c0); the chord is conservative
        rows.append(CaseResult(f"coil thrown at a face from {THROW_START_C0:g} c0, {advance:g} c0/step: deepest gap "
                               f"(mm; tangent {depth['tangent', advance]:.4f}), deeper by (c0)", reference,
                               depth["chord", advance], max(0.0, reference - depth["chord", advance]) / C0,
                               THROW_DEEPER_TOLERANCE_C0))
    gated, _ = throw_depth(None, THROW_ADVANCES_C0[0])  # gated_chord: θ 0.65, gated near the face, chord
    rows.append(CaseResult(f"coil thrown at a face from {THROW_START_C0:g} c0, {THROW_ADVANCES_C0[0]:g} c0/step, "
                           "gated_chord (θ 0.65 gated, chord): deepest gap (mm), deeper by (c0)", reference, gated,
                           max(0.0, reference - gated) / C0, THROW_DEEPER_TOLERANCE_C0))
    fine, finer = (abs(depth["chord", a] - reference) for a in THROW_ADVANCES_C0[-2:])
    order = float(np.log2(fine / finer))
    rows.append(CaseResult(f"... chord: observed order of its depth error ({THROW_ADVANCES_C0[-2]:g} → "
                           f"{THROW_ADVANCES_C0[-1]:g} c0/step; error: its shortfall below {THROW_MIN_ORDER:g})", 1.0, order,
                           max(0.0, THROW_MIN_ORDER - order),
                           0.0))
    return rows
