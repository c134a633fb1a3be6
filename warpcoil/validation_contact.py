"""Validation of how the contact law is lumped on the nodes (``warpcoil validate
contact-share``): each node's contact is weighted by its share of the coil, as its
mass is, so a coil lying on a flat wall under its weight presses it evenly.
Units mm, g, s, µN."""

from __future__ import annotations

import numpy as np

from .coil import CoilSpec
from .model import ModelBuilder
from .settings import ContactSettings
from .solver import Control, Solver, Stepper
from .state import state_from_positions
from .validation import REFERENCE_D_MM, CaseResult, _row
from .validation_friction import P0_UN, _floor, _law_uN, _overlap_for, _straight, straight_coils

FLOOR_G_MM_S2 = 2.0e5  # weight per node ~37 µN at l0 = d: u ≈ 0.25 into the law


def coil_on_floor(segment_length_mm: float, length_mm: float = 10 * REFERENCE_D_MM,
                  g_mm_s2: float = FLOOR_G_MM_S2, drop_mm: float = 0.01) -> tuple[np.ndarray, float]:
    """A straight coil dropped ``drop_mm`` onto a flat wall under a body acceleration
    g, damped to rest. Returns (every node's gap to the floor, mm; the gap at which
    the law carries an interior node's weight ρ l0 g, mm). With each node's contact
    weighted by its share of the coil (½ at an end, as its mass), every node sinks
    to that gap: uniform pressure, a level coil with no bending."""
    d = REFERENCE_D_MM
    spec = CoilSpec(wire_diameter_mm=d, length_mm=length_mm, segment_length_mm=segment_length_mm)
    nodes = round(length_mm / segment_length_mm) + 1
    rest = _straight(nodes, segment_length_mm)
    builder = ModelBuilder(contact=ContactSettings(P0_uN=P0_UN), wall=_floor())
    builder.add_coil(spec, rest)
    builder.body_acceleration(np.array([0.0, 0.0, -g_mm_s2]))
    model = builder.finalize()
    c0 = model.contact.c0_mm
    interior_mass = float(1.0 / model.inv_mass.numpy()[nodes // 2])
    reference = _overlap_for(interior_mass * g_mm_s2, c0)
    x = rest.copy()
    x[:, 2] = 0.5 * d + c0 + drop_mm
    stepper = Stepper(Solver(model, coil_contact=False), state_from_positions(model, x), Control.create(model),
                      chunk=500)
    state, rested = stepper.run_to_rest(1e-9, max_steps=400_000, min_steps=5_000)
    if not rested:
        raise RuntimeError("the coil on the floor did not come to rest")
    return state.x.numpy()[:, 2] - 0.5 * d, reference


def contact_share_cases() -> list[CaseResult]:
    """The coil on a floor at l0 = d and d/2: end node and middle node at the gap
    whose law carries an interior node's weight (a full-law end node, half the mass,
    would sit higher, by ~2 µm here)."""
    rows = []
    for fraction in (1.0, 0.5):
        gaps, reference = coil_on_floor(fraction * REFERENCE_D_MM)
        label = f"contact share: coil resting on a floor, l0 = {fraction:g} d"
        rows.append(_row(f"{label}: end-node gap (mm)", reference, gaps[0], 1e-4))
        rows.append(_row(f"{label}: middle-node gap (mm)", reference, gaps[len(gaps) // 2], 1e-4))
    return rows


def _chains_force(l0_mm: float, across_mm: float, spacing_mm: float, samples: int | None = None,
                  offset_mm: float = 0.0, nodes: int = 13) -> tuple[float, float, float]:
    """Coil–coil contact force (µN) on coil A (along x at height ``spacing_mm`` over coil B's
    axis, its nodes ``offset_mm`` off the crossing) from coil B of segment length ``l0_mm``:
    along y when ``across_mm`` is None (crossing at right angles), else parallel to A at
    ``across_mm`` sideways. ``samples``: force the contact samples per edge K (None: the model's). Returns (A's total force along z, µN; c0, mm;
    the solver's linear onset u)."""
    s = (np.arange(nodes) - nodes // 2) * l0_mm
    a = np.stack([s + offset_mm, np.zeros(nodes), np.full(nodes, spacing_mm)], axis=1)
    if across_mm is None:
        b = np.stack([np.zeros(nodes), s + offset_mm, np.zeros(nodes)], axis=1)
    else:
        b = np.stack([s + offset_mm, np.full(nodes, across_mm), np.zeros(nodes)], axis=1)
    model = straight_coils([a, b], segment_mm=l0_mm)
    if samples is not None:
        model.contact_samples.fill_(samples)
    solver = Solver(model)
    solver.compute_contacts(state_from_positions(model, np.concatenate([a, b])))
    force = solver.contact_force.numpy()[:nodes]
    return float(force[:, 2].sum()), model.contact.c0_mm, float(solver.contact_u_linear)


def _crossing_integral(l0_mm: float, spacing_mm: float, c0_mm: float) -> float:
    """The contact samples' limit K → ∞ for two straight coils crossing at right angles, their
    axes ``spacing_mm`` apart: A's samples at arc length s lie √(s² + z²) from B's axis, each
    weighing ds / l0, so the force along z is (1/l0) ∫ |F|(√(s² + z²) − d) z / √(s² + z²) ds
    (µN; a fine trapezoid sum; the wires overlap by at most c0 here, u ≤ 2, where the solver's
    law is MODEL.md's exponential: its linear onset is never below u = 2)."""
    d = REFERENCE_D_MM
    reach = np.sqrt(max((d + c0_mm) ** 2 - spacing_mm**2, 0.0))
    s = np.linspace(-reach, reach, 200_001)
    r = np.hypot(s, spacing_mm)
    f = _law_uN(r - d, c0_mm) * spacing_mm / r
    return float(np.trapezoid(f, s) / l0_mm)


def contact_sample_cases() -> list[CaseResult]:
    """Coil–coil contact samples between the nodes of segments above 1.5 d (model.py,
    contact_samples_per_edge): two parallel coils at l0 = 3d press each other with
    P0-law per unit length exactly as the nodes alone would (the samples' weights sum to
    the coil's nodes'); two coils crossing at right angles, their wires overlapping by
    c0, press each other with a force that converges, as the samples per edge K grow, to the
    integral of the law along the wire (observed order ≥ 1.5: a trapezoid sum of a C¹ law)."""
    d = REFERENCE_D_MM
    rows = []
    l0 = 3.0 * d
    force, c0, u_linear = _chains_force(l0, 0.0, d - 0.5 * (0.1 * d))
    nodes = 13
    reference = (nodes - 1) * float(_law_uN(-0.5 * c0, c0))
    rows.append(_row("contact samples: parallel coils, l0 = 3d (K = 3): force on one (µN)", reference, force, 1e-9))
    spacing = d - c0  # the wires overlap by c0 where they cross
    reference = _crossing_integral(l0, spacing, c0)
    errors = []
    for k in (3, 6, 12, 24):
        force, _, _ = _chains_force(l0, None, spacing, samples=k, offset_mm=0.37 * l0 / k)
        errors.append(abs(force / reference - 1.0))
        # K = 3, the default at 3d (samples a diameter apart, as a coil's nodes at l0 = d), resolves the
        # crossing's ~1.3 d of contact with one or two samples: within 60 % here; finer K within 5 %
        rows.append(_row(f"contact samples: coils crossing, l0 = 3d, K = {k}: force (µN)", reference, force,
                         0.6 if k == 3 else 0.05))
    order = float(np.polyfit(np.log([3, 6, 12, 24]), -np.log(errors), 1)[0])
    rows.append(CaseResult("contact samples: crossing force, observed order in K (≥ 1.5)", 2.0, order,
                           max(0.0, 1.5 - order), 0.0))
    return rows
