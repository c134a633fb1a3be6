"""Cheap steps, each against its full pass: the damping solve stopped at its fixed
point (bit-identical), the wall's narrow-band field against the BVH (within its
error bound; creases handed to the BVH)."""

import math
from pathlib import Path

import numpy as np
import trimesh
import warp as wp

import warpcoil as wc
from warpcoil import validation
from warpcoil.bench.steps import damped_speed_six  # the damping solve as it was: always six Newton iterations
from warpcoil.deploy import build_model
from warpcoil.kernels import integrate
from warpcoil.model import WallModel
from warpcoil.scene import load_scene
from warpcoil.settings import ContactSettings
from warpcoil.wall_field import GRAD_TOLERANCE, band_points, build_wall_field, field_error, field_error_bound_mm
from warpcoil.kernels import wall_field as field_kernels

SEED = Path(__file__).resolve().parents[1] / "scenes" / "seed_sphere.toml"


@wp.kernel
def both_damped_speeds(speed: wp.array(dtype=wp.float64), a: wp.array(dtype=wp.float64), k: wp.float64,
                       early: wp.array(dtype=wp.float64), six: wp.array(dtype=wp.float64)):
    i = wp.tid()
    early[i] = integrate.damped_speed(speed[i], a[i], k)
    six[i] = damped_speed_six(speed[i], a[i], k)


def test_damping_solve_stopped_at_its_fixed_point_is_bit_identical_and_solves_the_law():
    rng = np.random.default_rng(1)
    n = 20000
    speed = 10.0 ** rng.uniform(-6, 4, n)  # mm/s: resting nodes to a whipping free end
    a = 10.0 ** rng.uniform(-4, 3, n)  # dt c/m, mm/s
    k = 20.0
    early, six = wp.zeros(n, dtype=wp.float64), wp.zeros(n, dtype=wp.float64)
    wp.launch(both_damped_speeds, n, inputs=[wp.array(speed, dtype=wp.float64), wp.array(a, dtype=wp.float64), k,
                                             early, six])
    s = early.numpy()
    assert np.array_equal(s, six.numpy())
    residual = s + a * (1.0 - np.exp(-s / k)) - speed
    assert np.all(np.abs(residual) <= 1e-12 * (speed + a))  # converged to rounding in six iterations or fewer


def test_wall_field_validation_cases():
    rows = validation.wall_field_cases()
    failed = [r for r in rows if not r.passed]
    assert not failed, validation.format_table(failed)


def test_a_crease_goes_to_the_bvh_and_the_rest_of_the_field_keeps_its_bound():
    """Inside a 2 mm cube the distance has a 90° kink on the planes that bisect its
    edges: the interpolated gradient there is ~cos 45° long, so those samples are
    untrusted (the BVH takes them); every trusted sample keeps the bound."""
    box = trimesh.creation.box(extents=(2.0, 2.0, 2.0))
    wall = WallModel.create(np.asarray(box.vertices), np.asarray(box.faces), float(box.volume), wp.get_device())
    h = 0.04
    field = build_wall_field(wall, 0.3, h)  # whole wall
    pts = band_points(wall, (0.0, 0.25), 20000)
    err = field_error(wall, field, pts)
    assert err.distance_max_mm <= 1e-6  # flat faces away from the creases: trilinear is exact up to float32
    assert err.normal_rms_deg <= 0.1
    # the kink: points on the bisector of an edge, 0.05–0.2 mm from the wall
    depth = np.linspace(0.05, 0.2, 50)
    along = np.linspace(-0.8, 0.8, 50)
    kink = np.stack([1.0 - depth, 1.0 - depth, along], axis=1)
    n = len(kink)
    trusted = wp.zeros(n, dtype=wp.int32)
    wp.launch(field_kernels.sample_field, n, inputs=[field.id, wp.array(kink, dtype=wp.vec3d), GRAD_TOLERANCE,
                                                     trusted, wp.zeros(n, dtype=wp.float64),
                                                     wp.zeros(n, dtype=wp.vec3d)])
    assert trusted.numpy().sum() == 0


def test_wall_forces_from_the_field_are_the_bvh_forces_within_the_error_bound():
    """Every node of the seed coil placed in the contact band of the seed sphere
    (some pressed into it): the field's wall force differs from the BVH's by at
    most the law's stiffness × the measured distance error + |F| × the normal error."""
    model = build_model(load_scene(SEED))
    state = wc.packed_state(model)
    wall = model.wall
    n = model.node_count
    local = band_points(wall, (-0.02, 0.3), n, seed=3)
    state.x.assign(wp.array(local + wall.origin, dtype=wp.vec3d))
    state.free.fill_(1)
    forces, distances = {}, {}
    for query in ("bvh", "sdf"):
        solver = wc.Solver(model, wall_query=query)
        solver.compute_contacts(state)
        forces[query], distances[query] = solver.wall_force.numpy(), solver.wall_distance.numpy()
    bound = field_error_bound_mm(0.04)
    c = model.contact
    gap = distances["bvh"] - model.node_radius.numpy()
    touching = np.linalg.norm(forces["bvh"], axis=1) > 0
    assert touching.sum() > n // 3  # the comparison has forces to compare
    near = gap < c.c0_mm + 0.1
    assert np.all(np.abs(distances["sdf"] - distances["bvh"])[near] <= 0.05 * c.c0_mm)
    assert np.all(np.abs(distances["sdf"] - distances["bvh"])[near] <= bound)
    u = np.minimum(1.0 - (gap - 0.05 * c.c0_mm) / c.c0_mm, solver.contact_u_linear)  # the stiffest in reach
    stiffness = c.p0_uN / ((math.e - 1.0) * c.c0_mm) * (np.exp(u) * (1.0 + u) - 1.0) * (u > 0.0)
    allowed = stiffness * 0.05 * c.c0_mm + np.linalg.norm(forces["bvh"], axis=1) * math.radians(6.0)
    diff = np.linalg.norm(forces["sdf"] - forces["bvh"], axis=1)
    assert np.all(diff <= allowed + 1e-9)


def test_the_scene_key_chooses_the_wall_query_and_names_a_bad_value():
    from warpcoil.deploy import Deployment
    from warpcoil.scene import SceneError

    field_run = Deployment(load_scene(SEED, {"contact.wall_query": "sdf", "contact.wall_voxel_mm": 0.08}))
    field = field_run.solver.wall_fields[0]
    assert field is not None and field.voxel_mm == 0.08 and field.voxels > 0
    assert ContactSettings().wall_query == "bvh"  # default: the exact BVH (the seed scene chooses the field)
    assert Deployment(load_scene(SEED, {"contact.wall_query": "bvh"})).solver.wall_fields == [None]
    try:
        load_scene(SEED, {"contact.wall_query": "octree"})
    except SceneError as error:
        assert "contact.wall_query" in str(error) and "sdf" in str(error)
    else:
        raise AssertionError("a bad wall_query was accepted")


def small_seed_scene():
    """The accuracy benchmark's small seed case (20 mm of a 2 mm coil in a 2.5 mm sphere), implicit step."""
    from dataclasses import replace

    scene = load_scene(SEED, {"output.usd": False, "output.png": False, "contact.wall_query": "bvh"})
    return replace(scene, coils=(replace(scene.coils[0], length_mm=20.0, loop_diameter_mm=2.0),),
                   wall=replace(scene.wall, sphere_diameter_mm=2.5),
                   catheter=replace(scene.catheter, tip_mm=(0.0, 0.0, -0.95)))


def test_skipping_the_signed_wall_query_in_the_lumen_is_bit_identical_to_the_full_search():
    """400 implicit steps of a deployment pressing the coil along the wall: the same
    state bit for bit whether a node in contact that cannot have left the lumen skips
    its signed BVH query or not (gated_chord, whose chord pass reads the wall
    distances too, the default, and linearly implicit Euler); and the skip is taken: over 100 more
    steps of the Euler run, which keeps nodes pressed against the wall there, the nodes
    in contact throughout were searched in full in under 5 % of their steps (each
    skip's exact distance certifies the next, so a node sliding along the wall is
    not searched again)."""
    from warpcoil.deploy import Deployment
    from warpcoil.implicit import EULER, GATED_CHORD
    from warpcoil.solver import Stepper

    for scheme in (GATED_CHORD, EULER):
        states = {}
        for skip in (False, True):
            run = Deployment(small_seed_scene(), solver_options={"wall_sided_skip": skip, **scheme})
            stepper = Stepper(run.solver, run.stepper.state, run.control, chunk=100)
            stepper.run_steps(400)
            states[skip] = {k: getattr(stepper.state, k).numpy().copy() for k in ("x", "v", "m1", "omega", "free")}
        for k in states[False]:
            assert np.array_equal(states[False][k], states[True][k]), (scheme, k)
    solver = run.solver  # (the skipping run) 100 more steps, one at a time
    contact_range = run.model.node_radius.numpy() + run.model.contact.c0_mm
    touching = np.ones(run.model.node_count, bool)
    searches_before = solver.wall_searches.numpy().copy()
    x_before = stepper.state.x.numpy().copy()
    single = Stepper(solver, stepper.state, run.control, chunk=1, use_graph=False)
    for _ in range(100):
        single.run_chunk()
        touching &= solver.wall_distance.numpy() < contact_range
    searched = solver.wall_searches.numpy() - searches_before
    assert touching.sum() >= 3  # pressed against the wall throughout
    slid_mm = np.linalg.norm(stepper.state.x.numpy() - x_before, axis=1)[touching]
    assert slid_mm.min() > 0.5  # several centre distances along the wall: certified again and again
    assert searched[touching].max() < 5, searched[touching]


def test_frictions_normal_guard_stopped_at_its_fixed_point_is_bit_identical_to_every_pass():
    """With wall and coil friction, from a packing state (the small seed case, 16 of 20 mm in, coil
    pairs touching): 60 implicit and 300 reference steps give the same state bit for bit whether
    the normal guard stops its Jacobi passes at a fixed point or runs all GUARD_PASSES, where its
    last step needed more than one pass (the guard at work); and a step whose guard has nothing to
    do (the coil leaving the catheter) stops after at most two passes instead of 16."""
    from dataclasses import replace

    from warpcoil.bench.ensemble import STATE_ARRAYS
    from warpcoil.deploy import Deployment
    from warpcoil.kernels import friction
    from warpcoil.solver import Stepper

    scene = small_seed_scene()
    scene = replace(scene, contact=replace(scene.contact, friction_wall=0.3, friction_coil=0.3))
    packing = Deployment(scene)
    packing.control.set_active_coil(0)
    start = Stepper(packing.solver, packing.stepper.state, packing.control, chunk=100).run_steps(700)
    saved = {k: getattr(start, k).numpy().copy() for k in STATE_ARRAYS}
    assert packing.solver.coil_contacts.numpy().sum() > 0  # coil pairs in contact: the guard watches them

    def deployment(integrator: str, fixed_point: bool) -> Deployment:
        run = Deployment(replace(scene, simulation=replace(scene.simulation, integrator=integrator)),
                         solver_options={"guard_fixed_point": fixed_point})
        run.control.set_active_coil(0)
        return run

    for integrator, steps in (("implicit", 60), ("symplectic", 300)):
        states = []
        for fixed_point in (False, True):
            run = deployment(integrator, fixed_point)
            for k in STATE_ARRAYS:
                getattr(run.stepper.state, k).assign(saved[k])
            run.stepper.state.time_s = start.time_s
            state = Stepper(run.solver, run.stepper.state, run.control, chunk=50).run_steps(steps)
            states.append({k: getattr(state, k).numpy().copy() for k in STATE_ARRAYS})
            last_passes = int(run.solver._guard_loop.numpy()[friction.GUARD_DONE])
        assert last_passes > 1, integrator
        for k in STATE_ARRAYS:
            assert np.array_equal(states[0][k], states[1][k]), (integrator, k)
    leaving = deployment("symplectic", True)
    single = Stepper(leaving.solver, leaving.stepper.state, leaving.control, chunk=1, use_graph=False)
    passes = []
    for _ in range(20):
        single.run_chunk()
        passes.append(int(leaving.solver._guard_loop.numpy()[friction.GUARD_DONE]))
    assert max(passes) <= 2, passes


def fail_first_launch(monkeypatch, fail: bool) -> list:
    """Graph launches recorded in the returned list; with ``fail``, the first one fails as a GPU's would
    when it cannot instantiate the graph (warpcoil.solver.uninstantiated says so for it alone)."""
    from warpcoil import solver as solver_module

    calls = []
    launch = wp.capture_launch

    def first_fails(graph, stream=None):
        calls.append(graph)
        if fail and len(calls) == 1:
            raise RuntimeError("Graph creation error: (played)")
        launch(graph, stream)

    monkeypatch.setattr(solver_module.wp, "capture_launch", first_fails)
    monkeypatch.setattr(solver_module, "uninstantiated", lambda graph: len(calls) == 1)
    return calls


def test_a_graph_a_gpu_cannot_instantiate_is_captured_again_without_conditionals(monkeypatch):
    """CUDA instantiates a graph at its first launch, before any of it runs; a driver that captured the
    conditional neighbour-grid rebuild but cannot instantiate it fails there. The Stepper then captures
    the graph again without conditionals (the grid built every step, every guard pass run) and goes on:
    the same steps bit for bit. Played here on the CPU by failing the first launch as uninstantiated."""
    from test_contact import crossing_pair

    def run(fail_first: bool):
        model, state, _ = crossing_pair(200.0)
        solver = wc.Solver(model)
        stepper = wc.Stepper(solver, state, wc.Control.create(model), chunk=40)
        fail_first_launch(monkeypatch, fail_first)
        x = stepper.run_steps(400).x.numpy().copy()
        monkeypatch.undo()
        return x, solver._conditional_rebuild

    reference, conditional = run(False)
    fallen_back, after = run(True)
    assert conditional and not after
    assert np.array_equal(reference, fallen_back)


def test_a_frame_measurement_a_gpu_cannot_instantiate_is_captured_again_without_conditionals(monkeypatch):
    """The same for a frame's measurement graph (Solver._replayed): captured again without conditionals
    at the failed first launch, the same contact forces and gaps."""
    from test_contact import crossing_pair

    def measure(fail_first: bool):
        model, state, _ = crossing_pair(200.0)
        x = state.x.numpy()
        x[: len(x) // 2, 2] = 0.2  # coil A down onto coil B: in contact
        state.x.assign(x)
        solver = wc.Solver(model)
        calls = fail_first_launch(monkeypatch, fail_first)
        solver.measure_contacts(state, wc.Control.create(model).running)
        monkeypatch.undo()
        return solver.contact_force.numpy().copy(), solver.coil_gap.numpy().copy(), solver._conditional_rebuild, calls

    force, gap, conditional, _ = measure(False)
    force_again, gap_again, after, calls = measure(True)
    assert conditional and not after and len(calls) == 2 and calls[0] is not calls[1]
    assert np.abs(force).max() > 0.0
    assert np.array_equal(force, force_again) and np.array_equal(gap, gap_again)
