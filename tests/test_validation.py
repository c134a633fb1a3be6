"""The validation cases of `warpcoil validate`, asserted against analytic references
(shortened where the full case is long; each still fails on the defect it guards)."""

import numpy as np
import pytest

import warpcoil as wc
from warpcoil import validation


def assert_rows_pass(rows):
    failed = [r for r in rows if not r.passed]
    assert not failed, "\n" + validation.format_table(failed)


def test_contact_law_values_and_continuity():
    rows = validation.contact_law()
    assert_rows_pass(rows)
    assert rows[1].result == pytest.approx(4463.43, rel=1e-6)


def test_forces_are_minus_the_energy_gradient():
    assert_rows_pass(validation.gradient_cases())


def test_extensible_elastica_reduces_to_the_euler_elastica():
    assert validation.extensible_elastica(5.0, 0.0) == pytest.approx(0.713792, abs=1e-6)
    # stretch lengthens the rod: the tip drops further, by about the axial strain
    assert validation.extensible_elastica(5.0, 1e-3) > validation.extensible_elastica(5.0, 0.0)


def test_cantilever_clamped_at_node_0_matches_the_extensible_elastica_at_second_order():
    """Clamp at node 0 (x = 0): the old clamp (first edge, section at its midpoint)
    gave −2.2 % at 50 segments and first order for this placement."""
    rows = validation.cantilever_cases(resolutions=(25, 50))
    assert_rows_pass(rows)
    errors = [r.error for r in rows[:2]]
    assert errors[1] <= 5e-4
    assert validation.observed_order(errors) == pytest.approx(2.0, abs=0.3)


def test_bending_frequencies_converge_at_second_order():
    """End nodes carry half a segment's mass: full end masses gave −2 % / −3.9 % at
    50 segments (clamped-free / free-free) and first order. A short rod keeps it fast
    (the relative error depends on the segment count only)."""
    rows = validation.frequency_cases(resolutions=(12, 24, 48), length_mm=5.0)
    for support in ("clamped-free", "free-free"):
        errors = [r.error for r in rows if r.case.startswith(f"frequency {support},")]
        assert validation.observed_order(errors) == pytest.approx(2.0, abs=0.25)
        assert errors[-1] < 2.5e-3


def test_end_nodes_carry_half_a_segment():
    spec = wc.CoilSpec(length_mm=3.0, loop_diameter_mm=2.0)
    builder = wc.ModelBuilder()
    builder.add_coil(spec)
    builder.add_coil(spec)
    model = builder.finalize()
    mass = 1.0 / model.inv_mass.numpy()
    assert mass.sum() == pytest.approx(spec.rho * model.rest_length.numpy().sum(), rel=1e-12)  # both coils
    for first, last in zip(model.coil_first, model.coil_last):
        assert mass[first] == pytest.approx(0.5 * mass[first + 1], rel=1e-9)
        assert mass[last] == pytest.approx(0.5 * mass[last - 1], rel=1e-9)
    damping = model.damping_c.numpy()
    assert np.allclose(damping * model.inv_mass.numpy(), damping[1] * model.inv_mass.numpy()[1])  # one decay rate
    # the step bound is not cut by the lighter ends: the interior chain sets it
    m = spec.rho * model.rest_length.numpy()[1]
    assert wc.stable_step_bound(model).omega_rad_s["stretching (coil axial_stiffness_uN)"] == pytest.approx(
        (4.0 * spec.EA / model.rest_length.numpy()[1] / m) ** 0.5, rel=1e-6)


def test_helix_recovers_from_straight():
    assert_rows_pass(validation.helix_recovery())


def test_free_release_from_catheter_forms_the_helix():
    assert_rows_pass(validation.free_release())


def test_a_tilted_catheter_packs_the_coil_as_a_rigid_rotation():
    """The bench's free-release perturbation (a catheter turned by 0.01°) changes only
    round-off: the packed coil lies along the turned axis at the same arc positions and
    stores the same bending and twist energy."""
    from warpcoil.model import ModelBuilder
    from warpcoil.solver import Solver
    from warpcoil.state import packed_state

    def packed(catheter):
        builder = ModelBuilder(catheter=catheter)
        builder.add_coil(validation._helix_spec(None, dict(validation.HELIX, length_mm=6.0)))
        model = builder.finalize()
        state = packed_state(model)
        return state.x.numpy(), Solver(model).check_health(state)

    catheter = validation.tilted_catheter(30.0, 60.0)
    direction = np.array(catheter.direction)
    assert np.degrees(np.arccos(direction[2])) == pytest.approx(30.0, abs=1e-12)
    assert np.degrees(np.arctan2(direction[1], direction[0])) == pytest.approx(60.0, abs=1e-12)
    (x0, e0), (x1, e1) = packed(validation.tilted_catheter()), packed(catheter)
    np.testing.assert_allclose(x1 @ direction, x0[:, 2], atol=1e-12)  # same distances along the catheter
    np.testing.assert_allclose(np.linalg.norm(np.cross(x1, direction), axis=1), 0.0, atol=1e-12)  # on its axis
    for key in ("bend_nJ", "twist_nJ"):
        assert e0[key] > 0.0 and e1[key] == pytest.approx(e0[key], rel=1e-9)


def test_undamped_energy_is_conserved():
    assert_rows_pass(validation.energy_conservation())


def test_porous_field_volume_and_permeabilities():
    rows = validation.porous_cases()
    assert_rows_pass(rows)
    volume_errors = [r.error for r in rows if "capsule volume" in r.case]
    assert volume_errors[-1] < volume_errors[0]  # converges as the voxel shrinks


def _spring_mass_energy_errors(h_omega: float, steps: int = 2000) -> tuple[float, float, float]:
    """Symplectic Euler (kick, then drift) on x'' = −x from x = 1 at rest: largest
    relative error of the naive ½ v_{n−½}² + ½ x_n², of the time-centred
    ½ ((v_{n−½} + v_{n+½})/2)² + ½ x_n², and of the invariant ½ v_{n−½} v_{n+½} + ½ x_n²."""
    x, v, h = 1.0, 0.0, h_omega
    errors = np.zeros(3)
    for _ in range(steps):
        v_next = v - h * x
        energies = (0.5 * v * v + 0.5 * x * x, 0.125 * (v + v_next) ** 2 + 0.5 * x * x, 0.5 * v * v_next + 0.5 * x * x)
        errors = np.maximum(errors, np.abs(np.array(energies) / 0.5 - 1.0))
        v = v_next
        x = x + h * v
    return tuple(errors)


def test_spring_mass_symplectic_euler_energy_pairings():
    """The analytic invariant is exact; the naive pairing errs at O(h ω), the time-centred one at O(h ω)²."""
    coarse, fine = _spring_mass_energy_errors(0.2), _spring_mass_energy_errors(0.1)
    assert coarse[2] < 1e-12 and fine[2] < 1e-12
    assert np.log2(coarse[0] / fine[0]) == pytest.approx(1.0, abs=0.1)
    assert np.log2(coarse[1] / fine[1]) == pytest.approx(2.0, abs=0.1)


def test_undamped_3d_helix_synchronous_energy_converges_at_second_order():
    """Shortened: 20 000 steps (``warpcoil validate energy3d`` runs 10⁶)."""
    rows = validation.energy_3d_cases(steps=20_000)
    assert_rows_pass(rows)  # max |ΔE|/E0 ≤ 1 % at the default step and half of it, log2 of their ratio ≥ 1.5
    assert rows[1].result > rows[0].result  # the naive pairing errs more


def test_tip_trajectory_converges_with_the_time_step():
    """Shortened: 5 ms against a 1/16 step reference."""
    rows = validation.timestep_convergence(duration_s=0.005, refinements=(1, 2, 4), reference_refinement=16,
                                           sample_steps_at_default=10)
    assert_rows_pass(rows)


def test_undamped_step_is_time_reversible():
    """The released helix, run on, its velocities v_{n+½} and spins reversed, retraces its
    positions and frames to round-off: no dissipative part in the step (kick, drift,
    frame transport, twist update, damping solve at zero damping)."""
    solver, stepper = validation._opened_helix(validation.DEFAULT_DT_SAFETY, 0.0, 500)
    stepper.run_steps(1000)
    start = stepper.state
    x0, m0 = start.x.numpy().copy(), start.m1.numpy().copy()
    stepper.run_steps(2000)

    def reverse(state) -> None:  # (x_n, v_{n-1/2}) -> (x_n, -v_{n+1/2}); likewise the spins
        solver.compute_forces(state)
        model, h = solver.model, solver.dt_s
        state.v.assign(-(state.v.numpy() + h * model.inv_mass.numpy()[:, None] * solver.force.numpy()))
        spins = model.has_next.numpy() != 0
        state.omega.assign(-np.where(spins, state.omega.numpy() + h * model.inv_inertia.numpy() * solver.torque.numpy(), 0.0))

    reverse(stepper.state)
    stepper.run_steps(2000)
    back = stepper.state
    assert np.abs(back.x.numpy() - x0).max() < 1e-9 * np.ptp(x0, axis=0).max()
    assert np.abs(back.m1.numpy() - m0).max() < 1e-9


def test_implicit_step_converges_damps_as_stated_and_keeps_the_static_cases():
    assert_rows_pass(validation.implicit_cases())
