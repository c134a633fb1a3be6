"""Each edge's record of its same-coil partners' rest offsets (kernels/implicit.rest_offsets,
read by noted_rest_offset in the chord/tangent pair pass) gives, bit for bit, the offset
pair_rest_offset computes, for every pair that is not bonded: recorded, absent (0) and,
where the record overflowed, computed."""

import numpy as np
import pytest
import warp as wp

import warpcoil as wc
from warpcoil.kernels import implicit as kernels
from warpcoil.validation import _helix_spec

D = 0.2921


@wp.kernel
def both_ways(rest_x: wp.array(dtype=wp.vec3d), coil_of: wp.array(dtype=wp.int32), has_next: wp.array(dtype=wp.int32),
              node_radius: wp.array(dtype=wp.float64), exclusion: int, c0: wp.float64,
              rest_count: wp.array(dtype=wp.int32), rest_b: wp.array2d(dtype=wp.int32),
              rest_value: wp.array2d(dtype=wp.float64), computed: wp.array2d(dtype=wp.float64),
              noted: wp.array2d(dtype=wp.float64)):
    a, b = wp.tid()
    if has_next[a] != 0 and has_next[b] != 0 and not kernels.bonded(coil_of, exclusion, a, b):
        computed[a, b] = kernels.pair_rest_offset(rest_x, coil_of, node_radius, a, b, c0)
        noted[a, b] = kernels.noted_rest_offset(rest_count, rest_b, rest_value, rest_x, coil_of, node_radius, a, b,
                                                c0)


@pytest.mark.parametrize("width", [16, 2], ids=["recorded", "overflowing"])
def test_rest_offset_record_equals_the_computed_offset(width: int):
    """A close-wound helix (turns 5 µm apart at rest, within c0: offsets on both neighbouring
    turns) and a second coil (no offsets across coils)."""
    helix = dict(length_mm=20.0, loop_diameter_mm=3.0, pitch_mm=D + 0.005)
    builder = wc.ModelBuilder()
    builder.add_coil(_helix_spec(None, helix))
    builder.add_coil(_helix_spec(None, dict(helix, loop_diameter_mm=2.5)))
    model = builder.finalize()
    n, c = model.node_count, model.contact
    count = wp.zeros(n, dtype=wp.int32)
    partner = wp.zeros((n, width), dtype=wp.int32)
    value = wp.zeros((n, width), dtype=wp.float64)
    first = wp.array(model.coil_first, dtype=wp.int32)
    last = wp.array(model.coil_last, dtype=wp.int32)
    wp.launch(kernels.rest_offsets, n, inputs=[model.rest_x, model.coil_of, model.has_next, model.node_radius, first,
                                               last, c.exclusion_edges, c.c0_mm, count, partner, value])
    computed = wp.full((n, n), -1.0, dtype=wp.float64)
    noted = wp.full((n, n), -2.0, dtype=wp.float64)
    wp.launch(both_ways, (n, n), inputs=[model.rest_x, model.coil_of, model.has_next, model.node_radius,
                                         c.exclusion_edges, c.c0_mm, count, partner, value, computed, noted])
    computed, noted, count = computed.numpy(), noted.numpy(), count.numpy()
    pairs = computed >= 0.0
    assert np.array_equal(computed[pairs], noted[pairs])
    assert (computed[pairs] > 0.0).sum() > 100  # pairs with an offset, each found in the record or computed
    if width == 2:
        assert (count == kernels.OVERFLOW).sum() > 10
    else:
        assert (count == kernels.OVERFLOW).sum() == 0 and count.max() > 2
