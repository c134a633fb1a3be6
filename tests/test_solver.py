"""Integrator, damping, step bound, guards and catheter packing."""

import math

import numpy as np
import pytest

import warpcoil as wc
from warpcoil.model import voronoi_lengths
from warpcoil.solver import SimulationUnstable, UnstableStepError


def helix_model(settings=None, catheter=None, length_mm=6.0):
    spec = wc.CoilSpec(length_mm=length_mm, loop_diameter_mm=2.0, pitch_mm=0.6)
    builder = wc.ModelBuilder(catheter=catheter, settings=settings)
    builder.add_coil(spec)
    return builder.finalize(), spec


@pytest.mark.parametrize("direction", [(1.0, 0.0, 0.0), (1.0, 1.0, 1.0)])
def test_nonlinear_damping_follows_the_vector_law(direction):
    """A coil in its rest shape moving rigidly feels only damping; its speed follows
    m dv/dt = −c (1 − exp(−v/k)), whose solution is
    v(t) = k ln(1 + (exp(v0/k) − 1) exp(−c t/(m k))), whatever the direction."""
    settings = wc.SimulationSettings(damping_uN_per_mm=10.0, damping_speed_mm_s=20.0)
    model, spec = helix_model(settings)
    state = wc.rest_state(model)
    v0 = 60.0
    unit = np.asarray(direction) / np.linalg.norm(direction)
    state.v.assign(np.tile(v0 * unit, (model.node_count, 1)))
    solver = wc.Solver(model, dt_safety=0.15)  # the damping is first order in dt: a small step for the comparison
    stepper = wc.Stepper(solver, state, wc.Control.create(model), chunk=200)
    mass = 1.0 / model.inv_mass.numpy()[0]
    c = model.damping_c.numpy()[0]
    k = settings.damping_speed_mm_s
    for _ in range(5):
        stepper.run_chunk()
        t = stepper.state.time_s
        v = stepper.state.v.numpy()
        expected = k * math.log1p((math.exp(v0 / k) - 1.0) * math.exp(-c * t / (mass * k)))
        speeds = np.linalg.norm(v, axis=1)
        assert np.allclose(speeds, expected, rtol=5e-3)  # first order in dt: dt·c/(m k) ≈ 4e-3 here
        assert np.allclose(v / speeds[:, None], unit, atol=1e-9)  # direction kept


def test_step_above_the_bound_is_refused_with_the_limiting_term():
    model, _ = helix_model()
    bound = wc.Solver(model).bound  # with the contact term (each node's law weighted by its share, as its mass)
    with pytest.raises(UnstableStepError, match="stable bound") as info:
        wc.Solver(model, dt_s=1.5 * bound.dt_s)
    assert bound.limiting_term.split(" ")[0] in str(info.value)


def test_unstable_run_stops_with_a_reason_not_nan():
    model, _ = helix_model(wc.SimulationSettings(damping_uN_per_mm=1e-6))
    bound = wc.stable_step_bound(model)
    solver = wc.Solver(model, dt_s=3.0 * bound.dt_s, allow_unstable_dt=True)
    n = model.node_count
    straight = np.zeros((n, 3))
    straight[:, 0] = model.arc_s.numpy()
    stepper = wc.Stepper(solver, wc.state_from_positions(model, straight), wc.Control.create(model), chunk=100)
    with pytest.raises(SimulationUnstable, match="dt_s") as info:
        stepper.run_steps(20_000)
    assert "bound" in info.value.reason


def test_stable_step_bound_matches_the_chain_formulas():
    model, spec = helix_model()
    bound = wc.stable_step_bound(model)
    m = spec.rho * model.rest_length.numpy()[:-1].mean() * model.mass_scale
    l0 = model.rest_length.numpy()[0]
    stretch = math.sqrt(4.0 * spec.EA / l0 / m)
    bend = math.sqrt(16.0 * spec.EI / l0 / (m * l0**2))
    omegas = bound.omega_rad_s
    assert omegas["stretching (coil axial_stiffness_uN)"] == pytest.approx(stretch, rel=1e-6)
    assert omegas["bending (coil bending_stiffness_uN_mm2)"] == pytest.approx(bend, rel=1e-2)
    assert bound.dt_s == pytest.approx(2.0 / max(omegas.values()))


def run(model, state, control, use_graph, chunks=3):
    stepper = wc.Stepper(wc.Solver(model), state, control, chunk=100, use_graph=use_graph)
    for _ in range(chunks):
        stepper.run_chunk()
    return stepper.state.x.numpy(), stepper.state.m1.numpy()


def test_graph_replay_equals_plain_launches_bit_for_bit():
    model, _ = helix_model(catheter=wc.CatheterSpec())
    results = []
    for use_graph in (True, False):
        control = wc.Control.create(model, active_coil=0, push_speed_mm_s=50.0)
        results.append(run(model, wc.packed_state(model), control, use_graph))
    assert np.array_equal(results[0][0], results[1][0])
    assert np.array_equal(results[0][1], results[1][1])
    assert np.isfinite(results[0][0]).all()


def test_packed_coil_stores_the_bending_energy_of_its_preshape():
    """Straightened in the catheter, twist-free: W = Σ ½ k_b φ0² (angle form)."""
    model, spec = helix_model(catheter=wc.CatheterSpec(tip_mm=(1.0, 2.0, 3.0), direction=(0.0, 1.0, 0.0)))
    state = wc.packed_state(model)
    x = state.x.numpy()
    assert np.allclose(x[:, [0, 2]], [1.0, 3.0])  # on the catheter axis
    assert np.allclose(np.diff(x[:, 1]), -model.rest_length.numpy()[:-1])  # rest lengths kept
    rest = model.rest_positions
    t = np.diff(rest, axis=0)
    t /= np.linalg.norm(t, axis=1)[:, None]
    phi0 = np.arctan2(np.linalg.norm(np.cross(t[:-1], t[1:]), axis=1), np.sum(t[:-1] * t[1:], axis=1))
    expected = 0.5 * np.sum(model.k_bend.numpy()[1:-1] * phi0**2)
    energies = wc.Solver(model).energies(state)
    assert energies["bend_nJ"] == pytest.approx(expected, rel=1e-9)
    assert energies["twist_nJ"] == pytest.approx(0.0, abs=1e-9 * expected)
    assert energies["stretch_nJ"] == pytest.approx(0.0, abs=1e-12)


def test_packing_follows_a_polyline_catheter():
    path = ((0.0, 0.0, -20.0), (0.0, 0.0, -5.0), (0.0, 5.0, 0.0))
    catheter = wc.CatheterSpec(tip_mm=path[-1], direction=(0.0, 1.0, 1.0), centerline_mm=path)
    model, _ = helix_model(catheter=catheter, length_mm=12.0)
    x = wc.packed_state(model).x.numpy()
    pts = np.asarray(path)
    # every node lies on one of the two polyline segments
    def dist_to_segment(p, a, b):
        ab = b - a
        s = np.clip(((p - a) @ ab) / (ab @ ab), 0.0, 1.0)
        return np.linalg.norm(p - (a + s[:, None] * ab), axis=1)
    d = np.minimum(dist_to_segment(x, pts[0], pts[1]), dist_to_segment(x, pts[1], pts[2]))
    assert d.max() < 1e-12
    assert np.allclose(x[0], pts[-1])
    # arc length along the catheter from the tip equals the rest arc length
    seg = np.linalg.norm(pts[2] - pts[1])
    s = model.arc_s.numpy()
    on_last = s <= seg
    assert np.allclose(np.linalg.norm(x[on_last] - pts[-1], axis=1), s[on_last])


def test_world_energies_count_each_non_finite_node_once():
    """The per-world count of non-finite nodes: 0 for a healthy state (its fast path), and one per
    node with any non-finite coordinate (NaN or ±inf)."""
    model, _ = helix_model()
    solver = wc.Solver(model)
    straight = np.zeros((model.node_count, 3))
    straight[:, 0] = model.arc_s.numpy()
    _, bad = solver.world_energies(wc.state_from_positions(model, straight))
    assert bad.tolist() == [0]
    straight[3] = [np.nan, 0.0, np.nan]
    straight[7, 2] = np.inf
    _, bad = solver.world_energies(wc.state_from_positions(model, straight))
    assert bad.tolist() == [2]


@pytest.mark.parametrize("mass_scale", [1.0, 10.0])
def test_mass_scaling_keeps_the_damped_terminal_speed(mass_scale):
    """Mass scaling makes nodes heavier, not the damping stronger: a coil in its rest shape
    pulled by f = 6 µN per mm of coil reaches the terminal speed of c (1 − exp(−v/k)) = f,
    v = −k ln(1 − f/c), whatever mass_scale (scaled damping would make it f/(s c)-slow)."""
    settings = wc.SimulationSettings(damping_uN_per_mm=10.0, damping_speed_mm_s=20.0, mass_scale=mass_scale)
    free_model, spec = helix_model(settings)
    builder = wc.ModelBuilder(settings=settings)
    builder.add_coil(spec)
    per_mm = 6.0
    edges = np.linalg.norm(np.diff(free_model.rest_positions, axis=0), axis=1)
    for node, length in enumerate(voronoi_lengths(np.append(edges, 0.0))):
        builder.apply_force(0, node, (per_mm * length, 0.0, 0.0))
    model = builder.finalize()
    solver = wc.Solver(model, dt_safety=0.5)
    stepper = wc.Stepper(solver, wc.rest_state(model), wc.Control.create(model), chunk=500)
    while stepper.state.time_s < 0.3:  # 9 relaxation times m k exp(v/k)/c of the heavier coil
        stepper.run_chunk()
    terminal = -settings.damping_speed_mm_s * math.log(1.0 - per_mm / settings.damping_uN_per_mm)
    v = stepper.state.v.numpy()
    assert np.allclose(v[:, 0], terminal, rtol=2e-3)
    assert np.allclose(v[:, 1:], 0.0, atol=1e-6 * terminal)
