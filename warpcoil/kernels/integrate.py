"""Integration pass: semi-implicit Euler with implicit nonlinear damping, the
catheter/pusher kinematics, and the material-frame update.

Per free node (MODEL.md)::

    v* = v + dt F / m
    v' = v* − dt/m · c (1 − exp(−|v'|/k)) v'/|v'|      (solved exactly: v' ∥ v*)
    x' = x + dt v'

The damping is taken at the new velocity, so it never reverses a velocity
and adds no step-size limit; the conservative forces stay symplectic-Euler.
Nodes behind the catheter tip (catheter coordinate σ = advance − s < 0) are
placed on the catheter centerline and move with the pusher; clamped nodes
stay put.
"""

import warp as wp

from .rod import F64_0, F64_1, director_normal, edge_valid, rotate_about, transport


@wp.func
def damped_speed(speed: wp.float64, a: wp.float64, k: wp.float64) -> wp.float64:
    """Root s ≥ 0 of s + a (1 − exp(−s/k)) = speed (a = dt c/m, mm/s).

    The left side is increasing and concave, so Newton from the linearised
    root s0 = speed/(1 + a/k) (a lower bound) rises monotonically to the root.
    At most 6 iterations; it stops at the fixed point (an iterate that no longer
    changes, typically after 2: the iterations it skips would repeat it)."""
    if a <= F64_0 or speed <= F64_0:
        return speed
    s = speed / (F64_1 + a / k)
    for _ in range(6):
        e = wp.exp(-s / k)
        s_next = s - (s + a * (F64_1 - e) - speed) / (F64_1 + a / k * e)
        if s_next == s:
            break
        s = s_next
    return wp.max(s, F64_0)


@wp.func
def catheter_point(path: wp.array(dtype=wp.vec3d), first: int, count: int, depth: wp.float64):
    """Point and unit direction (towards the tip) on a catheter centerline at
    arc distance ``depth`` ≥ 0 behind the tip. The centerline is
    ``path[first:first + count]``, proximal → tip; beyond the proximal end the
    first segment is extended."""
    remaining = depth
    k = count - 1
    while k > 0:
        seg = path[first + k] - path[first + k - 1]
        length = wp.length(seg)
        direction = seg / length
        if remaining <= length or k == 1:
            return path[first + k] - remaining * direction, direction
        remaining = remaining - length
        k = k - 1
    return path[first + count - 1], wp.vec3d(F64_0, F64_0, F64_1)


@wp.func
def pushed(active_coil: wp.array(dtype=wp.int32), coil_world: wp.array(dtype=wp.int32), coil: int) -> bool:
    """The pusher of the coil's world drives its active coil and the coils waiting
    behind it in the catheter (so the next one arrives at the tip as the active
    one detaches)."""
    active = active_coil[coil_world[coil]]
    return active >= 0 and coil >= active


@wp.func
def coil_advance(advance: wp.array(dtype=wp.float64), active_coil: wp.array(dtype=wp.int32),
                 coil_world: wp.array(dtype=wp.int32), coil: int, push_step: wp.float64) -> wp.float64:
    a = advance[coil]
    if pushed(active_coil, coil_world, coil):
        a = a + push_step
    return a


@wp.func
def hold_node(
    i: int,
    x_in: wp.array(dtype=wp.vec3d),
    v_in: wp.array(dtype=wp.vec3d),
    free_in: wp.array(dtype=wp.int32),
    advance_in: wp.array(dtype=wp.float64),
    fixed: wp.array(dtype=wp.int32),
    coil_of: wp.array(dtype=wp.int32),
    world_of: wp.array(dtype=wp.int32),
    coil_world: wp.array(dtype=wp.int32),
    arc_s: wp.array(dtype=wp.float64),
    catheter_path: wp.array(dtype=wp.vec3d),
    catheter_first: wp.array(dtype=wp.int32),
    catheter_count: wp.array(dtype=wp.int32),
    active_coil: wp.array(dtype=wp.int32),
    push_speed: wp.array(dtype=wp.float64),
    running: wp.array(dtype=wp.int32),
    dt: wp.float64,
    x_out: wp.array(dtype=wp.vec3d),
    v_out: wp.array(dtype=wp.vec3d),
    free_out: wp.array(dtype=wp.int32),
    advance_out: wp.array(dtype=wp.float64),
) -> bool:
    """The part of node i's step that needs no force (both integrators): coil i's
    pusher advance (mm, for i < coils); a stopped world keeps its state, a clamped
    node rests, a node behind the catheter tip (σ < 0) sits on the centerline at
    the pusher's velocity. True when node i is free (free_out = 1; its x_out,
    v_out left to the caller)."""
    if i < advance_in.shape[0]:
        cw = coil_world[i]
        if running[cw] != 0:
            advance_out[i] = coil_advance(advance_in, active_coil, coil_world, i, push_speed[cw] * dt)
        else:
            advance_out[i] = advance_in[i]
    w = world_of[i]
    if running[w] == 0:
        x_out[i] = x_in[i]
        v_out[i] = v_in[i]
        free_out[i] = free_in[i]
        return False
    zero = wp.vec3d(F64_0, F64_0, F64_0)
    if fixed[i] != 0:
        x_out[i] = x_in[i]
        v_out[i] = zero
        free_out[i] = 0
        return False
    c = coil_of[i]
    sigma = coil_advance(advance_in, active_coil, coil_world, c, push_speed[w] * dt) - arc_s[i]
    if sigma < F64_0:
        p, direction = catheter_point(catheter_path, catheter_first[w], catheter_count[w], -sigma)
        x_out[i] = p
        if pushed(active_coil, coil_world, c):
            v_out[i] = push_speed[w] * direction
        else:
            v_out[i] = zero
        free_out[i] = 0
        return False
    free_out[i] = 1
    return True


@wp.kernel
def integrate_nodes(
    x_in: wp.array(dtype=wp.vec3d),
    v_in: wp.array(dtype=wp.vec3d),
    free_in: wp.array(dtype=wp.int32),
    advance_in: wp.array(dtype=wp.float64),
    force: wp.array(dtype=wp.vec3d),
    fixed: wp.array(dtype=wp.int32),
    coil_of: wp.array(dtype=wp.int32),
    world_of: wp.array(dtype=wp.int32),
    coil_world: wp.array(dtype=wp.int32),
    arc_s: wp.array(dtype=wp.float64),
    inv_mass: wp.array(dtype=wp.float64),
    damping_c: wp.array(dtype=wp.float64),
    damping_k: wp.float64,
    catheter_path: wp.array(dtype=wp.vec3d),
    catheter_first: wp.array(dtype=wp.int32),
    catheter_count: wp.array(dtype=wp.int32),
    active_coil: wp.array(dtype=wp.int32),
    push_speed: wp.array(dtype=wp.float64),
    running: wp.array(dtype=wp.int32),
    dt: wp.float64,
    x_out: wp.array(dtype=wp.vec3d),
    v_out: wp.array(dtype=wp.vec3d),
    free_out: wp.array(dtype=wp.int32),
    advance_out: wp.array(dtype=wp.float64),
):
    """One step of node i (and of coil i's pusher advance, mm, for i < coils):
    :func:`hold_node`, then a free node's damped semi-implicit Euler update."""
    i = wp.tid()
    if hold_node(i, x_in, v_in, free_in, advance_in, fixed, coil_of, world_of, coil_world, arc_s, catheter_path,
                 catheter_first, catheter_count, active_coil, push_speed, running, dt, x_out, v_out, free_out,
                 advance_out):
        v = v_in[i] + dt * inv_mass[i] * force[i]
        speed = wp.length(v)
        if speed > F64_0:
            v = v * (damped_speed(speed, dt * damping_c[i] * inv_mass[i], damping_k) / speed)
        v_out[i] = v
        x_out[i] = x_in[i] + dt * v


@wp.kernel
def update_frames(
    x_in: wp.array(dtype=wp.vec3d),
    x_out: wp.array(dtype=wp.vec3d),
    m1_in: wp.array(dtype=wp.vec3d),
    omega_in: wp.array(dtype=wp.float64),
    torque: wp.array(dtype=wp.float64),
    free_out: wp.array(dtype=wp.int32),
    fixed: wp.array(dtype=wp.int32),
    has_next: wp.array(dtype=wp.int32),
    inv_inertia: wp.array(dtype=wp.float64),
    twist_damping: wp.array(dtype=wp.float64),
    world_of: wp.array(dtype=wp.int32),
    running: wp.array(dtype=wp.int32),
    dt: wp.float64,
    m1_out: wp.array(dtype=wp.vec3d),
    omega_out: wp.array(dtype=wp.float64),
):
    """Carry each edge's director to its new tangent by parallel transport, then
    turn it about the tangent by its twist rate. An edge spins when each node is
    free or clamped and not both are clamped; edges with a node in the catheter
    (or parked) do not. Twist damping is linear and implicit:
    ω' = (ω + dt T/J) / (1 + dt b/J)."""
    i = wp.tid()
    if running[world_of[i]] == 0:
        m1_out[i] = m1_in[i]
        omega_out[i] = omega_in[i]
        return
    if not edge_valid(has_next, i):
        m1_out[i] = m1_in[i]
        omega_out[i] = F64_0
        return
    t_old = wp.normalize(x_in[i + 1] - x_in[i])
    t_new = wp.normalize(x_out[i + 1] - x_out[i])
    m = transport(m1_in[i], t_old, t_new)
    omega = F64_0
    held0 = fixed[i] != 0
    held1 = fixed[i + 1] != 0
    if (free_out[i] != 0 or held0) and (free_out[i + 1] != 0 or held1) and not (held0 and held1):
        inv_j = inv_inertia[i]
        omega = (omega_in[i] + dt * torque[i] * inv_j) / (F64_1 + dt * twist_damping[i] * inv_j)
        m = rotate_about(m, t_new, omega * dt)
    m1_out[i] = director_normal(m, t_new)
    omega_out[i] = omega


@wp.kernel
def kinetic_energies(
    v: wp.array(dtype=wp.vec3d),
    omega: wp.array(dtype=wp.float64),
    free: wp.array(dtype=wp.int32),
    inv_mass: wp.array(dtype=wp.float64),
    inv_inertia: wp.array(dtype=wp.float64),
    energy: wp.array(dtype=wp.float64),
    unhealthy: wp.array(dtype=wp.int32),
    speed_limit: wp.float64,
):
    """Kinetic energy (nJ) of free node i and of edge i's spin (zero unless it
    spins); flags a node whose velocity is non-finite or above ``speed_limit`` (mm/s)."""
    i = wp.tid()
    vi = v[i]
    speed_sq = wp.dot(vi, vi)
    bad = 0
    if not wp.isfinite(speed_sq) or speed_sq > speed_limit * speed_limit:
        bad = 1
    unhealthy[i] = bad
    e = wp.float64(0.5) * omega[i] * omega[i] / inv_inertia[i]
    if free[i] != 0:
        e = e + wp.float64(0.5) * speed_sq / inv_mass[i]
    energy[i] = e


@wp.kernel
def place_on_catheter(
    arc_s: wp.array(dtype=wp.float64),
    coil_of: wp.array(dtype=wp.int32),
    world_of: wp.array(dtype=wp.int32),
    advance: wp.array(dtype=wp.float64),
    catheter_path: wp.array(dtype=wp.vec3d),
    catheter_first: wp.array(dtype=wp.int32),
    catheter_count: wp.array(dtype=wp.int32),
    x: wp.array(dtype=wp.vec3d),
):
    """Packed positions: node i at depth −σ = s_i − advance behind its world's tip (σ ≤ 0)."""
    i = wp.tid()
    w = world_of[i]
    p, direction = catheter_point(catheter_path, catheter_first[w], catheter_count[w], arc_s[i] - advance[coil_of[i]])
    x[i] = p


@wp.kernel
def transported_directors(
    x: wp.array(dtype=wp.vec3d),
    coil_first: wp.array(dtype=wp.int32),
    coil_last: wp.array(dtype=wp.int32),
    first_director: wp.array(dtype=wp.vec3d),
    m1: wp.array(dtype=wp.vec3d),
):
    """Bishop (twist-free) directors along each coil: the first edge's director
    is given, each next one is the parallel transport of the previous. One
    thread per coil (the transport is sequential along the coil)."""
    c = wp.tid()
    first = coil_first[c]
    last = coil_last[c]
    t_prev = wp.normalize(x[first + 1] - x[first])
    d = director_normal(first_director[c], t_prev)
    m1[first] = d
    for i in range(first + 1, last):
        t = wp.normalize(x[i + 1] - x[i])
        d = director_normal(transport(d, t_prev, t), t)
        m1[i] = d
        t_prev = t
    m1[last] = d


@wp.func
def world_push_force(push_share: wp.array(dtype=wp.float64), world_node_range: wp.array2d(dtype=wp.int32), w: int):
    """World w's push force at the step's start (µN): Σ push shares of its nodes, in node order."""
    total = wp.float64(0.0)
    for i in range(world_node_range[w, 0], world_node_range[w, 1] + 1):
        total = total + push_share[i]
    return total


@wp.func
def add_push_reading(accumulator: wp.array2d(dtype=wp.float64), w: int, reading: wp.float64):
    """Adds a step's push force reading (µN) to accumulator[w, 0], keeps the step maximum
    (from 0: the peak compressive force) in accumulator[w, 1], adds its square to
    accumulator[w, 2] and counts the step in accumulator[w, 3]."""
    accumulator[w, 0] = accumulator[w, 0] + reading
    accumulator[w, 1] = wp.max(accumulator[w, 1], reading)
    accumulator[w, 2] = accumulator[w, 2] + reading * reading
    accumulator[w, 3] = accumulator[w, 3] + wp.float64(1.0)


@wp.kernel
def accumulate_push_force(push_share: wp.array(dtype=wp.float64), world_node_range: wp.array2d(dtype=wp.int32),
                          running: wp.array(dtype=wp.int32), accumulator: wp.array2d(dtype=wp.float64)):
    """One thread per running world: this step's push force (µN) = Σ push shares of its
    nodes, added to its accumulator (add_push_reading; a fixed-order sum, so the result
    does not depend on the device or on the other worlds; a world held while others
    step counts nothing)."""
    w = wp.tid()
    if running[w] == 0:
        return
    add_push_reading(accumulator, w, world_push_force(push_share, world_node_range, w))


@wp.kernel
def accumulate_blended_push_force(push_share: wp.array(dtype=wp.float64), world_node_range: wp.array2d(dtype=wp.int32),
                                  running: wp.array(dtype=wp.int32), theta: wp.float64,
                                  previous: wp.array2d(dtype=wp.float64), accumulator: wp.array2d(dtype=wp.float64)):
    """The θ-method's push force reading (θ < 1), one thread per running world: with P_n
    this step's push force (as accumulate_push_force) and P_{n−1} the previous step's
    (previous[w, 0], present where previous[w, 1] ≠ 0), the reading is
    (1 − θ) P_{n−1} + θ P_n, the push force at the θ-method's evaluation point x + θ Δx
    of the previous step: a stiff mode's step-to-step alternation (ratio −(1 − θ)/θ)
    cancels in it. Without a previous reading (the solver's first step) it is P_n.
    Stores P_n for the next step (docs/FORMULATION.md "Implicit step: the θ-method's
    push force reading")."""
    w = wp.tid()
    if running[w] == 0:
        return
    total = world_push_force(push_share, world_node_range, w)
    reading = total
    if previous[w, 1] != wp.float64(0.0):
        reading = (wp.float64(1.0) - theta) * previous[w, 0] + theta * total
    previous[w, 0] = total
    previous[w, 1] = wp.float64(1.0)
    add_push_reading(accumulator, w, reading)
