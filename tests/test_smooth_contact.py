"""Contact forces without jumps (so a damped pack comes to rest) and a tight pre-shape
that contact leaves alone (docs/FORMULATION.md, Contact)."""

import numpy as np
import pytest
import trimesh

import warpcoil as wc
from warpcoil.metrics import fit_helix
from warpcoil.validation import TIGHT_HELIX
from warpcoil.wall import WallMesh

D = 0.2921


def node_probes(points, wall=None, coil_contact=False):
    """One 3-node coil per point (centred on it, along x); a Solver; forces on the centres."""
    spec = wc.CoilSpec(length_mm=2 * D, segment_length_mm=D)
    builder = wc.ModelBuilder(wall=wall)
    for p in points:
        builder.add_coil(spec, np.asarray(p) + np.array([[-D, 0, 0], [0, 0, 0], [D, 0, 0]]))
    model = builder.finalize()
    solver = wc.Solver(model, coil_contact=coil_contact)
    solver.compute_contacts(wc.rest_state(model))
    return model, solver.wall_force.numpy()[1::3]


def closed_wall(mesh: trimesh.Trimesh) -> WallMesh:
    return WallMesh(np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int32), float(mesh.volume), (), None)


def test_wall_force_has_no_jump_where_the_closest_facet_changes():
    """A node slid at constant depth across a groove between two facets of a coarse
    sac (80 faces, ~20° between neighbours): with only the closest face's normal the
    force turns by that angle in one step; the feature sum turns it smoothly."""
    sphere = trimesh.creation.icosphere(subdivisions=1, radius=1.75)
    wall = closed_wall(sphere)
    # the shared edge of faces 0 and its first neighbour; slide across its midpoint
    pair = sphere.face_adjacency[0]
    edge = sphere.vertices[sphere.face_adjacency_edges[0]]
    midpoint = edge.mean(axis=0)
    across = np.cross(edge[1] - edge[0], midpoint)
    across /= np.linalg.norm(across)
    inward = -sphere.face_normals[pair].sum(axis=0)
    inward /= np.linalg.norm(inward)
    depth = D / 2 + 0.012  # gap ~ 0.4 c0 from either facet
    s = np.linspace(-0.02, 0.02, 81)
    points = midpoint + depth * inward + s[:, None] * across
    model, force = node_probes(points, wall)
    assert np.all(np.linalg.norm(force, axis=1) > 0.1 * model.contact.p0_uN)  # every probe pressed
    step = np.linalg.norm(np.diff(force, axis=0), axis=1)
    typical = np.median(step)
    assert step.max() < 5.0 * typical  # continuous: no step stands out (a jump would be ~ F · 0.36)
    assert step.max() < 0.02 * np.linalg.norm(force, axis=1).max()


def test_flat_facets_count_once():
    """In front of the diagonal shared by a box face's two triangles (and of a face
    interior), the force is the law of the distance to the plane, once."""
    box = trimesh.creation.box(extents=(4.0, 4.0, 4.0))
    wall = closed_wall(box)
    gap = 0.01
    centre_z = -2.0 + D / 2 + gap
    points = [(0.0, 0.0, centre_z), (0.7, 0.3, centre_z), (-0.5, 0.9, centre_z)]  # on the diagonal, off it
    model, force = node_probes(points, wall)
    c0, p0 = model.contact.c0_mm, model.contact.p0_uN
    u = 1.0 - gap / c0
    law = p0 / (np.e - 1.0) * u * (np.exp(u) - 1.0)
    assert np.allclose(force, np.tile([0.0, 0.0, law], (3, 1)), rtol=1e-9, atol=1e-9 * law)


def parallel_pair(tilt_rad: float, gap_mm: float, n: int = 9):
    """Coil A along x at height D + gap over coil B, tilted by ``tilt_rad`` about the
    y axis through its middle; node forces of coil contact (µN)."""
    s = (np.arange(n) - n // 2) * D
    a = np.stack([s * np.cos(tilt_rad), np.zeros(n), D + gap_mm - s * np.sin(tilt_rad)], axis=1)
    b = np.stack([s + 0.37 * D, np.zeros(n), np.zeros(n)], axis=1)  # nodes staggered against A's
    spec = wc.CoilSpec(length_mm=(n - 1) * D, segment_length_mm=D)
    builder = wc.ModelBuilder()
    builder.add_coil(spec, a)
    builder.add_coil(spec, b)
    model = builder.finalize()
    solver = wc.Solver(model)
    solver.compute_contacts(wc.rest_state(model))
    return model, solver.contact_force.numpy()


def test_coil_contact_has_no_jump_when_two_segments_turn_parallel():
    """Capsule–capsule closest points jump from one end of a segment to the other as
    two segments pass through parallel, and the force with them; the node–capsule
    sum changes smoothly."""
    tilts = np.linspace(-2e-3, 2e-3, 41)
    forces = np.stack([parallel_pair(t, 0.01)[1] for t in tilts])
    step = np.linalg.norm(np.diff(forces, axis=0), axis=2).max(axis=1)
    scale = np.linalg.norm(forces, axis=2).max()
    assert scale > 100.0
    assert step.max() < 0.02 * scale


def test_parallel_coils_press_with_the_law_once_per_node():
    """Two straight parallel coils at gap h: each interior node of one is pressed with
    |F|(h) along the normal (P0 per node patch d·l0, MODEL.md), wherever the other's
    nodes are."""
    gap = 0.01
    model, force = parallel_pair(0.0, gap, n=11)
    c0, p0 = model.contact.c0_mm, model.contact.p0_uN
    u = 1.0 - gap / c0
    law = p0 / (np.e - 1.0) * u * (np.exp(u) - 1.0)
    interior = force[3:8]  # coil A's middle nodes, away from either coil's ends
    assert np.allclose(interior, np.tile([0.0, 0.0, law], (5, 1)), rtol=1e-9, atol=1e-9 * law)
    assert np.allclose(force[:11].sum(axis=0), -force[11:].sum(axis=0), rtol=1e-12, atol=1e-9 * law)  # action = reaction


def test_a_tight_pitch_helix_at_rest_feels_no_contact():
    """Turns 10 µm apart (pitch d + 10 µm < d + c0): in the rest shape no contact term acts."""
    builder = wc.ModelBuilder()
    builder.add_coil(wc.CoilSpec(wire_diameter_mm=D, shape="helix", **TIGHT_HELIX))
    model = builder.finalize()
    solver = wc.Solver(model)
    solver.compute_contacts(wc.rest_state(model))
    assert TIGHT_HELIX["pitch_mm"] - D < model.contact.c0_mm  # the turns are within contact range
    assert np.abs(solver.contact_force.numpy()).max() == 0.0


def test_a_tight_pitch_helix_reports_contacts_only_beyond_its_rest_clearance():
    """coil_contacts / coil_gap (result.json coil_contacts, min_coil_gap_mm) measure the
    gap as the law sees it, from a same-coil pair's rest clearance: at rest the turns
    (10 µm apart) are not in contact and the smallest gap is c0 exactly; the helix
    compressed along its axis by ε is in contact, its smallest gap c0 − ε p cos α
    (p the pitch, α the helix angle: adjacent turns move ε p along the axis)."""
    builder = wc.ModelBuilder()
    builder.add_coil(wc.CoilSpec(wire_diameter_mm=D, shape="helix", **TIGHT_HELIX))
    model = builder.finalize()
    c0, pitch = model.contact.c0_mm, TIGHT_HELIX["pitch_mm"]
    solver = wc.Solver(model)
    rest = wc.rest_state(model)
    solver.compute_contacts(rest)
    assert solver.coil_contacts.numpy().sum() == 0
    assert abs(solver.coil_gap.numpy().min() - c0) < 1e-9
    x = rest.x.numpy()
    axis = fit_helix(x).axis
    strain = 0.02
    centre = x.mean(axis=0)
    pressed = x - strain * np.outer((x - centre) @ axis, axis)
    solver.compute_contacts(wc.state_from_positions(model, pressed))
    cos_angle = np.cos(np.arctan(pitch / (np.pi * TIGHT_HELIX["loop_diameter_mm"])))
    assert solver.coil_contacts.numpy().sum() > 0
    assert solver.coil_gap.numpy().min() == pytest.approx(c0 - strain * pitch * cos_angle, rel=0.02)


def settle(model, positions, steps=30_000):
    """Kinetic energy (nJ) after ``steps`` default steps from rest at ``positions``, and its largest value."""
    solver = wc.Solver(model)
    stepper = wc.Stepper(solver, wc.state_from_positions(model, positions), wc.Control.create(model), chunk=1000)
    largest = 0.0
    for _ in range(steps // stepper.chunk):
        largest = max(largest, solver.energies(stepper.run_chunk())["kinetic_nJ"])
    return solver.energies(stepper.state)["kinetic_nJ"], largest


def test_a_coil_pressed_into_a_groove_between_facets_comes_to_rest():
    """A short straight coil along the edge between two facets (80-face sac), pushed into
    the groove by a constant force on every node: a damped system with a static
    equilibrium must reach it. With the closest face's normal the nodes chatter
    across the groove's bisector for ever (kinetic energy ∝ dt², never decaying)."""
    sphere = trimesh.creation.icosphere(subdivisions=1, radius=1.75)
    pair = sphere.face_adjacency[0]
    edge = sphere.vertices[sphere.face_adjacency_edges[0]]
    along = (edge[1] - edge[0]) / np.linalg.norm(edge[1] - edge[0])
    inward = -sphere.face_normals[pair].sum(axis=0)
    inward /= np.linalg.norm(inward)
    centre = edge.mean(axis=0) + (D / 2 + 0.02) * inward
    positions = centre + np.outer((np.arange(3) - 1) * 0.5 * D, along)
    builder = wc.ModelBuilder(wall=closed_wall(sphere))
    builder.add_coil(wc.CoilSpec(length_mm=D, segment_length_mm=0.5 * D), positions)
    for node in range(3):
        builder.apply_force(0, node, -200.0 * inward)
    final, largest = settle(builder.finalize(), positions)
    assert largest > 1e-6  # it moved into the groove
    assert final < 1e-9 * largest
