"""The implicit step's wall stiffness is the Jacobian of the wall force: on a flat
face the law's k n nᵀ, in a groove (two faces within reach) both faces' k n nᵀ —
the net force's direction alone misses the second, and a coil tip pressed into a
groove then runs a limit cycle at the settling step."""

from pathlib import Path

import numpy as np
import pytest
import trimesh

import warpcoil as wc
from warpcoil.implicit import ImplicitSolver
from warpcoil.settings import WallSpec
from warpcoil.solver import Control
from warpcoil.state import new_state_like, state_from_positions
from warpcoil.wall import WallMesh, load_wall

D = 0.2921
HALF_BOX_MM = 1.0


@pytest.fixture(scope="module")
def box_wall(tmp_path_factory) -> WallMesh:
    path = Path(tmp_path_factory.mktemp("box")) / "box.stl"
    trimesh.creation.box(extents=(2 * HALF_BOX_MM,) * 3).export(path)
    return load_wall(WallSpec(mesh=path))


def stiffness_and_jacobian(wall, centre: np.ndarray, eps_mm: float = 1e-7) -> tuple[np.ndarray, np.ndarray]:
    """The implicit solver's wall stiffness at the middle node of a 3-node coil (along y)
    centred at ``centre``, and −∂F_wall/∂x there by central differences (µN/mm), with the
    wall queried through the BVH (float64; the field samples in float32)."""
    spec = wc.CoilSpec(length_mm=2 * D, segment_length_mm=D)
    builder = wc.ModelBuilder(wall=wall)
    builder.add_coil(spec, centre + np.array([[0, -D, 0], [0, 0, 0], [0, D, 0]]))
    model = builder.finalize()
    assert model.contact_share.numpy()[1] == 1.0
    state = state_from_positions(model, model.rest_positions)
    solver = ImplicitSolver(model, dt_s=1e-4, coil_contact=False, wall_query="bvh")  # the exact law (float64)
    solver.step(state, new_state_like(model), Control.create(model))
    stiffness = solver._wall_stiffness.numpy()[1]
    x0 = state.x.numpy().copy()  # (a CPU array's numpy() is a view)
    jacobian = np.zeros((3, 3))
    for a in range(3):
        forces = []
        for sign in (1.0, -1.0):
            x = x0.copy()
            x[1, a] += sign * eps_mm
            state.x.assign(x)
            solver.compute_contacts(state)
            forces.append(solver.wall_force.numpy()[1].copy())
        jacobian[:, a] = -(forces[0] - forces[1]) / (2 * eps_mm)
    return stiffness, 0.5 * (jacobian + jacobian.T)


def test_on_a_flat_face_the_single_law(box_wall):
    stiffness, jacobian = stiffness_and_jacobian(box_wall, np.array([0.0, 0.0, HALF_BOX_MM - 0.13]))
    assert np.linalg.matrix_rank(stiffness, tol=1e-6 * np.abs(stiffness).max()) == 1
    np.testing.assert_allclose(stiffness, jacobian, rtol=0, atol=1e-5 * np.abs(jacobian).max())


def test_in_a_groove_both_faces(box_wall):
    """0.13 mm from two faces of the box (the edge between them out of reach): the force
    Jacobian has two stiff directions, the faces' normals; the matrix has both."""
    stiffness, jacobian = stiffness_and_jacobian(box_wall, np.array([HALF_BOX_MM - 0.13, 0.0, HALF_BOX_MM - 0.12]))
    assert sorted(np.linalg.eigvalsh(jacobian) > 1e-3 * np.abs(jacobian).max()) == [False, True, True]
    np.testing.assert_allclose(stiffness, jacobian, rtol=0, atol=1e-5 * np.abs(jacobian).max())
