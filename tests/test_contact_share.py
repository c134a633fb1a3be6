"""Each node's contact is weighted by its share of the coil, as its mass is
(docs/FORMULATION.md, "Contact share"): uniform pressure, and an end node of half
mass that sets no shorter step than an interior one."""

import math

import numpy as np
import pytest

import warpcoil as wc
from warpcoil.solver import CONTACTS_PER_NODE
from warpcoil.validation import HELIX, REFERENCE_D_MM, _helix_spec
from warpcoil.validation_contact import FLOOR_G_MM_S2
from warpcoil.validation_friction import _floor, _overlap_for, _straight

D = REFERENCE_D_MM


def law(gap: float, model) -> float:
    c0, p0 = model.contact.c0_mm, model.contact.p0_uN
    u = 1.0 - gap / c0
    return p0 / (math.e - 1.0) * u * (math.exp(u) - 1.0)


def test_the_share_is_the_voronoi_share_and_the_end_node_sets_no_shorter_contact_step():
    builder = wc.ModelBuilder()
    builder.add_coil(_helix_spec(None, HELIX))
    model = builder.finalize()
    share = model.contact_share.numpy()
    assert share[0] == pytest.approx(0.5, rel=1e-12) and share[-1] == pytest.approx(0.5, rel=1e-12)
    assert np.allclose(share[1:-1], 1.0, rtol=1e-9)
    per_gram = share * model.inv_mass.numpy()
    assert np.allclose(per_gram, per_gram[1], rtol=1e-9)  # every node, the ends too, has one contact frequency
    solver = wc.Solver(model)
    interior_mass = 1.0 / model.inv_mass.numpy()[1]
    expected = math.sqrt(CONTACTS_PER_NODE * model.contact.stiffness_uN_mm() / interior_mass)
    assert solver.bound.omega_rad_s["contact (contact P0_uN / c0_mm)"] == pytest.approx(expected, rel=1e-9)
    assert solver.bound.limiting_term.startswith("stretching")  # the seed coil: stretching, not its end node


def test_a_level_coil_on_a_floor_is_in_equilibrium_at_the_law_of_its_weight():
    """A straight coil lying level on a flat wall, every node at the gap h where the law
    carries an interior node's weight ρ l0 g: the forces on every node, its end nodes
    (half mass, half patch) too, balance to rounding. A full law on an end node would
    push it up with half its weight."""
    nodes = 11
    builder = wc.ModelBuilder(wall=_floor())
    builder.add_coil(wc.CoilSpec(wire_diameter_mm=D, length_mm=(nodes - 1) * D), _straight(nodes, D))
    builder.body_acceleration(np.array([0.0, 0.0, -FLOOR_G_MM_S2]))
    model = builder.finalize()
    weight = FLOOR_G_MM_S2 / model.inv_mass.numpy()
    gap = _overlap_for(weight[nodes // 2], model.contact.c0_mm)
    x = _straight(nodes, D)
    x[:, 2] = 0.5 * D + gap
    solver = wc.Solver(model, coil_contact=False)
    solver.compute_forces(wc.state_from_positions(model, x))
    assert np.abs(solver.force.numpy()).max() < 1e-6 * weight.max()  # fixed-point sums: 1.5e-8 µN
    assert solver.wall_force.numpy()[0, 2] == pytest.approx(0.5 * law(gap, model), rel=1e-8)


def test_an_end_node_beside_a_parallel_coil_is_pressed_with_half_the_law():
    """Two aligned parallel coils at gap h: interior nodes get |F|(h), end nodes (half a
    patch) |F|(h)/2; action equals reaction."""
    n, gap = 9, 0.01
    s = np.arange(n) * D
    builder = wc.ModelBuilder()
    spec = wc.CoilSpec(wire_diameter_mm=D, length_mm=(n - 1) * D)
    builder.add_coil(spec, np.stack([s, np.zeros(n), np.zeros(n)], axis=1))
    builder.add_coil(spec, np.stack([s, np.zeros(n), np.full(n, -(D + gap))], axis=1))
    model = builder.finalize()
    solver = wc.Solver(model)
    solver.compute_contacts(wc.rest_state(model))
    force = solver.contact_force.numpy()
    full = law(gap, model)
    assert np.allclose(force[1:n - 1], [0.0, 0.0, full], rtol=1e-9, atol=1e-9 * full)
    for end in (0, n - 1):
        assert np.allclose(force[end], [0.0, 0.0, 0.5 * full], rtol=1e-9, atol=1e-9 * full)
    assert np.allclose(force[:n].sum(axis=0), -force[n:].sum(axis=0), rtol=1e-12, atol=1e-9 * full)
