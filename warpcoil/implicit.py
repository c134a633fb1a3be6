"""Linearly implicit θ-method (θ = 1: the linearly implicit Euler step of Baraff &
Witkin 1998) beside the reference symplectic Euler: the step is set by accuracy,
not by the stiffest spring.

The default scheme ("gated_chord"): θ 0.65, θ_i = 1 at nodes near an obstacle (``near_theta``)
or whose edges turn fast (``turn_gate_rad``), the chord contact stiffness, the pusher 0.8 c0 per
step; "euler" (θ = 1, linearly implicit Euler, no gate, the tangent contact stiffness) and
"bdf2" are named options (IMPLICIT_SCHEMES; scene key ``simulation.implicit_scheme``;
docs/FORMULATION.md "the turn gate", "Implicit step: gated_chord the default").

Forces, contact search, catheter kinematics and push accounting are the
reference's (for θ < 1 each step's push force reading is (1 − θ) P_{n−1} + θ P_n, the force
at the θ-method's evaluation point: Solver._accumulate_push_force); only the update differs
(kernels/implicit.py): per world,

    (M + θ dt B + θ² dt² H) v' = M v + dt F − (1 − θ) dt B v − θ (1 − θ) dt² H v
    x' = x + dt ((1 − θ) v + θ v')

(the forces linearised at x + θ Δx; v on the right at the solve's start: held nodes at their
new, prescribed velocities, so a catheter node's coupling is its step's own motion, and one
product A v gives both the right side and the start's residual: kernels.theta_start)
is solved by a few preconditioned conjugate-gradient
iterations (B: the damping law's secant coefficient at the old speed; H: stretching,
Gauss–Newton bending, contact along its normals, coil–coil pairs exactly;
preconditioner: each coil's banded block factorisation); then, at the new
positions, each coil's edge spins solve their tridiagonal system (backward Euler). Twist
is the fastest mode (inertia m r_w²: ω ≈ 7×10⁵ rad/s for the seed coil); at a step of
~100 µs the implicit spin update is overdamped, i.e. it relaxes the twist to its
equilibrium each step (quasi-static twist), which is what its negligible inertia means
physically. θ = 1 damps every mode it does not resolve, the slow bending modes of a coil
forced against a wall too: a numerical viscosity ≈ dt H that made a pushed coil bear on
the far wall and turned the push force's sign (docs/FORMULATION.md "Implicit step").

``method="bdf2"``: linearly implicit BDF2 (h = 2/3 dt, the Euler matrix at h, the history
x₋₁, v₋₁ carried in the State, an Euler start on a new or changed step): L-stable with
third-order slow-mode damping, but the push force stays Euler's (docs/FORMULATION.md
"Implicit step: BDF2"), so it is an option (θ 1, no gate, tangent stiffness unless given).

``near_theta``: the proximity-gated θ, θ_i = near_theta for a node that could reach an obstacle
within the step, θ elsewhere (kernels/node_theta.py; docs/FORMULATION.md "Implicit step:
proximity-gated θ"); None: every node at θ.

``contact_stiffness="chord"``: each contact's stiffness along its normal is the law's chord
between the step start and a predicted end (``chord_end``: the damped free flight, or the
tangent step's solution), where steeper than the tangent (kernels/chord.py): a contact that
enters during the step is seen (docs/FORMULATION.md "Implicit step: chord contact stiffness");
"tangent": the law's slope at the step start.

The contact law keeps the reference's linear onset (computed for the explicit
step), so both integrators integrate the same forces.
"""

from __future__ import annotations

import math

import warp as wp

from .devices import ImplicitDeviceStiffness
from .kernels import chord, friction_damping
from .kernels import implicit as kernels
from .kernels import node_theta
from .kernels import elastic
from .model import Model
from .settings import DEFAULT_DT_SAFETY, DEFAULT_IMPLICIT_SCHEME, SimulationSettings
from .solver import Control, Solver, contact_linear_onset
from .state import State
from .wall_field import GRAD_TOLERANCE

INTEGRATORS = ("symplectic", "implicit")
# default implicit step: the pusher advances this fraction of the contact onset c0 per step
# (accuracy, not stability, sets it: BENCHMARKS.md, bench accuracy)
IMPLICIT_ADVANCE_PER_C0 = 0.8
IMPLICIT_DT_MAX_S = 5.0e-4  # and never more than this (a released coil's damping time ~1.3 ms)
# finest settling step once every coil is out (no pusher to follow): the step the settling starts at,
# when the coil's end still whips at ~50 mm/s (docs/FORMULATION.md "Settling step")
IMPLICIT_SETTLE_DT_S = 2.0e-3
# the settling step grows while the fastest free node moves at most this fraction of c0 per step:
# no node crosses the contact range in one step (docs/FORMULATION.md "Settling step") ...
SETTLE_ADVANCE_PER_C0 = 1.0
# ... up to this: at 4–5 ms the seed coil's free distal tip runs a growing bend–twist oscillation
# (speed and edge spin ×1.6 a step, no contact near: the position/spin split amplifies it) that
# lengthens the settling 1.5–2×; none at 2.5 ms (docs/FORMULATION.md "Implicit step: the settling step")
IMPLICIT_SETTLE_DT_MAX_S = 2.5e-3
# ... both for segments of l0 ≥ d. Below, the oscillation sets in at shorter steps: a coil with l0 < d settles
# at both × (l0/d)^SETTLE_FINE_EXPONENT (settle_step_scale). Unscaled, a 40 mm loop of d 0.3 mm at l0 = d/2 in a
# wide sac gained bending and twist energy after its release (kinetic + elastic 69 → 1 577 nJ) and timed out
# unsettled; in an 8 mm sphere it still gained 301 nJ (on 3 012) at (l0/d)³ of the bounds, none at (l0/d)⁴, where
# it comes to rest as the reference does (0.61 against 0.62 s) (docs/FORMULATION.md "Implicit step: the settling
# step of fine segments")
SETTLE_FINE_EXPONENT = 4
# ... and for coils stiffer than the shipped ones: × SETTLE_RELAXATION_MAX_PER_S / λ where a coil's
# λ = EI v_d / (c d⁴) (settle_relaxation_per_s) is above it (a bend's force constant EI/l0³ against a node's
# low-speed damping c l0 / v_d, at l0 = d; (l0/d)⁴ is its own dependence on the segment). A 50 mm spherical
# coil of d 0.2921 mm at 10 × its derived EI (3e4 µN·mm², λ 8.2e6/s) gained up to +9 098 nJ in a frame after
# its release at the unscaled bounds (a 183 mN wall force, node centres 0.31 mm past the wall), at 5 × (λ 4.1e6)
# 47 rises of up to 90 nJ; at the scaled bounds none, settling in fewer steps. The shipped patient coils
# (d 0.381 mm, EI 1.72e4: λ 1.64e6) and every catalogue line lie at or below the limit: their runs are
# unchanged. Lower damping scales the bounds down too: the seed case at c 1 / 0.2 µN/mm took 3 476 / 5 312
# steps against 3 570 / 3 754 unscaled, completing and coming to rest sooner (1.5 against 2.8 s at 0.2; the
# twenty-third session's review) (docs/FORMULATION.md "Implicit step: the settling step of stiff coils")
SETTLE_RELAXATION_MAX_PER_S = 1.65e6
# ... but not for a member whose kinetic energy stops falling: a 6 mm framing coil in C0001 ran a
# steady oscillation at 2.5 ms (kinetic 0.031 nJ from 2.8 s to the 6 s timeout) and came to rest
# at ≤ 2 ms. A member whose frame kinetic energy fell by less than SETTLE_STALL_DROP over the last
# SETTLE_STALL_S of settling (a decay at the slowest measured rate, τ = 0.3 s, falls to 4 % in 0.5 s;
# the seed case's plateaus while it creeps last ~0.1 s) settles at the finest step for the rest of
# the run (docs/FORMULATION.md "Implicit step: the settling step")
SETTLE_STALL_S = 0.5
SETTLE_STALL_DROP = 0.1
# ... and, stalled again over SETTLE_STALL_S at that step, at half of it, up to SETTLE_REFINE_MAX times in all
# (finest / 4): C0091 tilted 0.01° ran its filling coil's free tip in place at 50 mm/s (2.3 nJ) at 2 ms from
# 4.2 s to the 8 s timeout, and comes to rest at 1 ms (docs/SCENES.md "C0031's one deep wall overlap")
SETTLE_REFINE_MAX = 3
# ... and a settling frame in which a member's kinetic + elastic energy rose by more than SETTLE_RISE_NJ and
# SETTLE_RISE_FRACTION of it (nothing drives a settling coil: damping only takes energy out; what the contact's
# own, uncounted energy gives back stays below that) is redone from its start at half the member's step, as
# often as it rises, up to SETTLE_RISE_REFINE_MAX refinements in all (finest / 32). The linearly implicit
# step about a coil at rest can itself grow a mode: an 8 mm helix of d 0.381 mm released in a 3.5 mm sphere,
# at rest 0.06 s, then whirled at 2.5 ms steps (+4 870 nJ, kinetic 460 nJ for 0.9 s, `completed`); a
# derived 18-system coil (EI 6.2e4 µN·mm²) rose 11.8 nJ in a contact-free frame (the twenty-fourth session's
# physicist's; docs/FORMULATION.md "Implicit step: a settling frame that gains energy")
SETTLE_RISE_NJ = 1.0
# ... of SETTLE_RISE_QUIET_NJ where the frame started with no contact at all (no contact energy to give back):
# a coil settling free of wall and coil gained 0.1–0.38 nJ a frame at ~1 nJ (+141 % over four frames: a curved
# catheter's release, a physicist's audit), below the 1 nJ floor, where a finer step or the reference gain none
SETTLE_RISE_QUIET_NJ = 0.01
SETTLE_RISE_FRACTION = 1e-3
SETTLE_RISE_REFINE_MAX = 6
# detachment step: a push frame in which a coil's tail leaves the catheter, and those up to DETACH_WHIP_S after
# its last node's release (the whip's measured duration: 10–15 ms on C0031 and the seed case), run at dt / k,
# k whole: the fewest steps in which the pusher moves at most DETACH_ADVANCE_PER_C0 · c0 per step (a quarter of
# the default push step), so a tail whipping at up to 18× the push speed (C0031's measured peak at fine steps,
# 1.4–1.8 m/s at 100 mm/s) moves at most 3.6 c0 per step. Measured, the deepest overlap while the tail whips
# against k: within 0.1 c0 of k = 8's from k = 3 on (C0031), within 0.3 c0 of k = 16's from k = 4 on (a 4 mm
# helix into a 3.5 mm sphere; k = 2 and 3 were 1.5 and 0.8 c0 deeper than the push step's, whose numerical
# damping slows the whip) (docs/FORMULATION.md "Implicit step: the detachment step")
DETACH_WHIP_S = 0.015
# ... and on the θ-method below θ 1 (gated_chord) from DETACH_LEAD_SEGMENTS of the coil's last edges before that
# frame: releasing the last nodes snaps them toward the pre-shape in one push step (an edge turned ~50° and
# stretched 40-70 % by the straight-line step), which Euler's step removes at once but θ 0.65 returns at 0.54 a
# step with the sign flipped: in a 2 mm sphere the penultimate node's release rang through the pack (kinetic
# energy 13 → 998 nJ in two steps, coils 0.18 mm (7 c0) deep, −0.091 mm at the frame end; Euler −0.030 mm);
# resolved at dt / k from two edges before, −0.018 mm (docs/FORMULATION.md "Implicit step: the release lead")
DETACH_LEAD_SEGMENTS = 2
DETACH_ADVANCE_PER_C0 = 0.2
DETACH_LEVEL_MAX = 16
# coil–coil neighbour skin (mm): a step moves a node ~12 × farther than the explicit one, so the grid
# is rebuilt less often with a wider skin (the fixed-point sums keep every force bit-identical)
IMPLICIT_NEIGHBOUR_SKIN_MM = 0.2
# θ of the linearly implicit θ-method (1: linearly implicit Euler; the default 0.65, gated_chord's: its push force is
# within 0.25 F0 of the finest reference where Euler's numerical damping is 0.53 F0 off). Below 1 the straight-line
# step's error on fast-turning edges (their stretch α²/2) is returned instead of removed: ungated θ 0.65 blows up a
# helix pushed slowly into free space, Euler does not; the turn gate (TURN_GATE_RAD) steps those nodes at θ 1
# (docs/FORMULATION.md "Unseen cases", "Implicit step: the turn gate"). A deployment settles with θ = 1
# (deploy.Ensemble._settle_step; docs/FORMULATION.md "Implicit step: push force and the θ-method")
IMPLICIT_THETA = 0.65
# θ once nothing is pushed (deploy.Ensemble._settle_step): the θ-method at 0.65 (gated_chord) damps the stiff modes by only
# (1 − θ)/θ = 0.54 a step and brings a free coil to rest slowly (the 60 mm helix recovered from straight at the
# default step: 62 000 steps against Euler's 3 000); Euler (θ 1) settles it, with the gate a no-op and the chord on
IMPLICIT_SETTLE_THETA = 1.0
# proximity-gated θ (solver option near_theta): θ_i = near_theta (1: the node moves with its new velocity alone) for
# every node whose wall, stent strut, balloon or other coil edge lies within the contact range c0 plus a margin
# PROXIMITY_MARGIN_C0 · c0 + |v_i| dt of its surface at the step start, θ elsewhere (kernels/node_theta.py;
# docs/FORMULATION.md "Implicit step: proximity-gated θ"). The default 1 (gated_chord); None: every node at θ
IMPLICIT_NEAR_THETA: float | None = 1.0
PROXIMITY_MARGIN_C0 = 2.0
# the turn gate of a gated run (solver option turn_gate_rad): θ_i = near_theta also for every node whose edge turns by
# more than this angle in the step at the step start's velocities. The linearly implicit step moves nodes on straight
# lines, so an edge turning α a step is stretched by ≈ α²/2 of its length, an error in the stiffest springs that
# θ 0.65 returns at 0.54 a step where Euler removes it: at the curling front of a slowly pushed helix it grew into
# strains of 1–8 % and kinetic energy of 64 µJ (Euler 18.5 nJ). Stable from 0.003 to 0.03 rad; 0.01 keeps
# the seed's push force (docs/FORMULATION.md "Implicit step: the turn gate"). 0: no turn gate
TURN_GATE_RAD = 0.01
# the implicit step's scheme: "theta" (the θ-method above) or "bdf2" (linearly implicit BDF2, L-stable; not the
# default: its push force is Euler's, and at 1.6–2.4 c0 it presses deeper into C0020's wall than Euler at 0.8 c0;
# docs/FORMULATION.md "Implicit step: BDF2"). BDF2 takes θ 1, no gate and the tangent stiffness unless told otherwise:
# the θ-method's defaults above are not its (BDF2_DEFAULTS)
IMPLICIT_METHODS = ("theta", "bdf2")
IMPLICIT_METHOD = "theta"
BDF2_SCALE = 2.0 / 3.0  # BDF2's implicit coefficient h = 2/3 dt
CG_ITERATIONS = 3  # conjugate-gradient iterations per step (benchmarked: BENCHMARKS.md)
# solves a step with wall or device friction: linearised about the old velocities, then about the solved ones
OBSTACLE_FRICTION_SOLVES = 2
# ... in a world whose pusher drives a coil (a solver option, push_cg_iterations; fewer there do not add
# steps, the pusher sets them): 1 or 2 keep the seed case's shape and push force but let coils overlap
# deeper in dense patient packs (C0031's smallest coil gap −0.048 → −0.061 / −0.092 mm at 2 / 1), so
# the default is all of them (docs/FORMULATION.md "Conjugate-gradient iterations while pushing")
PUSH_CG_ITERATIONS = CG_ITERATIONS
# each contact's stiffness along its normal: "tangent" (the law's slope at the step start) or "chord" (the law's
# secant between the step start and the predicted end, where steeper: contacts that enter during the step are
# seen; kernels/chord.py, docs/FORMULATION.md "Implicit step: chord contact stiffness"). The default: "chord"
CONTACT_STIFFNESS = ("tangent", "chord")
IMPLICIT_CONTACT_STIFFNESS = "chord"
# the chord's predicted end: "flight" (each node's damped free flight x + dt m v/(m + dt β): no extra solve) or
# "solve" (the tangent step's solution: a second assembly and solve per step; sees force-driven approaches too)
CHORD_ENDS = ("flight", "solve")
CHORD_END = "flight"
CHORD_END_CG_ITERATIONS = 1  # conjugate-gradient iterations of the "solve" end's first solve (a predictor)
PAIRS_PER_EDGE = 16  # touching coil–coil pairs recorded per edge for the exact contact product
# same-coil partners with a nonzero rest offset recorded per edge (kernels.rest_offsets; more: computed per pair):
# a close-wound helix (turns 5 µm apart at rest) ≤ 6 an edge, the seed case's spherical coil none
REST_PARTNERS_PER_EDGE = 16
# chord candidates the contact pass notes per edge for the chord pass (more: it walks the edge's neighbour list;
# seed case late in the push: ≤ 12 an edge; docs/FORMULATION.md "Implicit step: the chord pass over noted candidates")
CHORD_CANDIDATES_PER_EDGE = 32
# the implicit step's named schemes (scene key simulation.implicit_scheme; solver options): "gated_chord" the θ-method
# defaults above (θ 0.65 with the proximity and turn gates, the chord stiffness: the push force within 0.25 F0 of the
# finest reference and free releases that come to rest in their helix at 0.8 c0, at ~1.1–1.25× Euler's run time;
# docs/FORMULATION.md "Implicit step: gated_chord the default"), "euler" linearly implicit Euler with the tangent
# stiffness (stable without gates, but its numerical damping bends the push force 0.53 F0 off and tangles a fast
# free release), "bdf2" linearly implicit BDF2 (tangent)
GATED_CHORD = {"method": "theta", "theta": IMPLICIT_THETA, "near_theta": IMPLICIT_NEAR_THETA,
               "contact_stiffness": IMPLICIT_CONTACT_STIFFNESS}  # the θ-method defaults above
EULER = {"method": "theta", "theta": 1.0, "near_theta": None, "contact_stiffness": "tangent"}
BDF2_DEFAULTS = {key: EULER[key] for key in ("theta", "near_theta", "contact_stiffness")}  # Euler's
IMPLICIT_SCHEMES = {
    "euler": EULER,
    "gated_chord": GATED_CHORD,
    "bdf2": {"method": "bdf2", **BDF2_DEFAULTS},
}
_UNSET = object()  # a solver option not given: the method's default


def scheme_options(scheme: str) -> dict:
    """The solver options of a named scheme (IMPLICIT_SCHEMES): none for the default
    (options given beside it then take their method's defaults)."""
    if scheme not in IMPLICIT_SCHEMES:
        raise ValueError(f"implicit_scheme must be one of {tuple(IMPLICIT_SCHEMES)}, got {scheme!r}")
    return {} if scheme == DEFAULT_IMPLICIT_SCHEME else dict(IMPLICIT_SCHEMES[scheme])


def implicit_step_s(model: Model, push_speed_mm_s: float) -> float:
    """Default implicit step (s): the pusher moves IMPLICIT_ADVANCE_PER_C0 · c0 per
    step, at most IMPLICIT_DT_MAX_S."""
    return min(IMPLICIT_ADVANCE_PER_C0 * model.contact.c0_mm / max(push_speed_mm_s, 1e-9), IMPLICIT_DT_MAX_S)


def settle_relaxation_per_s(coil, sim: SimulationSettings) -> float:
    """λ = EI v_d / (c d⁴) (1/s) of a coil (CoilSpec) in ``sim``'s damping (c = damping_uN_per_mm, which
    mass_scale leaves alone; v_d = damping_speed_mm_s): the rate at which the damping relaxes a bend
    over segments of d; 0 without damping (no relaxation to scale by: its bounds stay those of l0)."""
    damping = sim.damping_uN_per_mm
    if damping <= 0.0:
        return 0.0
    return coil.EI * sim.damping_speed_mm_s / (damping * coil.d ** 4)


def settle_step_scale(coils, sim: SimulationSettings) -> float:
    """Factor (≤ 1) on the settling steps' bounds for these coils (CoilSpec) in ``sim``'s damping: the
    smallest over the coils of (l0/d)^SETTLE_FINE_EXPONENT where l0 < d, times SETTLE_RELAXATION_MAX_PER_S /
    λ where a coil's λ (settle_relaxation_per_s, at segments of d) is above it; 1 for the shipped coils. The
    two factors multiply: the fine segments' was measured at the derived stiffness, and λ at l0 > d is not
    reduced (both conservative)."""
    def stiff(coil) -> float:
        rate = settle_relaxation_per_s(coil, sim)
        return SETTLE_RELAXATION_MAX_PER_S / rate if rate > SETTLE_RELAXATION_MAX_PER_S else 1.0

    return min([1.0] + [min(1.0, c.l0 / c.d * (1.0 + 1e-9)) ** SETTLE_FINE_EXPONENT * stiff(c) for c in coils])


def settle_step_s(push_dt_s: float, frame_interval_s: float, scale: float = 1.0) -> float:
    """Finest default implicit step (s) after the push: the largest frame / (2 k) (k whole:
    every settling step splits a frame evenly) up to ``scale`` × IMPLICIT_SETTLE_DT_S
    (settle_step_scale), never below the push's step."""
    return max(frame_interval_s / (2 * settle_finest_level(frame_interval_s, scale)), push_dt_s)


def settle_finest_level(frame_interval_s: float, scale: float = 1.0) -> int:
    """Steps per half frame at the finest settling step (≤ ``scale`` × IMPLICIT_SETTLE_DT_S)."""
    return max(1, math.ceil(frame_interval_s / (2.0 * scale * IMPLICIT_SETTLE_DT_S) - 1e-9))


def settle_stalled(kinetic_nJ: list[float], frame_interval_s: float) -> bool:
    """Whether a settling member's kinetic energy (nJ, one value per frame of
    ``frame_interval_s``, oldest first) fell by less than SETTLE_STALL_DROP over its last
    SETTLE_STALL_S of simulated time."""
    frames = max(1, math.ceil(SETTLE_STALL_S / frame_interval_s - 1e-9))
    if len(kinetic_nJ) <= frames:
        return False
    return kinetic_nJ[-1] > (1.0 - SETTLE_STALL_DROP) * kinetic_nJ[-1 - frames]


def settle_energy_rose(before_nJ: float, after_nJ: float, contact_free: bool = False) -> bool:
    """Whether a settling frame's kinetic + elastic energy (nJ) rose past its tolerance: by more than
    SETTLE_RISE_NJ (SETTLE_RISE_QUIET_NJ for a frame that started ``contact_free``) and SETTLE_RISE_FRACTION
    of ``before_nJ``."""
    floor = SETTLE_RISE_QUIET_NJ if contact_free else SETTLE_RISE_NJ
    return after_nJ - before_nJ > max(floor, SETTLE_RISE_FRACTION * before_nJ)


def settle_level(speed_mm_s: float, c0_mm: float, frame_interval_s: float, scale: float = 1.0) -> int:
    """Steps per half frame of the settling step for a world whose fastest free node moves
    at ``speed_mm_s`` (mm/s): the fewest (the longest step frame / (2 k)) that move it at
    most SETTLE_ADVANCE_PER_C0 · c0 (mm), from the coarsest level (a step up to
    ``scale`` × IMPLICIT_SETTLE_DT_MAX_S: settle_step_scale) to the finest."""
    finest = settle_finest_level(frame_interval_s, scale)
    coarsest = min(max(1, math.ceil(frame_interval_s / (2.0 * scale * IMPLICIT_SETTLE_DT_MAX_S) - 1e-9)), finest)
    if not math.isfinite(speed_mm_s):
        return finest
    wanted = math.ceil(frame_interval_s * speed_mm_s / (2.0 * SETTLE_ADVANCE_PER_C0 * c0_mm) - 1e-9)
    return min(max(wanted, coarsest), finest)


def detach_level(push_speed_mm_s: float, dt_s: float, c0_mm: float) -> int:
    """Steps per push step in a detachment frame (1: none added): the fewest in which the
    pusher (``push_speed_mm_s``, mm/s) moves at most DETACH_ADVANCE_PER_C0 · ``c0_mm`` per
    step of ``dt_s`` / k, at most DETACH_LEVEL_MAX (4 at the default push step)."""
    wanted = math.ceil(push_speed_mm_s * dt_s / (DETACH_ADVANCE_PER_C0 * c0_mm) - 1e-9)
    return min(max(wanted, 1), DETACH_LEVEL_MAX)


def implicit_options(method: str, theta=_UNSET, near_theta=_UNSET, contact_stiffness=_UNSET
                     ) -> tuple[float, float | None, str]:
    """(θ, near_theta, contact stiffness) of ``method``: the options given, the others
    that method's defaults (θ-method: IMPLICIT_THETA, IMPLICIT_NEAR_THETA,
    IMPLICIT_CONTACT_STIFFNESS; BDF2: BDF2_DEFAULTS)."""
    defaults = BDF2_DEFAULTS if method == "bdf2" else IMPLICIT_SCHEMES[DEFAULT_IMPLICIT_SCHEME]
    given = {"theta": theta, "near_theta": near_theta, "contact_stiffness": contact_stiffness}
    chosen = {key: defaults[key] if value is _UNSET else value for key, value in given.items()}
    return chosen["theta"], chosen["near_theta"], chosen["contact_stiffness"]


class ImplicitSolver(Solver):
    """A :class:`Solver` whose step is the linearly implicit θ-method (by default gated_chord:
    θ 0.65, proximity and turn gates, chord contact stiffness; linearly implicit Euler is
    ``**EULER`` — θ 1, ``near_theta`` None, tangent — or the scheme name "euler": ``theta=1``
    alone keeps the gates, a no-op at θ 1, and the chord) or BDF2 (module docstring).

    ``dt_s`` has no stability limit; the contact law's linear onset is the one the
    reference takes at ``dt_safety`` × its explicit bound."""

    integrator = "implicit"
    record_touching = True
    kernel_modules = Solver.kernel_modules + (kernels, chord, node_theta, friction_damping)

    def __init__(self, model: Model, dt_s: float, dt_safety: float = DEFAULT_DT_SAFETY, coil_contact: bool = True,
                 cg_iterations: int = CG_ITERATIONS, push_cg_iterations: int = PUSH_CG_ITERATIONS,
                 theta: float = _UNSET, method: str = IMPLICIT_METHOD,
                 near_theta: float | None = _UNSET, proximity_margin_c0: float = PROXIMITY_MARGIN_C0,
                 turn_gate_rad: float = TURN_GATE_RAD, contact_stiffness: str = _UNSET, chord_end: str = CHORD_END,
                 **kwargs):
        theta, near_theta, contact_stiffness = implicit_options(method, theta, near_theta, contact_stiffness)
        kwargs.pop("allow_unstable_dt", None)
        kwargs.setdefault("neighbour_skin_mm", IMPLICIT_NEIGHBOUR_SKIN_MM)
        super().__init__(model, dt_s=None, dt_safety=dt_safety, coil_contact=coil_contact, **kwargs)
        self.contact_u_linear = contact_linear_onset(model, self.dt_s)  # the reference's law
        self.dt_s = float(dt_s)
        n, dev = model.node_count, model.device
        mats = lambda: wp.zeros(n, dtype=wp.mat33d, device=dev)  # noqa: E731
        vecs = lambda: wp.zeros(n, dtype=wp.vec3d, device=dev)  # noqa: E731
        if cg_iterations < 1:
            raise ValueError(f"cg_iterations must be ≥ 1, got {cg_iterations}")
        self.cg_iterations = int(cg_iterations)
        if not 1 <= push_cg_iterations:
            raise ValueError(f"push_cg_iterations must be ≥ 1, got {push_cg_iterations}")
        self.push_cg_iterations = min(int(push_cg_iterations), self.cg_iterations)
        self._settling = wp.zeros(model.world_count, dtype=wp.int32, device=dev)
        if not 0.5 < theta <= 1.0:
            raise ValueError(f"theta must be in (0.5, 1] (1: linearly implicit Euler), got {theta}")
        self.theta = float(theta)
        if method not in IMPLICIT_METHODS:
            raise ValueError(f"method must be one of {IMPLICIT_METHODS}, got {method!r}")
        if method == "bdf2" and theta != 1.0:
            raise ValueError(f"theta applies to the θ-method only; BDF2 needs theta = 1, got {theta}")
        self.method = method
        if near_theta is not None and not (0.5 < near_theta <= 1.0 and method == "theta"):
            raise ValueError(f"near_theta applies to the θ-method and must be in (0.5, 1] (taken as at least θ), got "
                             f"{near_theta} with method {method!r}")
        self.near_theta = None if near_theta is None else float(near_theta)
        self.proximity_margin_mm = float(proximity_margin_c0) * model.contact.c0_mm
        if not turn_gate_rad >= 0.0:  # NaN too
            raise ValueError(f"turn_gate_rad must be ≥ 0 (0: no turn gate; it applies with near_theta only), got "
                             f"{turn_gate_rad}")
        self.turn_gate_rad = float(turn_gate_rad)
        self.node_theta = wp.zeros(n, dtype=wp.float64, device=dev)  # per node: its θ_i in the last step
        self._obstacles = self.has_wall or self.has_balloon or self.has_stent  # what friction must not push into
        # wall and device friction: linearised in the step's system (kernels/friction_damping.py)
        self.obstacle_friction = self.friction and model.contact.friction_wall > 0.0 and self._obstacles
        friction_nodes = n if self.obstacle_friction else 1
        # per node and contact (wall, device): the linearisation's block (µN·s/mm), force (µN), slip (mm/s)
        self._wall_block, self._device_block = (wp.zeros(friction_nodes, dtype=wp.mat33d, device=dev)
                                                for _ in range(2))
        self._wall_friction, self._device_friction, self._wall_slip, self._device_slip = (
            wp.zeros(friction_nodes, dtype=wp.vec3d, device=dev) for _ in range(4))
        # the coil pairs' law then counts no wall or device contact in its shares (Solver._friction_law)
        self._no_obstacle_force = wp.zeros(friction_nodes if self.coil_friction else 1, dtype=wp.vec3d, device=dev)
        if contact_stiffness not in CONTACT_STIFFNESS:
            raise ValueError(f"contact_stiffness must be one of {CONTACT_STIFFNESS}, got {contact_stiffness!r}")
        self.chord = contact_stiffness == "chord"
        if chord_end not in CHORD_ENDS:
            raise ValueError(f"chord_end must be one of {CHORD_ENDS}, got {chord_end!r}")
        self.chord_end = chord_end
        self._x_end = vecs() if self.chord else None  # the chord's predicted end (mm)
        self._end_mid = vecs()  # per edge at the predicted end: midpoint (mm), half-length + radius (mm)
        self._end_half = wp.zeros(n, dtype=wp.float64, device=dev)
        self._sweep = wp.zeros(n, dtype=wp.float64, device=dev)  # per edge: kernels.edge_ends (mm)
        self._end_move = wp.zeros(n, dtype=wp.float64, device=dev)  # per edge: kernels.edge_ends (mm)
        self._node_move = vecs()  # per node: kernels.edge_ends (mm)
        # the free-flight end is known before the contact pass, which then notes the chord candidates (Solver)
        self._noted_chord = self.chord and chord_end == "flight" and self.coil_contact
        self._chord_b = wp.zeros((n, CHORD_CANDIDATES_PER_EDGE if self._noted_chord else 1), dtype=wp.int32, device=dev)
        self._chord_st = wp.zeros(self._chord_b.shape, dtype=wp.vec2d, device=dev)  # their closest-point parameters
        self._diag, self._diag_exact, self._upper1, self._upper2 = mats(), mats(), mats(), mats()
        self._inv_d, self._lower1, self._lower2 = mats(), mats(), mats()
        self._stiff_start, self._stiff_end = mats(), mats()
        self.wall_stiffness = mats()  # per node: the wall's contact stiffness at P0 (µN/mm), from the wall pass
        self._rhs, self._y, self._v, self._r, self._z, self._p, self._q = (vecs() for _ in range(7))
        self._rz = wp.zeros(model.world_count, dtype=wp.float64, device=dev)
        self._pair_count = wp.zeros(n, dtype=wp.int32, device=dev)
        self._pair_b = wp.zeros((n, PAIRS_PER_EDGE), dtype=wp.int32, device=dev)
        self._pair_st = wp.zeros((n, PAIRS_PER_EDGE), dtype=wp.vec2d, device=dev)
        self._pair_k = wp.zeros((n, PAIRS_PER_EDGE), dtype=wp.float64, device=dev)
        self._pair_n = wp.zeros((n, PAIRS_PER_EDGE), dtype=wp.vec3d, device=dev)
        self._pair_sums = wp.zeros((n, 4), dtype=kernels.vec3l, device=dev)  # per edge: Gershgorin block sums
        # per edge, its same-coil partners' rest offsets (the rest shape's: once)
        self._rest_count = wp.zeros(n, dtype=wp.int32, device=dev)
        self._rest_b = wp.zeros((n, REST_PARTNERS_PER_EDGE), dtype=wp.int32, device=dev)
        self._rest_value = wp.zeros((n, REST_PARTNERS_PER_EDGE), dtype=wp.float64, device=dev)
        wp.launch(kernels.rest_offsets, n, device=dev, inputs=[
            model.rest_x, model.coil_of, model.has_next, model.node_radius, self._coil_first, self._coil_last,
            model.contact.exclusion_edges, model.contact.c0_mm, self._rest_count, self._rest_b, self._rest_value])
        self._spin_c, self._spin_d = wp.zeros(n, dtype=wp.float64, device=dev), wp.zeros(n, dtype=wp.float64,
                                                                                         device=dev)
        self._devices = ImplicitDeviceStiffness(model) if self.has_balloon or self.has_stent else None
        self.scheme = {"integrator": "implicit", "method": self.method, "theta": self.theta,
                       "near_theta": self.near_theta,
                       "turn_gate_rad": self.turn_gate_rad if self.near_theta is not None else None,
                       "contact_stiffness": contact_stiffness,
                       "chord_end": self.chord_end if self.chord else None}  # as built (the push's: settling sets θ 1)

    def step(self, state_in: State, state_out: State, control: Control, dt: float | None = None) -> None:
        """Advance ``state_in`` by dt into ``state_out`` (distinct buffers)."""
        m, dev, n = self.model, self.model.device, self.model.node_count
        dt = self.dt_s if dt is None else dt
        theta = self.theta
        bdf2 = self.method == "bdf2" and state_in.history_dt_s == dt  # else its Euler start (θ = 1)
        dt_m = theta * dt  # the system matrix is M + θ dt B + θ² dt² H + θ dt² K_c
        if bdf2:
            dt_m = BDF2_SCALE * dt  # BDF2: M + h B + h² (H + K_c), h = 2/3 dt
        c = m.contact
        p0_stiff = c.p0_uN / theta  # contact stiffness K_c/θ in a matrix assembled at θ dt: θ dt² K_c
        noted = self._noted_chord
        if noted:  # the free-flight end first: the contact pass notes the chord pass's candidates from it
            self._hold_nodes(state_in, state_out, control, dt)
            self._predict_end(state_in, state_out, dt)
            self._edge_ends(state_in.x, self._x_end)
        self._note_chord = noted
        self.compute_forces(state_in, control.running)
        self._note_chord = False
        if self.method == "bdf2":
            wp.launch(kernels.keep_history, n, device=dev, inputs=[state_in.x, state_in.v, state_out.x_prev,
                                                                  state_out.v_prev])
        if not noted:
            self._hold_nodes(state_in, state_out, control, dt)
        device_dt = dt_m if bdf2 else math.sqrt(theta) * dt  # the devices' stiffness enters at θ dt² K_c too
        x_end = state_in.x
        if self.chord:  # the predicted end and the wall's chord excess on its tangent (kernels/chord.py)
            x_end = self._x_end
            if self.chord_end == "solve":  # the tangent step's solution (a first solve)
                self._assemble(state_in, state_out, control, state_in.x, 0, p0_stiff, dt_m, device_dt)
                self._solve_velocities(state_in, state_out, control, dt_m, CHORD_END_CG_ITERATIONS)
                wp.launch(kernels.end_of_solve, n, device=dev, inputs=[
                    state_in.x, self._v, state_out.x, state_out.free, dt, x_end])
            elif not noted:  # the damped free flight
                self._predict_end(state_in, state_out, dt)
            if self.has_wall:
                wp.launch(chord.wall_chord_stiffness, n, device=dev, inputs=[
                    state_in.x, x_end, state_in.free, m.world_of, control.running, m.node_radius, m.wall_mesh,
                    m.wall_face_first, m.wall_origin, m.wall_vertices, m.wall_faces, m.wall_owners, self._field_ids,
                    GRAD_TOLERANCE, self._wall_side, self.wall_distance, self.wall_force, c.p0_uN, c.c0_mm,
                    self.contact_u_linear, self.wall_stiffness])
        gated = self.near_theta is not None and not bdf2
        if gated:
            self._gate(state_in, dt)
        self._assemble(state_in, state_out, control, x_end, int(self.chord), p0_stiff, dt_m, device_dt, ends=not noted,
                       noted=noted)
        if self.obstacle_friction:  # linearised about the old velocities
            self._obstacle_friction(state_in.v, state_in, state_out, control, dt_m, force_dt=dt_m, mean_dt=0.0,
                                    fresh=True, rhs_scale=0.0)
        started = theta != 1.0 and not bdf2
        if started:  # the θ-method's right side and the solve's start residual from one product A v (theta_start)
            self._start_velocity(state_in, state_out, control)
            wp.launch(kernels.system_product, n, device=dev, inputs=[self._v, self._rhs, 0] + self._product_args(
                state_out, control, dt_m) + [self._q])
            wp.launch(kernels.theta_start, n, device=dev, inputs=[
                self._rhs, self._q, theta, state_out.free, m.fixed, m.world_of, control.running, self._r])
        if gated:  # rows at θ_i ≠ θ: mass M θ/θ_i (kernels/node_theta.py)
            wp.launch(node_theta.shift_rows, n, device=dev, inputs=[
                state_in.v, state_out.free, m.fixed, m.world_of, control.running, m.inv_mass, self.node_theta, theta,
                self._diag, self._diag_exact, self._rhs])
        if bdf2:  # BDF2's right side: the history terms (y in _z, A y in _q)
            wp.launch(kernels.bdf2_history_rate, n, device=dev, inputs=[state_in.x, state_in.x_prev, dt_m, self._z])
            wp.launch(kernels.system_product, n, device=dev, inputs=[self._z, self._rhs, 0] + self._product_args(
                state_out, control, dt_m) + [self._q])
            wp.launch(kernels.bdf2_rhs, n, device=dev, inputs=[
                state_in.v, state_in.v_prev, self._z, self._q, m.inv_mass, m.damping_c, m.damping_k, dt_m,
                int(self.obstacle_friction), self._wall_block, self._device_block, self._rhs])
        self._solve_velocities(state_in, state_out, control, dt_m, started=started)
        self._finish_positions(state_in, state_out, control, self._v, dt, dt_m, bdf2, gated, True)
        force_dt = dt_m / theta if started else dt_m  # a force's weight on the right side (θ: dt)
        for _ in range(OBSTACLE_FRICTION_SOLVES - 1 if self.obstacle_friction else 0):  # about the solved velocities
            self._obstacle_friction(state_out.v, state_in, state_out, control, dt_m, force_dt=force_dt,
                                    mean_dt=0.0 if bdf2 else dt, fresh=False,
                                    rhs_scale=(1.0 - theta) / theta if started else 0.0)
            self._solve_from(state_in, state_out, control, dt_m, factored=False)
            self._finish_positions(state_in, state_out, control, self._v, dt, dt_m, bdf2, gated, True)
        if self.coil_friction:  # implicit Coulomb friction of coil pairs on the new velocities (kernels/friction.py),
            friction_dt = dt_m if bdf2 else dt  # its impulse carried through this step's system
            self._friction_law(state_in, state_out, control.running, friction_dt,
                               with_obstacles=not self.obstacle_friction)
            self._friction_guard(state_in, state_out, control.running)
            self._friction_through_system(state_in, state_out, control, dt_m, gated)
            self._launch_friction_apply(state_in, state_out, control.running, friction_dt)
            if theta != 1.0 or bdf2 or gated:  # the positions from the scheme's combination of the old and new velocities
                self._finish_positions(state_in, state_out, control, state_out.v, dt, dt_m, bdf2, gated, False)
        # twist after the positions (Gauss–Seidel): directors carried to the new tangents, the
        # torque there, then the spins solved and the directors turned
        wp.launch(kernels.transport_frames, n, device=dev, inputs=[
            state_in.x, state_out.x, state_in.m1, m.has_next, m.world_of, control.running, state_out.m1])
        wp.launch(elastic.vertex_theta_gradients, n, device=dev, inputs=[
            state_out.x, state_out.m1, state_out.free, m.has_next, m.clamp_tangent, m.clamp_director, m.k_bend,
            m.k_twist, m.rest_K0, m.rest_K1, m.rest_twist, self.grad_theta])
        wp.launch(kernels.solve_spin, m.coil_count, device=dev, inputs=[
            self._coil_first, self._coil_last, m.coil_world, control.running, state_out.free, m.fixed, m.has_next,
            m.clamp_tangent, state_in.omega, self.grad_theta, m.inv_inertia, m.twist_damping, m.k_twist, m.k_bend,
            m.rest_K0, m.rest_K1, state_out.x, dt, self._spin_c, self._spin_d, state_out.m1, state_out.omega])
        self._accumulate_push_force(control, theta)  # θ < 1: (1 − θ) P_{n−1} + θ P_n (global θ, near_theta too)
        state_out.time_s = state_in.time_s + dt
        state_out.history_dt_s = dt if self.method == "bdf2" else 0.0

    def _hold_nodes(self, state_in: State, state_out: State, control: Control, dt: float) -> None:
        """Catheter kinematics, releases and pusher advance as the reference has them."""
        m = self.model
        wp.launch(kernels.hold_nodes, m.node_count, device=m.device, inputs=[
            state_in.x, state_in.v, state_in.free, state_in.advance, m.fixed, m.coil_of, m.world_of, m.coil_world,
            m.arc_s, m.catheter_path, m.catheter_first, m.catheter_count, control.active_coil,
            control.push_speed_mm_s, control.running, dt, state_out.x, state_out.v, state_out.free,
            state_out.advance])

    def _edge_ends(self, x: wp.array, x_end: wp.array) -> None:
        """Per edge, its midpoint and reach at the predicted end ``x_end`` and its sweep and
        move from ``x`` (kernels.edge_ends: the chord pass's and the contact pass's filters)."""
        m = self.model
        wp.launch(kernels.edge_ends, m.node_count, device=m.device, inputs=[
            x, x_end, m.has_next, m.node_radius, self._end_mid, self._end_half, self._sweep, self._end_move,
            self._node_move])

    def _predict_end(self, state_in: State, state_out: State, dt: float) -> None:
        """The chord's free-flight end into ``self._x_end`` (after _hold_nodes)."""
        m = self.model
        wp.launch(kernels.predict_positions, m.node_count, device=m.device, inputs=[
            state_in.x, state_in.v, state_out.x, state_out.free, m.inv_mass, m.damping_c, m.damping_k, dt,
            self._x_end])

    def _assemble(self, state_in: State, state_out: State, control: Control, x_end: wp.array, chord_on: int,
                  p0_stiff: float, dt_m: float, device_dt: float, ends: bool = True, noted: bool = False) -> None:
        """The system's blocks, its right side M v + dt F and the recorded coil–coil pairs:
        contact stiffness at the step start (``chord_on``: the chord to ``x_end``, its
        kernels.edge_ends launched here unless ``ends`` is False; ``noted``: over the chord
        candidates the contact pass noted from them); the devices' at ``device_dt``."""
        m, dev, n, c = self.model, self.model.device, self.model.node_count, self.model.contact
        theta = self.theta
        if self.coil_contact:
            if chord_on and ends:
                self._edge_ends(state_in.x, x_end)
            self._coil_stiffness(state_in, control.running, x_end, chord_on, p0_stiff, noted)
        wp.launch(kernels.assemble_blocks, n, device=dev, inputs=[
            state_in.x, state_in.v, self.force, state_in.free, state_out.free, m.has_next, m.clamp_tangent,
            m.inv_mass, m.damping_c, m.damping_k, m.k_stretch,
            m.rest_length, m.k_bend, self.wall_stiffness, 1.0 / theta, self._stiff_start, self._stiff_end,
            int(self.coil_contact), m.node_radius, c.fold_span, p0_stiff, c.c0_mm, self.contact_u_linear, dt_m,
            self._diag, self._diag_exact, self._upper1, self._upper2, self._rhs])
        if self._devices is not None:  # balloon and stent contact stiffness (devices.py)
            self._devices.add(self, state_in, control.running, device_dt, self._diag, self._diag_exact, self._upper1,
                              x_end if chord_on else None)

    def _coil_stiffness(self, state: State, running: wp.array, x_end: wp.array, chord_on: int, p0_stiff: float,
                        noted: bool, touch_count: wp.array | None = None) -> None:
        """Coil–coil Gershgorin blocks (µN/mm, ``p0_stiff`` the law's P0) and pair records at ``state``
        (kernels.edge_contact_stiffness: each pair once, both edges; ``chord_on``: the chord to ``x_end``;
        ``noted``: over the contact pass's chord candidates; ``touch_count``: the touching record's counts,
        default the contact pass's)."""
        m, dev, n, c = self.model, self.model.device, self.model.node_count, self.model.contact
        record = [self._pair_count, self._pair_b, self._pair_st, self._pair_k, self._pair_n]
        wp.launch(kernels.clear_pair_records, n, device=dev, inputs=[self._pair_count, self._pair_sums])
        wp.launch(kernels.edge_contact_stiffness, n, device=dev, inputs=[
            state.x, m.rest_x, state.free, m.has_next, m.coil_of, m.world_of, running, m.fixed, m.node_radius,
            self._grid.id, self._neighbours, self._neighbour_count, self._midpoints, m.query_radius_of,
            self._grid_radius, c.exclusion_edges, p0_stiff, c.c0_mm, self.contact_u_linear,
            self._touch_count if touch_count is None else touch_count, self._touch_b, self._pair_sums, *record, x_end,
            self._end_mid, self._end_half, self._sweep, self._end_move, chord_on, self._chord_count, self._chord_b,
            self._chord_st, int(noted), self._node_move, self._rest_count, self._rest_b, self._rest_value])
        wp.launch(kernels.finish_pair_records, n, device=dev, inputs=[
            self._pair_sums, *record, self._stiff_start, self._stiff_end])

    def needs_start(self, state: State) -> bool:
        """BDF2 without a history at this step (first step, a changed step, a restart):
        the next step is its Euler start."""
        return self.method == "bdf2" and state.history_dt_s != self.dt_s

    def _gate(self, state_in: State, dt: float) -> None:
        """Each node's θ_i (``node_theta``) from its distances at the step start, which the
        contact pass has just measured, and its edges' turn in the step (kernels/node_theta.py)."""
        m, dev, n = self.model, self.model.device, self.model.node_count
        reach = m.contact.c0_mm + self.proximity_margin_mm  # the contact range and a margin
        near = max(self.near_theta, self.theta)  # θ = 1 (the settling step, Ensemble._settle_step): Euler everywhere
        wp.launch(node_theta.proximity_theta, n, device=dev, inputs=[
            state_in.x, state_in.v, state_in.free, m.has_next, m.node_radius, self.wall_distance, self.coil_gap,
            int(self.coil_contact), m.contact_samples, reach, self.turn_gate_rad, dt, self.theta, near, self.node_theta])
        if self.has_stent:
            wp.launch(node_theta.strut_proximity, n, device=dev, inputs=[
                state_in.x, state_in.v, state_in.free, m.has_next, m.world_of, m.node_radius, self._strut_grid.id,
                m.strut_start, m.strut_end, m.strut_radius_mm, self._strut_query_mm, reach, dt, near, self.node_theta])
        if self.has_balloon:
            wp.launch(node_theta.balloon_proximity, n, device=dev, inputs=[
                state_in.x, state_in.v, state_in.free, m.world_of, m.node_radius, m.balloon_stations,
                m.balloon_cap_radius, m.balloon_first, m.balloon_count, m.balloon_inflation, reach, dt, near,
                self.node_theta])

    def _finish_positions(self, state_in: State, state_out: State, control: Control, v_new: wp.array, dt: float,
                          dt_m: float, bdf2: bool, gated: bool = False, solved_is_u: bool = True) -> None:
        """New velocities and positions of the unknowns: BDF2's x' = 4/3 x − 1/3 x₋₁ + h v',
        or the θ-method's x' = x + dt ((1 − θ) v + θ v') (``gated``: per node θ_i, ``v_new``
        the solve's u where ``solved_is_u``, kernels/node_theta.py)."""
        m, dev, n = self.model, self.model.device, self.model.node_count
        if gated:
            wp.launch(node_theta.finish_nodes, n, device=dev, inputs=[
                state_in.x, state_in.v, v_new, int(solved_is_u), state_out.free, m.fixed, m.world_of, control.running,
                dt, self.theta, self.node_theta, state_out.x, state_out.v])
            return
        if bdf2:
            wp.launch(kernels.finish_nodes_bdf2, n, device=dev, inputs=[
                state_in.x, state_in.x_prev, v_new, state_out.free, m.fixed, m.world_of, control.running, dt_m,
                state_out.x, state_out.v])
            return
        wp.launch(kernels.finish_nodes, n, device=dev, inputs=[
            state_in.x, state_in.v, v_new, state_out.free, m.fixed, m.world_of, control.running, dt, self.theta,
            state_out.x, state_out.v])

    def _obstacle_friction(self, v: wp.array, state_in: State, state_out: State, control: Control, dt_m: float,
                           force_dt: float, mean_dt: float, fresh: bool, rhs_scale: float) -> None:
        """Wall and device friction linearised about velocities ``v`` (or, ``mean_dt`` > 0, about
        the step's mean velocity (x' − x)/``mean_dt``) into the system: its block at ``dt_m``, its
        force at ``force_dt`` (``fresh``: onto the blocks and right side just assembled; else in
        place of the last linearisation, the θ right side corrected by ``rhs_scale``;
        kernels/friction_damping.py)."""
        m, c = self.model, self.model.contact
        wp.launch(friction_damping.obstacle_friction, m.node_count, device=m.device, inputs=[
            v, state_in.v, state_out.free, m.fixed, m.world_of, control.running, self.wall_force, self.wall_stiffness,
            state_in.x, state_out.x, self.device_force, c.friction_wall, c.friction_speed_mm_s, dt_m, force_dt,
            mean_dt, int(fresh), rhs_scale, self._wall_block, self._device_block, self._wall_friction,
            self._device_friction, self._wall_slip, self._device_slip, self._diag, self._diag_exact, self._rhs])

    def _through_system(self, impulse: wp.array, state_in: State, state_out: State, control: Control, dt_m: float,
                        gated: bool) -> None:
        """y = A⁻¹ (M + dt B) Δv into ``self._v`` for a velocity change Δv (``impulse``, mm/s):
        this step's matrix and factorisation, started at y = Δv (kernels.impulse_start)."""
        m, dev, n = self.model, self.model.device, self.model.node_count
        wp.launch(kernels.impulse_start, n, device=dev, inputs=[
            impulse, state_in.v, m.inv_mass, m.damping_c, m.damping_k, dt_m, state_out.free, m.fixed,
            m.world_of, control.running, self.node_theta, self.theta, int(gated), self._v, self._rhs])
        self._solve_from(state_in, state_out, control, dt_m, factored=True)

    def _solve_from(self, state_in: State, state_out: State, control: Control, dt_m: float, factored: bool) -> None:
        """The system solved again from the start already in ``self._v`` (its residual against
        ``self._rhs`` first; ``factored``: this step's factorisation still holds)."""
        wp.launch(kernels.system_product, self.model.node_count, device=self.model.device, inputs=[
            self._v, self._rhs, 1] + self._product_args(state_out, control, dt_m) + [self._r])
        self._solve_velocities(state_in, state_out, control, dt_m, started=True, factored=factored)

    def _friction_through_system(self, state_in: State, state_out: State, control: Control, dt_m: float,
                                 gated: bool) -> None:
        """The coil pairs' friction change Δv_f as an impulse on this step's system:
        y = A⁻¹ (M + dt B) Δv_f (the step's matrix and factorisation, started at y = Δv_f;
        kernels.impulse_start), so that the stiff terms coupling a contact node to its
        neighbours carry the impulse with it instead of being strained by dt Δv_f and
        ringing the step after. Where the whole response would raise a world's kinetic energy,
        the world takes the largest share of it that does not (kernels.keep_dissipative_change;
        the law's Δv_f applied at the nodes instead, as before, strained their neighbours, and
        a coil with coil friction alone never came to rest). Δv_f comes with its normal guard
        (Solver._friction_guard); the change applied loses any part into the wall or a device
        again (docs/FORMULATION.md
        "Friction through the step's system")."""
        m, dev, n = self.model, self.model.device, self.model.node_count
        self._through_system(self._friction_change, state_in, state_out, control, dt_m, gated)
        wp.launch(kernels.keep_dissipative_change, m.world_count, device=dev, inputs=[
            m.world_node_range, control.running, state_out.free, m.fixed, m.inv_mass, state_out.v, self._v,
            self.node_theta, self.theta, int(gated), self._friction_change])
        if self._obstacles:  # nothing of it into the wall or a device
            self._launch_add_guard(state_out, control.running, with_coil_terms=False)

    def _product_args(self, state_out: State, control: Control, dt_m: float) -> list:
        """The arguments of kernels.system_product after (x, b, residual), before out."""
        m = self.model
        return [state_out.free, m.fixed, m.has_next, m.world_of, control.running, self._diag_exact, self._upper1,
                self._upper2, self._stiff_start, self._stiff_end, self._pair_count, self._pair_b, self._pair_st,
                self._pair_k, self._pair_n, dt_m]

    def _start_velocity(self, state_in: State, state_out: State, control: Control) -> None:
        """The solve's start into ``self._v``: unknowns at their old velocities, held nodes at their new ones."""
        m = self.model
        wp.launch(kernels.start_velocity, m.node_count, device=m.device, inputs=[
            state_in.v, state_out.v, state_out.free, m.fixed, m.world_of, control.running, self._v])

    def _solve_velocities(self, state_in: State, state_out: State, control: Control, dt: float,
                          iterations: int | None = None, started: bool = False, factored: bool = False) -> None:
        """(M + dt² (H + K_c)) v* = M v + dt F into ``self._v``: preconditioned conjugate
        gradients per world, started at the old velocities, preconditioned by each
        coil's banded factorisation: ``cg_iterations`` iterations, ``push_cg_iterations``
        in a world whose pusher drives a coil (its later iterations' launches skip it);
        ``iterations``: that many in every world instead. ``started``: the start (``self._v``)
        and its residual (``self._r``) are already there (kernels.theta_start); ``factored``: so is
        this step's factorisation (a second solve with the same matrix)."""
        m, dev, n, coils = self.model, self.model.device, self.model.node_count, self.model.coil_count
        total = self.cg_iterations if iterations is None else iterations
        pushing = self.push_cg_iterations if iterations is None else iterations
        free, running = state_out.free, control.running
        coil_args = [self._coil_first, self._coil_last, m.coil_world, running, free, m.fixed]
        if not factored:
            wp.launch(kernels.factor_coils, coils, device=dev, inputs=coil_args + [
                self._diag, self._upper1, self._upper2, self._inv_d, self._lower1, self._lower2])
        product_args = self._product_args(state_out, control, dt)
        precondition_args = coil_args + [self._inv_d, self._lower1, self._lower2, self._r, self._y, self._z]
        if not started:
            self._start_velocity(state_in, state_out, control)
            wp.launch(kernels.system_product, n, device=dev, inputs=[self._v, self._rhs, 1] + product_args + [self._r])
        wp.launch(kernels.precondition, coils, device=dev, inputs=precondition_args)
        wp.launch(kernels.pcg_begin, m.world_count, device=dev, inputs=[
            m.world_node_range, running, self._r, self._z, self._p, self._rz])
        if pushing < total:
            wp.launch(kernels.settling_worlds, m.world_count, device=dev, inputs=[
                running, control.active_coil, self._settling])

        def worlds(k: int) -> wp.array:  # the worlds taking iteration k
            return running if k < pushing else self._settling

        for k in range(total):
            wp.launch(kernels.system_product, n, device=dev, inputs=[self._p, self._rhs, 0] + product_args[:4]
                      + [worlds(k)] + product_args[5:] + [self._q])
            wp.launch(kernels.pcg_advance, m.world_count, device=dev, inputs=[
                m.world_node_range, worlds(k), self._p, self._q, self._rz, self._v, self._r])
            if k + 1 < total:
                wp.launch(kernels.precondition, coils, device=dev, inputs=precondition_args[:3] + [worlds(k + 1)]
                          + precondition_args[4:])
                wp.launch(kernels.pcg_direction, m.world_count, device=dev, inputs=[
                    m.world_node_range, worlds(k + 1), self._r, self._z, self._rz, self._p])

    def unstable_reason(self, problem: str, time_s: float) -> str:
        return (f"{problem} at t = {time_s:.6f} s (implicit step dt = {self.dt_s:.3e} s): reduce simulation.dt_s, "
                f"or soften the contact (contact.P0_uN, larger contact.c0_mm)")


def make_solver(model: Model, integrator: str, dt_s: float, dt_safety: float = DEFAULT_DT_SAFETY,
                allow_unstable_dt: bool = False, **kwargs) -> Solver:
    """The solver of ``integrator`` ("symplectic": the reference, "implicit")."""
    if integrator == "implicit":
        return ImplicitSolver(model, dt_s=dt_s, dt_safety=dt_safety, **kwargs)
    if integrator != "symplectic":
        raise ValueError(f"unknown integrator {integrator!r}; use one of {INTEGRATORS}")
    return Solver(model, dt_s=dt_s, dt_safety=dt_safety, allow_unstable_dt=allow_unstable_dt, **kwargs)
