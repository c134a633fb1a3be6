"""The skips of the fast path give the same run, bit for bit, as the full passes."""

import numpy as np

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
    solver.touching_chunks = solver.wall_chunks = 0
    for _ in range(steps // stepper.chunk):
        stepper.run_chunk()
        solver.touching_chunks += int(solver.coil_contacts.numpy().sum()) > 0
        solver.wall_chunks += bool((np.abs(solver.wall_force.numpy()).sum(axis=1) > 0).any())
    state = stepper.state
    return {name: getattr(state, name).numpy().copy() for name in ("x", "v", "m1", "omega")}, solver


def test_neighbour_skin_and_wall_anchors_change_nothing_but_the_work():
    steps = 20000  # 14 mm of coil out: the second coil presses on the first and both on the wall
    full, full_solver = run_pushed(steps, neighbour_skin_mm=0.0, wall_guard_steps=0)
    fast, fast_solver = run_pushed(steps)
    assert full_solver.touching_chunks > 5 and full_solver.wall_chunks > 10  # the passes had work to do
    for name in full:
        assert np.array_equal(full[name], fast[name]), name
    assert full_solver.grid_builds == steps  # every step
    assert fast_solver.grid_builds < steps / 5  # only when a midpoint moved half the skin


def test_a_larger_skin_gives_the_same_run():
    base, _ = run_pushed(2000, neighbour_skin_mm=0.0)
    wide, solver = run_pushed(2000, neighbour_skin_mm=0.3)
    assert solver.grid_builds < 100
    for name in base:
        assert np.array_equal(base[name], wide[name]), name
