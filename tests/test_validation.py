"""The validation cases of `warpcoil validate`, asserted against analytic references."""

import pytest

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


def test_cantilever_matches_elastica_and_converges():
    rows = validation.cantilever_cases()
    assert_rows_pass(rows)
    errors = [r.error for r in rows[:3]]
    assert errors[0] > errors[1] > errors[2]
    assert errors[1] <= 5e-3


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
