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


def test_undamped_energy_is_conserved():
    assert_rows_pass(validation.energy_conservation())


def test_porous_field_volume_and_permeabilities():
    rows = validation.porous_cases()
    assert_rows_pass(rows)
    volume_errors = [r.error for r in rows if "capsule volume" in r.case]
    assert volume_errors[-1] < volume_errors[0]  # converges as the voxel shrinks


def test_undamped_3d_helix_energy_error_shrinks_at_least_at_first_order():
    """Shortened: 20 000 steps (``warpcoil validate energy3d`` runs 10⁶)."""
    rows = validation.energy_3d_cases(steps=20_000)
    assert_rows_pass([rows[-1]])  # the order from the error ratio, default / half step
    assert rows[2].result < rows[0].result


def test_tip_trajectory_converges_with_the_time_step():
    """Shortened: 5 ms against a 1/16 step reference."""
    rows = validation.timestep_convergence(duration_s=0.005, refinements=(1, 2, 4), reference_refinement=16,
                                           sample_steps_at_default=10)
    assert_rows_pass(rows)
