"""Wall and device friction inside the implicit step's system.

A node pressed on a fixed obstacle (the wall, a balloon, a stent strut) with
normal force N along n feels regularised Coulomb friction
F_t = −μ N w / max(|w|, v_reg), w = (I − n nᵀ) v its tangential velocity. On the
implicit step this force is linearised about a tangential velocity w_k and solved
together with the stiff terms (its block joins the node's diagonal block, as the
damping law's dt β I does; its constant part joins the right side):

* stuck (|w_k| ≤ v_reg, or w_k turned back against a previous linearisation's slide): the
  law's linear part, a damper μ N / v_reg (I − n nᵀ) — exact while |w'| ≤ v_reg, and
  symmetric positive semi-definite, so it only takes kinetic energy out;
* sliding: Newton's linearisation −μ N ŵ_k − μ N/|w_k| (I − n nᵀ − ŵ_k ŵ_kᵀ) w':
  exactly μ N against the slip, a damper across it.

The velocity w is the one the block acts on: v' on Euler and BDF2 rows, the mean
(1 − θ_i) v + θ_i v' on a θ-method row. The step linearises about the old velocities (the
load at the step start), solves, linearises again about the solved ones (the wall's load
at the solved end, as the system's wall stiffness has it) and solves again (ImplicitSolver,
OBSTACLE_FRICTION_SOLVES). A stuck node whose load passes μ N thus slides in the same step,
and a sliding one that stops or turns back is held by the damper in the last solve. A node in a stiff chain
sticks against the chain's whole inertia and stiffness, as the law asks, instead of
against its own mass (kernels/friction.py's per-node law, which the symplectic
reference keeps).
"""

import warp as wp

from .friction import tangential
from .implicit import solving
from .rod import F64_0


@wp.func
def linearised_friction(f: wp.vec3d, v: wp.vec3d, previous: wp.vec3d, mu: wp.float64, v_reg: wp.float64):
    """Block (µN·s/mm) and constant force (µN) of the friction of an obstacle pushing
    with force f (N = |f|, n = f/N), linearised about the tangential part w of v;
    stuck where |w| ≤ v_reg or w turned back against ``previous`` (the last
    linearisation's w, where that slid); zero without a load. Also returns w."""
    load = wp.length(f)
    if load > F64_0:
        n = f / load
        slip = tangential(v, n)
        speed = wp.length(slip)
        plane = wp.identity(n=3, dtype=wp.float64) - wp.outer(n, n)
        turned = wp.dot(slip, previous) < F64_0 and wp.length(previous) > v_reg  # a slide turned back
        if speed <= v_reg or turned:
            return (mu * load / v_reg) * plane, wp.vec3d(F64_0, F64_0, F64_0), slip
        along = slip / speed
        return (mu * load / speed) * (plane - wp.outer(along, along)), -(mu * load) * along, slip
    return wp.mat33d(), wp.vec3d(F64_0, F64_0, F64_0), wp.vec3d(F64_0, F64_0, F64_0)


@wp.kernel
def obstacle_friction(
    v: wp.array(dtype=wp.vec3d),
    v_start: wp.array(dtype=wp.vec3d),
    free: wp.array(dtype=wp.int32),
    fixed: wp.array(dtype=wp.int32),
    world_of: wp.array(dtype=wp.int32),
    running: wp.array(dtype=wp.int32),
    wall_force: wp.array(dtype=wp.vec3d),
    wall_stiffness: wp.array(dtype=wp.mat33d),
    x_in: wp.array(dtype=wp.vec3d),
    x_out: wp.array(dtype=wp.vec3d),
    device_force: wp.array(dtype=wp.vec3d),
    mu: wp.float64,
    v_reg: wp.float64,
    dt: wp.float64,
    force_dt: wp.float64,
    mean_dt: wp.float64,
    fresh: int,
    rhs_scale: wp.float64,
    wall_block: wp.array(dtype=wp.mat33d),
    device_block: wp.array(dtype=wp.mat33d),
    wall_friction: wp.array(dtype=wp.vec3d),
    device_friction: wp.array(dtype=wp.vec3d),
    wall_slip: wp.array(dtype=wp.vec3d),
    device_slip: wp.array(dtype=wp.vec3d),
    diag: wp.array(dtype=wp.mat33d),
    diag_exact: wp.array(dtype=wp.mat33d),
    rhs: wp.array(dtype=wp.vec3d),
):
    """Node i's wall and device friction linearised about ``v`` (blocks C, forces f, the
    slips w they were taken at) into the per-contact arrays, the wall's load that at the
    step start (``fresh``) or at ``x_out`` by ``wall_stiffness`` (µN/mm) from ``x_in``
    (the device's: at the step start), about (x_out − x_in)/``mean_dt`` where that is > 0 and
    not ``fresh`` (the θ-method's (1 − θ_i) v + θ_i v', on which its rows' damping acts);
    dt (C − C_before) added to its diagonal blocks and ``force_dt`` (f − f_before) to its
    right side (``fresh``: nothing before, the blocks just assembled, no previous slip). The θ-method's right side, which
    holds −(1 − θ)/θ A v_start, also takes −``rhs_scale`` dt (C − C_before) v_start
    (``rhs_scale`` = (1 − θ)/θ after kernels.theta_start, else 0)."""
    i = wp.tid()
    zero = wp.vec3d(F64_0, F64_0, F64_0)
    if not solving(free, fixed, world_of, running, i):
        wall_block[i] = wp.mat33d()
        device_block[i] = wp.mat33d()
        wall_friction[i] = zero
        device_friction[i] = zero
        return
    before_wall = zero
    before_device = zero
    change = wp.mat33d()
    change_f = zero
    pressing = wall_force[i]
    about = v[i]
    if fresh == 0:  # in place of the last linearisation
        before_wall = wall_slip[i]
        before_device = device_slip[i]
        change = -(wall_block[i] + device_block[i])
        change_f = -(wall_friction[i] + device_friction[i])
        moved = x_out[i] - x_in[i]
        load = wp.length(pressing)
        if load > F64_0:  # the wall's load at the solved end, x_out (its linearisation, as the system has it)
            n = pressing / load
            pressing = wp.max(wp.dot(n, pressing - wall_stiffness[i] * moved), F64_0) * n
        if mean_dt > F64_0:
            about = moved / mean_dt
    c_wall, f_wall, s_wall = linearised_friction(pressing, about, before_wall, mu, v_reg)
    c_device, f_device, s_device = linearised_friction(device_force[i], about, before_device, mu, v_reg)
    change = dt * (change + c_wall + c_device)
    change_f = change_f + f_wall + f_device
    diag[i] = diag[i] + change
    diag_exact[i] = diag_exact[i] + change
    r = rhs[i] + force_dt * change_f
    if rhs_scale != F64_0:
        r = r - rhs_scale * (change * v_start[i])
    rhs[i] = r
    wall_block[i] = c_wall
    device_block[i] = c_device
    wall_friction[i] = f_wall
    device_friction[i] = f_device
    wall_slip[i] = s_wall
    device_slip[i] = s_device

