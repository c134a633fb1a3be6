"""Validation of the numerical-dissipation ledger (dissipation.py), each row running the
meter on the solver: on a clamped straight 3-node chain oscillating along its axis (a linear
system: stretching only) the meter's books equal the θ-method's analytic loss
(θ − ½) Σ (Δvᵀ M Δv + Δxᵀ K Δx) of the trajectory (θ = 1: linearly implicit Euler's;
the default gated_chord's θ 0.65 too), and with the model's damping its ratio
numerical / physical falls at order 1 with the step; the same ratio on a released coil
(docs/FORMULATION.md "Implicit step: numerical dissipation")."""

from __future__ import annotations

import math

import numpy as np

from . import preshape
from .coil import CoilSpec
from .dissipation import DissipationMeter
from .implicit import EULER, GATED_CHORD, IMPLICIT_THETA, make_solver
from .model import Model, ModelBuilder
from .settings import SimulationSettings
from .solver import Control
from .state import state_from_positions
from .validation import REFERENCE_D_MM, CaseResult, _row

# the chain's free nodes start displaced along its axis by these amounts (mm): a slow and a fast mode
CHAIN_START_MM = (1.0e-3, 1.5e-3)
# a 10 mm helical coil released from its pre-shape stretched 2 % along its axis (its slow modes: a step
# of 10–20 µs resolves them, the fastest node-scale modes it does not), 4 ms of free motion
COIL_LENGTH_MM, COIL_STRETCH, COIL_TIME_S, COIL_STEPS_S = 10.0, 1.02, 4.0e-3, (2.0e-5, 1.0e-5)


def observed_order(ratio_coarse: float, ratio_fine: float, refinement: float = 2.0) -> float:
    """Order p of a quantity ∝ dtᵖ from its values at dt and dt / refinement."""
    return math.log(ratio_coarse / ratio_fine) / math.log(refinement)


def axial_chain(damped: bool) -> tuple[Model, np.ndarray, np.ndarray, float]:
    """A straight 3-node coil of the reference wire clamped at node 0: (model, axial stiffness
    matrix K of nodes 1–2 (µN/mm), their masses (g), the fastest mode's ω (rad/s)). Axial
    motion keeps it straight, so its forces are exactly linear. ``damped``: the model's
    damping law on, else off."""
    l0 = REFERENCE_D_MM
    builder = ModelBuilder(settings=SimulationSettings())
    builder.add_coil(CoilSpec(wire_diameter_mm=REFERENCE_D_MM, length_mm=2.0 * l0),
                     rest_centerline=np.array([[0.0, 0.0, 0.0], [l0, 0.0, 0.0], [2.0 * l0, 0.0, 0.0]]))
    builder.clamp(0, node=0)
    model = builder.finalize()
    if not damped:
        model.damping_c.zero_()
    k0, k1 = model.k_stretch.numpy()[:2]
    stiffness = np.array([[k0 + k1, -k1], [-k1, k1]])
    mass = 1.0 / model.inv_mass.numpy()[1:3]
    omega = math.sqrt(float(np.linalg.eigvals(stiffness / mass[:, None]).real.max()))
    return model, stiffness, mass, omega


def chain_run(damped: bool, omega_dt: float, steps: int, options: dict | None = None
              ) -> tuple[DissipationMeter, float]:
    """The chain stepped by the implicit step (``options``: the solver's, default linearly
    implicit Euler) at dt = omega_dt / ω: (its meter, the θ-method's analytic loss
    (θ − ½) Σ (Δvᵀ M Δv + Δxᵀ K Δx) of the axial trajectory, nJ). Derivation: with
    M Δv = −dt K (x + θ Δx) and Δx = dt ((1 − θ) v + θ v'), ΔE = ½ (v + v')ᵀ M Δv +
    ½ (x + x')ᵀ K Δx = (½ − θ) (Δvᵀ M Δv + Δxᵀ K Δx); no node is gated (no obstacle)."""
    options = EULER if options is None else options
    theta = options.get("theta", IMPLICIT_THETA)  # not given: the default's (gated_chord)
    model, stiffness, mass, omega = axial_chain(damped)
    start = model.rest_x.numpy().copy()
    start[1:3, 0] += CHAIN_START_MM
    meter = DissipationMeter(make_solver(model, "implicit", omega_dt / omega, **options),
                             state_from_positions(model, start), Control.create(model))
    x, v = [start[1:3, 0]], [np.zeros(2)]
    for _ in range(steps):
        meter.step()
        x.append(meter.state.x.numpy()[1:3, 0].copy())
        v.append(meter.state.v.numpy()[1:3, 0].copy())  # (CPU .numpy() is a view)
    dx, dv = np.diff(x, axis=0), np.diff(v, axis=0)
    quadratic = float(np.einsum("ni,ni,i->", dv, dv, mass) + np.einsum("ni,ij,nj->", dx, stiffness, dx))
    analytic = (theta - 0.5) * quadratic
    return meter, analytic


def chain_rows() -> list[CaseResult]:
    """The meter against the θ-method's analytic loss (undamped; Euler and gated_chord's θ 0.65), and its
    ratio's order (damped, Euler)."""
    rows = []
    for label, options in (("Euler", EULER), (f"gated_chord θ {GATED_CHORD['theta']:g}", GATED_CHORD)):
        meter, analytic = chain_run(damped=False, omega_dt=0.5, steps=40, options=options)
        rows.append(_row(f"meter on a clamped 3-node chain oscillating along its axis, undamped, dt ω 0.5, {label}: "
                         "numerical dissipation vs (θ − ½) Σ (ΔvᵀMΔv + ΔxᵀKΔx) of its trajectory (nJ)", analytic,
                         meter.totals.numerical_nJ, 1e-9))
    steps = [round(2.0 * math.pi / w) for w in (0.05, 0.025)]  # one period of the fastest mode
    ratios = [chain_run(damped=True, omega_dt=w, steps=n)[0].totals.ratio for w, n in zip((0.05, 0.025), steps)]
    rows.append(_row(f"meter on the damped chain: order of numerical/physical in dt (dt ω 0.05 → 0.025: "
                     f"{ratios[0]:.3f} → {ratios[1]:.3f})", 1.0, observed_order(*ratios), 5e-2))
    return rows


def coil_ratio(dt_s: float) -> tuple[float, float]:
    """(numerical / physical dissipation, Σ numerical nJ) of the implicit step over COIL_TIME_S of
    the stretched 10 mm helix's free motion."""
    spec = CoilSpec(wire_diameter_mm=REFERENCE_D_MM, shape="helix", length_mm=COIL_LENGTH_MM, loop_diameter_mm=3.0,
                    pitch_mm=0.6)
    builder = ModelBuilder(settings=SimulationSettings())
    builder.add_coil(spec)
    model = builder.finalize()
    start = preshape.helix(3.0, COIL_STRETCH * 0.6, COIL_LENGTH_MM, spec.l0)
    meter = DissipationMeter(make_solver(model, "implicit", dt_s), state_from_positions(model, start),
                             Control.create(model))
    for _ in range(round(COIL_TIME_S / dt_s)):
        meter.step()
    return meter.totals.ratio, meter.totals.numerical_nJ


def coil_rows() -> list[CaseResult]:
    """The implicit step's numerical/physical ratio on a free coil falls at order ≈ 1 (0.83 measured:
    order 1 is reached as dt ω → 0 for the modes that carry the energy)."""
    (coarse, numerical), (fine, _) = (coil_ratio(dt) for dt in COIL_STEPS_S)
    rows = [_row(f"free coil, implicit dt {COIL_STEPS_S[0]:.0e} s: numerical dissipation {numerical:.4g} nJ, "
                 "its negative part (nJ)", 0.0, min(numerical, 0.0), 1e-9)]
    rows.append(_row(f"free coil, implicit: order of numerical/physical ratio in dt ({coarse:.2f} → {fine:.2f})",
                     1.0, observed_order(coarse, fine), 0.25))
    return rows


def dissipation_cases() -> list[CaseResult]:
    return chain_rows() + coil_rows()
