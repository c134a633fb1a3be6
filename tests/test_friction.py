"""Regularised Coulomb friction: stick/slide on an incline, the capstan law,
energy never rising, scene keys, and ensemble members equal to single runs."""

import math
from dataclasses import replace

import numpy as np
import pytest

import warpcoil as wc
from warpcoil import validation_friction as vf
from warpcoil.deploy import Deployment, Ensemble
from warpcoil.scene import SceneError, load_scene
from warpcoil.settings import OutputSettings


@pytest.mark.parametrize("ratio", [0.8, 0.99])
def test_incline_sticks_below_the_friction_angle_creeping_below_v_reg(ratio):
    _, _, creep, top_speed = vf.incline_motion(0.3, ratio, steps=6000)
    v_reg = wc.ContactSettings().friction_speed_mm_s
    assert creep == pytest.approx(ratio * v_reg, rel=1e-2)  # creep v_reg F_t/(μN) < v_reg
    assert top_speed < 1.01 * v_reg  # the start (level, at contact equilibrium) overshoots by < 1 %


def test_stick_converges_to_rest_as_the_regularisation_velocity_shrinks():
    """Creep = v_reg F_t/(μN): first order in v_reg, so exact stick in the limit."""
    creep = [vf.incline_motion(0.3, 0.9, steps=4000, v_reg_mm_s=v)[2] for v in (0.01, 0.001)]  # second half
    assert creep == pytest.approx([0.009, 0.0009], rel=1e-2)


def test_incline_slides_above_with_the_coulomb_acceleration():
    acceleration, reference, _, _ = vf.incline_motion(0.3, 1.5, steps=6000)
    assert acceleration == pytest.approx(reference, rel=1e-2)


@pytest.mark.parametrize("implicit", [False, True])
@pytest.mark.parametrize("segment_d", [2.0, 3.0])
def test_friction_takes_the_load_of_the_contact_samples(segment_d, implicit):
    """Segments above 1.5 d meet the wall at contact samples too (a node's own law weighs 1/K): the
    friction on the incline is μ times the whole load, nodes' and samples' (from the nodes' own load
    alone it would slide at g (sin θ − μ cos θ / K)), on either step."""
    acceleration, reference, _, _ = vf.incline_motion(0.3, 2.0, implicit=implicit, segment_d=segment_d,
                                                      duration_s=0.065)  # (6 000 steps at segments of d)
    assert acceleration == pytest.approx(reference, rel=1e-3)
    _, _, creep, _ = vf.incline_motion(0.3, 0.8, implicit=implicit, segment_d=segment_d, duration_s=0.065)
    assert creep == pytest.approx(0.8 * wc.ContactSettings().friction_speed_mm_s, rel=1e-2)


def test_capstan_slips_at_the_exponential_tension_ratio():
    ratio, reference = vf.capstan_slip_ratio(0.3, 0.5 * math.pi)
    assert ratio == pytest.approx(reference, rel=2e-2)


def test_undamped_frictional_energy_never_rises_beyond_the_integrators_own_fluctuation():
    rise, fluctuation, dissipated = vf.frictional_energy()
    assert rise <= fluctuation
    assert dissipated > 5.0 * fluctuation


@pytest.mark.parametrize("scheme", ["gated_chord", "euler", "bdf2"])
@pytest.mark.parametrize("ratio", [0.8, 1.5])
def test_the_implicit_step_sticks_and_slides_on_the_incline_as_the_reference_does(ratio, scheme):
    """At its default step, through its system: creep v_reg tanθ/μ below the friction angle,
    the Coulomb acceleration above (a rigid change: the system passes it unchanged), in
    each scheme (gated rows, θ = 1, BDF2's step)."""
    acceleration, reference, creep, _ = vf.incline_motion(0.3, ratio, steps=6000, implicit=True, scheme=scheme)
    if ratio < 1.0:
        assert creep == pytest.approx(ratio * wc.ContactSettings().friction_speed_mm_s, rel=1e-2)
    else:
        assert acceleration == pytest.approx(reference, rel=1e-2)


def test_the_implicit_steps_friction_never_raises_the_energy():
    """Undamped, two coils sliding across each other on the floor (wall and coil friction): the
    change carried through the step's system is kept only where it raises no world's kinetic
    energy. (Applied at the contact nodes alone, it raised the total by ~100 nJ here.)"""
    rise, fluctuation, _ = vf.frictional_energy(implicit=True)
    assert rise <= fluctuation
    assert rise < 0.01  # nJ (measured 0; the frictionless range is the step's own energy loss, ~2 nJ)


def test_the_implicit_capstan_slips_near_the_exponential_tension_ratio_and_converges():
    """Wall friction linearised inside the step's system: the wrap holds against the whole
    coil's stiffness, as on the reference step. (As a per-node change carried through the
    system after the solve it was −4.8 % at the default step and −10.6 % at a quarter of it.)"""
    ratio, reference = vf.capstan_slip_ratio(0.3, 0.5 * math.pi, implicit=True)
    assert ratio == pytest.approx(reference, rel=vf.IMPLICIT_CAPSTAN_TOLERANCE)
    quarter, _ = vf.capstan_slip_ratio(0.3, 0.5 * math.pi, implicit=True, step_scale=0.25)
    assert abs(quarter - ratio) / reference <= vf.IMPLICIT_CAPSTAN_CONVERGENCE


def test_a_frictional_deployment_on_the_implicit_step_comes_to_rest():
    """μ 0.1/0.2/0.3: at rest within its time limit, gaps no deeper than without friction + c0/2.
    (With friction applied at the contact nodes alone, a node stuck on the wall strained its
    stiff neighbours each step and the coil's tip chattered at ~10 mm/s to the time limit.)"""
    rows = vf.frictional_rest_cases()
    assert "completed" in rows[0].case
    for row in rows:
        assert row.passed, (row.case, row.reference, row.result)


def test_friction_keys_are_read_and_checked(tmp_path):
    path = tmp_path / "s.toml"
    base = '[[coil]]\nwire_diameter_mm = 0.3\nloop_diameter_mm = 3\nlength_mm = 10\n[contact]\n'
    path.write_text(base + "friction_wall = 0.2\nfriction_coil = 0.1\nfriction_catheter = 0.05\n")
    c = load_scene(path).contact
    assert (c.friction_wall, c.friction_coil, c.friction_catheter) == (0.2, 0.1, 0.05)
    path.write_text(base + "friction_wall = -0.1\n")
    with pytest.raises(SceneError, match=r"contact\.friction_wall.*≥ 0"):
        load_scene(path)


@pytest.mark.parametrize("integrator", ["symplectic", "implicit"])
def test_frictional_members_equal_their_single_runs(integrator):
    def scene(angle_deg):
        a = math.radians(angle_deg)
        return wc.Scene(
            coils=(wc.CoilSpec(shape="helix", length_mm=6.0, loop_diameter_mm=2.5, pitch_mm=0.6),),
            catheter=wc.CatheterSpec(tip_mm=(0.0, 0.0, -1.475), direction=(math.sin(a), 0.0, math.cos(a))),
            wall=wc.WallSpec(sphere_diameter_mm=3.5),
            contact=wc.ContactSettings(friction_wall=0.3, friction_coil=0.2, friction_catheter=0.1),
            simulation=wc.SimulationSettings(push_speed_mm_s=100.0, frame_interval_s=0.005, integrator=integrator))
    scenes = [scene(0.0), scene(20.0)]
    results = Ensemble(scenes).run()
    for s, member in zip(scenes, results):
        single = Deployment(s).run()
        assert member.status == single.status == "completed"
        for a, b in zip(single.positions_mm, member.positions_mm):
            assert np.array_equal(a, b)


def _coil_friction_changes(model, state, velocities):
    """Coil–coil friction velocity changes (per edge start and end node, mm/s) that
    the Solver gives ``velocities`` with the contacts of ``state``."""
    solver = wc.Solver(model)
    solver.compute_contacts(state)
    out = wc.state_from_positions(model, state.x.numpy())
    out.v.assign(velocities)
    solver._apply_friction(state, out, wc.Control.create(model).running, solver.dt_s)
    return solver, solver._friction_start.numpy(), solver._friction_end.numpy()


def test_turns_touching_in_the_rest_shape_get_no_coil_friction():
    """A tight-pitch helix (turns 10 µm apart, within c0) at rest carries no normal
    force (rest offset) and so no friction load: sliding its turns costs nothing."""
    from warpcoil.validation import TIGHT_HELIX
    builder = wc.ModelBuilder(contact=wc.ContactSettings(friction_coil=0.5))
    builder.add_coil(wc.CoilSpec(wire_diameter_mm=0.2921, shape="helix", **TIGHT_HELIX))
    model = builder.finalize()
    state = wc.rest_state(model)
    velocities = np.random.default_rng(1).normal(scale=5.0, size=(model.node_count, 3))
    solver, start, end = _coil_friction_changes(model, state, velocities)
    assert solver.coil_friction
    assert TIGHT_HELIX["pitch_mm"] - 0.2921 < model.contact.c0_mm  # the turns are within contact range
    assert np.abs(solver.contact_force.numpy()).max() == 0.0
    assert np.abs(start).max() == 0.0 and np.abs(end).max() == 0.0


def test_coil_friction_load_is_the_normal_force_between_the_edges():
    """Two crossing straight coils pressed together, sliding fast (above the stick
    range): each edge pair's friction impulse is dt μ |F_pair|, F_pair the normal
    force that pair's contact terms put on the edge, so the total tangential
    friction on a coil is μ × its total normal contact force."""
    d, mu, gap = 0.2921, 0.4, 0.01
    nodes = 9
    s = (np.arange(nodes) - nodes // 2) * d
    a = np.stack([s, np.zeros(nodes), np.zeros(nodes)], axis=1)  # A's middle node under the middle of a B edge
    b = np.stack([np.zeros(nodes), s + 0.5 * d, np.full(nodes, d + gap)], axis=1)
    builder = wc.ModelBuilder(contact=wc.ContactSettings(friction_coil=mu))
    spec = wc.CoilSpec(wire_diameter_mm=d, length_mm=(nodes - 1) * d, segment_length_mm=d)
    builder.add_coil(spec, a)
    builder.add_coil(spec, b)
    model = builder.finalize()
    state = wc.state_from_positions(model, np.concatenate([a, b]))
    velocities = np.zeros((2 * nodes, 3))
    velocities[nodes:, 0] = 200.0  # coil B slides along x over coil A
    solver, start, end = _coil_friction_changes(model, state, velocities)
    mass = 1.0 / model.inv_mass.numpy()
    has_next = model.has_next.numpy()
    change = np.zeros((2 * nodes, 3))
    for i in range(2 * nodes - 1):
        if has_next[i]:
            change[i] += start[i]
            change[i + 1] += end[i]
    assert solver.coil_contacts.numpy().max() <= 2  # every node has at most two contacts: the exact law
    friction_on_a = (mass[:nodes, None] * change[:nodes]).sum(axis=0) / solver.dt_s  # µN
    normal_on_a = solver.contact_force.numpy()[:nodes].sum(axis=0)
    assert np.linalg.norm(normal_on_a) > 0.1 * model.contact.p0_uN
    assert friction_on_a[0] == pytest.approx(mu * np.linalg.norm(normal_on_a), rel=1e-6)



def _closest_points(x, a, b):
    """The closest points (mm) of edges a and b's segment axes (Ericson §5.1.9)."""
    p1, q1, p2, q2 = x[a], x[a + 1], x[b], x[b + 1]
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    aa, e, f, c, bb = d1 @ d1, d2 @ d2, d2 @ r, d1 @ r, d1 @ d2
    den = aa * e - bb * bb
    s = np.clip((bb * f - c * e) / den, 0.0, 1.0) if den > 1e-14 * aa * e else 0.0
    t = (bb * s + f) / e
    if t < 0.0:
        t, s = 0.0, np.clip(-c / aa, 0.0, 1.0)
    elif t > 1.0:
        t, s = 1.0, np.clip((bb - c) / aa, 0.0, 1.0)
    return s, t, p1 + s * d1 - p2 - t * d2


def _normal_rates(x, v, pairs):
    """Rate (mm/s) at which each edge pair's closest points separate along its axes' normal."""
    rates = []
    for a, b in pairs:
        s, t, delta = _closest_points(x, a, b)
        rel = (1 - s) * v[a] + s * v[a + 1] - (1 - t) * v[b] - t * v[b + 1]
        rates.append(rel @ delta / np.linalg.norm(delta))
    return np.array(rates)


@pytest.mark.parametrize("angle_deg", [90.0, 60.0, 30.0])
def test_coil_friction_never_lowers_a_contacts_normal_separation_rate(angle_deg):
    """Two straight coils crossing at an angle, overlapping by c0 (as in a dense pack),
    B sliding fast over A while lifting off: friction acts in each contact's tangent
    plane about the true normal (the segment axes' closest-point direction), so no
    touching pair separates more slowly after it (neither by its own impulse along a
    tilted normal nor by its neighbours' impulses on shared nodes), while it does
    brake the slide. (Taking the pair force's direction as the normal, and summing
    the contacts' impulses unguarded, let crossing coils sink through each other.)"""
    d, mu = 0.2921, 0.5
    c0 = 0.1 * d  # the default contact range
    nodes = 9
    s = (np.arange(nodes) - nodes // 2) * d
    b_dir = np.array([math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg)), 0.0])
    a = np.stack([s, np.zeros(nodes), np.zeros(nodes)], axis=1)
    b = (s[:, None] + 0.3 * d) * b_dir + np.array([0.0, 0.0, d - c0])  # overlap c0, B's nodes off the crossing
    builder = wc.ModelBuilder(contact=wc.ContactSettings(friction_coil=mu))
    spec = wc.CoilSpec(wire_diameter_mm=d, length_mm=(nodes - 1) * d, segment_length_mm=d)
    builder.add_coil(spec, a)
    builder.add_coil(spec, b)
    model = builder.finalize()
    assert model.contact.c0_mm == pytest.approx(c0)
    state = wc.state_from_positions(model, np.concatenate([a, b]))
    solver = wc.Solver(model)
    solver.compute_contacts(state)
    velocities = np.zeros((2 * nodes, 3))
    velocities[nodes:] = [0.0, 200.0, 20.0]  # B slides along y over A and separates at 20 mm/s
    out = wc.state_from_positions(model, state.x.numpy())
    out.v.assign(velocities)
    solver._apply_friction(state, out, wc.Control.create(model).running, solver.dt_s)
    after = out.v.numpy()
    x = state.x.numpy()
    pairs = [(i, nodes + j) for i in range(nodes - 1) for j in range(nodes - 1)]
    touching = [p for p in pairs if np.linalg.norm(_closest_points(x, *p)[2]) - d < c0]
    assert len(touching) >= 2
    before_rates, after_rates = _normal_rates(x, velocities, touching), _normal_rates(x, after, touching)
    # (the guard's Jacobi passes leave (1 − 1/K)^passes of a shortfall: here 0.1 mm/s of 26)
    assert np.all(after_rates >= before_rates - 0.005 * 200.0)
    slide_before = velocities[nodes:, 1].mean() - velocities[:nodes, 1].mean()
    slide_after = after[nodes:, 1].mean() - after[:nodes, 1].mean()
    assert slide_after < 0.97 * slide_before  # friction brakes the slide (by 7 % here)


def test_the_normal_guard_conserves_momentum_beside_turns_touching_at_rest():
    """A tight-pitch helix (turns within c0 in the rest shape: no load between them) with a
    straight coil pressed onto one turn and sliding across it, in free space: friction and its
    normal guard are internal impulses, equal and opposite on each watched pair, so the total
    momentum does not change. (A guard that watched a rest-touching turn pair from the loaded
    turn's side only pushed that turn alone: a net impulse.)"""
    from warpcoil.validation import TIGHT_HELIX
    d, c0 = 0.2921, 0.02921
    builder = wc.ModelBuilder(contact=wc.ContactSettings(friction_coil=0.5))
    builder.add_coil(wc.CoilSpec(wire_diameter_mm=d, shape="helix", **TIGHT_HELIX))
    helix = builder.finalize().rest_x.numpy()
    nodes = 9
    s = (np.arange(nodes) - nodes // 2) * d
    top = helix[np.argmax(helix[:, 0])]  # the outermost point along x of a middle turn: B crosses it along z
    b = np.stack([np.full(nodes, top[0] + d - c0), np.zeros(nodes) + top[1], s + top[2] + 0.5 * d], axis=1)
    builder.add_coil(wc.CoilSpec(wire_diameter_mm=d, length_mm=(nodes - 1) * d, segment_length_mm=d), b)
    model = builder.finalize()
    state = wc.state_from_positions(model, np.concatenate([helix, b]))
    rng = np.random.default_rng(3)
    velocities = rng.normal(scale=20.0, size=(model.node_count, 3))
    velocities[len(helix):] += [0.0, 200.0, 0.0]  # B slides over the turn
    solver, _, _ = _coil_friction_changes(model, state, velocities)
    assert solver.coil_contacts.numpy().max() > 0
    out = wc.state_from_positions(model, state.x.numpy())
    out.v.assign(velocities)
    solver._apply_friction(state, out, wc.Control.create(model).running, solver.dt_s)
    mass = 1.0 / model.inv_mass.numpy()
    change = (mass[:, None] * (out.v.numpy() - velocities)).sum(axis=0)  # g·mm/s
    moved = (mass[:, None] * np.abs(out.v.numpy() - velocities)).sum()
    assert moved > 0.0  # friction acted
    assert np.linalg.norm(change) <= 1e-7 * moved  # (fixed-point sums: ~2e-9)


@pytest.mark.parametrize("options", [{"theta": 0.65, "near_theta": None}, {"theta": 1.0}])
def test_wall_friction_stops_a_slide_on_the_implicit_step_without_turning_it_back(options):
    """A coil piece sliding at 3 mm/s on a level floor (μ 0.3) is stopped by wall friction
    inside the step's system at the Coulomb time and stays stopped: the step's mean velocity
    (x' − x)/dt, on which a θ-method row's friction acts, never turns back by more than v_reg.
    (A θ < 1 row's end velocity v' rings at the stop, −(1 − θ)/θ a step, as the θ-method
    does for any stiff damper; Euler's does not.)"""
    from warpcoil.implicit import ImplicitSolver, implicit_step_s
    from warpcoil.solver import Control, Stepper
    from warpcoil.state import state_from_positions

    mu, g = 0.3, 2000.0
    model, x = vf.rod_on_floor(mu, np.array([0.0, 0.0, -g]))
    state = state_from_positions(model, x)
    state.v.assign(np.tile([3.0, 0.0, 0.0], (len(x), 1)))
    solver = ImplicitSolver(model, dt_s=implicit_step_s(model, wc.SimulationSettings().push_speed_mm_s),
                            coil_contact=False, **options)
    stepper = Stepper(solver, state, Control.create(model), chunk=1)
    path = [float(x[:, 0].mean())] + [float(stepper.run_chunk().x.numpy()[:, 0].mean()) for _ in range(120)]
    speeds = np.diff(path) / solver.dt_s  # mm/s
    v_reg = model.contact.friction_speed_mm_s
    stop = next(k for k, s in enumerate(speeds) if s < v_reg)  # Coulomb: 3 mm/s / (μ g) = 5 ms
    assert (stop + 1) * solver.dt_s == pytest.approx(3.0 / (mu * g), abs=2.0 * solver.dt_s)
    assert speeds.min() > -v_reg
    assert np.abs(speeds[stop + 10:]).max() < v_reg


def test_coil_friction_alone_lets_a_pack_come_to_rest_on_the_implicit_step():
    """A 60 mm coil into a 4 mm sphere at 40 mm/s with coil–coil friction alone (μ 0.2) comes
    to rest, as it does without friction and on the reference step (at 1.69 s). Where the coil
    pairs' change carried through the step's system would raise a world's kinetic energy, the
    world takes the largest share of it that does not; applying the law's per-node change
    instead (the previous release) strained the stiff neighbours every such step and the pack
    rattled to the time limit (kinetic energy 30× the rest tolerance)."""
    scene = wc.Scene(coils=(wc.CoilSpec(shape="spherical", wire_diameter_mm=0.2921, loop_diameter_mm=3.5,
                                         length_mm=60.0),),
                     catheter=wc.CatheterSpec(tip_mm=(0.0, 0.0, -1.7), direction=(0.0, 0.0, 1.0)),
                     wall=wc.WallSpec(sphere_diameter_mm=4.0),
                     contact=wc.ContactSettings(friction_coil=0.2, wall_query="sdf"),
                     simulation=wc.SimulationSettings(push_speed_mm_s=40.0, integrator="implicit",
                                                      frame_interval_s=0.01),
                     output=OutputSettings(usd=False))
    deployment = Deployment(scene)
    result = deployment.run()
    assert result.status == "completed", result.reason
    assert result.min_coil_gap_mm > -2.0 * deployment.model.contact.c0_mm  # no crossing held by friction


@pytest.mark.parametrize("contact, simulation, integrator", [
    ("friction_wall = 0.2\n", "", "symplectic"),  # wall friction, no integrator named: the reference
    ("friction_coil = 0.2\nfriction_catheter = 0.1\n", "", "implicit"),  # no wall friction: the default
    ("friction_wall = 0.2\n", 'integrator = "implicit"\n', "implicit"),  # named: as named
    ("friction_wall = 0.2\n", 'implicit_scheme = "euler"\n', "implicit"),  # a scheme of the implicit step names it
    ("friction_wall = 0.2\n", "dt_s = 2e-4\n", "implicit"),  # a step chosen for one integrator: not switched
    ("", "", "implicit")])
def test_wall_friction_chooses_the_reference_where_the_scene_names_no_integrator(tmp_path, contact, simulation,
                                                                                  integrator):
    """The implicit step's push force with wall friction is several times the reference's: a scene
    with wall friction that names no integrator runs the reference, and its notes say why."""
    path = tmp_path / "s.toml"
    path.write_text('[[coil]]\nwire_diameter_mm = 0.3\nloop_diameter_mm = 3\nlength_mm = 10\n'
                    f"[contact]\n{contact}[simulation]\n{simulation}")
    scene = load_scene(path)
    assert scene.simulation.integrator == integrator
    chose = bool(scene.notes) and "the reference (symplectic) step runs it" in scene.notes[0]
    assert chose == (integrator == "symplectic")


@pytest.mark.parametrize("contact, simulation, integrator", [
    ({"friction_wall": 0.2}, {}, "symplectic"),  # as the TOML reader: wall friction, none named
    ({"friction_coil": 0.2}, {}, "implicit"),
    ({"friction_wall": 0.2}, {"integrator": "implicit"}, "implicit"),
    ({"friction_wall": 0.2}, {"implicit_scheme": "euler"}, "implicit"),
    ({"friction_wall": 0.2}, {"dt_s": 2e-4}, "implicit")])
def test_a_scene_built_in_python_gets_the_readers_integrator_rule(contact, simulation, integrator):
    """A Scene built in Python that names no integrator runs what the same scene read from TOML runs
    (settings.resolve_integrator), and says why in a warning (its preflight); replacing a
    field of a Python-built scene before its run chooses again."""
    import warnings

    from warpcoil.deploy import IntegratorChoice
    from warpcoil.settings import resolve_integrator

    scene = wc.Scene(coils=(wc.CoilSpec(wire_diameter_mm=0.3, loop_diameter_mm=3.0, length_mm=10.0),),
                     contact=wc.ContactSettings(**contact), simulation=wc.SimulationSettings(**simulation),
                     output=OutputSettings(usd=False))
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        deployment = Deployment(scene)
    assert deployment.integrator == deployment.scene.simulation.integrator == integrator
    chose = [w for w in said if issubclass(w.category, IntegratorChoice)]
    assert bool(chose) == (integrator == "symplectic")
    assert all("the reference (symplectic) step runs it" in str(w.message) for w in chose)
    assert deployment.scene.notes == tuple(str(w.message).removeprefix("scene: ") for w in chose)
    again = resolve_integrator(replace(deployment.scene, contact=wc.ContactSettings(),
                                       simulation=replace(deployment.scene.simulation, integrator="auto")))
    assert again.simulation.integrator == "implicit" and again.notes == ()  # chosen again: no stale reason
    if not simulation:  # the same rule from the other side: friction added to a frictionless scene
        other = replace(scene, contact=wc.ContactSettings(friction_wall=0.0 if contact.get("friction_wall") else 0.3))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", IntegratorChoice)
            assert Deployment(other).integrator == ("implicit" if integrator == "symplectic" else "symplectic")


def test_a_malformed_simulation_table_beside_wall_friction_is_one_clear_error(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text('simulation = 5\n[[coil]]\nwire_diameter_mm = 0.3\nloop_diameter_mm = 3\nlength_mm = 10\n'
                    "[contact]\nfriction_wall = 0.2\n")
    with pytest.raises(SceneError, match=r"simulation"):
        load_scene(path)


def test_a_sweep_switches_only_members_that_choose_no_integrator(tmp_path):
    """sweep.one_integrator: beside a frictional member on the reference, a frictionless member
    that names nothing runs the reference too; one that names the implicit step (its integrator,
    a scheme or a step) keeps it, as a plan's option may."""
    from warpcoil.sweep import Member, one_integrator

    path = tmp_path / "s.toml"
    path.write_text('[[coil]]\nwire_diameter_mm = 0.3\nloop_diameter_mm = 3\nlength_mm = 10\n')
    chosen = [{}, {"simulation.integrator": "implicit"}, {"simulation.implicit_scheme": "euler"},
              {"simulation.dt_s": 2e-4}]
    todo = [Member(0, {"contact.friction_wall": 0.3})] + [
        Member(k + 1, {"contact.friction_wall": 0.0, **values}) for k, values in enumerate(chosen)]
    scenes, notes = one_integrator(path, todo, [load_scene(path, m.values) for m in todo])
    assert [s.simulation.integrator for s in scenes] == ["symplectic", "symplectic", "implicit", "implicit", "implicit"]
    assert "1 of 5 members have wall friction" in notes[0] and "the 1 other member run the reference" in notes[0]
    alone = todo[:1] + todo[2:]  # no member left to switch: nothing said
    scenes, notes = one_integrator(path, alone, [load_scene(path, m.values) for m in alone])
    assert notes == [] and [s.simulation.integrator for s in scenes] == ["symplectic", "implicit", "implicit", "implicit"]


@pytest.mark.parametrize("alignment", ["node over node", "node over edge", "parallel", "over a stuck coil"])
def test_a_coil_sliding_on_another_loses_mu_n_whatever_the_alignment(alignment):
    """A helper's find: each pair's friction was scaled by α = min(1, 2/K), K the contacts counted at
    its nodes, so a coil sliding node over node (K = 4) lost μN/2 and parallel coils μN/3; a share by the
    sum of the slip fractions at the pair's nodes still gave 0.246 μN over a coil stuck on a third. Each
    node now caps its contacts' fractions where they would stop it: sliding contacts get the whole law."""
    from warpcoil.validation_coil_friction import sliding_friction_ratio

    assert sliding_friction_ratio(alignment) == pytest.approx(1.0, abs=1e-6)


def test_parallel_coils_stick_below_mu_n_and_slide_with_coulombs_acceleration_above():
    """Two free parallel coils pressed together and pulled apart along their axes: at 0.8 μN they creep
    below v_reg (they slid at 48 mm/s² with the count-based share), at 2 μN they slide at 2 (g_t − μ g_n)
    within 2 % on both steps."""
    from warpcoil.validation_coil_friction import parallel_coils_motion

    acceleration, reference, creep = parallel_coils_motion(0.8)
    assert reference == 0.0 and abs(acceleration) < 1.0 and 0.0 < creep < wc.ContactSettings().friction_speed_mm_s
    for implicit in (False, True):
        acceleration, reference, _ = parallel_coils_motion(2.0, implicit=implicit)
        assert acceleration == pytest.approx(reference, rel=2e-2)
