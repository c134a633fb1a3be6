"""Contact pass: MODEL.md's exponential pressure–overclosure law (Abaqus form,
corrected), the one implementation used by coil–wall and coil–coil contact.

With clearance h (mm, > 0 apart) and u = 1 − h/c0::

    |F| = 0                                              h ≥ c0
    |F| = P0/(e−1) · u (e^u − 1)                         1 < u < 7
    |F| = P0/(e−1) · [7(e^7 − 1) + (8e^7 − 1)(u − 7)]     u ≥ 7

|F|(0) = P0, |F|(−6 c0) ≈ 4463.43 P0, value and slope continuous at u = 7.
"""

import warp as wp

E_MINUS_1 = wp.constant(wp.float64(1.718281828459045))
U_LINEAR = wp.constant(wp.float64(7.0))
F_AT_7 = wp.constant(wp.float64(7.0 * (1096.6331584284585 - 1.0)))  # 7 (e^7 − 1)
SLOPE_AT_7 = wp.constant(wp.float64(8.0 * 1096.6331584284585 - 1.0))  # 8 e^7 − 1


@wp.func
def contact_force_magnitude(h: wp.float64, p0: wp.float64, c0: wp.float64) -> wp.float64:
    """|F| (µN) at clearance h (mm) for force P0 (µN) at zero clearance and onset c0 (mm)."""
    if h >= c0:
        return wp.float64(0.0)
    u = wp.float64(1.0) - h / c0
    if u < U_LINEAR:
        return p0 / E_MINUS_1 * u * (wp.exp(u) - wp.float64(1.0))
    return p0 / E_MINUS_1 * (F_AT_7 + SLOPE_AT_7 * (u - U_LINEAR))


@wp.func
def contact_stiffness(h: wp.float64, p0: wp.float64, c0: wp.float64) -> wp.float64:
    """−d|F|/dh (µN/mm): the law's local stiffness."""
    if h >= c0:
        return wp.float64(0.0)
    u = wp.float64(1.0) - h / c0
    if u < U_LINEAR:
        return p0 / (E_MINUS_1 * c0) * (wp.exp(u) * (wp.float64(1.0) + u) - wp.float64(1.0))
    return p0 / (E_MINUS_1 * c0) * SLOPE_AT_7


@wp.kernel
def evaluate_law(
    h: wp.array(dtype=wp.float64), p0: wp.float64, c0: wp.float64,
    force: wp.array(dtype=wp.float64), stiffness: wp.array(dtype=wp.float64),
):
    """The law and its stiffness at each clearance (for validation and the step bound)."""
    i = wp.tid()
    force[i] = contact_force_magnitude(h[i], p0, c0)
    stiffness[i] = contact_stiffness(h[i], p0, c0)
