"""The detachment step (implicit.detach_level, deploy.Ensemble._push_chunk): the push frames in
which a coil's tail leaves the catheter, and the whip after it, at the push step / k: the
rule, which frames take it, that the pusher and the clock are unchanged, and the whip's
deepest wall overlap against the finest step (validation_detach)."""

import math

import numpy as np
import pytest

from warpcoil.deploy import Deployment, Ensemble
from warpcoil.implicit import (DETACH_ADVANCE_PER_C0, DETACH_LEAD_SEGMENTS, DETACH_LEVEL_MAX, DETACH_WHIP_S,
                               IMPLICIT_ADVANCE_PER_C0, detach_level)
from warpcoil.validation_detach import detach_cases, whip_scene

C0_MM = 0.0292


@pytest.mark.parametrize("speed_mm_s", [5.0, 50.0, 100.0, 400.0])
@pytest.mark.parametrize("dt_s", [1e-5, 1e-4, 5e-4])
def test_the_detachment_step_is_the_fewest_that_move_the_pusher_at_most_its_share_of_c0(speed_mm_s, dt_s):
    k = detach_level(speed_mm_s, dt_s, C0_MM)
    limit = DETACH_ADVANCE_PER_C0 * C0_MM
    assert 1 <= k <= DETACH_LEVEL_MAX
    if k < DETACH_LEVEL_MAX:
        assert speed_mm_s * dt_s / k <= limit * (1 + 1e-9)
    if k > 1:
        assert speed_mm_s * dt_s / (k - 1) > limit
    # at the default push step (the pusher IMPLICIT_ADVANCE_PER_C0 · c0 per step)
    assert detach_level(speed_mm_s, IMPLICIT_ADVANCE_PER_C0 * C0_MM / speed_mm_s, C0_MM) == math.ceil(
        IMPLICIT_ADVANCE_PER_C0 / DETACH_ADVANCE_PER_C0 - 1e-9)


def _run(level=None, scene=None):
    deployment = Deployment(whip_scene() if scene is None else scene)
    if level is not None:
        deployment.detach_rule = lambda _speed, _dt, _c0: level
    levels: list[tuple[float, int]] = []
    real = deployment._push_chunk

    def recorded(live):
        start = deployment.stepper.state.time_s
        real(live)
        levels.append((start, deployment.members[0].detach_level))

    deployment._push_chunk = recorded
    advance: list[float] = []
    result = deployment.run(lambda frame, state: advance.append(float(state.advance.numpy()[0])))
    return result, deployment, levels, advance


def test_detachment_frames_are_the_release_frame_and_the_whip_after_it_with_the_pusher_unchanged():
    """The frames at push step / k are exactly those from the one in which the last node leaves
    the tip (on the default gated_chord's θ < 1, the one in which the release lead opens:
    DETACH_LEAD_SEGMENTS last edges earlier) to DETACH_WHIP_S after; each frame keeps its length
    and the pusher its advance."""
    result, deployment, levels, advance = _run()
    plain, _, plain_levels, plain_advance = _run(1)
    frame_s = deployment.members[0].frames[1].time_s - deployment.members[0].frames[0].time_s
    speed = deployment.scene.simulation.push_speed_mm_s
    release_s = float(deployment.coil_lengths_mm[0]) / speed
    assert deployment.solver.scheme["theta"] < 1.0  # the default gated_chord (its push): the release lead
    arc = deployment.model.arc_s.numpy()
    lead_s = (arc[-1] - arc[-1 - DETACH_LEAD_SEGMENTS]) / speed
    k = detach_level(speed, result.dt_s, deployment.model.contact.c0_mm)
    assert k == 4
    fine = [start for start, level in levels if level > 1]
    expected = [start for start, _ in levels
                if start + frame_s > release_s - lead_s - 1e-9 and start < release_s + DETACH_WHIP_S]
    assert fine == pytest.approx(expected) and len(fine) >= 10
    assert all(level == k for _, level in levels if level > 1)
    assert all(level == 1 for _, level in plain_levels)
    steps_per_frame = round(frame_s / result.dt_s)
    assert result.detach_steps == (k - 1) * steps_per_frame * len(fine)
    assert plain.detach_steps == 0
    # the same clock and, frame by frame up to the push's end, the same pusher advance
    push_frames = [i for i, t in enumerate(f.time_s for f in plain.frames) if t <= deployment.push_time_s]
    times = [plain.frames[i].time_s for i in push_frames]
    assert [result.frames[i].time_s for i in push_frames] == pytest.approx(times, abs=1e-12)
    assert np.allclose([advance[i] for i in push_frames], [plain_advance[i] for i in push_frames], atol=1e-9)


def test_the_whips_deepest_overlap_matches_the_finest_step_and_stays_within_c0():
    """validation_detach: two helices whose tails whip against a sphere's wall: the rule's deepest
    overlap within 0.5 c0 of the range the k = 16, 32 and 64 runs span (and k doubled too), and no
    deeper than c0. (With the push step throughout the 3 mm helix's is 1.2 c0 deep: docs/FORMULATION.md.)"""
    rows = detach_cases()
    assert len(rows) == 6
    for row in rows:
        assert row.passed, row


def tiny_sac_scene(scheme: str):
    """A 20.7 mm framing coil (d 0.254 mm, loop 2 mm) pushed at 50 mm/s into a 2 mm sphere (25 %
    packing): its last nodes leave the tip pressed hard against the pack."""
    import warpcoil as wc

    return wc.Scene(
        coils=(wc.CoilSpec(shape="spherical", wire_diameter_mm=0.254, loop_diameter_mm=2.0, length_mm=20.7),),
        catheter=wc.CatheterSpec(tip_mm=(0.0, 0.0, -0.75), direction=(0.0, 0.0, 1.0)),
        wall=wc.WallSpec(sphere_diameter_mm=2.0),
        simulation=wc.SimulationSettings(push_speed_mm_s=50.0, integrator="implicit", implicit_scheme=scheme))


def test_a_gated_chord_push_steps_finely_through_its_last_nodes_releases_and_they_do_not_ring_through_the_pack():
    """gated_chord (θ 0.65) opens the detachment frames DETACH_LEAD_SEGMENTS last edges early; Euler
    keeps the release frame. Without the lead the penultimate node's release snapped it ~50° in one push
    step and θ 0.65 rang that through the pack: coils −0.091 mm (3.6 c0) deep at a frame end (Euler
    −0.030 mm); with it −0.018 mm (docs/FORMULATION.md "Implicit step: the release lead")."""
    runs = {scheme: _run(scene=tiny_sac_scene(scheme)) for scheme in ("euler", "gated_chord")}
    firsts = {}
    for scheme, (result, deployment, levels, _advance) in runs.items():
        assert result.status == "completed"
        frame_s = deployment.members[0].frames[1].time_s - deployment.members[0].frames[0].time_s
        speed = deployment.scene.simulation.push_speed_mm_s
        arc = deployment.model.arc_s.numpy()
        lead_mm = (arc[-1] - arc[-1 - DETACH_LEAD_SEGMENTS]) if scheme == "gated_chord" else 0.0
        opens_s = (float(deployment.coil_lengths_mm[0]) - lead_mm) / speed  # the lead's first release
        firsts[scheme] = first = min(start for start, level in levels if level > 1)
        assert first <= opens_s + 1e-9 < first + frame_s  # the frame in which it falls
    assert firsts["gated_chord"] < firsts["euler"]
    c0 = runs["gated_chord"][1].model.contact.c0_mm
    assert runs["gated_chord"][0].min_coil_gap_mm > -c0  # −3.6 c0 without the lead
