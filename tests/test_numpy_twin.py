"""The NumPy twin (benchmarks/numpy_twin.py) simulates the same thing as the Warp
solver: positions, free flags and energies agree to rounding after hundreds of
steps, with the catheter, coil–coil contact and the wall.

Energies are compared relative to the total energy (a component can be ~1e-29,
pure rounding, when the state has none of it)."""

import numpy as np
from test_contact import crossing_pair
import pytest

import warpcoil as wc

from benchmarks.numpy_twin import NumpyTwin, contact_force_magnitude  # (the checkout's root: conftest.py)
from warpcoil.kernels import contact
from warpcoil.wall import sphere_wall  # noqa: E402

D = 0.2921


def run_both(model, state, steps, push_speed_mm_s=0.0, active_coil=-1, coil_contact=True):
    """``steps`` steps of the Warp Stepper (no graph, 2 steps a chunk) and of the
    twin from the same state; returns (warp state, solver, twin, largest contact
    force the twin saw, µN)."""
    solver = wc.Solver(model, coil_contact=coil_contact, wall_query="bvh")  # the twin mirrors the exact wall
    twin = NumpyTwin(model, state, solver.dt_s, push_speed_mm_s=push_speed_mm_s, active_coil=active_coil,
                     coil_contact=coil_contact)
    control = wc.Control.create(model, active_coil=active_coil, push_speed_mm_s=push_speed_mm_s)
    stepper = wc.Stepper(solver, state, control, chunk=2, use_graph=False)
    largest = 0.0
    for _ in range(steps // 2):
        stepper.run_chunk()
        twin.run(2)
        largest = max(largest, float(np.abs(twin.contact_force).max()))
    assert stepper.steps == steps and twin.time_s == pytest.approx(stepper.state.time_s, rel=1e-12)
    return stepper.state, solver, twin, largest


def assert_agree(state, solver, twin, rtol):
    x = state.x.numpy()
    size = float(np.ptp(x, axis=0).max())
    assert np.abs(x - twin.x).max() <= rtol * size
    assert np.array_equal(state.free.numpy(), twin.free)
    assert np.abs(state.m1.numpy() - twin.m1).max() <= rtol
    warp_e, twin_e = solver.energies(state), twin.energies()
    assert warp_e.keys() == twin_e.keys()
    total = sum(abs(e) for e in warp_e.values())
    assert total > 0.0
    for key in warp_e:
        assert abs(warp_e[key] - twin_e[key]) <= rtol * total, key


def helix_model(catheter=None):
    builder = wc.ModelBuilder(catheter=catheter)
    builder.add_coil(wc.CoilSpec(length_mm=10.0, loop_diameter_mm=2.0, pitch_mm=0.6))
    return builder.finalize()


def test_free_helix_released_from_straight():
    model = helix_model()
    straight = np.zeros((model.node_count, 3))
    straight[:, 0] = model.arc_s.numpy()
    state, solver, twin, _ = run_both(model, wc.state_from_positions(model, straight), 300)
    assert twin.energies()["kinetic_nJ"] > 1.0  # it is recovering its helix
    assert_agree(state, solver, twin, 1e-9)


@pytest.mark.parametrize("bent, push_speed_mm_s", [(False, 100.0), (True, 1000.0)])
def test_push_out_of_the_catheter(bent, push_speed_mm_s):
    """At 100 mm/s 400 steps push out a few segments; at 1 m/s through a bent
    catheter (the polyline walk of catheter_point) at least eight nodes leave it."""
    catheter = None
    if bent:
        catheter = wc.CatheterSpec(tip_mm=(0.0, 0.0, 0.0),
                                   centerline_mm=((-20.0, 0.0, -20.0), (0.0, 0.0, -2.0), (0.0, 0.0, 0.0)))
    model = helix_model(catheter)
    state, solver, twin, _ = run_both(model, wc.packed_state(model), 400, push_speed_mm_s=push_speed_mm_s,
                                      active_coil=0)
    out = int((model.arc_s.numpy() <= twin.advance[0]).sum())  # nodes past the tip
    assert twin.free.sum() == out and out >= (8 if bent else 1)
    assert np.allclose(twin.advance, state.advance.numpy(), rtol=0.0, atol=1e-12)
    assert_agree(state, solver, twin, 1e-9)
    warp_push = [float(v[0]) for v in solver.take_push_force()[:2]]  # (the solver counted the 400 steps)
    twin_push = twin.take_push_force(400)
    assert twin_push[1] > 0.0  # mean and largest step push force (µN)
    assert np.allclose(twin_push, warp_push, rtol=1e-9, atol=0.0)


def test_coil_coil_contact():
    model, state, _ = crossing_pair(200.0)
    state, solver, twin, largest = run_both(model, state, 200)
    assert largest > model.contact.p0_uN  # pressed past zero clearance
    assert np.array_equal(solver.coil_contacts.numpy(), twin.coil_contacts)
    assert_agree(state, solver, twin, 1e-7)


def test_wall_contact():
    """A straight 5-node coil inside a 3.5 mm sphere thrown at the wall. Warp's
    BVH finds the closest point in float32, so the two agree to ~1e-7."""
    n = 5
    builder = wc.ModelBuilder(wall=sphere_wall(3.5), settings=wc.SimulationSettings(mass_scale=1.0))
    x = np.stack([(np.arange(n) - n // 2) * D + 0.13, np.full(n, 0.21), np.full(n, 1.35)], axis=1)
    builder.add_coil(wc.CoilSpec(length_mm=(n - 1) * D, segment_length_mm=D), x)
    model = builder.finalize()
    state = wc.rest_state(model)
    state.v.assign(np.tile([0.0, 0.0, 300.0], (n, 1)))
    state, solver, twin, largest = run_both(model, state, 200, coil_contact=False)
    assert largest > 0.1 * model.contact.p0_uN
    assert_agree(state, solver, twin, 1e-6)
    # in the run, a node out of its contact range may report the bound it was anchored with
    # (above the range, at most its true distance) instead of searching
    near = twin.wall_distance < model.node_radius.numpy() + model.contact.c0_mm
    anchored = solver.wall_distance.numpy().copy()
    # searched everywhere (as a frame's measurement does), both give every node's exact distance
    solver.compute_contacts(state, wall_search_mm=float(contact.FAR_MM))
    twin.wall_search_mm = float(contact.FAR_MM)
    twin.wall_contact(twin.x, twin.free)
    assert np.all(np.abs(twin.wall_distance) < 2.0)  # every node measured (inside a 3.5 mm sphere)
    assert np.allclose(twin.wall_distance, solver.wall_distance.numpy(), rtol=0.0, atol=1e-6)
    # the anchored bound of a node out of range: above the contact range, at most its exact distance
    # (the twin's windowed search reports the window's edge there, not the distance)
    far = model.node_radius.numpy()[~near] + model.contact.c0_mm
    assert np.all((anchored[~near] > far) & (anchored[~near] <= twin.wall_distance[~near] + 1e-6))


def test_contact_law_matches_the_kernel():
    import warp as wp

    c0 = 0.03
    h = np.linspace(-10 * c0, 2 * c0, 97)
    for u_linear in (7.0, 3.4):  # MODEL.md's onset, and an earlier one as a solver may choose
        force = wp.zeros(len(h), dtype=wp.float64)
        stiffness = wp.zeros(len(h), dtype=wp.float64)
        wp.launch(contact.evaluate_law, len(h), inputs=[wp.array(h, dtype=wp.float64), 1.0e3, c0, u_linear, force,
                                                        stiffness])
        assert np.allclose(contact_force_magnitude(h, 1.0e3, c0, u_linear), force.numpy(), rtol=1e-14, atol=0.0)
