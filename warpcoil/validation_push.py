"""Validation of the push force (``warpcoil validate push-force``): the pusher's
reaction has a known value in two cases, for the reference step and the implicit
one at its default push step.

* A straight coil pushed out of a straight catheter into free space moves with the
  pusher: the push force is the damping its free part meets, Σ c_i (1 − e^{−v/k}).
* A straight coil pushed onto a flat wall (perpendicular to the catheter), the
  pusher then stopped and the coil come to rest: the push force is the wall's
  reaction on the distal node, s₀ |F|(h) (s₀ = ½: its contact share), where the
  clearance h follows from the pusher's advance minus the free part's axial
  compression, h = h_nominal + P N / k_s (N free segments in series, k_s each).

Units mm, g, s, µN.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from .coil import CoilSpec
from .implicit import EULER, GATED_CHORD, implicit_step_s, make_solver
from .kernels import contact
from .model import ModelBuilder
from .settings import CatheterSpec, ContactSettings
from .solver import Control, Stepper
from .state import packed_state
from .validation import REFERENCE_D_MM, CaseResult, _row
from .validation_friction import P0_UN, _floor

PUSH_MM_S = 50.0


def _straight_coil(segments: int, builder: ModelBuilder):
    spec = CoilSpec(wire_diameter_mm=REFERENCE_D_MM, length_mm=segments * REFERENCE_D_MM,
                    segment_length_mm=REFERENCE_D_MM)
    rest = np.zeros((segments + 1, 3))
    rest[:, 2] = np.arange(segments + 1) * spec.l0
    builder.add_coil(spec, rest)
    return builder.finalize()


def _step(model, integrator: str, dt_s: float | None) -> float | None:
    """The step to run: the given one, the implicit default for PUSH_MM_S, or None (the reference's)."""
    if dt_s is None and integrator == "implicit":
        return implicit_step_s(model, PUSH_MM_S)
    return dt_s


def free_space_push_force(integrator: str, dt_s: float | None = None, out_mm: float = 3.0,
                          window_mm: float = 0.6, **options) -> tuple[float, float]:
    """A straight coil (40 segments) pushed ``out_mm`` out of a straight catheter into
    free space: (the push force averaged over the next ``window_mm``, the damping force
    its free nodes meet at the push speed, Σ c_i (1 − e^{−v/k}), the mean of its values at
    the window's ends) (µN, compressive > 0)."""
    model = _straight_coil(40, ModelBuilder(catheter=CatheterSpec(tip_mm=(0.0, 0.0, 0.0), direction=(0.0, 0.0, 1.0))))
    solver = make_solver(model, integrator, _step(model, integrator, dt_s), coil_contact=False, **options)
    control = Control.create(model, active_coil=0, push_speed_mm_s=PUSH_MM_S)
    stepper = Stepper(solver, packed_state(model), control, chunk=2)
    c = model.damping_c.numpy() * (1.0 - np.exp(-PUSH_MM_S / model.damping_k))
    stepper.run_steps(2 * round(out_mm / PUSH_MM_S / solver.dt_s / 2), check_every_chunk=False)
    damping = c[stepper.state.free.numpy() != 0].sum()
    solver.take_push_force()
    stepper.run_steps(2 * round(window_mm / PUSH_MM_S / solver.dt_s / 2), check_every_chunk=False)
    damping = 0.5 * (damping + c[stepper.state.free.numpy() != 0].sum())
    return float(solver.take_push_force().mean_uN[0]), float(damping)


def _law_uN(h_mm: float, p0_uN: float, c0_mm: float, u_linear: float) -> float:
    f = wp.zeros(1, dtype=wp.float64, device="cpu")  # on the CPU whatever the default device (a GPU's)
    k = wp.zeros(1, dtype=wp.float64, device="cpu")
    wp.launch(contact.evaluate_law, 1, inputs=[wp.array([h_mm], dtype=wp.float64, device="cpu"), p0_uN, c0_mm,
                                               u_linear, f, k], device="cpu")
    return float(f.numpy()[0])


def wall_push_force(integrator: str, dt_s: float | None = None, overlap_c0: float = 0.5,
                    tip_height_mm: float = 1.0, **options) -> tuple[float, float, float]:
    """A straight coil (10 segments) pushed down a catheter whose tip is ``tip_height_mm``
    above a flat floor, until its distal node would sit ``overlap_c0`` c0 into the contact
    (nominal clearance −overlap_c0 c0, its radius counted), the pusher stopped, the coil
    brought to rest. Returns (push force at rest, the wall's reaction along the catheter
    axis, the analytic value s₀ |F|(h) with h = h_nominal + P N / k_s) (µN)."""
    builder = ModelBuilder(contact=ContactSettings(P0_uN=P0_UN), wall=_floor(),
                           catheter=CatheterSpec(tip_mm=(0.0, 0.0, tip_height_mm), direction=(0.0, 0.0, -1.0)))
    model = _straight_coil(10, builder)
    solver = make_solver(model, integrator, _step(model, integrator, dt_s), coil_contact=False, **options)
    c0, radius = model.contact.c0_mm, float(model.node_radius.numpy()[0])
    advance = tip_height_mm - radius + overlap_c0 * c0
    control = Control.create(model, active_coil=0, push_speed_mm_s=PUSH_MM_S)
    steps = max(1, round(advance / PUSH_MM_S / solver.dt_s))
    solver.dt_s = advance / PUSH_MM_S / steps  # the pusher stops exactly at the advance
    stepper = Stepper(solver, packed_state(model), control, chunk=1)
    stepper.run_steps(steps, check_every_chunk=False)
    control.set_push_speed(0.0)
    stepper.chunk = 50
    state, rested = stepper.run_to_rest(1e-9, max_steps=steps + 400_000, min_steps=steps + 2_000)
    if not rested:
        raise RuntimeError(f"the coil pushed onto the floor did not come to rest ({integrator})")
    solver.take_push_force()
    stepper.run_steps(stepper.chunk, check_every_chunk=False)
    push = float(solver.take_push_force().mean_uN[0])
    axis = model.catheter_axis_of.numpy()[0]
    free = stepper.state.free.numpy() != 0
    reaction = float(-(solver.wall_force.numpy()[free] @ axis).sum())
    # analytic: P = s0 |F|(h), h = nominal clearance + compression of the N free segments in series
    pushed = float(stepper.state.advance.numpy()[0])
    nominal = tip_height_mm - pushed - radius
    share, k_s, segments = float(model.contact_share.numpy()[0]), float(model.k_stretch.numpy()[0]), int(free.sum())
    low, high = 0.0, 50.0 * P0_UN
    for _ in range(200):  # s0 |F|(nominal + P N / k_s) − P is decreasing in P
        mid = 0.5 * (low + high)
        excess = share * _law_uN(nominal + mid * segments / k_s, model.contact.p0_uN, c0,
                                 solver.contact_u_linear) - mid
        low, high = (mid, high) if excess > 0.0 else (low, mid)
    return push, reaction, 0.5 * (low + high)


def push_force_cases() -> list[CaseResult]:
    rows = []
    variants = (("symplectic", {}, "reference step"),
                ("implicit", EULER, "implicit Euler default step"),
                ("implicit", {"method": "bdf2"}, "implicit BDF2 default step"),
                ("implicit", {}, f"implicit default step, gated_chord θ {GATED_CHORD['theta']:g} gated, chord"))  # θ < 1: the blended reading
    for integrator, options, label in variants:
        push, damping = free_space_push_force(integrator, **options)
        rows.append(_row(f"push force, straight coil into free space ({label}): = damping (µN)", damping, push, 5e-2))
        push, reaction, analytic = wall_push_force(integrator, **options)
        rows.append(_row(f"push force, straight coil at rest on a wall ({label}): s0|F|(h) (µN)", analytic, push,
                         1e-3))
        rows.append(_row(f"push force, straight coil at rest on a wall ({label}): = wall reaction (µN)", reaction,
                         push, 1e-5))
    return rows
