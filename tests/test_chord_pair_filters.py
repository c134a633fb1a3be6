"""The chord pair pass's candidate filters (kernels/implicit.edge_ends: partners swept
apart, the gap at x_end only for pairs in reach there; the contact pass's noted chord
candidates, contact.chord_candidate) skip only pairs that add nothing: the assembled
blocks and recorded pairs equal, bit for bit, those of the pass with every filter opened
(every listed partner evaluated at x and at x_end)."""

import math

import numpy as np
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
                   end_move: wp.array(dtype=wp.float64)):
    e = wp.tid()
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


def test_chord_pair_filters_change_nothing():
    deployment = Deployment(implicit_scene(length_mm=12.0, sac_diameter_mm=3.0), solver_options=GATED_CHORD)
    solver, control = deployment.solver, deployment.control
    scratch = new_state_like(deployment.model)
    seen = {"frames": 0, "pairs": 0, "skipped": 0, "unnoted": 0}

    def on_frame(frame, state):
        solver.step(state, scratch, control)  # the contact pass, lists and predicted end at this state
        filtered = assembled(solver, state, scratch, control, implicit_module.kernels.edge_ends, True)
        mid, sweep = solver._midpoints.numpy(), solver._sweep.numpy()
        listed, partners = solver._neighbour_count.numpy(), solver._neighbours.numpy()
        noted = solver._chord_count.numpy()
        within = (noted <= solver._chord_b.shape[1]) & (listed > 0)
        seen["unnoted"] += int((listed[within] - noted[within]).sum())
        c0 = deployment.model.contact.c0_mm
        for a in np.nonzero(listed > 0)[0]:
            d = mid[a] - mid[partners[a, :listed[a]]]
            seen["skipped"] += int(((d * d).sum(1) > (sweep[a] + sweep[partners[a, :listed[a]]] + c0) ** 2).sum())
        opened = assembled(solver, state, scratch, control, open_edge_ends, False)
        for f, o in zip(filtered, opened):
            assert np.array_equal(f, o)
        seen["frames"] += 1
        seen["pairs"] += int(filtered[3][filtered[3] > 0].sum())

    deployment.run(on_frame)
    assert seen["frames"] > 5 and seen["pairs"] > 0 and seen["skipped"] > 0 and seen["unnoted"] > 0, seen
