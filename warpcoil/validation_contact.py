"""Validation of how the contact law is lumped on the nodes (``warpcoil validate
contact-share``): each node's contact is weighted by its share of the coil, as its
mass is, so a coil lying on a flat wall under its weight presses it evenly.
Units mm, g, s, µN."""

from __future__ import annotations

import numpy as np
import trimesh

from .coil import CoilSpec
from .model import ModelBuilder
from .settings import ContactSettings
from .solver import Control, Solver, Stepper
from .state import state_from_positions
from .validation import REFERENCE_D_MM, CaseResult, _row
from .validation_friction import P0_UN, _floor, _law_uN, _overlap_for, _straight, _wall, straight_coils

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


RIDGE_HEIGHT_MM = 1.0  # a floor rising to a ridge along y (x = 0) at this height, falling 1 in 5 on either side


def ridge_wall():
    """A closed box lumen 10 × 10 × 5 mm whose floor is a ridge along y: z = 1 − |x|/5 mm (a wall edge
    that bulges into the lumen, as a neck's rim or the crease between two lobes)."""
    half, top, h = 5.0, 5.0, RIDGE_HEIGHT_MM
    v = np.array([[-half, -half, 0.0], [-half, half, 0.0], [0.0, -half, h], [0.0, half, h], [half, -half, 0.0],
                  [half, half, 0.0], [-half, -half, top], [-half, half, top], [half, -half, top], [half, half, top]])
    faces = [[0, 2, 3], [0, 3, 1], [2, 4, 5], [2, 5, 3],  # the floor's two slopes
             [6, 7, 9], [6, 9, 8],  # the top
             [0, 1, 7], [0, 7, 6], [4, 8, 9], [4, 9, 5],  # the ends x = ∓5
             [0, 6, 8], [0, 8, 4], [0, 4, 2], [1, 3, 5], [1, 5, 9], [1, 9, 7]]  # the sides y = ∓5
    mesh = trimesh.Trimesh(v, np.array(faces), process=True)
    mesh.fix_normals()
    return _wall(mesh)


def ridge_edge_forces(samples_on: bool = True) -> tuple[np.ndarray, np.ndarray, float, float]:
    """A coil of two edges of l0 = 3d (K = 3 contact samples each), the first straight across the ridge, off
    its middle (so a swap of the samples' shares would show), both its nodes out of the contact range and a
    sample between them in it: (the wall's force on the
    three nodes, µN; the reference: the wall at the nodes and samples as a fine coil's nodes there feel it
    (whole nodes' law), weighted by the node's contact share over K or a sample's 1/K and shared (1 − s, s);
    the nodes' and the samples' smallest gaps, mm). ``samples_on`` False: the samples off (the nodes alone)."""
    from .kernels import contact
    from .solver import Solver

    d = REFERENCE_D_MM
    l0, k_samples = 3.0 * d, 3
    height = RIDGE_HEIGHT_MM + 0.13  # node centres 0.13 mm above the ridge's height, the edge 0.1 mm off its middle
    nodes = np.array([[-0.5 * l0 + 0.1, 0.0, height], [0.5 * l0 + 0.1, 0.0, height], [1.5 * l0 + 0.1, 0.0, height]])
    fractions = np.arange(k_samples) / k_samples
    points = np.array([nodes[e] + s * (nodes[e + 1] - nodes[e]) for e in range(2) for s in fractions] + [nodes[2]])

    def wall_forces(positions: np.ndarray, segment_mm: float, samples: bool):
        builder = ModelBuilder(contact=ContactSettings(P0_uN=P0_UN), wall=ridge_wall())
        builder.add_coil(CoilSpec(wire_diameter_mm=d, length_mm=2 * l0, segment_length_mm=segment_mm), positions)
        model = builder.finalize()
        solver = Solver(model, coil_contact=False)
        solver._has_samples = samples and solver._has_samples
        solver.compute_contacts(state_from_positions(model, positions), wall_search_mm=float(contact.FAR_MM))
        return solver.wall_force.numpy().copy(), solver.wall_distance.numpy() - 0.5 * d, model

    result, node_gaps, _ = wall_forces(nodes, l0, samples_on)
    fine, fine_gaps, fine_model = wall_forces(points, l0 / k_samples, False)
    law = fine / fine_model.contact_share.numpy()[:, None]  # a whole node's law at each point
    share = np.array([0.5, 1.0, 0.5])  # the coarse coil's nodes' contact shares
    reference = np.zeros((3, 3))
    for e in range(2):
        for m, s in enumerate(fractions):
            point = law[e * k_samples + m]
            if m == 0:  # the edge's start node itself
                reference[e] += share[e] / k_samples * point
            else:
                reference[e] += (1.0 - s) / k_samples * point
                reference[e + 1] += s / k_samples * point
    reference[2] += share[2] / k_samples * law[-1]
    samples = [i for i in range(len(points) - 1) if i % k_samples]
    return result, reference, float(node_gaps.min()), float(fine_gaps[samples].min())


def wall_sample_cases() -> list[CaseResult]:
    """The wall at the contact samples of a segment longer than 1.5 d: an edge of 3d across a ridge, its
    nodes out of the contact range, its middle in it, is pushed as nodes at its samples would be (weight
    1/K each, shared 1 − s and s); with the samples off (nodes alone, as before) it felt nothing."""
    result, reference, node_gap, sample_gap = ridge_edge_forces()
    off, _, _, _ = ridge_edge_forces(samples_on=False)
    label = "wall at contact samples: a 3d edge across a ridge (nodes out of range)"
    rows = [_row(f"{label}: upward force on the coil (µN)", float(reference[:, 2].sum()), float(result[:, 2].sum()),
                 1e-9),
            _row(f"{label}: its shared node's force (µN)", float(np.linalg.norm(reference[1])),
                 float(np.linalg.norm(result[1])), 1e-9),
            CaseResult(f"{label}: force with the samples off (µN; the nodes alone)", 0.0,
                       float(np.abs(off).sum()), float(np.abs(off).sum()), 1e-12)]
    if not (node_gap > 0.1 * REFERENCE_D_MM and sample_gap < 0.0):
        raise RuntimeError(f"ridge case set up wrong: node gap {node_gap}, sample gap {sample_gap}")
    # the law per length kept: a coil of 3d segments resting on a floor sinks to the gap of a coil of d segments
    gaps, reference = coil_on_floor(3.0 * REFERENCE_D_MM, length_mm=12 * REFERENCE_D_MM)
    label = "wall at contact samples: coil resting on a floor, l0 = 3d (K = 3)"
    rows.append(_row(f"{label}: end-node gap (mm)", reference, gaps[0], 1e-4))
    rows.append(_row(f"{label}: middle-node gap (mm)", reference, gaps[len(gaps) // 2], 1e-4))
    return rows
