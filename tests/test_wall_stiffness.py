"""The implicit step's wall stiffness is the Jacobian of the wall force: on a flat
face the law's k n nᵀ, in a groove (two faces within reach) both faces' k n nᵀ —
the net force's direction alone misses the second, and a coil pressed into a groove
then cycles and runs away at the settling step (warpcoil/validation_implicit_wall.py)."""

import numpy as np

from warpcoil.validation import REFERENCE_D_MM
from warpcoil.validation_implicit_wall import HALF_BOX_MM, groove_centre, groove_rest, stiffness_probe

C0 = 0.1 * REFERENCE_D_MM


def test_on_a_flat_face_the_single_law():
    stiffness, jacobian = stiffness_probe(np.array([0.3, 0.1, HALF_BOX_MM - 0.5 * REFERENCE_D_MM + 0.5 * C0]))
    assert np.linalg.matrix_rank(stiffness, tol=1e-6 * np.abs(stiffness).max()) == 1
    np.testing.assert_allclose(stiffness, jacobian, rtol=0, atol=1e-5 * np.abs(jacobian).max())


def test_in_a_groove_both_faces():
    """Half c0 into two faces of the box (the edge between them out of reach): the force
    Jacobian has two stiff directions, the faces' normals; the matrix has both."""
    stiffness, jacobian = stiffness_probe(groove_centre(-0.5 * C0))
    assert sorted(np.linalg.eigvalsh(jacobian) > 1e-3 * np.abs(jacobian).max()) == [False, True, True]
    np.testing.assert_allclose(stiffness, jacobian, rtol=0, atol=1e-5 * np.abs(jacobian).max())


def test_a_coil_pressed_into_a_groove_rests_at_the_settling_step_where_each_face_carries_its_share():
    rows = groove_rest()
    assert len(rows) == 3 and all(r.passed for r in rows), rows
