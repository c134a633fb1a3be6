"""`warpcoil validate node-theta`: the implicit θ-method with the proximity-gated θ
(``near_theta``, kernels/node_theta.py; docs/FORMULATION.md "Implicit step: proximity-gated θ").

- In free space no node is gated: the lowest cantilever mode loses the θ-method's
  1 − |R|^(2π/w), |R|² = (1 + (1−θ)² w²)/(1 + θ² w²) per period (w = ω dt).
- Every node gated (θ_i = 1, the elastic force still at x + θ Δx, x' = x + dt v'):
  |R|² = 1/(1 + θ w²) — between the θ-method and Euler's 1/(1 + w²).
- Every node gated converges to the reference integrator as dt shrinks (first order).
- The free release (60 mm helix pushed into free space at 100 and 150 mm/s, catheter
  turned 0.01°) comes to rest in the helix, where linearly implicit Euler tangles.
- The turn gate (``turn_gate_rad``): a 30 mm helix pushed slowly (25 mm/s) into free space
  stays quasi-static (kinetic ≤ 0.1 × elastic energy in every frame of the push) under
  gated_chord, as under Euler; without the turn gate θ 0.65 reached 0.83 there.
"""

from __future__ import annotations

import math

from .coil import CoilSpec
from .deploy import Deployment
from .implicit import GATED_CHORD
from .settings import Scene, SimulationSettings
from .validation import CaseResult, _row, cantilever_vibration_loss, free_release, implicit_convergence, tilted_catheter

THETA = 0.7
GATED = {"theta": THETA, "near_theta": 1.0, "contact_stiffness": "tangent"}  # the gate alone (no chord)
EVERY_NODE = {**GATED, "proximity_margin_c0": 1.0e12}  # a reach beyond any distance: every node at θ_i = 1


def damping_rows() -> list[CaseResult]:
    rows = []
    for label, options, gated in (("free space (no node gated)", GATED, False), ("every node gated", EVERY_NODE, True)):
        loss, omega, dt, _ = cantilever_vibration_loss(options)
        w = omega * dt
        r2 = 1.0 / (1.0 + THETA * w * w) if gated else (1.0 + ((1.0 - THETA) * w) ** 2) / (1.0 + (THETA * w) ** 2)
        rows.append(_row(f"gated θ {THETA:g}, {label}: amplitude lost per period of the lowest cantilever mode at "
                         f"dt {dt:.3g} s", 1.0 - r2 ** (math.pi / w), loss, 0.25))
    return rows


def convergence_rows() -> list[CaseResult]:
    """Every node gated against the reference on the relaxing helix as dt shrinks
    (validation.implicit_convergence): relative RMS node distance and the observed order."""
    return implicit_convergence(labelled_options=(f"gated θ {THETA:g} (every node gated)", EVERY_NODE))


def release_rows() -> list[CaseResult]:
    rows = []
    for speed in (100.0, 150.0):
        rows += free_release(push_speed_mm_s=speed, integrator="implicit", catheter=tilted_catheter(0.01, 90.0),
                             solver_options=GATED,
                             label=f"free release at {speed:g} mm/s, gated θ {THETA:g}, catheter turned 0.01°")
    return rows


SLOW_HELIX = CoilSpec(wire_diameter_mm=0.254, length_mm=30.0, loop_diameter_mm=3.5, shape="helix")
SLOW_PUSH_MM_S = 25.0
QUASI_STATIC = 0.1  # MODEL.md's quasi-static report: kinetic / elastic energy


def slow_helix_kinetic_ratio(solver_options: dict) -> float:
    """Largest kinetic / elastic energy over the frames of SLOW_HELIX's push into free
    space at SLOW_PUSH_MM_S on the implicit step with ``solver_options`` (the first frame,
    with nothing out, left aside); inf where the run does not complete."""
    scene = Scene(coils=(SLOW_HELIX,), simulation=SimulationSettings(integrator="implicit",
                                                                    push_speed_mm_s=SLOW_PUSH_MM_S))
    result = Deployment(scene, solver_options=solver_options).run()
    pushing = [f for f in result.frames if f.deployed_length_mm < SLOW_HELIX.length_mm - 0.2][1:]
    if result.status != "completed" or len(pushing) < 50:
        return float("inf")
    return max(f.kinetic_nJ / (f.bend_nJ + f.twist_nJ + f.stretch_nJ) for f in pushing)


def turn_gate_rows() -> list[CaseResult]:
    rows = []
    for label, options in (("gated_chord, turn gate 0.01 rad", GATED_CHORD),
                           ("gated_chord, turn gate 0.003 rad", {**GATED_CHORD, "turn_gate_rad": 0.003})):
        ratio = slow_helix_kinetic_ratio(options)
        rows.append(_row(f"{label}: 30 mm helix pushed at 25 mm/s into free space: max kinetic/elastic", 0.0, ratio,
                         QUASI_STATIC))
    return rows


def node_theta_cases() -> list[CaseResult]:
    return damping_rows() + convergence_rows() + release_rows() + turn_gate_rows()
