"""Skipped work of the implicit step's contact passes gives the full passes' results
(docs/FORMULATION.md, "Skipped work, same results"): the coil–coil stiffness gathered
over the touching partners the contact pass noted equals the one gathered over the
whole neighbour list, bit for bit; the wall's feature sum (faces beyond the contact
range skipped with their edges and vertices) equals the sum over every face, edge
and vertex of the wall."""

import numpy as np
import trimesh
import warp as wp

import warpcoil as wc
from benchmarks.numpy_twin import contact_force_magnitude
from warpcoil.faceted_sac import lobulated_sac
from warpcoil.implicit import ImplicitSolver
from warpcoil.kernels import contact
from warpcoil.kernels import implicit as kernels
from warpcoil.validation import _helix_spec

D = 0.2921


def stiffness(solver: ImplicitSolver, state, touch_count: wp.array, chord: int = 0) -> dict:
    """edge_contact_stiffness at ``state`` (after its contact pass) with ``touch_count`` (``chord``:
    the chord to the predicted end x itself, over every neighbour-list partner)."""
    m, c = solver.model, solver.model.contact
    if chord:  # the predicted end's per-edge values (its filters)
        wp.launch(kernels.edge_ends, m.node_count, inputs=[
            state.x, state.x, m.has_next, m.node_radius, solver._end_mid, solver._end_half, solver._sweep,
            solver._end_move, solver._node_move])
    solver._coil_stiffness(state, solver._running_all, state.x, chord, c.p0_uN, False, touch_count)
    out = {k: getattr(solver, k).numpy().copy() for k in ("_stiff_start", "_stiff_end", "_pair_count")}
    count = np.maximum(out["_pair_count"], 0)
    for k in ("_pair_b", "_pair_st", "_pair_k", "_pair_n"):  # the recorded slots
        values = getattr(solver, k).numpy()
        out[k] = [values[e, :count[e]].copy() for e in range(len(count))]
    return out


def test_contact_stiffness_over_the_touching_record_equals_the_neighbour_list_pass():
    """Two interleaved close-wound helices jittered by 2 µm (hundreds of touching pairs)."""
    helix = dict(length_mm=20.0, loop_diameter_mm=3.0, pitch_mm=D + 0.005)
    builder = wc.ModelBuilder()
    builder.add_coil(_helix_spec(None, helix))
    builder.add_coil(_helix_spec(None, dict(helix, loop_diameter_mm=2.5)))
    model = builder.finalize()
    x = model.rest_positions + 2e-3 * np.random.default_rng(1).standard_normal(model.rest_positions.shape)
    state = wc.state_from_positions(model, x)
    solver = ImplicitSolver(model, dt_s=4.0e-4)
    solver.allocate_neighbour_grid(state)
    solver.compute_contacts(state)
    noted = solver._touch_count.numpy()
    touching = solver.coil_contacts.numpy()
    assert touching.sum() > 500 and np.all(noted >= touching)  # every touching pair noted (a hair more allowed)
    assert noted.max() <= solver._touch_b.shape[1]  # the record held them all: its path is the one tested
    from_record = stiffness(solver, state, solver._touch_count)
    overflowed = wp.array(np.where(noted > 0, solver._touch_b.shape[1] + 1, 0).astype(np.int32))
    from_list = stiffness(solver, state, overflowed)
    from_chord = stiffness(solver, state, solver._touch_count, chord=1)  # no motion: the chord is the tangent
    assert from_record["_pair_count"].sum() > 500
    for other in (from_list, from_chord):
        for k, v in other.items():
            if isinstance(v, list):
                assert all(np.array_equal(a, b) for a, b in zip(v, from_record[k])), k
            else:
                assert np.array_equal(v, from_record[k]), k


def reference_wall_force(local: np.ndarray, vertices: np.ndarray, faces: np.ndarray, owners: np.ndarray,
                         radius: float, p0: float, c0: float, u_linear: float) -> np.ndarray:
    """Σ faces − Σ owned edges + Σ owned vertices of the law along p − closest point, over the whole wall."""
    tri = vertices[faces]
    closest = trimesh.triangles.closest_point(tri, np.repeat(local[None], len(faces), axis=0))
    points = [closest]
    signs = [np.ones(len(faces))]
    for flag, (i, j) in ((contact.OWN_EDGE_AB, (0, 1)), (contact.OWN_EDGE_BC, (1, 2)), (contact.OWN_EDGE_CA, (2, 0))):
        a, b = tri[:, i], tri[:, j]
        t = np.clip(np.einsum("ij,ij->i", local - a, b - a) / np.einsum("ij,ij->i", b - a, b - a), 0.0, 1.0)
        points.append(a + t[:, None] * (b - a))
        signs.append(np.where(owners & int(flag), -1.0, 0.0))
    for flag, i in ((contact.OWN_VERTEX_A, 0), (contact.OWN_VERTEX_B, 1), (contact.OWN_VERTEX_C, 2)):
        points.append(tri[:, i])
        signs.append(np.where(owners & int(flag), 1.0, 0.0))
    delta = local - np.concatenate(points)
    dist = np.linalg.norm(delta, axis=1)
    law = contact_force_magnitude(dist - radius, p0, c0, u_linear)
    return ((np.concatenate(signs) * law / dist)[:, None] * delta).sum(axis=0)


def test_wall_feature_sum_equals_the_sum_over_the_whole_wall():
    """Probes within the contact range of a coarse faceted sac (320 faces: ridges,
    grooves and vertices in reach): the node's wall force equals the NumPy sum over
    every face, edge and vertex of the wall."""
    wall = lobulated_sac(20.0, subdivisions=2, seed=3)
    mesh = trimesh.Trimesh(wall.vertices_mm, wall.faces, process=False)
    rng = np.random.default_rng(2)
    surface, face = trimesh.sample.sample_surface(mesh, 40, seed=4)
    c0 = 0.1 * D  # the default contact onset
    depth = D / 2 + rng.uniform(0.0, 1.0, len(surface)) * c0  # a clearance within [0, c0]
    normals = mesh.face_normals[face]
    points = surface - depth[:, None] * normals  # inward
    builder = wc.ModelBuilder(wall=wall)
    spec = wc.CoilSpec(length_mm=2 * D, segment_length_mm=D)
    for p, n in zip(points, normals):  # a 3-node coil per probe along the wall's tangent, its middle node on it
        tangent = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
        builder.add_coil(spec, p + np.outer([-1.0, 0.0, 1.0], D * tangent / np.linalg.norm(tangent)))
    model = builder.finalize()
    solver = wc.Solver(model, coil_contact=False)
    solver.compute_contacts(wc.rest_state(model))
    force = solver.wall_force.numpy()[1::3]
    origin = model.wall_origin.numpy()[0]
    vertices = model.wall_vertices.numpy()
    faces = model.wall_faces.numpy().reshape(-1, 3)
    owners = model.wall_owners.numpy()
    c = model.contact
    assert abs(c.c0_mm - c0) < 1e-12
    pressed = 0
    for p, f in zip(points, force):
        expected = reference_wall_force(p - origin, vertices, faces, owners, D / 2, c.p0_uN, c.c0_mm,
                                        solver.contact_u_linear)
        scale = max(np.linalg.norm(expected), c.p0_uN)
        assert np.linalg.norm(f - expected) <= 1e-9 * scale, (f, expected)
        pressed += np.linalg.norm(expected) > 0.01 * c.p0_uN
    assert pressed >= 30  # most probes pressed (some by several faces)
