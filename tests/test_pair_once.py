"""Each coil–coil pair is evaluated once and added to both edges (kernels/contact.py
``edge_contact``): the forces equal, bit for bit, each edge's own evaluation of
every pair (``pair_contact`` from both sides), counts and gaps included."""

import numpy as np
import pytest
import warp as wp

import warpcoil as wc
from warpcoil.kernels import contact
from warpcoil.validation import _helix_spec


@wp.kernel
def both_sides(x: wp.array(dtype=wp.vec3d), rest_x: wp.array(dtype=wp.vec3d), coil_of: wp.array(dtype=wp.int32),
               free: wp.array(dtype=wp.int32), has_next: wp.array(dtype=wp.int32), fixed: wp.array(dtype=wp.int32),
               node_radius: wp.array(dtype=wp.float64), share: wp.array(dtype=wp.float64),
               samples: wp.array(dtype=wp.int32), mid: wp.array(dtype=wp.vec3d), exclusion: int, p0: wp.float64,
               c0: wp.float64, u_linear: wp.float64,
               far: wp.float64, force_start: wp.array(dtype=wp.vec3d), force_end: wp.array(dtype=wp.vec3d),
               contacts: wp.array(dtype=wp.int32)):
    """Edge a against every other edge (brute force), evaluated from a's side only."""
    a = wp.tid()
    total_start = contact.vec3l()
    total_end = contact.vec3l()
    touching = int(0)
    if contact.edge_in_contact_pass(free, has_next, a):
        reach_a = wp.float64(0.5) * wp.length(x[a + 1] - x[a]) + node_radius[a] + c0
        for b in range(x.shape[0]):
            if has_next[b] != 0 and not contact.bonded(coil_of, exclusion, a, b):
                s, e, gap, hit, bad = contact.pair_contact(x, rest_x, coil_of, free, has_next, fixed, node_radius,
                                                           share, samples, mid, a, b, exclusion, reach_a, p0, c0,
                                                           u_linear, far)
                total_start = total_start + s
                total_end = total_end + e
                touching += hit
    force_start[a] = contact.from_fixed(total_start)
    force_end[a] = contact.from_fixed(total_end)
    contacts[a] = touching


@pytest.mark.parametrize("segments_d, samples, touching", [(None, 1, 500), (1.9, 2, 200), (3.4, 4, 100)])
def test_pairs_evaluated_once_equal_both_sides_bit_for_bit(segments_d, samples, touching):
    """Two interleaved close-wound helices (every turn touching its neighbours and the
    other coil), jittered by 2 µm: over 250 touching pairs (fewer, longer edges above 1.5 d); with
    segments above 1.5 d, their contact samples between the nodes too."""
    helix = dict(length_mm=20.0, loop_diameter_mm=3.0, pitch_mm=0.2921 + 0.005)
    segment_mm = None if segments_d is None else segments_d * 0.2921
    builder = wc.ModelBuilder()
    builder.add_coil(_helix_spec(segment_mm, helix))
    builder.add_coil(_helix_spec(segment_mm, dict(helix, loop_diameter_mm=2.5)))
    model = builder.finalize()
    assert set(model.contact_samples.numpy()) == {samples}
    x = model.rest_positions + 2e-3 * np.random.default_rng(1).standard_normal(model.rest_positions.shape)
    state = wc.state_from_positions(model, x)
    solver = wc.Solver(model)
    solver.compute_contacts(state)
    n, c = model.node_count, model.contact
    start, end = wp.zeros(n, dtype=wp.vec3d), wp.zeros(n, dtype=wp.vec3d)
    contacts = wp.zeros(n, dtype=wp.int32)
    wp.launch(both_sides, n, inputs=[state.x, model.rest_x, model.coil_of, state.free, model.has_next, model.fixed,
                                     model.node_radius, model.contact_share, model.contact_samples, solver._midpoints,
                                     c.exclusion_edges,
                                     c.p0_uN, c.c0_mm, solver.contact_u_linear, c.query_radius_mm, start, end,
                                     contacts])
    assert solver.coil_contacts.numpy().sum() > touching  # touching pairs, each counted by both edges
    assert np.array_equal(solver.coil_contacts.numpy(), contacts.numpy())
    assert np.array_equal(solver._edge_force_start.numpy(), start.numpy())
    assert np.array_equal(solver._edge_force_end.numpy(), end.numpy())
