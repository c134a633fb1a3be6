"""The skips of the fast path give the same run, bit for bit, as the full passes."""

import functools

import numpy as np
import pytest

import warpcoil as wc
from warpcoil.deploy import build_model
from test_deploy import two_coil_scene


def run_pushed(steps: int, **solver_options):
    """The two-coil scene pushed for ``steps`` steps (contact with the wall and
    between windings); returns the final state's arrays and the solver."""
    scene = two_coil_scene()
    model = build_model(scene)
    solver = wc.Solver(model, **solver_options)
    control = wc.Control.create(model, active_coil=0, push_speed_mm_s=scene.simulation.push_speed_mm_s)
    stepper = wc.Stepper(solver, wc.packed_state(model, gap_mm=1.0), control, chunk=100, use_graph=False)
    solver.touching_chunks = solver.wall_chunks = solver.overflow_chunks = 0
    for _ in range(steps // stepper.chunk):
        stepper.run_chunk()
        solver.touching_chunks += int(solver.coil_contacts.numpy().sum()) > 0
        solver.wall_chunks += bool((np.abs(solver.wall_force.numpy()).sum(axis=1) > 0).any())
        solver.overflow_chunks += bool((solver._neighbour_count.numpy() == -1).any())
    state = stepper.state
    return {name: getattr(state, name).numpy().copy() for name in ("x", "v", "m1", "omega")}, solver


STEPS = 20000  # 14 mm of coil out: the second coil presses on the first and both on the wall


@functools.lru_cache(maxsize=2)
def full_passes(wall_query: str = "bvh"):
    """The run with every skip off: grid rebuilt and every node searched each step
    (through the BVH, or the wall field where it is trusted)."""
    return run_pushed(STEPS, neighbour_skin_mm=0.0, wall_guard_steps=0, wall_query=wall_query)


@pytest.mark.parametrize("wall_query", ["bvh", "sdf"])
def test_neighbour_skin_and_wall_anchors_change_nothing_but_the_work(wall_query):
    """With the field, an anchored node skips a sample the field would also have
    found out of contact (the anchor margin covers the field's error bound)."""
    steps = STEPS
    full, full_solver = full_passes(wall_query)
    fast, fast_solver = run_pushed(steps, wall_query=wall_query)
    assert full_solver.touching_chunks >= (5 if wall_query == "bvh" else 1)  # the passes had work to do
    assert full_solver.wall_chunks > 10
    for name in full:
        assert np.array_equal(full[name], fast[name]), name
    assert full_solver.grid_builds == steps  # every step
    # only when a midpoint moved half the skin (≈ every 5th step here: the distal end, half a segment's
    # mass, whips out of the catheter; 18 % of the steps with full end masses, 21 % with half)
    assert fast_solver.grid_builds < steps / 4


@pytest.mark.parametrize("options", [{"neighbour_skin_mm": 0.3}, {"neighbour_capacity": 2}],
                         ids=["wide skin", "overflowing lists"])
def test_other_skins_and_list_sizes_give_the_same_run(options):
    full, _ = full_passes()
    fast, solver = run_pushed(STEPS, wall_query="bvh", **options)
    if "neighbour_capacity" in options:
        assert solver.overflow_chunks > 5  # the grid fallback did the work
    for name in full:
        assert np.array_equal(full[name], fast[name]), name


def run_implicit_with_friction(neighbour_capacity: int, steps: int = 2500):
    """The two-coil scene with wall, coil and catheter friction on the implicit step
    (dt 0.1 ms); final arrays, and the chunks in which a list overflowed / coils touched."""
    from dataclasses import replace

    from warpcoil.implicit import ImplicitSolver

    scene = replace(two_coil_scene(), contact=wc.ContactSettings(friction_wall=0.3, friction_coil=0.2,
                                                                 friction_catheter=0.1))
    model = build_model(scene)
    solver = ImplicitSolver(model, dt_s=1.0e-4, neighbour_capacity=neighbour_capacity)
    control = wc.Control.create(model, active_coil=0, push_speed_mm_s=scene.simulation.push_speed_mm_s)
    stepper = wc.Stepper(solver, wc.packed_state(model, gap_mm=1.0), control, chunk=100, use_graph=False)
    overflow = touching = 0
    for _ in range(steps // stepper.chunk):
        stepper.run_chunk()
        overflow += bool((solver._neighbour_count.numpy() == -1).any())
        touching += int(solver.coil_contacts.numpy().sum()) > 0
    state = stepper.state
    return {name: getattr(state, name).numpy().copy() for name in ("x", "v", "m1", "omega")}, overflow, touching


def test_grid_fallback_gives_the_implicit_frictional_run_of_the_lists():
    """The coil–coil force, friction and implicit-stiffness passes read their partners
    through one iterator (contact.next_partner): overflowing lists (grid search) give
    the same run, bit for bit, as lists that hold every partner."""
    listed, listed_overflow, touching = run_implicit_with_friction(64)
    searched, overflow, _ = run_implicit_with_friction(2)
    assert listed_overflow == 0 and overflow > 5 and touching > 0  # both paths had work to do
    for name in listed:
        assert np.array_equal(listed[name], searched[name]), name
