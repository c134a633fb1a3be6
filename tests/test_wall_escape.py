"""No node centre outside the wall: a step that carries a node through the contact
range unseen (the implicit settling step of a coil still moving fast) is a step
failure, redone at half the step; an ensemble member doing so is rerun alone and
still equals its single run."""

from dataclasses import replace

import numpy as np
import pytest

import warpcoil as wc
from warpcoil.deploy import COIL_GAP_MM, Deployment, Ensemble
from warpcoil.implicit import DETACH_WHIP_S, IMPLICIT_SETTLE_DT_MAX_S
from warpcoil.solver import Solver

from test_ensemble import assert_same_run, scene as ensemble_scene

RADIUS_MM = 0.5 * wc.CoilSpec().d


def released_fast(angle_deg: float, scheme: str = "euler") -> wc.Scene:
    """A 6 mm helix shot out at 2 m/s into a 3.5 mm sphere on the implicit default step,
    linearly implicit Euler by default here (``scheme``; gated_chord, the scenes' default, tunnels here too, at the settling
    step: test_gated_chord_tunnels_too_and_the_check_redoes_the_frame): the coil is out after
    3.5 ms and still whips at ~10³ mm/s when the settling step takes over (pinned at its
    coarsest, 2.5 ms, by ``coarsest_settling``: 2.5 mm per step against c0 = 0.029 mm)."""
    s = ensemble_scene(angle_deg=angle_deg, push_mm_s=2000.0)
    return replace(s, simulation=replace(s.simulation, integrator="implicit", implicit_scheme=scheme))


@pytest.fixture
def coarsest_settling(monkeypatch):
    """The settling step at its coarsest whatever the nodes' speed (implicit.settle_level
    would take the finest here), from the push's end on, before the tail's whip is over
    (deploy.world_steps waits DETACH_WHIP_S after the last release): the failure the
    health check must catch."""
    real = Ensemble.__init__

    def coarsest(self, *args, **kwargs):
        real(self, *args, **kwargs)
        self.settle_rule = lambda _speed, _c0, _frame_s, _scale: 1
        speed = self.scenes[0].simulation.push_speed_mm_s
        self.push_time_s -= max(0.0, DETACH_WHIP_S - COIL_GAP_MM / speed)

    monkeypatch.setattr(Ensemble, "__init__", coarsest)
    assert ensemble_scene().simulation.frame_interval_s / 2 == IMPLICIT_SETTLE_DT_MAX_S


def centre_distances_mm(result) -> np.ndarray:
    """Per frame: the smallest signed centre distance of a free node to the wall (> 0 in the lumen)."""
    return np.array([f.min_wall_gap_mm for f in result.frames]) + RADIUS_MM


def without_the_wall_check(monkeypatch) -> None:
    real = Solver.world_health
    monkeypatch.setattr(Solver, "world_health", lambda self, state, budget=None, _wall=None: real(self, state, budget))


def test_the_case_tunnels_without_the_check(monkeypatch, coarsest_settling):
    """The test case is real: unchecked, the settling step carries the coil through the
    wall (the node is then beyond the wall search and feels nothing) and it leaves the sac."""
    without_the_wall_check(monkeypatch)
    result = Deployment(released_fast(0.0)).run()
    assert result.step_reductions == []
    assert centre_distances_mm(result).min() < -1.0  # mm outside the lumen


def test_a_node_past_the_wall_redoes_the_frame_at_half_the_step(coarsest_settling):
    """Every frame keeps every free node centre in the lumen; the reason is reported."""
    deployment = Deployment(released_fast(0.0))
    result = deployment.run()
    assert result.status == "completed", result.reason
    assert centre_distances_mm(result).min() > 0.0
    assert len(result.step_reductions) == 1
    halved = 0.5 * IMPLICIT_SETTLE_DT_MAX_S
    assert "past the wall" in result.step_reductions[0] and f"step halved to {halved:.3e} s" in result.step_reductions[0]
    assert result.settle_dt_s == pytest.approx(halved)  # the settling step, halved once


def test_gated_chord_tunnels_too_and_the_check_redoes_the_frame(monkeypatch, coarsest_settling):
    """The named scheme gated_chord (settling with Euler + chord) at 10° (the coil's roll is the wall's since
    the twenty-first session; at 20°, where it tunnelled with the coordinate axes' roll, it now does not):
    unchecked, the coarsest settling step carries it out of the lumen (the chord sees only the predicted
    free flight's approach); checked, that frame is redone at half the step and every centre stays inside."""
    checked = Deployment(released_fast(10.0, "gated_chord")).run()
    assert checked.status == "completed", checked.reason
    assert centre_distances_mm(checked).min() > 0.0
    assert len(checked.step_reductions) == 1 and "past the wall" in checked.step_reductions[0]
    without_the_wall_check(monkeypatch)
    unchecked = Deployment(released_fast(10.0, "gated_chord")).run()
    assert unchecked.step_reductions == [] and centre_distances_mm(unchecked).min() < -1.0


def test_the_settling_step_set_by_the_fastest_node_keeps_every_node_in_the_lumen(monkeypatch):
    """The same fast release with the settling step its fastest node sets (at most
    c0 per step, implicit.settle_level): nothing to redo, every frame's node centres
    in the lumen, at rest."""
    without_the_wall_check(monkeypatch)
    result = Deployment(released_fast(0.0)).run()
    assert result.status == "completed", result.reason
    assert result.step_reductions == []
    assert centre_distances_mm(result).min() > 0.0


def test_an_escaping_member_is_rerun_alone_and_both_equal_their_single_runs(coarsest_settling):
    scenes = [released_fast(0.0), released_fast(20.0)]  # the first tunnels, the second does not
    results = Ensemble(scenes).run()
    singles = [Deployment(s).run() for s in scenes]
    assert singles[0].step_reductions and not singles[1].step_reductions
    for single, member in zip(singles, results):
        assert member.status == "completed", member.reason
        assert centre_distances_mm(member).min() > 0.0
        assert member.step_reductions == single.step_reductions
        assert_same_run(single, member)


def test_health_names_free_nodes_past_the_wall_only():
    """A free node's centre 0.02 mm outside is a failure; the same distance on a node
    still in the catheter, or any centre inside, is not."""
    deployment = Deployment(released_fast(0.0))
    solver, state = deployment.solver, deployment.stepper.state
    free = state.free.numpy().copy()
    n = len(free)
    inside = np.full(n, 0.5)
    assert solver.world_health(state, wall_distance_mm=inside)[1] == [None]
    caught = int(np.flatnonzero(free == 0)[0])
    outside = inside.copy()
    outside[caught] = -0.02
    assert solver.world_health(state, wall_distance_mm=outside)[1] == [None]
    free[caught] = 1
    state.free.assign(free)
    problem = solver.world_health(state, wall_distance_mm=outside)[1][0]
    assert "1 free node centre(s) past the wall (deepest 0.02 mm outside" in problem
