"""The chord pair pass's candidate filters (kernels/implicit.edge_ends: partners swept
apart, the gap at x_end only for pairs in reach there and not farther out of range than
their nodes' moves, contact.relative_move; the contact pass's noted chord candidates,
contact.chord_candidate) skip only pairs that add nothing: the assembled
blocks and recorded pairs equal, bit for bit, those of the pass with every filter opened
(every listed partner evaluated at x and at x_end)."""

import math

import numpy as np
import pytest
import warp as wp

from test_implicit import implicit_scene

import warpcoil.implicit as implicit_module
from warpcoil.deploy import Deployment
from warpcoil.state import new_state_like

GATED_CHORD = {"theta": 0.7, "near_theta": 1.0, "contact_stiffness": "chord"}
OPEN_MM = 1.0e3  # a sweep, half-length and move no pair exceeds: no filter skips


@wp.kernel
def open_edge_ends(x: wp.array(dtype=wp.vec3d), x_end: wp.array(dtype=wp.vec3d), has_next: wp.array(dtype=wp.int32),
                   node_radius: wp.array(dtype=wp.float64), end_mid: wp.array(dtype=wp.vec3d),
                   end_half: wp.array(dtype=wp.float64), sweep: wp.array(dtype=wp.float64),
                   end_move: wp.array(dtype=wp.float64), node_move: wp.array(dtype=wp.vec3d)):
    e = wp.tid()
    node_move[e] = wp.vec3d(wp.float64(OPEN_MM) * wp.float64(e), wp.float64(0.0), wp.float64(0.0))  # apart ≥ OPEN_MM
    end_mid[e] = x_end[e]
    if has_next[e] != 0:
        end_mid[e] = wp.float64(0.5) * (x_end[e] + x_end[e + 1])
    end_half[e] = wp.float64(OPEN_MM) + node_radius[e]
    sweep[e] = wp.float64(OPEN_MM) + wp.length(x[e])
    end_move[e] = wp.float64(OPEN_MM)


def assembled(solver, state, scratch, control, edge_ends, noted: bool) -> list[np.ndarray]:
    """The chord pass's blocks and recorded pairs at ``state`` with ``edge_ends`` (``noted``:
    over the candidates the step's contact pass noted, else every listed partner)."""
    kernels = implicit_module.kernels
    real = kernels.edge_ends
    kernels.edge_ends = edge_ends
    try:
        theta, dt = solver.theta, solver.dt_s
        solver._assemble(state, scratch, control, solver._x_end, 1, solver.model.contact.p0_uN / theta, theta * dt,
                         math.sqrt(theta) * dt, noted=noted)
    finally:
        kernels.edge_ends = real
    count = solver._pair_count.numpy().copy()
    return [solver._stiff_start.numpy().copy(), solver._stiff_end.numpy().copy(), solver._diag.numpy().copy(), count,
            solver._pair_b.numpy().copy(), solver._pair_k.numpy().copy(), solver._pair_n.numpy().copy()]


def segment_gap(p1, q1, p2, q2) -> float:
    """Distance (mm) between segments p1q1 and p2q2 (contact.segment_closest_params' algorithm)."""
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a, e, f, c, b = d1 @ d1, d2 @ d2, d2 @ r, d1 @ r, d1 @ d2
    denom = a * e - b * b
    s = min(max((b * f - c * e) / denom, 0.0), 1.0) if denom > 1e-14 * a * e else 0.0
    t = (b * s + f) / e
    if t < 0.0:
        t, s = 0.0, min(max(-c / a, 0.0), 1.0)
    elif t > 1.0:
        t, s = 1.0, min(max((b - c) / a, 0.0), 1.0)
    return float(np.linalg.norm(p1 + s * d1 - p2 - t * d2))


def same_blocks_and_records(filtered: list[np.ndarray], opened: list[np.ndarray]) -> bool:
    """Equal blocks and, per edge, equal recorded pairs (the first ``count`` of a row: the
    rest of a row, and an overflowed row, hold what the order of the candidates left)."""
    if not all(np.array_equal(f, o) for f, o in zip(filtered[:4], opened[:4])):
        return False
    count = filtered[3]
    for row in np.nonzero(count > 0)[0]:
        if not all(np.array_equal(f[row, :count[row]], o[row, :count[row]]) for f, o in zip(filtered[4:], opened[4:])):
            return False
    return True


@pytest.mark.parametrize("overflowing", [False, True], ids=["records", "overflowing"])
def test_chord_pair_filters_change_nothing(overflowing: bool, monkeypatch):
    """``overflowing``: neighbour lists of 3 and chord records of 1, so most edges search
    the grid or walk their whole list (the overflow paths)."""
    options = dict(GATED_CHORD)
    if overflowing:
        monkeypatch.setattr(implicit_module, "CHORD_CANDIDATES_PER_EDGE", 1)
        options["neighbour_capacity"] = 3
    deployment = Deployment(implicit_scene(length_mm=12.0, sac_diameter_mm=2.5), solver_options=options)  # coils touch
    solver, control = deployment.solver, deployment.control
    scratch = new_state_like(deployment.model)
    seen = {"frames": 0, "pairs": 0, "skipped": 0, "unnoted": 0, "overflowed": 0, "searched": 0, "relative": 0}

    def on_frame(frame, state):
        solver.step(state, scratch, control)  # the contact pass, lists and predicted end at this state
        filtered = assembled(solver, state, scratch, control, implicit_module.kernels.edge_ends, True)
        mid, sweep = solver._midpoints.numpy(), solver._sweep.numpy()
        listed, partners = solver._neighbour_count.numpy(), solver._neighbours.numpy()
        noted = solver._chord_count.numpy()
        within = (noted <= solver._chord_b.shape[1]) & (listed > 0)
        seen["overflowed"] += int((noted > solver._chord_b.shape[1]).sum())
        seen["searched"] += int((listed < 0).sum())
        seen["unnoted"] += int((listed[within] - noted[within]).sum())
        c0 = deployment.model.contact.c0_mm
        x, radius = state.x.numpy(), deployment.model.node_radius.numpy()
        move, end_move = solver._node_move.numpy(), solver._end_move.numpy()
        for a in np.nonzero(listed > 0)[0]:
            d = mid[a] - mid[partners[a, :listed[a]]]
            seen["skipped"] += int(((d * d).sum(1) > (sweep[a] + sweep[partners[a, :listed[a]]] + c0) ** 2).sum())
            for b in partners[a, :listed[a]]:  # out of range by more than the relative move, not the moves' sum
                gap = segment_gap(x[a], x[a + 1], x[b], x[b + 1]) - radius[a] - radius[b]
                relative = max(np.linalg.norm(move[i] - move[j]) for i in (a, a + 1) for j in (b, b + 1))
                seen["relative"] += int(c0 + relative + 1e-6 < gap < c0 + end_move[a] + end_move[b])
        opened = assembled(solver, state, scratch, control, open_edge_ends, False)
        assert same_blocks_and_records(filtered, opened)
        seen["frames"] += 1
        seen["pairs"] += int(filtered[3][filtered[3] > 0].sum())

    deployment.run(on_frame)
    assert seen["frames"] > 5 and seen["pairs"] > 0, seen
    if overflowing:
        assert seen["overflowed"] > 0 and seen["searched"] > 0, seen
    else:
        assert seen["skipped"] > 0 and seen["unnoted"] > 0 and seen["relative"] > 0, seen
