"""Chord contact stiffness of the implicit step (``contact_stiffness="chord"``,
kernels/chord.py): the law's secant between the gap at the step start and at the
predicted end, checked against the law evaluated at the two positions (wall face, coil
pair), its limit (the tangent) as the predicted end nears the start, and a node driven
at a wall from outside the contact range at a long step."""

import numpy as np
import pytest

from warpcoil.coil import CoilSpec
from warpcoil.implicit import ImplicitSolver
from warpcoil.model import ModelBuilder
from warpcoil.solver import Control
from warpcoil.state import new_state_like, state_from_positions
from warpcoil.validation import REFERENCE_D_MM
from warpcoil.validation_implicit_wall import HALF_BOX_MM, box_wall

D = REFERENCE_D_MM
C0 = 0.1 * D
DT_S = 1e-3


def wall_probe(gap_mm: float, speed_mm_s: float, stiffness: str):
    """A 3-node coil along y, its middle node ``gap_mm`` from the box's face z = +HALF,
    moving towards it at ``speed_mm_s`` (negative: away): after one step, the middle
    node's wall stiffness (µN/mm), its predicted end and the solver."""
    spec = CoilSpec(wire_diameter_mm=D, length_mm=2 * D)
    builder = ModelBuilder(wall=box_wall())
    z = HALF_BOX_MM - 0.5 * D - gap_mm
    start = np.array([[0.3, -spec.l0, z], [0.3, 0.0, z], [0.3, spec.l0, z]])
    builder.add_coil(spec, start)
    model = builder.finalize()
    state = state_from_positions(model, start)
    state.v.assign(np.tile([0.0, 0.0, speed_mm_s], (3, 1)))
    solver = ImplicitSolver(model, dt_s=DT_S, coil_contact=False, wall_query="bvh", contact_stiffness=stiffness)
    solver.step(state, new_state_like(model), Control.create(model))
    x_end = solver._x_end.numpy()[1].copy() if solver.chord else None
    return solver.wall_stiffness.numpy()[1].copy(), x_end, solver, state


def law_force(solver: ImplicitSolver, state, position: np.ndarray) -> float:
    """|F| (µN) of the wall on the middle node (contact share 1) at ``position``."""
    x = state.x.numpy().copy()
    x[1] = position
    state.x.assign(x)
    solver.compute_contacts(state, wall_search_mm=1.0)
    return float(np.linalg.norm(solver.wall_force.numpy()[1]))


def face_gap(position: np.ndarray) -> float:
    return HALF_BOX_MM - position[2] - 0.5 * D


@pytest.mark.parametrize("gap_c0, speed", [(1.5, 60.0), (0.5, 60.0), (-0.5, 20.0)])
def test_wall_chord_is_the_secant_of_the_law(gap_c0, speed):
    """On a flat face, closing: k_zz = (|F|(x̃) − |F|(x)) / (h(x) − h(x̃)), the finite-difference
    secant of the law between the step start and the predicted end (from outside the range,
    within it, and deep); no stiffness across the normal."""
    k, x_end, solver, state = wall_probe(gap_c0 * C0, speed, "chord")
    start = state.x.numpy()[1].copy()
    h, h_end = face_gap(start), face_gap(x_end)
    assert h_end < min(h, C0)  # the end is in range and deeper
    secant = (law_force(solver, state, x_end) - law_force(solver, state, start)) / (h - h_end)
    assert k[2, 2] == pytest.approx(secant, rel=1e-9)
    assert np.abs(k - np.diag([0.0, 0.0, k[2, 2]])).max() <= 1e-9 * k[2, 2]
    tangent, _, _, _ = wall_probe(gap_c0 * C0, speed, "tangent")
    assert k[2, 2] >= tangent[2, 2]  # convex law: the chord is the steeper


def test_wall_chord_keeps_the_tangent_when_opening_and_tends_to_it():
    """Moving away: the tangent, exactly; closing ever slower: the chord tends to the tangent."""
    opening, _, _, _ = wall_probe(-0.5 * C0, -40.0, "chord")
    tangent, _, _, _ = wall_probe(-0.5 * C0, -40.0, "tangent")
    assert np.array_equal(opening, tangent)
    errors = []
    for speed in (4.0, 0.4, 0.04):
        chord, _, _, _ = wall_probe(-0.5 * C0, speed, "chord")
        errors.append(abs(chord[2, 2] / tangent[2, 2] - 1.0))
    assert errors[0] > 1e-3
    assert errors[1] < 0.2 * errors[0] and errors[2] < 0.2 * errors[1]  # → 0 linearly with the step's reach


def pair_probe(gap_mm: float, speed_mm_s: float, stiffness: str):
    """Two straight 3-node coils crossing at right angles (along x and z) at their middle
    nodes, ``gap_mm`` apart along y, closing at ``speed_mm_s`` each: the touching pairs
    recorded per edge, their stiffness (µN/mm), the gaps at the step start and at the
    predicted end, and the solver."""
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
    solver = ImplicitSolver(model, dt_s=DT_S, contact_stiffness=stiffness)
    solver.step(state, new_state_like(model), Control.create(model))
    ends = solver._x_end.numpy() if solver.chord else start
    gap = lambda x: x[4, 1] - x[1, 1] - D  # noqa: E731 (every edge pair's closest points: the middle nodes)
    return solver._pair_count.numpy(), solver._pair_k.numpy(), gap(start), gap(ends), solver


EDGES = [0, 1, 3, 4]  # the two coils' edges (node 2 ends coil a)


@pytest.mark.parametrize("gap_c0", [1.5, 0.5])
def test_pair_chord_is_the_secant_of_the_law(gap_c0):
    """A coil pair closing from outside (or inside) the contact range: each edge pair's
    recorded stiffness is (|F|(h̃) − |F|(h)) / (h − h̃) of the contact law at the two gaps."""
    count, k, h, h_end, solver = pair_probe(gap_c0 * C0, 30.0, "chord")
    assert h_end < min(h, C0)
    assert list(count[EDGES]) == [2, 2, 2, 2]  # each edge touches both edges of the other coil
    law = law_at(solver)
    secant = (law(h_end) - law(h)) / (h - h_end)
    np.testing.assert_allclose(k[EDGES, :2], secant, rtol=1e-9)
    tangent_count, tangent_k, _, _, _ = pair_probe(gap_c0 * C0, 30.0, "tangent")
    if gap_c0 > 1.0:
        assert list(tangent_count[EDGES]) == [0, 0, 0, 0]  # the tangent does not see the entering pair
    else:
        assert (k[EDGES, :2] > tangent_k[EDGES, :2]).all()


def law_at(solver: ImplicitSolver):
    """The solver's contact law |F|(h) (µN)."""
    import warp as wp

    from warpcoil.kernels import contact

    def law(h: float) -> float:
        dev = solver.model.device
        hs = wp.array([h], dtype=wp.float64, device=dev)
        force, stiffness = wp.zeros(1, dtype=wp.float64, device=dev), wp.zeros(1, dtype=wp.float64, device=dev)
        c = solver.model.contact
        wp.launch(contact.evaluate_law, 1, device=dev, inputs=[hs, c.p0_uN, c.c0_mm, solver.contact_u_linear, force,
                                                                stiffness])
        return float(force.numpy()[0])
    return law


def approach_depth(stiffness: str, steps: int = 12) -> float:
    """A 3-node coil driven at a face from 2 c0 outside the contact range, at 120 mm/s with a
    body load holding it against the damping, at a step that carries it 4 c0 (beyond the
    whole range): its smallest gap to the face (mm)."""
    from warpcoil.settings import SimulationSettings

    spec = CoilSpec(wire_diameter_mm=D, length_mm=2 * D)
    builder = ModelBuilder(settings=SimulationSettings(damping_uN_per_mm=10.0), wall=box_wall())
    z = HALF_BOX_MM - 0.5 * D - 3.0 * C0
    start = np.array([[0.3, -spec.l0, z], [0.3, 0.0, z], [0.3, spec.l0, z]])
    builder.add_coil(spec, start)
    builder.body_acceleration(np.array([0.0, 0.0, 2.0e5]))  # ≈ 38 µN per node towards the face (P0 = 1000 µN)
    model = builder.finalize()
    speed = 120.0
    state = state_from_positions(model, start)
    state.v.assign(np.tile([0.0, 0.0, speed], (3, 1)))
    solver = ImplicitSolver(model, dt_s=4.0 * C0 / speed, coil_contact=False, wall_query="bvh",
                            contact_stiffness=stiffness)
    control = Control.create(model)
    out = new_state_like(model)
    smallest = np.inf
    for _ in range(steps):
        solver.step(state, out, control)
        state, out = out, state
        smallest = min(smallest, face_gap(state.x.numpy()[1]))
    return smallest


def test_chord_stops_an_approaching_node_shallower():
    """From outside the contact range at a step longer than the range: the tangent step
    sees no contact and carries the node deep; the chord sees it and stops it shallower."""
    tangent, chord = approach_depth("tangent"), approach_depth("chord")
    assert chord > tangent + 0.5 * C0
