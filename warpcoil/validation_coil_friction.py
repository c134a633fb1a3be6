"""Validation of coil–coil friction (``warpcoil validate friction``): a coil sliding on another
loses μN whatever the nodes' alignment, and two parallel coils pressed together under a
tangential load stick below μN and slide above it with Coulomb's acceleration. Units mm, g, s, µN."""

from __future__ import annotations

import numpy as np

from .coil import CoilSpec
from .settings import ContactSettings
from .solver import Control, Solver, Stepper
from .state import state_from_positions
from .validation import REFERENCE_D_MM, CaseResult, _row
from .validation_friction import _chunk, _label, _overlap_for, _solver, _straight, straight_coils

MU_COIL = 0.4
NODES = 21


def sliding_friction_ratio(alignment: str, mu: float = MU_COIL, speed_mm_s: float = 200.0) -> float:
    """One step of the friction law for a coil sliding at ``speed_mm_s`` over another, 0.01 mm
    into contact: the friction force on it over μ × its normal contact force. ``alignment``:
    "node over node" or "node over edge" (crossing at right angles, sliding diagonally), "parallel"
    (along each other, nodes aligned), "over a stuck coil" (node over node across a coil that rests,
    stuck, on a third pressed under it: its nodes' other contacts would stop them)."""
    d, nodes, gap = REFERENCE_D_MM, 9, 0.01
    lower = _straight(nodes, d)
    others = []
    if alignment == "parallel":
        upper = _straight(nodes, d, centre=(0.0, 0.0, d + gap))
        slide = np.array([1.0, 0.0, 0.0])
    else:
        shift = 0.5 * d if alignment == "node over edge" else 0.0
        upper = _straight(nodes, d, axis=(0.0, 1.0, 0.0), centre=(shift, 0.0, d + gap))
        slide = np.array([1.0, 1.0, 0.0]) / np.sqrt(2.0)
        if alignment == "over a stuck coil":
            others = [_straight(nodes, d, centre=(0.0, 0.0, -d))]
    model = straight_coils([lower, upper, *others], mu_coil=mu)
    x = np.concatenate([lower, upper, *others])
    state, out = state_from_positions(model, x), state_from_positions(model, x)
    velocity = np.zeros_like(x)
    velocity[nodes:2 * nodes] = speed_mm_s * slide
    out.v.assign(velocity)
    solver = Solver(model)
    solver.compute_contacts(state)
    solver._friction_law(state, out, Control.create(model).running, solver.dt_s)
    moving = slice(nodes, 2 * nodes)
    mass = 1.0 / model.inv_mass.numpy()[moving]
    friction = (mass[:, None] * solver._friction_change.numpy()[moving]).sum(axis=0) / solver.dt_s
    normal = np.linalg.norm(solver.contact_force.numpy()[moving].sum(axis=0))
    return float(-friction @ slide / (mu * normal))


def parallel_coils_motion(tan_ratio: float, implicit: bool = False, mu: float = MU_COIL,
                          g_n_mm_s2: float = 200.0, chunks: int = 60) -> tuple[float, float, float]:
    """Two free parallel coils pressed together by opposite body forces m g_n and pulled apart
    along their axes by m g_t = m tan_ratio μ g_n (no damping, no wall: the net external force is 0).
    Returns (their relative acceleration fitted over the second half, mm/s²; Coulomb's 2 (g_t − μ g_n)
    or 0 when they stick; their mean relative speed over the second half, mm/s)."""
    d = REFERENCE_D_MM
    g_t = tan_ratio * mu * g_n_mm_s2
    lower = _straight(NODES, d)
    spec_mass = CoilSpec(wire_diameter_mm=d).rho * d  # an interior node's mass
    gap = _overlap_for(spec_mass * g_n_mm_s2, 0.1 * d)  # the pair's contact equilibrium
    upper = _straight(NODES, d, centre=(0.0, 0.0, d + gap))
    model = straight_coils([lower, upper], mu_coil=mu, damping=0.0)
    mass = 1.0 / model.inv_mass.numpy()
    load = np.zeros((2 * NODES, 3))
    load[NODES:] = mass[NODES:, None] * np.array([g_t, 0.0, -g_n_mm_s2])
    load[:NODES] = -mass[:NODES, None] * np.array([g_t, 0.0, -g_n_mm_s2])
    model.external.assign(load)
    solver = _solver(model, implicit)
    stepper = Stepper(solver, state_from_positions(model, np.concatenate([lower, upper])), Control.create(model),
                      chunk=_chunk(solver, 100))
    times, relative = [], []
    upper_mass, lower_mass = mass[NODES:].sum(), mass[:NODES].sum()
    for _ in range(chunks):
        state = stepper.run_chunk()
        v = state.v.numpy()[:, 0]
        times.append(state.time_s)
        relative.append(float((mass[NODES:] * v[NODES:]).sum() / upper_mass - (mass[:NODES] * v[:NODES]).sum()
                              / lower_mass))
    half = len(times) // 2
    acceleration = float(np.polyfit(times[half:], relative[half:], 1)[0])
    return acceleration, 2.0 * max(g_t - mu * g_n_mm_s2, 0.0), float(np.mean(relative[half:]))


def coil_friction_cases() -> list[CaseResult]:
    """Sliding friction μN at three alignments and over a stuck coil (one step of the law); two parallel coils stuck at
    0.8 μN of tangential load (creeping below v_reg: the law's v_reg F_t/(μN) for each of two coils
    pulled opposite ways, 2 × 0.8 v_reg relative at most) and sliding at 2 μN, on both steps."""
    rows = [_row(f"coil friction: sliding {alignment}: force / μN", 1.0, sliding_friction_ratio(alignment), 1e-6)
            for alignment in ("node over node", "node over edge", "parallel", "over a stuck coil")]
    v_reg = ContactSettings().friction_speed_mm_s
    _, _, creep = parallel_coils_motion(0.8)
    rows.append(CaseResult("coil friction: parallel coils at 0.8 μN: stick, relative creep ≤ v_reg (mm/s)", v_reg,
                           creep, max(0.0, creep / v_reg - 1.0), 0.0))
    for implicit in (False, True):
        acceleration, reference, _ = parallel_coils_motion(2.0, implicit=implicit)
        rows.append(_row(f"{_label(implicit)}: parallel coils at 2 μN: slide accel. (mm/s²)", reference,
                         acceleration, 2e-2))
    return rows
