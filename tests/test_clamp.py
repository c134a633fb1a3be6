"""ModelBuilder.clamp: position and tangent held at node 0 (a virtual fixed edge)."""

import math

import numpy as np
import pytest

import warpcoil as wc


def straight_rod(segments=10, length_mm=5.0):
    spec = wc.CoilSpec(length_mm=length_mm, segment_length_mm=length_mm / segments)
    rest = np.zeros((segments + 1, 3))
    rest[:, 0] = np.linspace(0.0, length_mm, segments + 1)
    return spec, rest


def test_a_straight_rod_follows_a_tilted_clamp_rigidly():
    """No load, clamp direction 0.2 rad off the rest axis: the rest state is a rigid
    rotation about node 0, so the rod comes to rest straight along the clamp."""
    spec, rest = straight_rod()
    angle = 0.2
    direction = (math.cos(angle), math.sin(angle), 0.0)
    omega1 = 3.516 * math.sqrt(spec.EI / (spec.rho * spec.length_mm**4))
    settings = wc.SimulationSettings(damping_uN_per_mm=2.0 * spec.rho * omega1 * 1e3, damping_speed_mm_s=1e3)
    builder = wc.ModelBuilder(settings=settings)
    builder.add_coil(spec, rest)
    builder.clamp(0, node=0, direction=direction)
    model = builder.finalize()
    solver = wc.Solver(model, coil_contact=False)
    stepper = wc.Stepper(solver, wc.state_from_positions(model, rest), wc.Control.create(model), chunk=1000)
    state, rested = stepper.run_to_rest(1e-14, max_steps=400_000, min_steps=10_000)
    assert rested
    x = state.x.numpy()
    expected = np.outer(np.linspace(0.0, spec.length_mm, len(rest)), direction)
    assert np.abs(x - expected).max() < 1e-6 * spec.length_mm
    assert solver.energies(state)["bend_nJ"] < 1e-12


def test_the_clamp_holds_node_0_and_lets_edge_0_twist():
    spec, rest = straight_rod()
    builder = wc.ModelBuilder()
    builder.add_coil(spec, rest)
    builder.clamp(0, node=0)
    model = builder.finalize()
    state = wc.state_from_positions(model, rest)
    state.omega.assign(np.r_[5.0, np.zeros(len(rest) - 1)])  # edge 0 spins
    stepper = wc.Stepper(wc.Solver(model, coil_contact=False), state, wc.Control.create(model), chunk=10)
    stepper.run_chunk()
    assert np.array_equal(stepper.state.x.numpy()[0], rest[0])
    assert stepper.state.omega.numpy()[0] != 0.0  # one clamped, one free node: it spins
    k_bend = model.k_bend.numpy()
    assert k_bend[0] == pytest.approx(2.0 * k_bend[1])  # half a Voronoi cell at the clamp


def test_a_tangent_is_clamped_only_at_node_0():
    spec, rest = straight_rod()
    builder = wc.ModelBuilder()
    builder.add_coil(spec, rest)
    with pytest.raises(ValueError, match="node 0"):
        builder.clamp(0, node=3)
    with pytest.raises(ValueError, match="direction"):
        builder.clamp(0, node=0, direction=(0.0, 0.0, 0.0))
    builder.clamp(0, node=-1, tangent=False)  # a position alone anywhere
    assert wc.ModelBuilder.finalize(builder).fixed.numpy()[-1] == 1
