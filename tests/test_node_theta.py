"""The proximity-gated θ of the implicit θ-method (kernels/node_theta.py): θ_i = θ
everywhere is the θ-method bit for bit (θ = 1: linearly implicit Euler); a node within
reach of the wall, a stent strut or a balloon at the step start gets θ_i = 1; the
per-node update solves the θ-method's momentum balance with x' = x + dt ((1 − θ_i) v + θ_i v')."""

from pathlib import Path

import numpy as np
import pytest

from warpcoil.coil import CoilSpec
from warpcoil.deploy import Deployment
from warpcoil.implicit import EULER, ImplicitSolver, PROXIMITY_MARGIN_C0, TURN_GATE_RAD
from warpcoil.model import ModelBuilder
from warpcoil.scene import load_scene
from warpcoil.settings import ContactSettings, SimulationSettings
from warpcoil.solver import Control
from warpcoil.state import new_state_like, state_from_positions
from warpcoil.wall import sphere_wall

from test_implicit import blocks_dense, straight_rod
from test_implicit_devices import ASSISTED, STENT

R_SAC, DT = 1.5, 2.0e-4  # mm, s


FRICTION = "[contact]\nfriction_wall = 0.3\nfriction_coil = 0.2\n"


@pytest.mark.parametrize("theta, friction", [(0.7, False), (1.0, False), (0.7, True)])
def test_node_theta_equal_to_theta_is_the_theta_method_bit_for_bit(tmp_path: Path, theta: float, friction: bool):
    """A helix pushed past stent struts into a sphere (wall, coil and strut gates all
    evaluated; with friction, the positions recomputed from the frictional velocities),
    every θ_i = θ: positions, steps and push force equal the θ-method's (θ = 1: linearly
    implicit Euler's) bit for bit; the settling (θ = 1) on the gated path equals Euler's."""
    path = tmp_path / "s.toml"
    path.write_text(ASSISTED.format(integrator="implicit") + STENT + (FRICTION if friction else ""))
    runs = []
    for options in ({"theta": theta, "near_theta": None, "contact_stiffness": "tangent"},
                    {"theta": theta, "near_theta": theta, "contact_stiffness": "tangent"}):
        deployment = Deployment(load_scene(path), solver_options=options)
        result = deployment.run()
        assert result.status == "completed"
        runs.append((result, deployment))
    (plain, _), (gated, deployment) = runs
    assert deployment.solver.near_theta == theta
    free = deployment.stepper.state.free.numpy() == 1
    # the gate ran (its last step: θ_i = θ everywhere while pushing, 1 while settling; a frictional
    # run can come to rest as its last coil detaches, before a settling step)
    assert len(set(deployment.solver.node_theta.numpy()[free])) == 1
    assert deployment.solver.node_theta.numpy()[free][0] in (theta, 1.0)
    assert gated.steps == plain.steps
    assert np.array_equal(gated.positions_mm[0], plain.positions_mm[0])
    assert gated.push_force_mean_max_uN == plain.push_force_mean_max_uN


def one_step_theta(model, x, v, theta=0.7, **options):
    """Each node's θ_i after one gated step from positions x, velocities v."""
    solver = ImplicitSolver(model, dt_s=DT, theta=theta, near_theta=1.0, contact_stiffness="tangent", **options)
    state = state_from_positions(model, x)
    state.v.assign(v)
    solver.allocate_neighbour_grid(state)
    solver.step(state, new_state_like(model), Control.create(model))
    return solver.node_theta.numpy()


def test_a_node_that_could_reach_the_wall_within_the_step_gets_theta_one():
    """A straight coil along a radius of a sphere, nodes at surface gaps from −c0 to
    many c0, some moving towards the wall: θ_i = 1 exactly where the gap is below
    c0 (1 + PROXIMITY_MARGIN_C0) + |v_i| dt (the exact distance at the step start:
    every node just left no catheter, so each is searched in full)."""
    spec = CoilSpec(wire_diameter_mm=0.2921, length_mm=1.2, segment_length_mm=0.1)
    builder = ModelBuilder(wall=sphere_wall(2 * R_SAC, subdivisions=6))
    builder.add_coil(spec)
    model = builder.finalize()
    n = model.node_count
    r, c0 = 0.5 * spec.d, model.contact.c0_mm
    x = np.zeros((n, 3))
    x[:, 0] = R_SAC - r - np.linspace(-0.5 * c0, 1.2, n)[::-1]  # the last node outermost
    v = np.zeros((n, 3))
    v[::2, 0] = 300.0  # mm/s towards the wall: 0.06 mm (2 c0) a step
    theta = one_step_theta(model, x, v)
    radius_at = np.linalg.norm(x, axis=1)
    faceted = R_SAC * np.cos(np.radians(2.0))  # the icosphere's faces lie within 2° of the sphere here
    reach = c0 * (1.0 + PROXIMITY_MARGIN_C0) + np.linalg.norm(v, axis=1) * DT
    surely_near = (faceted - radius_at - r) < reach - 1e-9  # the faceted gap is smaller than the sphere's
    surely_far = (R_SAC - radius_at - r) > reach + 1e-9
    assert surely_near.any() and surely_far.any()
    assert np.all(theta[surely_near] == 1.0) and np.all(theta[surely_far] == 0.7)
    assert theta[1] == 0.7 and theta[0] == 0.7  # (far, whatever its speed)


def test_a_strut_or_balloon_within_reach_gives_theta_one():
    """One coil edge beside a stent strut and nodes beside a balloon, at gaps just inside
    and just outside the reach: θ_i = 1 inside only."""
    r, c0 = 0.15, 0.03
    reach = c0 * (1.0 + PROXIMITY_MARGIN_C0)
    for obstacle in ("strut", "balloon"):
        for gap, expected in ((reach - 0.005, 1.0), (reach + 0.005, 0.7)):
            spec = CoilSpec(wire_diameter_mm=2 * r, length_mm=0.6, segment_length_mm=0.3)
            rest = np.zeros((3, 3))
            rest[:, 2] = np.arange(3) * 0.3
            builder = ModelBuilder(settings=SimulationSettings(damping_uN_per_mm=0.0),
                                   contact=ContactSettings(P0_uN=1.0e3, c0_mm=c0))
            builder.add_coil(spec, rest)
            if obstacle == "strut":  # across the coil's axis at z = 0.3, gap away along −x
                strut_r = 0.035
                builder.stent = (np.array([[-(r + strut_r + gap), -2.0, 0.3]]),
                                 np.array([[-(r + strut_r + gap), 2.0, 0.3]]), strut_r)
            else:  # a straight balloon of radius 1 along z, the coil beside it
                builder.balloon = (np.array([[0.0, 0.0, -3.0], [0.0, 0.0, 3.0]]), np.full(2, 1.0))
                rest = rest + [1.0 + r + gap, 0.0, 0.0]
            theta = one_step_theta(builder.finalize(), rest, np.zeros_like(rest))
            assert np.all(theta == expected), (obstacle, gap, theta)


def test_a_node_whose_edge_turns_past_the_gate_gets_theta_one():
    """A straight free 4-node rod, far from everything, its last node moving sideways so that
    its edge turns just above or just below the turn gate in the step: θ_i = 1 on that edge's
    two nodes only when above; a gate of 0 gates nothing; a negative or NaN gate is refused."""
    spec = CoilSpec(wire_diameter_mm=0.3, length_mm=0.9, segment_length_mm=0.3)
    rest = np.zeros((4, 3))
    rest[:, 2] = np.arange(4) * 0.3
    builder = ModelBuilder(settings=SimulationSettings(damping_uN_per_mm=0.0))
    builder.add_coil(spec, rest)
    model = builder.finalize()
    for factor, expected in ((1.05, [0.7, 0.7, 1.0, 1.0]), (0.95, [0.7] * 4)):
        v = np.zeros_like(rest)
        v[3, 0] = factor * TURN_GATE_RAD * 0.3 / DT  # mm/s: edge 2 turns factor × the gate in a step
        assert np.array_equal(one_step_theta(model, rest, v), expected), factor
    v = np.zeros_like(rest)
    v[3, 0] = 10.0 * TURN_GATE_RAD * 0.3 / DT
    assert np.array_equal(one_step_theta(model, rest, v, turn_gate_rad=0.0), [0.7] * 4)
    for bad in (-0.01, float("nan")):
        with pytest.raises(ValueError, match="turn_gate_rad"):
            ImplicitSolver(model, dt_s=DT, theta=0.7, near_theta=1.0, turn_gate_rad=bad)


def test_mixed_theta_step_is_the_momentum_balance_with_per_node_position_updates():
    """A stretched straight rod, moving, half of it beside a balloon (within reach, outside
    the contact range: no contact force), solved to convergence: the step satisfies
    M (v' − v) = dt (F(x) − θ H Δx) with Δx_i = dt ((1 − θ_i) v_i + θ_i v'_i), θ_i = 1 beside
    the balloon and θ = 0.7 elsewhere (H: the Euler step's assembled Hessian at x)."""
    model, x = straight_rod(segments=8, stretch=1.01)
    c0 = model.contact.c0_mm
    r = float(model.node_radius.numpy()[0])
    builder = ModelBuilder(settings=SimulationSettings(damping_uN_per_mm=0.0))
    builder.add_coil(model.coils[0], model.rest_positions)
    # a balloon of radius 1 along x below the first half of the rod, 2 c0 from its surface
    gap = 2.0 * c0
    builder.balloon = (np.array([[-1.0, 0.0, -(1.0 + r + gap)], [0.5 * x[-1, 0], 0.0, -(1.0 + r + gap)]]),
                       np.full(2, 1.0))
    model = builder.finalize()
    n, theta = model.node_count, 0.7
    rng = np.random.default_rng(3)
    v = rng.normal(scale=20.0, size=(n, 3))  # mm/s: ≤ 0.01 mm a step, no node reaches contact
    state = state_from_positions(model, x)
    state.v.assign(v)
    euler = ImplicitSolver(model, dt_s=DT, **EULER)
    euler.allocate_neighbour_grid(state)
    euler.step(state, new_state_like(model), Control.create(model))
    mass = np.repeat(1.0 / model.inv_mass.numpy(), 3)
    hessian = (blocks_dense(euler, n) - np.diag(mass)) / DT**2
    euler.compute_forces(state)
    force = euler.force.numpy().ravel()
    assert np.abs(euler.contact_force.numpy()).max() == 0.0  # no contact force: the balloon is only near
    gated = ImplicitSolver(model, dt_s=DT, theta=theta, near_theta=1.0, contact_stiffness="tangent",
                           cg_iterations=200, turn_gate_rad=0.0)  # the balloon's gate alone (random velocities turn edges)
    gated.allocate_neighbour_grid(state)
    out = new_state_like(model)
    gated.step(state, out, Control.create(model))
    node_theta = gated.node_theta.numpy()
    assert 0 < (node_theta == 1.0).sum() < n and set(node_theta) == {theta, 1.0}
    v_new, dx = out.v.numpy(), out.x.numpy() - x
    expected_dx = DT * ((1.0 - node_theta)[:, None] * v + node_theta[:, None] * v_new)
    np.testing.assert_allclose(dx, expected_dx, rtol=0, atol=1e-15)
    residual = mass * (v_new - v).ravel() - DT * (force - theta * hessian @ dx.ravel())
    assert np.abs(residual).max() < 1e-9 * np.abs(DT * force).max()  # (the terms are 1e-2 … 1 g·mm/s)


def test_validate_node_theta_rows():
    """`warpcoil validate node-theta`: the lowest cantilever mode loses the θ-method's
    share per period with no node gated and 1 − (1 + θ w²)^(−π/w) with every node gated
    (between θ 0.7's 1.08 % and Euler's 2.70 %); every node gated converges to the
    reference; the free release at 100 and 150 mm/s comes to rest in the helix (linearly
    implicit Euler: tangled in 5 of 5 turned runs at both speeds, FORMULATION.md); with the
    turn gate (0.01 and 0.003 rad) gated_chord pushes a helix slowly into free space
    quasi-statically."""
    from warpcoil.validation_node_theta import node_theta_cases

    rows = node_theta_cases()
    failed = [r.case for r in rows if not r.passed]
    assert not failed, failed
    gated = next(r for r in rows if "every node gated: amplitude" in r.case)
    free = next(r for r in rows if "no node gated" in r.case)
    assert free.result < gated.result < 0.0270  # θ 0.7 < gated < Euler at the same step


def test_gated_ensemble_members_equal_their_single_runs():
    """Two sphere deployments in one ensemble with the gated θ equal their single runs
    bit for bit (each node's gate reads only its own world's distances)."""
    from warpcoil.deploy import Ensemble

    from test_ensemble import assert_same_run
    from test_implicit import implicit_scene

    options = {"theta": 0.7, "near_theta": 1.0}
    scenes = [implicit_scene(angle_deg=0.0), implicit_scene(angle_deg=20.0, sac_diameter_mm=4.0)]
    results = Ensemble(scenes, solver_options=options).run()
    for s, member in zip(scenes, results):
        assert_same_run(Deployment(s, solver_options=options).run(), member)
