"""Chord contact stiffness of the implicit step (``contact_stiffness="chord"``,
kernels/chord.py): the law's secant between the gap at the step start and at the
predicted end, against the law evaluated at the two gaps (wall face, coil pair); its
limit, the tangent, as the predicted end nears the start; the tangent where the gap
opens; and a coil driven at a wall from outside the contact range at a long step."""

import numpy as np
import pytest

from test_ensemble import assert_same_run
from test_implicit import blocks_dense, implicit_scene
from test_implicit_devices import BALLOON_R, DT, R_NODE, edge_model
from test_implicit_devices import C0 as DEVICE_C0

from warpcoil.deploy import Deployment, Ensemble
from warpcoil.implicit import EULER, ImplicitSolver
from warpcoil.kernels.chord import CHORD_WALL_SKIP_C0
from warpcoil.solver import Control
from warpcoil.state import new_state_like, state_from_positions
from warpcoil.validation_chord import C0, law, pair_probe, throw_depth, wall_probe


@pytest.mark.parametrize("gap_c0, speed", [(1.5, 60.0), (0.5, 60.0), (-0.5, 20.0)])
def test_wall_chord_is_the_secant_of_the_law(gap_c0, speed):
    """On a flat face, closing: k_zz = (|F|(h̃) − |F|(h)) / (h − h̃), the finite-difference
    secant of the law between the step start and the predicted end (entering the range,
    within it, deep); nothing across the normal; steeper than the tangent (convex law)."""
    k, h, h_end, solver = wall_probe(gap_c0 * C0, speed, "chord")
    assert h_end < min(h, C0)
    secant = (law(solver, h_end) - law(solver, h))[0] / (h - h_end)
    assert k[2, 2] == pytest.approx(secant, rel=1e-9)
    assert np.abs(k - np.diag([0.0, 0.0, k[2, 2]])).max() <= 1e-9 * k[2, 2]
    tangent, _, _, _ = wall_probe(gap_c0 * C0, speed, "tangent")
    assert k[2, 2] > tangent[2, 2]


def test_wall_chord_keeps_the_tangent_when_opening_and_tends_to_it():
    """Moving away: the tangent, exactly; closing ever slower: the chord → the tangent,
    linearly in the closing; a node pressed on the wall that closes by less than
    CHORD_WALL_SKIP_C0 · c0 keeps the tangent exactly."""
    opening, _, _, _ = wall_probe(-0.5 * C0, -40.0, "chord")
    tangent, _, _, _ = wall_probe(-0.5 * C0, -40.0, "tangent")
    assert np.array_equal(opening, tangent)
    dt = 2e-4
    closings, errors = [], []
    for speed in (50.0, 5.0):
        k, h, h_end, _ = wall_probe(-0.5 * C0, speed, "chord", dt_s=dt)
        closings.append(h - h_end)
        errors.append(k[2, 2] / tangent[2, 2] - 1.0)
    assert closings[1] > float(CHORD_WALL_SKIP_C0) * C0
    assert errors[0] > errors[1] > 0.0
    assert errors[1] / errors[0] == pytest.approx(closings[1] / closings[0], rel=0.15)
    sliding, h, h_end, _ = wall_probe(-0.5 * C0, 0.5, "chord", dt_s=dt)
    assert 0.0 < h - h_end < float(CHORD_WALL_SKIP_C0) * C0
    assert np.array_equal(sliding, tangent)


EDGES = [0, 1, 3, 4]  # the two coils' edges (node 2 ends the first coil)


@pytest.mark.parametrize("gap_c0", [1.5, 0.5])
def test_pair_chord_is_the_secant_of_the_law(gap_c0):
    """A crossing coil pair closing from outside (or inside) the contact range: each edge
    pair's recorded stiffness is (|F|(h̃) − |F|(h)) / (h − h̃) of the law at the two gaps."""
    count, k, h, h_end, solver = pair_probe(gap_c0 * C0, 30.0, "chord")
    assert h_end < min(h, C0)
    assert list(count[EDGES]) == [2, 2, 2, 2]  # each edge touches both edges of the other coil
    secant = (law(solver, h_end) - law(solver, h))[0] / (h - h_end)
    np.testing.assert_allclose(k[EDGES, :2], secant, rtol=1e-9)
    tangent_count, tangent_k, _, _, _ = pair_probe(gap_c0 * C0, 30.0, "tangent")
    if gap_c0 > 1.0:
        assert list(tangent_count[EDGES]) == [0, 0, 0, 0]  # the tangent does not see the entering pair
    else:
        assert (k[EDGES, :2] > tangent_k[EDGES, :2]).all()


def test_pair_chord_keeps_the_tangent_when_opening():
    count, k, _, _, _ = pair_probe(0.5 * C0, -30.0, "chord")
    tangent_count, tangent_k, _, _, _ = pair_probe(0.5 * C0, -30.0, "tangent")
    assert np.array_equal(count, tangent_count) and np.array_equal(k[EDGES, :2], tangent_k[EDGES, :2])


def test_chord_stops_a_thrown_coil_no_deeper_than_the_energy_balance():
    """A straight coil thrown at a face from outside the contact range at 4 c0 per step: the
    tangent sees no contact and goes deeper than the energy balance allows; the chord stops
    shallower, short of it (conservative), and converges to it as the step shrinks."""
    tangent, balance = throw_depth("tangent", 4.0)
    chord, _ = throw_depth("chord", 4.0)
    assert tangent < balance - 0.5 * C0
    assert chord >= balance
    errors = [throw_depth("chord", advance)[0] - balance for advance in (1.0, 0.25)]
    assert 0.0 <= errors[1] < 0.5 * errors[0]


def device_part(strut_or_balloon: str, x, velocity, stiffness: str):
    """(M + dt² H) with the device less without it, over dt² (µN/mm), of one implicit step from
    positions ``x`` at ``velocity`` (the devices test's straight 2-edge coil, undamped)."""
    strut = ((-(R_NODE + 0.035), -2.0, 0.09), (-(R_NODE + 0.035), 2.0, 0.09))
    parts = []
    for with_device in (True, False):
        model, _ = edge_model(balloon=with_device and strut_or_balloon == "balloon",
                              strut=strut if with_device and strut_or_balloon == "strut" else None)
        solver = ImplicitSolver(model, dt_s=DT, **{**EULER, "contact_stiffness": stiffness})  # blocks: K, not K/θ
        state = state_from_positions(model, x)
        state.v.assign(np.tile(velocity, (model.node_count, 1)))
        solver.allocate_neighbour_grid(state)
        solver.step(state, new_state_like(model), Control.create(model))
        parts.append(blocks_dense(solver, model.node_count))
    return (parts[0] - parts[1]) / DT**2


@pytest.mark.parametrize("device", ["strut", "balloon"])
def test_device_chord_is_the_secant_of_the_law(device):
    """An edge across a stent strut (30 % along it), a coil beside a balloon, each closing
    on it from 1.5 c0 (outside the contact range) to −0.5 c0 in one step: the device's
    stiffness along the normal is the law's secant between the two gaps (k w wᵀ ⊗ n nᵀ
    for the strut, s_i k n nᵀ per node for the balloon); the tangent sees nothing."""
    model, rest = edge_model(balloon=False)
    gap, closing = 1.5 * DEVICE_C0, 2.0 * DEVICE_C0
    if device == "strut":  # the strut runs along y at x = −(R + r_strut), z = 0.09: edge 0, s = 0.3
        x, velocity = rest + [gap, 0.0, 0.0], [-closing / DT, 0.0, 0.0]
    else:  # the balloon: radius BALLOON_R about z
        x, velocity = rest + [BALLOON_R + R_NODE + gap, 0.0, 0.0], [-closing / DT, 0.0, 0.0]
    chord = device_part(device, x, velocity, "chord")
    tangent = device_part(device, x, velocity, "tangent")
    forces = law(ImplicitSolver(model, dt_s=DT), [gap, gap - closing])  # the solver's law (|F| = 0 beyond c0)
    secant = (forces[1] - forces[0]) / closing
    n = np.diag([1.0, 0.0, 0.0])
    if device == "strut":
        w = np.array([0.7, 0.3])
        expected = np.zeros_like(chord)
        expected[:6, :6] = secant * np.kron(np.outer(w, w), n)
    else:
        expected = np.kron(np.diag(model.contact_share.numpy()), secant * n)
    assert chord == pytest.approx(expected, rel=1e-9, abs=1e-9 * secant)
    assert np.abs(tangent).max() == 0.0


@pytest.mark.parametrize("chord_end", ["flight", "solve"])
def test_ensemble_members_equal_their_single_runs_with_the_chord(chord_end):
    """Gather-form chord passes and fixed-point sums: an ensemble member is its single run."""
    options = {"contact_stiffness": "chord", "chord_end": chord_end}
    scenes = [implicit_scene(angle_deg=0.0), implicit_scene(angle_deg=20.0, sac_diameter_mm=4.0)]
    results = Ensemble(scenes, solver_options=options).run()
    for s, member in zip(scenes, results):
        assert_same_run(Deployment(s, solver_options=options).run(), member)


def test_chord_options_are_checked():
    model, _ = edge_model(balloon=False)
    with pytest.raises(ValueError, match="contact_stiffness"):
        ImplicitSolver(model, dt_s=DT, contact_stiffness="secant")
    with pytest.raises(ValueError, match="chord_end"):
        ImplicitSolver(model, dt_s=DT, contact_stiffness="chord", chord_end="guess")
