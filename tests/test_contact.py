"""Contact geometry and the no-crossing / no-escape invariants."""

import math

import numpy as np
import pytest

import warpcoil as wc
from warpcoil.kernels import contact
from warpcoil.wall import sphere_wall

R_SAC = 1.75
D = 0.2921


def one_node_per_coil_model(points, wall=None):
    """Tiny 3-node straight coils (one per point, centred on it) to probe contact."""
    spec = wc.CoilSpec(length_mm=2 * D, segment_length_mm=D)
    builder = wc.ModelBuilder(wall=wall)
    for p in points:
        builder.add_coil(spec, np.asarray(p) + np.array([[-D, 0, 0], [0, 0, 0], [D, 0, 0]]))
    return builder.finalize()


def test_wall_gap_sign_and_normal_inside_and_outside_the_sac():
    wall = sphere_wall(2 * R_SAC)
    radii = np.array([0.3, 1.0, 1.6, 1.9, 2.5])  # inside, inside, near the wall, outside, far outside
    directions = np.array([[0, 0, 1], [1, 0, 0], [0, -1, 0], [1, 1, 1], [-1, 2, 0.5]], float)
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    points = radii[:, None] * directions
    model = one_node_per_coil_model(points, wall)
    state = wc.rest_state(model)
    solver = wc.Solver(model, coil_contact=False)
    solver.compute_contacts(state)
    centre = solver.wall_distance.numpy()[1::3]
    faceting = R_SAC * (1 - math.cos(math.radians(3.0)))  # subdivision-4 icosphere: faces ~3° across
    assert np.allclose(centre, R_SAC - radii, atol=faceting)  # > 0 inside, < 0 outside
    force = solver.wall_force.numpy()[1::3]
    gap = centre - D / 2
    c0 = model.contact.c0_mm
    touching = gap < c0
    assert touching.tolist() == [False, False, True, True, True]
    normals = force[touching] / np.linalg.norm(force[touching], axis=1)[:, None]
    assert np.allclose(normals, -directions[touching], atol=0.06)  # pushes back into the sac
    assert np.all(np.linalg.norm(force[~touching], axis=1) == 0.0)
    # magnitude from the one contact law: outside, of the closest face's distance; inside, the
    # facets around the closest point add their share (the sac is faceted, its edges are grooves)
    f = wp_law(gap[touching], model.contact.p0_uN, c0, solver.contact_u_linear)
    magnitude = np.linalg.norm(force[touching], axis=1)
    assert np.allclose(magnitude[1:], f[1:], rtol=1e-9)
    assert f[0] <= magnitude[0] < 1.01 * f[0]


def wp_law(h, p0, c0, u_linear):
    import warp as wp

    out = wp.zeros(len(h), dtype=wp.float64)
    k = wp.zeros(len(h), dtype=wp.float64)
    wp.launch(contact.evaluate_law, len(h), inputs=[wp.array(h, dtype=wp.float64), p0, c0, u_linear, out, k])
    return out.numpy()


def crossing_pair(speed_mm_s, l0_mm=D, offset_mm=None):
    """Coil A along x at z = +0.6 falls onto coil B along y at z = 0, aimed so that a
    node of B passes exactly between two nodes of A (the worst case for node–node
    contact), or, with ``offset_mm``, so that the two segments cross that far from a node
    of each (l0/2: at their middles, the worst case for the nodes' terms alone; l0/(2K):
    midway between two of K contact samples per edge). Undamped."""
    n = 9
    s = (np.arange(n) - n // 2) * l0_mm
    a = np.stack([s, np.zeros(n), np.full(n, 0.6)], axis=1)
    across = l0_mm / 2 if offset_mm is None else offset_mm
    b = np.stack([np.full(n, across), s + (0.0 if offset_mm is None else offset_mm), np.zeros(n)], axis=1)
    spec = wc.CoilSpec(length_mm=(n - 1) * l0_mm, segment_length_mm=l0_mm)
    # true inertia: an impact at metres per second is no quasi-static motion for mass scaling
    builder = wc.ModelBuilder(settings=wc.SimulationSettings(damping_uN_per_mm=0.0, mass_scale=1.0))
    builder.add_coil(spec, a)
    builder.add_coil(spec, b)
    model = builder.finalize()
    state = wc.rest_state(model)
    v = np.zeros((2 * n, 3))
    v[:n, 2] = -speed_mm_s
    v[n:, 2] = +speed_mm_s
    state.v.assign(v)
    return model, state, n


def segment_separation(x, n):
    """Smallest distance between edges of A and edges of B, and the sign of A's height
    over B at their closest pair."""
    best, sign = np.inf, 0.0
    for i in range(n - 1):
        for j in range(n - 1):
            p1, q1, p2, q2 = x[i], x[i + 1], x[n + j], x[n + j + 1]
            # sample-based closest points (fine grid; segments are short)
            t = np.linspace(0, 1, 41)
            pa = p1 + t[:, None] * (q1 - p1)
            pb = p2 + t[:, None] * (q2 - p2)
            dist = np.linalg.norm(pa[:, None] - pb[None], axis=2)
            k = np.unravel_index(np.argmin(dist), dist.shape)
            if dist[k] < best:
                best, sign = dist[k], np.sign(pa[k[0]][2] - pb[k[1]][2])
    return best, sign


@pytest.mark.parametrize("speed_mm_s, bounces", [(200.0, True), (2000.0, False)])
def test_two_coil_segments_driven_across_each_other_do_not_cross(speed_mm_s, bounces):
    """At 2 m/s the coils wrap around each other before they part; they still never cross."""
    model, state, n = crossing_pair(speed_mm_s)
    stepper = wc.Stepper(wc.Solver(model), state, wc.Control.create(model), chunk=10)
    approach = 0.6 / (2 * speed_mm_s)
    steps = int(3 * approach / stepper.solver.dt_s)
    closest = np.inf
    for _ in range(steps // stepper.chunk + 1):
        x = stepper.run_steps(stepper.chunk).x.numpy()
        gap, sign = segment_separation(x, n)
        closest = min(closest, gap)
        assert sign > 0, "coil A passed through coil B"
    assert closest < D + model.contact.c0_mm  # they did touch
    assert closest > 0.5 * D  # and the surfaces overlapped by less than half a diameter
    if bounces:
        v = stepper.state.v.numpy()
        assert v[:n, 2].mean() > 0 and v[n:, 2].mean() < 0


def closest_approach(model, state, n, speed_mm_s, solver=None):
    """Drive the pair across each other (the approach three times over) with ``solver``
    (default: the reference's): the closest distance between their segments' centre lines
    (mm), and whether A stayed above B throughout."""
    solver = wc.Solver(model) if solver is None else solver
    stepper = wc.Stepper(solver, state, wc.Control.create(model), chunk=10)
    steps = int(3 * 0.6 / (2 * speed_mm_s) / stepper.solver.dt_s)
    closest, above = np.inf, True
    for _ in range(steps // stepper.chunk + 1):
        gap, sign = segment_separation(stepper.run_steps(stepper.chunk).x.numpy(), n)
        closest, above = min(closest, gap), above and sign > 0
    return closest, above


def test_nodes_alone_let_segments_of_two_diameters_cross_at_their_middles():
    """Why coarse coils have contact samples: with the nodes' terms alone (K = 1 forced) two
    segments of l0 = 2d crossing at their middles hold each node l0/2 = d from the other's
    axis, at the contact's onset, and at 500 mm/s they pass through each other."""
    model, state, n = crossing_pair(500.0, 2.0 * D, offset_mm=D)
    assert set(model.contact_samples.numpy()) == {2}  # the middle of each edge
    model.contact_samples.fill_(1)
    assert not closest_approach(model, state, n, 500.0)[1]


@pytest.mark.parametrize("integrator", ["symplectic", "implicit"])
@pytest.mark.parametrize("l0_factor", [1.0, 1.5, 2.0, 3.0, 4.5])
def test_segments_crossing_between_contact_samples_hold_at_any_segment_length(l0_factor, integrator):
    """Two coils of segment length l0 driven across each other at 500 mm/s (the stress bench's
    fastest push ×2.5), crossing midway between two contact points of each (the nodes for
    l0 ≤ 1.5 d; else K = ⌈l0 / d⌉ samples per edge, l0/(2K) from the nearest): they part with
    A above B and their centre lines over d/2 apart, on both integrators."""
    l0 = l0_factor * D
    samples = 1 if l0_factor <= 1.5 else math.ceil(l0_factor - 1e-9)
    model, state, n = crossing_pair(500.0, l0, offset_mm=l0 / (2 * samples))
    assert set(model.contact_samples.numpy()) == {samples}
    solver = None
    if integrator == "implicit":
        from warpcoil.implicit import ImplicitSolver, implicit_step_s

        solver = ImplicitSolver(model, dt_s=implicit_step_s(model, 500.0))
    closest, above = closest_approach(model, state, n, 500.0, solver)
    assert above
    assert closest > 0.5 * D


def test_a_run_whose_coils_came_within_half_a_diameter_says_they_may_have_crossed():
    from warpcoil.measure import crossing_note

    assert crossing_note(-0.1 * D, D) == "" and crossing_note(float("nan"), D) == ""
    assert "passed through each other" in crossing_note(-0.6 * D, D)


def sphere_scene(length_mm=12.0, push_speed_mm_s=100.0, loop_diameter_mm=2.5):
    return wc.Scene(
        coils=(wc.CoilSpec(shape="helix", length_mm=length_mm, loop_diameter_mm=loop_diameter_mm, pitch_mm=0.6),),
        catheter=wc.CatheterSpec(tip_mm=(0.0, 0.0, -1.45), direction=(0.0, 0.0, 1.0)),
        wall=wc.WallSpec(sphere_diameter_mm=2 * R_SAC),
        simulation=wc.SimulationSettings(push_speed_mm_s=push_speed_mm_s, frame_interval_s=0.005),
    )


def test_short_deployment_into_the_sphere_completes_inside_with_the_analytic_packing_density():
    from warpcoil.deploy import COMPLETED, Deployment

    scene = sphere_scene()
    deployment = Deployment(scene)
    radii = []
    result = deployment.run(lambda frame, state: radii.append(
        np.linalg.norm(state.x.numpy()[state.free.numpy() == 1], axis=1).max(initial=0.0)))
    assert result.status == COMPLETED, result.reason
    assert max(radii) < R_SAC  # no node centre left the sac in any frame
    assert result.length_outside_sac_mm == 0.0
    assert result.min_wall_gap_mm > -0.5 * D
    assert result.min_coil_gap_mm > -0.1 * D
    length = result.coil_length_mm
    analytic = math.pi * (D / 2) ** 2 * length / (math.pi / 6 * (2 * R_SAC) ** 3)
    assert result.packing_density == pytest.approx(analytic, rel=0.01)
    assert result.deployed_length_mm == pytest.approx(length)


def test_limited_wall_search_gives_the_same_run_as_the_full_search():
    """Skipping the BVH search beyond the contact range changes nothing, bit for bit."""
    from warpcoil.kernels.contact import FAR_MM
    from warpcoil.deploy import build_model

    scene = sphere_scene(length_mm=6.0, loop_diameter_mm=4.0)  # loops larger than the sac press on the wall
    results = []
    for search in (0.1, float(FAR_MM)):
        model = build_model(scene)
        solver = wc.Solver(model, wall_search_mm=search)
        control = wc.Control.create(model, active_coil=0, push_speed_mm_s=100.0)
        stepper = wc.Stepper(solver, wc.packed_state(model), control, chunk=500)
        touched = 0.0
        for _ in range(16):
            stepper.run_steps(500)
            touched = max(touched, np.linalg.norm(solver.wall_force.numpy(), axis=1).max())
        results.append(stepper.state.x.numpy().copy())
        assert touched > 0.0
    assert np.array_equal(results[0], results[1])
    assert np.isfinite(results[0]).all()


def test_a_sharp_fold_is_pushed_open_by_the_neighbouring_windings():
    """Bonded neighbours never touch, but nodes i and i + 2 of a coil folded back on
    itself (170° at one vertex) repel with the contact law of |x_i − x_j| − d."""
    l0 = D
    half = np.radians(5.0)  # half the 10° between the two arms: a 170° turn at node 2
    x = np.array([[-2 * l0 * np.sin(half), -2 * l0 * np.cos(half), 0.0],
                  [-l0 * np.sin(half), -l0 * np.cos(half), 0.0],
                  [0.0, 0.0, 0.0],
                  [l0 * np.sin(half), -l0 * np.cos(half), 0.0],
                  [2 * l0 * np.sin(half), -2 * l0 * np.cos(half), 0.0]])
    straight = np.stack([np.arange(5) * l0, np.zeros(5), np.zeros(5)], axis=1)
    builder = wc.ModelBuilder()
    builder.add_coil(wc.CoilSpec(length_mm=4 * l0, segment_length_mm=l0), straight)
    model = builder.finalize()
    solver = wc.Solver(model, coil_contact=False)
    state = wc.state_from_positions(model, x)
    solver.compute_forces(state)
    force = solver.force.numpy()
    apart = (x[1] - x[3]) / np.linalg.norm(x[1] - x[3])
    gap = np.linalg.norm(x[1] - x[3]) - D
    law = wp_law(np.array([gap]), model.contact.p0_uN, model.contact.c0_mm, solver.contact_u_linear)[0]
    assert model.contact.fold_span == 1
    assert force[1] @ apart >= law > 100 * model.contact.p0_uN
    assert force[3] @ -apart >= law


def test_contact_samples_keep_the_pressure_per_length_and_converge_on_a_crossing():
    """`warpcoil validate contact-samples`: parallel coils at l0 = 3d press each other as the nodes
    alone would (P0 law per unit length, to 1e-9), and the force of two crossing coils converges to
    the law's integral along the wire as the samples per edge grow (within 5 % from K = 6, order ≥ 1.5)."""
    from warpcoil.validation_contact import contact_sample_cases

    rows = contact_sample_cases()
    assert len(rows) == 6 and all(row.passed for row in rows), [(r.case, r.error) for r in rows if not r.passed]
    crossing = [row.error for row in rows if "coils crossing" in row.case]
    assert crossing[1] > crossing[2] > crossing[3]


def test_the_wall_acts_at_the_contact_samples_of_coarse_segments():
    """An edge of 3d across a ridge, both nodes out of the contact range and its middle in it (a helper's
    coils of 2d threaded a 0.2 mm septum this way, every node inside): pushed as nodes at its samples
    would be, not at all with the samples off; a coil of 3d segments on a floor keeps the law per length
    (it sinks to the gap of one of d segments: its nodes weigh 1/K of the law); the implicit step's matrix
    takes the samples' stiffness on their nodes."""
    from warpcoil.implicit import ImplicitSolver
    from warpcoil.kernels import contact as kernels
    from warpcoil.validation_contact import ridge_edge_forces, wall_sample_cases

    for row in wall_sample_cases():
        assert row.passed, row
    result, reference, node_gap, sample_gap = ridge_edge_forces()
    assert node_gap > 0.0292 > 0.0 > sample_gap and result[:, 2].sum() > 500.0  # µN, up, out of the ridge
    from warpcoil.validation_contact import ridge_wall
    from warpcoil.validation_friction import _floor

    d, l0 = 0.2921, 3 * 0.2921

    def wall_pass(nodes: np.ndarray, segment_mm: float, wall):
        """An implicit solver's wall pass on a coil through ``nodes``: (solver, state) as a step takes it."""
        length_mm = float(np.linalg.norm(np.diff(nodes, axis=0), axis=1).sum())
        builder = wc.ModelBuilder(contact=wc.ContactSettings(P0_uN=1000.0), wall=wall)
        builder.add_coil(wc.CoilSpec(wire_diameter_mm=d, length_mm=length_mm, segment_length_mm=segment_mm), nodes)
        model = builder.finalize()
        solver = ImplicitSolver(model, dt_s=1e-4)
        state = wc.state_from_positions(model, nodes)
        solver.compute_contacts(state, wall_search_mm=float(kernels.FAR_MM))  # every node's side and distance known
        solver.compute_contacts(state)  # as a step takes it (its stiffness)
        return solver, state

    # the implicit step: each node's wall block its own over K plus its shares of the samples' (PSD, upward)
    solver, _ = wall_pass(np.array([[-0.5 * l0, 0.0, 1.101], [0.5 * l0, 0.0, 1.101], [1.5 * l0, 0.0, 1.101]]), l0,
                          ridge_wall())
    blocks = solver.wall_stiffness.numpy()
    assert blocks[0][2, 2] > 0.0 and blocks[1][2, 2] > 0.0 and np.all(np.linalg.eigvalsh(blocks[:2]) > -1e-9)
    assert np.allclose(blocks[2], 0.0)  # the second edge's samples are out of range
    # θ 1 at the nodes of an edge whose sample touches the wall, as at a touching node: an edge of 6d whose middle
    # presses the ridge, its nodes 0.12 mm away (beyond the gate's 3 c0 of their own)
    long = 6 * d
    solver, state = wall_pass(np.array([[-0.5 * long, 0.0, 1.1], [0.5 * long, 0.0, 1.1], [1.5 * long, 0.0, 1.1]]),
                              long, ridge_wall())
    assert solver.wall_distance.numpy()[:2].min() - 0.5 * d > 3 * 0.1 * d  # the nodes: out of the gate's reach
    solver._gate(state, 1e-4)
    theta = solver.node_theta.numpy()
    assert theta[0] == theta[1] == 1.0 > solver.theta
    # on a floor: an interior node's block is the nodes-only coil's k (its own k/3 and its samples' shares 2/3),
    # an end node's 2/3 of it (its own k/3, its one edge's samples' 1/3)
    gap = 0.5 * 0.1 * d  # half c0 into the law's range
    zz = {}
    for segment in (d, l0):
        line = np.array([[x, 0.0, 0.5 * d + gap] for x in np.arange(0.0, 6 * l0 + 1e-9, segment)])
        zz[segment] = wall_pass(line, segment, _floor())[0].wall_stiffness.numpy()[:, 2, 2]
    k = zz[d][3]
    assert k > 0.0 and zz[l0][3] == pytest.approx(k, rel=1e-12) and zz[l0][0] == pytest.approx(2 / 3 * k, rel=1e-12)
