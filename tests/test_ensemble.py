"""Ensembles: B deployments advanced by one set of launches give each member
exactly the result of its single run."""

import dataclasses
import math

import numpy as np
import pytest

import warpcoil as wc
from warpcoil.deploy import Deployment, Ensemble, ensemble_groups
from warpcoil.model import EnsembleError


def scene(angle_deg=0.0, push_mm_s=100.0, sac_diameter_mm=3.5, length_mm=6.0, dt_s=None, axial_stiffness_uN=None,
          p0_uN=1.0e3, max_time_s=None):
    """A 6 mm framing coil into a small sphere, the catheter tilted by ``angle_deg``, on the
    reference step (symplectic Euler)."""
    a = math.radians(angle_deg)
    return wc.Scene(
        coils=(wc.CoilSpec(shape="helix", length_mm=length_mm, loop_diameter_mm=2.5, pitch_mm=0.6, name="framing",
                           axial_stiffness_uN=axial_stiffness_uN),),
        catheter=wc.CatheterSpec(tip_mm=(0.0, 0.0, -0.45 * sac_diameter_mm + 0.1),
                                 direction=(math.sin(a), 0.0, math.cos(a))),
        wall=wc.WallSpec(sphere_diameter_mm=sac_diameter_mm), contact=wc.ContactSettings(P0_uN=p0_uN),
        simulation=wc.SimulationSettings(push_speed_mm_s=push_mm_s, frame_interval_s=0.005, dt_s=dt_s,
                                         max_time_s=max_time_s, integrator="symplectic"))


def assert_same_run(single, member):
    assert member.status == single.status and member.reason == single.reason
    assert member.steps == single.steps
    assert len(member.frames) == len(single.frames)
    for a, b in zip(single.positions_mm, member.positions_mm):
        assert np.array_equal(a, b)
    assert member.min_coil_gap_mm == single.min_coil_gap_mm
    assert member.push_force_peak_uN == single.push_force_peak_uN
    assert member.push_force_rms_uN == single.push_force_rms_uN
    assert [f.kinetic_nJ for f in member.frames] == [f.kinetic_nJ for f in single.frames]


def test_members_equal_their_single_runs():
    """Different catheter angles, push speeds and walls (two sphere sizes) in one ensemble."""
    scenes = [scene(0.0), scene(20.0, push_mm_s=150.0), scene(10.0, sac_diameter_mm=4.0)]
    results = Ensemble(scenes).run()
    assert [r.status for r in results] == ["completed"] * 3
    assert not np.allclose(results[0].positions_mm[0], results[1].positions_mm[0])  # members differ
    for s, member in zip(scenes, results):
        assert_same_run(Deployment(s).run(), member)


def test_theta_method_members_equal_their_single_runs():
    """Implicit θ 0.7 (its push force reading keeps the previous step's per world): each
    member's steps, positions and push force peak and RMS equal its single run's."""
    scenes = [dataclasses.replace(s, simulation=dataclasses.replace(s.simulation, integrator="implicit"))
              for s in (scene(0.0), scene(10.0, sac_diameter_mm=4.0))]
    options = {"theta": 0.7}
    results = Ensemble(scenes, solver_options=options).run()
    assert [r.status for r in results] == ["completed"] * 2
    for s, member in zip(scenes, results):
        assert_same_run(Deployment(s, solver_options=options).run(), member)


def test_a_member_that_goes_unstable_is_rerun_alone(monkeypatch):
    """Force member 1 unstable at its second frame: it leaves the ensemble and is
    rerun alone (where a real instability would halve its step); both members
    end as their single runs do."""
    from warpcoil.solver import Solver

    scenes = [scene(0.0), scene(15.0)]
    real = Solver.world_health
    calls = {"n": 0, "alone": 0}

    def flaky(self, state, energy_budget_nJ=None, wall_distance_mm=None):
        calls["n"] += 1
        energies, problems = real(self, state, energy_budget_nJ, wall_distance_mm)
        calls["alone"] += len(problems) == 1
        if calls["n"] == 3 and len(problems) == 2:
            problems = [problems[0], "forced for the test at t = 0"]
        return energies, problems

    monkeypatch.setattr(Solver, "world_health", flaky)
    seen: dict[int, list[float]] = {0: [], 1: []}

    def on_frame(member, frame, state):  # the member's own nodes in the state it comes with
        x = np.concatenate([state.x.numpy()[s] for s in member.coil_nodes])
        assert len(x) == sum(s.stop - s.start for s in member.coil_nodes) > 0 and np.isfinite(x).all()
        seen[member.index].append(frame.time_s)

    results = Ensemble(scenes).run(on_frame)
    monkeypatch.setattr(Solver, "world_health", real)
    assert calls["alone"] > 0  # member 1 ran again, alone
    assert seen[1].count(0.0) == 2  # ... its frames from the start again
    assert len(seen[0]) == len(results[0].frames)
    for s, member in zip(scenes, results):
        assert_same_run(Deployment(s).run(), member)


def test_members_with_different_steps_are_grouped_apart():
    scenes = [scene(0.0), scene(0.0, length_mm=7.3), scene(5.0)]
    with pytest.raises(EnsembleError, match="same step"):
        Ensemble(scenes)
    assert ensemble_groups(scenes) == [[0, 2], [1]]


def test_the_catheter_of_each_world_is_its_own():
    scenes = [scene(0.0), scene(30.0)]
    ensemble = Ensemble(scenes)
    x = ensemble.stepper.state.x.numpy()
    for w, s in enumerate(scenes):
        tip = np.asarray(s.catheter.tip_mm)
        direction = np.asarray(s.catheter.direction) / np.linalg.norm(s.catheter.direction)
        nodes = x[ensemble.model.world_nodes(w)]
        behind = (tip - nodes) @ direction
        assert np.allclose(np.linalg.norm(tip - nodes - np.outer(behind, direction), axis=1), 0.0, atol=1e-9)
        assert np.all(behind >= -1e-9)


def test_members_with_their_own_step_bound_and_search_radius():
    """Two different coils (length, hence segment length and search radius; axial
    stiffness, hence step bound) on one explicit step (and a contact soft enough
    that its linear onset is MODEL.md's u = 7 for both): each member reports its
    own bound and gaps, as its single run does."""
    common = dict(dt_s=5e-6, p0_uN=1.0, max_time_s=0.08)
    scenes = [scene(0.0, **common), scene(10.0, length_mm=7.3, axial_stiffness_uN=9.0e5, **common)]
    ensemble = Ensemble(scenes)
    radius = ensemble.model.query_radius_of.numpy()
    assert radius[0] < radius[1] == ensemble.model.contact.query_radius_mm  # the grid searches the larger
    results = ensemble.run()
    assert results[0].step_bound_s != results[1].step_bound_s
    for s, member in zip(scenes, results):
        single = Deployment(s).run()
        assert member.step_bound_s == single.step_bound_s
        assert_same_run(single, member)
        assert [f.min_coil_gap_mm for f in member.frames] == [f.min_coil_gap_mm for f in single.frames]


@pytest.mark.parametrize("scheme, push_mm_s, tilt_deg", [("euler", 600.0, 40.0), ("gated_chord", 400.0, 60.0)])
def test_members_settling_at_different_steps_equal_their_single_runs(monkeypatch, scheme, push_mm_s, tilt_deg):
    """Implicit step, Euler and gated_chord (the default). After the push each member steps at the settling
    step its own fastest node sets (implicit.settle_level); members at different steps in the same frame
    advance apart, so each still equals its single run. (gated_chord's members with the catheter tilted
    40° settle at one step in every shared frame at 200–600 mm/s, so its second member is tilted 60°.)"""
    from dataclasses import replace

    scenes = [scene(a, push_mm_s=push_mm_s) for a in (0.0, tilt_deg)]
    scenes = [replace(s, simulation=replace(s.simulation, integrator="implicit", implicit_scheme=scheme)) for s in scenes]
    real = Ensemble._settle_chunk
    levels: list[set[int]] = []

    def recorded(self, live):
        real(self, live)
        if len(live) > 1:
            levels.append({m.settle_level for m in live})

    monkeypatch.setattr(Ensemble, "_settle_chunk", recorded)
    results = Ensemble(scenes).run()
    assert any(len(frame) > 1 for frame in levels)  # a frame with the members at different steps
    for s, member in zip(scenes, results):
        assert member.status == "completed", member.reason
        assert_same_run(Deployment(s).run(), member)
        assert member.settle_dt_s is not None


@pytest.mark.parametrize("options", [None, {"method": "bdf2"}])
def test_members_detaching_at_different_frames_equal_their_single_runs(monkeypatch, options):
    """Implicit default step: a member whose coil's tail leaves the catheter takes that
    frame (and those of the whip after it) at the detachment step (deploy.Ensemble._push_chunk) while the
    other is held at the push step; two coils each, in swapped order (the same push time),
    so the members detach at different frames and each still equals its single run. BDF2
    (one history flag per state, shared by the members) keeps the push step through
    detachment, and its members equal their single runs too."""
    from dataclasses import replace

    def two_coils(first_mm, second_mm, angle_deg):
        s = scene(angle_deg)
        coil = s.coils[0]
        return replace(s, coils=(replace(coil, length_mm=first_mm, name="first"),
                                 replace(coil, length_mm=second_mm, name="second")),
                       simulation=replace(s.simulation, integrator="implicit"))

    scenes = [two_coils(2.0, 5.0, 0.0), two_coils(5.0, 2.0, 20.0)]
    real = Ensemble._push_chunk
    levels: list[tuple[int, ...]] = []

    def recorded(self, live):
        real(self, live)
        levels.append(tuple(m.detach_level for m in live) if len(live) == 2 else ())

    monkeypatch.setattr(Ensemble, "_push_chunk", recorded)
    results = Ensemble(scenes, solver_options=options).run()
    mixed = [lv for lv in levels if len(set(lv)) > 1]
    if options is None:
        assert mixed  # frames in which one member detaches and the other is pushed at the push step
        assert {lv.index(1) for lv in mixed} == {0, 1}  # ... each member in turn
    else:
        assert not mixed
    for s, member in zip(scenes, results):
        assert member.status == "completed", member.reason
        assert (member.detach_steps > 0) == (options is None)
        assert_same_run(Deployment(s, solver_options=options).run(), member)
