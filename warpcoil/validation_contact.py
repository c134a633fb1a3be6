"""Validation of how the contact law is lumped on the nodes (``warpcoil validate
contact-share``): each node's contact is weighted by its share of the coil, as its
mass is, so a coil lying on a flat wall under its weight presses it evenly.
Units mm, g, s, µN."""

from __future__ import annotations

import numpy as np

from .coil import CoilSpec
from .model import ModelBuilder
from .settings import ContactSettings, SimulationSettings
from .solver import Control, Solver, Stepper
from .state import state_from_positions
from .validation import REFERENCE_D_MM, CaseResult, _row
from .validation_friction import P0_UN, _floor, _overlap_for, _straight

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
