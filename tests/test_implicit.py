"""The linearly implicit θ-method step: its system matrix, its banded solve, its
stability beyond the explicit bound, and the deployment machinery around it
(push, step halving, ensembles, the scene key)."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import warpcoil as wc
from warpcoil import validation
from warpcoil.coil import CoilSpec
from warpcoil.deploy import Deployment, Ensemble
from warpcoil.implicit import (DEFAULT_IMPLICIT_SCHEME, EULER, GATED_CHORD, IMPLICIT_DT_MAX_S, IMPLICIT_SCHEMES, ImplicitSolver,
                               TURN_GATE_RAD, make_solver)
from warpcoil.model import ModelBuilder
from warpcoil.scene import SceneError, load_scene
from warpcoil.settings import CatheterSpec, SimulationSettings
from warpcoil.solver import Control, Solver, Stepper
from warpcoil.state import packed_state, state_from_positions, new_state_like
from warpcoil.validation_friction import P0_UN
from warpcoil.validation_node_theta import QUASI_STATIC, slow_helix_kinetic_ratio
from warpcoil.validation_push import free_space_push_force, wall_push_force

from test_ensemble import assert_same_run, scene as ensemble_scene


def straight_rod(segments=12, stretch=1.01, damping=0.0):
    spec = CoilSpec(length_mm=segments * 0.3, segment_length_mm=0.3)
    rest = np.zeros((segments + 1, 3))
    rest[:, 0] = np.arange(segments + 1) * spec.l0
    builder = ModelBuilder(settings=SimulationSettings(damping_uN_per_mm=damping))
    builder.add_coil(spec, rest)
    return builder.finalize(), rest * stretch


def blocks_dense(solver: ImplicitSolver, n: int) -> np.ndarray:
    """The assembled banded M + dt² H (without coil–coil contact) as a dense (3n, 3n) matrix."""
    diag, up1, up2 = solver._diag_exact.numpy(), solver._upper1.numpy(), solver._upper2.numpy()
    a = np.zeros((3 * n, 3 * n))
    for i in range(n):
        a[3 * i:3 * i + 3, 3 * i:3 * i + 3] = diag[i]
        for off, up in ((1, up1), (2, up2)):
            if i + off < n:
                a[3 * i:3 * i + 3, 3 * (i + off):3 * (i + off) + 3] = up[i]
                a[3 * (i + off):3 * (i + off) + 3, 3 * i:3 * i + 3] = up[i].T
    return a


def test_matrix_is_the_elastic_hessian_of_a_straight_stretched_rod():
    """On a straight rod under tension (rest straight) the Gauss–Newton bending
    Hessian and the stretching Hessian are exact: (A − M)/dt² equals the
    central-difference Jacobian of −F."""
    model, x0 = straight_rod()
    n = model.node_count
    dt = 1.0e-3
    solver = ImplicitSolver(model, dt_s=dt, coil_contact=False)
    state = state_from_positions(model, x0)
    out = new_state_like(model)
    solver.step(state, out, Control.create(model))
    mass = 1.0 / model.inv_mass.numpy()
    hessian = (blocks_dense(solver, n) - np.kron(np.diag(mass), np.eye(3))) / (solver.theta * dt)**2
    eps = 1e-6
    fd = np.zeros((3 * n, 3 * n))
    for k in range(3 * n):
        forces = []
        for sign in (1.0, -1.0):
            x = x0.copy()
            x[k // 3, k % 3] += sign * eps
            s = state_from_positions(model, x)
            solver.compute_forces(s)
            forces.append(solver.force.numpy().ravel().copy())  # a CPU array's numpy() is a view
        fd[:, k] = -(forces[0] - forces[1]) / (2 * eps)
    assert np.abs(hessian - fd).max() <= 1e-5 * np.abs(fd).max()


def test_banded_solve_satisfies_the_system_with_held_nodes():
    """Pushed half out of a catheter: the free nodes' new velocities solve
    (M + dt² H) v' = M v + dt F with the held nodes' velocities (the pusher's)
    moved to the right side (undamped, so v' is the solve's own output), once
    the conjugate gradients have converged."""
    spec = CoilSpec(shape="helix", length_mm=6.0, loop_diameter_mm=2.0, pitch_mm=0.5)
    builder = ModelBuilder(catheter=CatheterSpec(), settings=SimulationSettings(damping_uN_per_mm=0.0))
    builder.add_coil(spec)
    model = builder.finalize()
    control = Control.create(model, active_coil=0, push_speed_mm_s=50.0)
    solver = ImplicitSolver(model, dt_s=2.0e-4, coil_contact=False, cg_iterations=40, **EULER)  # θ 1: the system above
    stepper = Stepper(solver, packed_state(model), control, chunk=20)
    stepper.run_steps(300)  # 3 mm out
    state_in = stepper.state
    out = new_state_like(model)
    solver.step(state_in, out, control)
    free = out.free.numpy() == 1
    assert 5 < free.sum() < model.node_count - 5
    n = model.node_count
    a = blocks_dense(solver, n)
    v_new = out.v.numpy().ravel()
    rows = np.repeat(free, 3)
    residual = a[rows] @ v_new - solver._rhs.numpy().ravel()[rows]
    assert np.abs(residual).max() <= 1e-9 * np.abs(solver._rhs.numpy().ravel()[rows]).max()
    held = ~free
    assert np.allclose(out.v.numpy()[held][:, 2], 50.0)  # the pusher's speed along the catheter


def test_stable_far_beyond_the_explicit_bound():
    """Undamped bent rod at 50 × the explicit bound: no blow-up, energy never
    grows (the step only dissipates), and it relaxes towards straight."""
    model, _ = straight_rod(segments=20, stretch=1.0)
    s = np.arange(model.node_count) * 0.3
    radius = 3.0
    arc = np.stack([radius * np.sin(s / radius), radius * (1.0 - np.cos(s / radius)), 0 * s], axis=1)
    bound = Solver(model, coil_contact=False).bound.dt_s
    solver = ImplicitSolver(model, dt_s=50.0 * bound, coil_contact=False)
    stepper = Stepper(solver, state_from_positions(model, arc), Control.create(model), chunk=10)
    energies = [sum(solver.energies(stepper.state).values())]
    for _ in range(30):
        stepper.run_steps(10)
        energies.append(sum(solver.energies(stepper.state).values()))
    assert all(np.isfinite(energies))
    assert all(b <= a + 1e-9 * energies[0] for a, b in zip(energies, energies[1:]))  # up to round-off at rest
    assert energies[-1] < 1e-3 * energies[0]


@pytest.mark.parametrize("scheme", ["default", "euler"])
def test_converges_to_the_reference_at_first_order(scheme):
    """The default scheme (gated_chord, θ 0.65; no obstacle, so no node gated) and linearly
    implicit Euler against the reference as dt shrinks: first order at the finest pair. Euler's
    order still rises towards 1 across these steps (0.73 → 0.80); gated_chord's is already near 1
    there (0.91 → 0.93: within 0.1 of 1), so the "rises" row is Euler's (the full sweep of
    `warpcoil validate implicit` shows gated_chord rising from its coarser steps)."""
    labelled = validation.EULER_LABELLED if scheme == "euler" else None
    rows = validation.implicit_convergence(factors=(0.1, 0.05, 0.025), labelled_options=labelled)
    if labelled is None:
        rows = [r for r in rows if "rises" not in r.case]
        assert abs(rows[-1].result - 1.0) < 0.1
    failed = [r for r in rows if not r.passed]
    assert not failed, validation.format_table(failed)
    errors = [r.result for r in rows if "rel. RMS" in r.case]
    assert errors[0] > errors[1] > errors[2]


@pytest.mark.parametrize("theta", [1.0, 0.7])
def test_numerical_damping_is_the_theta_methods(theta):
    """Undamped lowest bending mode of a cantilever at the default step: the amplitude lost
    per period is the θ-method's linear theory, 1 − |R|^(2π/ω dt) (θ 0.7 loses less than θ 1)."""
    rows = validation.implicit_damping(theta=theta)
    failed = [r for r in rows if not r.passed]
    assert not failed, validation.format_table(failed)
    assert rows[1].result < (0.02 if theta < 1.0 else 0.04)


def implicit_scene(**kwargs):
    s = ensemble_scene(**kwargs)
    return replace(s, simulation=replace(s.simulation, integrator="implicit"))


def test_implicit_deployment_completes_with_far_fewer_steps():
    explicit = Deployment(ensemble_scene()).run()
    implicit = Deployment(implicit_scene()).run()
    assert implicit.status == explicit.status == "completed"
    assert implicit.steps * 5 < explicit.steps
    assert implicit.deployed_length_mm == pytest.approx(explicit.deployed_length_mm)
    assert implicit.min_wall_gap_mm > -0.5 * wc.CoilSpec().d  # no node through the wall
    assert implicit.push_force_peak_uN > 0.0


def test_ensemble_members_equal_their_single_implicit_runs():
    scenes = [implicit_scene(angle_deg=0.0), implicit_scene(angle_deg=20.0, sac_diameter_mm=4.0)]
    results = Ensemble(scenes).run()
    for s, member in zip(scenes, results):
        assert_same_run(Deployment(s).run(), member)


def test_step_halving_keeps_the_implicit_integrator():
    deployment = Deployment(implicit_scene())
    dt = deployment.solver.dt_s
    snapshot = new_state_like(deployment.model)
    snapshot.copy_from(deployment.stepper.state)
    deployment._halve_step(snapshot, "test at t = 0")
    assert isinstance(deployment.solver, ImplicitSolver)
    assert deployment.solver.dt_s == pytest.approx(0.5 * dt)


def test_make_solver_refuses_an_unknown_integrator():
    model, _ = straight_rod()
    with pytest.raises(ValueError, match="integrator"):
        make_solver(model, "rk4", None)


def test_scene_key_integrator(tmp_path: Path):
    base = '[[coil]]\nwire_diameter_mm = 0.3\nloop_diameter_mm = 3.0\nlength_mm = 10.0\n[simulation]\n'
    good = tmp_path / "good.toml"
    good.write_text(base + 'integrator = "implicit"\n')
    assert load_scene(good).simulation.integrator == "implicit"
    bad = tmp_path / "bad.toml"
    bad.write_text(base + 'integrator = "rk4"\n')
    with pytest.raises(SceneError) as caught:
        load_scene(bad)
    assert "simulation.integrator" in str(caught.value) and "bad.toml" in str(caught.value)


def test_named_schemes_build_their_solvers_and_bdf2_takes_its_own_defaults():
    """simulation.implicit_scheme names each of implicit.IMPLICIT_SCHEMES (the default: gated_chord,
    θ 0.65 gated, chord); method "bdf2" alone takes θ 1, no gate, the tangent stiffness; the θ-method's
    options given to BDF2 are refused by name; explicit solver options override the scheme."""
    for name, options in IMPLICIT_SCHEMES.items():
        s = implicit_scene()
        s = replace(s, simulation=replace(s.simulation, implicit_scheme=name))
        scheme = Deployment(s).solver.scheme
        assert {key: scheme[key] for key in options} == options, name
    assert IMPLICIT_SCHEMES[DEFAULT_IMPLICIT_SCHEME] == {"method": "theta", "theta": 0.65, "near_theta": 1.0,
                                                         "contact_stiffness": "chord"}
    assert IMPLICIT_SCHEMES["euler"] == {"method": "theta", "theta": 1.0, "near_theta": None,
                                         "contact_stiffness": "tangent"}
    default = Deployment(implicit_scene()).solver  # the scene default is gated_chord, its turn gate on
    assert (default.scheme["theta"], default.scheme["turn_gate_rad"]) == (0.65, TURN_GATE_RAD)
    euler = ImplicitSolver(straight_rod()[0], dt_s=1e-4, **EULER)  # the solver's default is the scene's
    assert (euler.theta, euler.near_theta, euler.chord) == (1.0, None, False)
    assert ImplicitSolver(straight_rod()[0], dt_s=1e-4).scheme == default.scheme
    model, _ = straight_rod()
    bdf2 = ImplicitSolver(model, dt_s=1e-4, method="bdf2")
    assert (bdf2.theta, bdf2.near_theta, bdf2.chord) == (1.0, None, False)
    with pytest.raises(ValueError, match="near_theta"):
        ImplicitSolver(model, dt_s=1e-4, method="bdf2", near_theta=1.0)
    s = replace(implicit_scene(), simulation=replace(implicit_scene().simulation, implicit_scheme="gated_chord"))
    overridden = Deployment(s, solver_options={"theta": 0.7}).solver.scheme  # key by key: the gates and chord stay
    assert (overridden["theta"], overridden["near_theta"], overridden["contact_stiffness"]) == (0.7, 1.0, "chord")


def test_conjugate_gradients_solve_the_system_with_exact_contact_coupling():
    """Two free rods pressed across each other: after enough iterations the
    velocities solve (M + dt² (H + K_c)) v' = M v + dt F with K_c the pairs'
    exact k wᵀw ⊗ n nᵀ (off the band: it couples the two coils), which is
    symmetric (each pair recorded from both sides)."""
    spec = CoilSpec(length_mm=3.0, segment_length_mm=0.3)
    builder = ModelBuilder(settings=SimulationSettings(damping_uN_per_mm=0.0))
    s = np.arange(11) * 0.3 - 1.5
    first = np.stack([s, 0 * s, 0 * s], axis=1)
    second = np.stack([0 * s + 0.05, s + 0.02, 0 * s + spec.d - 0.01], axis=1)  # 0.01 mm overlap
    for rod in (first, second):
        builder.add_coil(spec, rod)
    model = builder.finalize()
    x0 = np.concatenate([first, second])
    dt = 2.0e-4
    solver = ImplicitSolver(model, dt_s=dt, cg_iterations=60, **EULER)  # ungated: the solve's unknown is v'
    state, out = state_from_positions(model, x0), new_state_like(model)
    solver.allocate_neighbour_grid(state)
    solver.step(state, out, Control.create(model))
    n = model.node_count
    a = blocks_dense(solver, n)
    counts = solver._pair_count.numpy()
    assert counts.sum() >= 2 and (counts >= 0).all()
    pb, pst, pk, pn = (getattr(solver, f"_pair_{k}").numpy() for k in ("b", "st", "k", "n"))
    for e in range(n):
        for k in range(counts[e]):
            b, (s_, t_) = pb[e, k], pst[e, k]
            w = {e: 1 - s_, e + 1: s_}
            other = {b: -(1 - t_), b + 1: -t_}
            nn = np.outer(pn[e, k], pn[e, k])
            for i, wi in w.items():
                for j, wj in {**w, **other}.items() if not set(w) & set(other) else []:
                    a[3 * i:3 * i + 3, 3 * j:3 * j + 3] += (solver.theta * dt)**2 * pk[e, k] * wi * wj * nn
    assert np.allclose(a, a.T, rtol=0, atol=1e-12 * np.abs(a).max())
    residual = a @ out.v.numpy().ravel() - solver._rhs.numpy().ravel()
    assert np.abs(residual).max() <= 1e-8 * np.abs(solver._rhs.numpy()).max()
    assert np.abs(a - np.diag(np.diag(a)))[:33, 33:].max() > 0.0  # the coils are coupled


def crossed_rods_step(cg_iterations: int, push_cg_iterations: int, pushing: bool) -> np.ndarray:
    """The velocities after one step of two free rods pressed across each other
    (0.01 mm overlap: coil–coil contact, off the preconditioner's band), coil 0's
    pusher driving it (at zero speed, every node already out) or none."""
    spec = CoilSpec(length_mm=3.0, segment_length_mm=0.3)
    builder = ModelBuilder(settings=SimulationSettings(damping_uN_per_mm=0.0))
    s = np.arange(11) * 0.3 - 1.5
    first = np.stack([s, 0 * s, 0 * s], axis=1)
    second = np.stack([0 * s + 0.05, s + 0.02, 0 * s + spec.d - 0.01], axis=1)
    for rod in (first, second):
        builder.add_coil(spec, rod)
    model = builder.finalize()
    solver = ImplicitSolver(model, dt_s=2.0e-4, cg_iterations=cg_iterations, push_cg_iterations=push_cg_iterations)
    state, out = state_from_positions(model, np.concatenate([first, second])), new_state_like(model)
    state.advance.assign(np.full(model.coil_count, 10.0))  # past every node's arc length: all free
    control = Control.create(model, active_coil=0 if pushing else -1, push_speed_mm_s=0.0)
    solver.allocate_neighbour_grid(state)
    solver.step(state, out, control)
    assert out.free.numpy().all()
    return out.v.numpy()


def test_a_pushed_world_takes_the_push_iterations_and_a_settling_world_all_of_them():
    """With a pusher driving a coil the step is that of push_cg_iterations conjugate-gradient
    iterations, bit for bit (the later iterations' launches skip the world); without one,
    that of cg_iterations; and the iterations converge (1 → 3 → 60 ever nearer the solution)."""
    settled = crossed_rods_step(3, 1, pushing=False)
    assert np.array_equal(settled, crossed_rods_step(3, 3, pushing=False))
    pushed = crossed_rods_step(3, 1, pushing=True)
    assert np.array_equal(pushed, crossed_rods_step(1, 1, pushing=True))
    assert np.array_equal(crossed_rods_step(3, 3, pushing=True), settled)
    solution = crossed_rods_step(60, 60, pushing=False)
    errors = [np.abs(v - solution).max() for v in (pushed, settled)]
    assert errors[0] > errors[1] > 0.0


def test_push_force_of_a_steady_push_is_the_damping_the_free_part_meets_at_any_step():
    """Pushed straight out, the free part moves with the pusher: the push force balances
    its damping. Linearly implicit Euler gives that at large steps as the reference does
    (damping applied after the solve gave a spurious compression growing as dt²); the gated_chord
    scheme over its push steps (≤ IMPLICIT_DT_MAX_S: at 2 ms, 7 c0 a step, each released node's
    stiff transient rings at −(1 − θ)/θ = −0.54 a step and the reading is 7 % high)."""
    push, damping = free_space_push_force("symplectic")
    assert push == pytest.approx(damping, rel=0.05)
    for options, steps in ((EULER, (1.0e-4, 5.0e-4, 2.0e-3)), (GATED_CHORD, (1.0e-4, IMPLICIT_DT_MAX_S))):
        for dt in steps:
            push, damping = free_space_push_force("implicit", dt, **options)
            assert push == pytest.approx(damping, rel=0.05), (options, dt)


@pytest.mark.parametrize("integrator, options", [("symplectic", {}), ("implicit", {}), ("implicit", {"theta": 0.7})])
def test_push_force_on_a_wall_at_rest_is_the_wall_reaction(integrator, options):
    """A straight coil pushed onto a flat wall, the pusher stopped, at rest: the push force
    is the wall's reaction on the distal node, s0 |F|(h), with h the pusher's advance less the
    free part's axial compression (series springs); θ 0.7's blended reading too."""
    push, reaction, analytic = wall_push_force(integrator, **options)
    assert push == pytest.approx(analytic, rel=1e-3)
    assert push == pytest.approx(reaction, rel=1e-5)
    assert analytic > 1.2 * P0_UN * 0.5  # pressed past zero clearance: the law's stiff part


def test_a_theta_method_run_settles_with_the_euler_step():
    """θ < 1 (less numerical damping) during the push; at the settling step the linearly
    implicit Euler step (θ = 1) brings the coil to rest."""
    deployment = Deployment(implicit_scene(), solver_options={"theta": 0.7})
    assert deployment.solver.theta == 0.7
    result = deployment.run()
    assert result.status == "completed" and deployment.solver.theta == 1.0
    assert deployment.solver.dt_s == result.settle_dt_s >= deployment.settle_dt_s


def test_the_default_step_settles_at_the_settling_step_from_the_push_end():
    """Once every coil is out and its whip over (the scheduled push end) the default implicit step goes on
    at the settling step, the frame length kept; a step the scene gives is kept to the end."""
    from warpcoil.deploy import world_steps
    from warpcoil.implicit import DETACH_WHIP_S, IMPLICIT_SETTLE_DT_MAX_S, settle_step_s

    deployment = Deployment(implicit_scene())
    push_dt = deployment.solver.dt_s
    result = deployment.run()
    assert result.status == "completed"
    frame = deployment.scenes[0].simulation.frame_interval_s
    assert deployment.settle_dt_s == settle_step_s(push_dt, frame) > push_dt
    assert deployment.solver.dt_s == result.settle_dt_s  # the last settling step, ...
    assert deployment.settle_dt_s <= result.settle_dt_s <= IMPLICIT_SETTLE_DT_MAX_S  # ... between finest and cap
    assert round(frame / result.settle_dt_s) % 2 == 0  # an even split of the frame
    assert result.dt_s == push_dt  # both reported
    speed = deployment.scenes[0].simulation.push_speed_mm_s  # (the last coil's whip over: deploy.world_steps)
    assert result.simulated_time_s > deployment.push_time_s == pytest.approx(
        (result.coil_length_mm + 1.0) / speed + max(0.0, DETACH_WHIP_S - 1.0 / speed))
    times = np.array([f.time_s for f in deployment.members[0].frames])
    assert np.allclose(np.diff(times), frame, rtol=0.25)  # about the same frames (even steps) before and after
    given = Deployment(implicit_scene(dt_s=push_dt))
    settle_dt, push_time = world_steps(given.model, given.scenes)[0][4:6]
    assert settle_dt == 0.0  # a given step is kept, but it settles at θ IMPLICIT_SETTLE_THETA from the same push end
    assert push_time == deployment.push_time_s
    assert given.run().settle_dt_s is None
    assert given.solver.dt_s == push_dt


def test_a_free_release_comes_to_rest_in_the_helix_at_a_fine_enough_push_step():
    """At 100 mm/s the default push step (0.8 c0) comes to rest tangled from every
    perturbation tried (docs/FORMULATION.md, "the free release that comes to rest tangled");
    at 0.4 c0 per push step it reaches the rest helix, also with the catheter turned 0.01°."""
    for catheter in (None, validation.tilted_catheter(0.01, 90.0)):
        rows = validation.free_release(push_speed_mm_s=100.0, integrator="implicit", catheter=catheter,
                                       advance_per_c0=0.4)
        assert all(r.passed for r in rows), validation.format_table(rows)


def test_euler_pushes_a_helix_slowly_into_free_space_quasi_statically():
    """A 30 mm helix (d 0.254 mm, loop 3.5 mm) pushed at 25 mm/s into empty space: the
    pusher barely works, so the coil's kinetic energy must stay a small part of its elastic
    energy (MODEL.md's quasi-static report, ≤ 0.1) in every frame of the push. Linearly
    implicit Euler: 0.013. The same case under the default gated_chord (0.83 before its turn
    gate, 0.041 with it) is `validate node-theta`'s, asserted by
    test_node_theta.py::test_validate_node_theta_rows (docs/FORMULATION.md "the turn gate")."""
    assert slow_helix_kinetic_ratio(EULER) <= QUASI_STATIC
