"""The settling step set by the fastest node (implicit.settle_level, deploy.Ensemble._settle_chunk):
its rule, the settled state against the finest-step settle, and captured-graph sizes
that change no result."""

import math

import numpy as np
import pytest

from test_implicit import implicit_scene

from warpcoil.deploy import Deployment
from warpcoil.implicit import (IMPLICIT_SETTLE_DT_MAX_S, IMPLICIT_SETTLE_DT_S, IMPLICIT_SETTLE_THETA, GATED_CHORD,
                               SETTLE_ADVANCE_PER_C0, SETTLE_STALL_S, settle_finest_level, settle_level, settle_stalled)
from warpcoil.state import new_state_like
from warpcoil.validation_settle import settle_cases

C0_MM = 0.02921


@pytest.mark.parametrize("frame_s", [0.004, 0.005, 0.01, 0.02])
def test_the_settling_step_moves_the_fastest_node_at_most_c0_unless_at_the_finest(frame_s):
    finest = settle_finest_level(frame_s)
    assert frame_s / (2 * finest) <= IMPLICIT_SETTLE_DT_S < frame_s / (2 * (finest - 1)) if finest > 1 else True
    for speed in np.geomspace(0.01, 1e4, 60):
        k = settle_level(speed, C0_MM, frame_s)
        dt = frame_s / (2 * k)  # a whole number of steps splits the frame
        assert 1 <= k <= finest and dt <= IMPLICIT_SETTLE_DT_MAX_S * (1 + 1e-12)
        if k < finest:  # not held at the finest: the step keeps the node within SETTLE_ADVANCE_PER_C0 · c0
            assert speed * dt <= SETTLE_ADVANCE_PER_C0 * C0_MM * (1 + 1e-9)
            if k > 1 and frame_s / (2 * (k - 1)) <= IMPLICIT_SETTLE_DT_MAX_S:  # and is the longest allowed that does
                assert speed * frame_s / (2 * (k - 1)) > SETTLE_ADVANCE_PER_C0 * C0_MM
    assert settle_level(math.inf, C0_MM, frame_s) == finest


def test_the_settled_state_is_at_rest_within_the_chaotic_spread_of_the_finest_step_settle():
    """Small seed case: node-wise distance to the finest-step settle under half the spread
    that a 0.01° catheter turn makes, no wall gap after the push deeper than the finest-step
    run's deepest, at rest."""
    rows = settle_cases()
    assert len(rows) == 3
    for row in rows:
        assert row.passed, (row.case, row.reference, row.result, row.error)


def test_the_graph_size_changes_no_result():
    """A chunk replayed from 2-step graphs (the settling steppers) or from 8-step ones:
    bit-identical states."""
    from warpcoil.deploy import Deployment
    from warpcoil.solver import Stepper
    from warpcoil.state import new_state_like
    from warpcoil.validation_settle import small_seed

    states, starts = [], []
    for most in (2, 8):
        deployment = Deployment(small_seed())
        start = new_state_like(deployment.model)
        start.copy_from(deployment.stepper.state)
        starts.append(start.x.numpy().copy())
        stepper = Stepper(deployment.solver, start, deployment.control, chunk=16, graph_steps_max=most)
        stepper.run_chunk()
        states.append(stepper.state)
    assert not np.array_equal(states[0].x.numpy(), starts[0])  # the chunk moved the coil
    for name in ("x", "v", "m1", "omega", "advance"):
        assert np.array_equal(getattr(states[0], name).numpy(), getattr(states[1], name).numpy()), name


@pytest.mark.parametrize("frame_s", [0.01, 0.05])
def test_a_stalled_kinetic_energy_is_told_from_a_slow_decay_and_a_creeping_plateau(frame_s):
    """A decay at the slowest rate measured while settling (τ = 0.3 s; kinetic energy
    ∝ exp(−2t/τ)) and the seed case's creeping plateaus (0.1 s flat) are not stalls; a
    steady oscillation (C0001's 6 mm framing coil at 2.5 ms: 0.031 nJ for 3 s) is, once
    it has lasted SETTLE_STALL_S."""
    t = np.arange(0.0, 2.0, frame_s)
    decay = list(0.5 * np.exp(-2.0 * t / 0.3))
    plateau = list(np.where((t > 0.6) & (t < 0.7), 0.02, 0.5 * np.exp(-2.0 * np.minimum(t, 0.6) / 0.3)
                            * np.exp(-2.0 * np.maximum(t - 0.7, 0.0) / 0.3)))
    steady = list(0.0313 * (1.0 + 0.002 * np.sin(37.0 * t)))
    assert not any(settle_stalled(decay[:k], frame_s) for k in range(1, len(decay) + 1))
    assert not any(settle_stalled(plateau[:k], frame_s) for k in range(1, len(plateau) + 1))
    first = next(k for k in range(1, len(steady) + 1) if settle_stalled(steady[:k], frame_s))
    assert (first - 1) * frame_s == pytest.approx(SETTLE_STALL_S, abs=frame_s)


def test_a_settling_that_stalls_again_goes_to_half_the_step_up_to_the_limit(monkeypatch):
    """A member whose kinetic energy stalls (here: every SETTLE_STALL_S, as a steady oscillation
    would) goes to the finest settling step, then, stalled again over SETTLE_STALL_S of its own
    frames at that step, to half of it, SETTLE_REFINE_MAX times in all."""
    from dataclasses import replace

    import warpcoil.deploy as deploy
    from warpcoil.deploy import Deployment
    from warpcoil.implicit import SETTLE_REFINE_MAX

    from test_ensemble import scene

    frame_s = 0.005
    window = math.ceil(SETTLE_STALL_S / frame_s - 1e-9)
    monkeypatch.setattr(deploy, "settle_stalled", lambda kinetic, _frame_s: len(kinetic) > window)
    base = scene(0.0)
    push_s = (base.coils[0].length_mm + 1.0) / base.simulation.push_speed_mm_s
    s = replace(base, simulation=replace(base.simulation, integrator="implicit", rest_kinetic_energy_nJ=1e-30,
                                         max_time_s=push_s + (SETTLE_REFINE_MAX + 0.5) * SETTLE_STALL_S))
    deployment = Deployment(s)
    levels: list[int] = []
    real = deployment._settle_chunk

    def recorded(live):
        real(live)
        levels.append(deployment.members[0].settle_level)

    deployment._settle_chunk = recorded
    result = deployment.run()
    assert result.status == "timeout"
    finest = settle_finest_level(frame_s)
    changes = [i for i in range(1, len(levels)) if levels[i] != levels[i - 1]]
    assert [levels[i] for i in changes[-SETTLE_REFINE_MAX:]] == [finest * 2 ** r for r in range(SETTLE_REFINE_MAX)]
    assert np.diff(changes[-SETTLE_REFINE_MAX:]).min() == window + 1  # each after its own window of frames
    assert result.settle_dt_s == pytest.approx(frame_s / (2 * finest * 2 ** (SETTLE_REFINE_MAX - 1)))


def test_every_implicit_run_settles_at_the_settling_theta():
    """θ IMPLICIT_SETTLE_THETA once every coil is out of a gated_chord run (θ 0.65 while pushing),
    also for a run whose push step was halved or a scene that gives dt_s (the θ-method at 0.65
    takes ~20× the steps to rest); a step halved while settling goes on at θ 1 with the push's
    gate and contact stiffness (BDF2's: none, tangent)."""
    scene = implicit_scene()
    halved = Deployment(scene, solver_options=GATED_CHORD)
    snapshot = new_state_like(halved.model)
    snapshot.copy_from(halved.stepper.state)
    halved._halve_step(snapshot, "halved for the test at t = 0")
    assert halved.solver.theta == GATED_CHORD["theta"]
    assert halved.run().status == "completed" and halved.solver.theta == IMPLICIT_SETTLE_THETA
    given = Deployment(implicit_scene(dt_s=halved.solver.dt_s), solver_options=GATED_CHORD)
    assert given.run().status == "completed" and given.solver.theta == IMPLICIT_SETTLE_THETA
    bdf2 = Deployment(scene, solver_options={"method": "bdf2"})
    bdf2._settle_step()
    before = (bdf2.solver.near_theta, bdf2.solver.chord)
    bdf2._halve_step(new_state_like(bdf2.model), "halved for the test while settling")
    assert (bdf2.solver.theta, bdf2.solver.near_theta, bdf2.solver.chord) == (IMPLICIT_SETTLE_THETA, *before)


def test_a_run_settling_at_its_own_step_replays_the_settling_scheme(monkeypatch):
    """A run that gives ``dt_s`` settles at that step, at θ = 1 after the push (Ensemble._settle_scheme):
    the captured graph the push replayed holds the push's θ, so it is captured again. The run
    equals the same run with every step launched directly, frame by frame."""
    from dataclasses import replace

    import warpcoil.solver as solver_mod

    from test_ensemble import assert_same_run, scene

    base = scene(0.0, dt_s=2.5e-4)
    s = replace(base, simulation=replace(base.simulation, integrator="implicit", implicit_scheme="gated_chord"))
    captured = Deployment(s).run()
    launched = solver_mod.Stepper.__init__

    def direct(self, *args, **kwargs):
        kwargs["use_graph"] = False
        launched(self, *args, **kwargs)

    monkeypatch.setattr(solver_mod.Stepper, "__init__", direct)
    assert captured.settle_dt_s is None  # (settled at the given step)
    assert_same_run(Deployment(s).run(), captured)
