"""The numerical-dissipation ledger (warpcoil/dissipation.py) run on the solver: backward Euler's
analytic loss on a linear chain, and the implicit step's books on a free and a pushed coil."""

import math

import pytest

from warpcoil import preshape
from warpcoil.coil import CoilSpec
from warpcoil.dissipation import DissipationMeter
from warpcoil.implicit import GATED_CHORD, make_solver
from warpcoil.model import ModelBuilder
from warpcoil.settings import CatheterSpec, SimulationSettings
from warpcoil.solver import Control
from warpcoil.state import packed_state, state_from_positions
from warpcoil.validation import REFERENCE_D_MM
from warpcoil.validation_dissipation import chain_run, observed_order


@pytest.mark.parametrize("omega_dt, options", [(0.5, None), (0.1, None), (0.5, GATED_CHORD)])
def test_meter_books_the_theta_methods_loss_on_a_linear_chain(omega_dt, options):
    """Undamped, axially oscillating chain (exactly linear forces): the meter's numerical
    dissipation = (θ − ½) Σ (Δvᵀ M Δv + Δxᵀ K Δx) of the trajectory (backward Euler: θ 1;
    GATED_CHORD: θ 0.65), and it is all of it (no physical)."""
    meter, analytic = chain_run(damped=False, omega_dt=omega_dt, steps=30, options=options)
    assert analytic > 0.0
    assert meter.totals.physical_nJ == 0.0
    assert meter.totals.numerical_nJ == pytest.approx(analytic, rel=1e-9)


def test_meter_ratio_on_the_damped_chain_falls_at_first_order():
    """Damped chain, one period of its fastest mode: numerical / physical ∝ dt (dt ω 0.1, 0.05, 0.025)."""
    ratios = [chain_run(damped=True, omega_dt=w, steps=round(2.0 * math.pi / w))[0].totals.ratio
              for w in (0.1, 0.05, 0.025)]
    orders = [observed_order(a, b) for a, b in zip(ratios, ratios[1:])]
    assert orders == pytest.approx([1.0, 1.0], abs=0.05)


def _helix_model(length_mm: float, catheter: bool = False):
    spec = CoilSpec(wire_diameter_mm=REFERENCE_D_MM, shape="helix", length_mm=length_mm, loop_diameter_mm=3.0,
                    pitch_mm=0.6)
    builder = ModelBuilder(catheter=CatheterSpec() if catheter else None, settings=SimulationSettings())
    builder.add_coil(spec)
    return builder.finalize(), spec


def test_free_coil_books_close_and_the_ratio_falls_with_the_step():
    """A free coil (no pusher): the steps' ledgers sum to E0 − E_N − physical (the solver's own
    energies), every step dissipates (≥ 0), and the ratio numerical/physical halves with dt."""
    model, spec = _helix_model(6.0)
    start = preshape.helix(3.0, 1.02 * 0.6, 6.0, spec.l0)
    ratios = []
    for dt in (2e-5, 1e-5):
        meter = DissipationMeter(make_solver(model, "implicit", dt), state_from_positions(model, start),
                                 Control.create(model))
        meter.step()  # the first step flags the nodes free
        e0 = sum(meter.solver.energies(meter.state).values())
        numerical0, physical0 = meter.totals.numerical_nJ, meter.totals.physical_nJ
        steps = [meter.step() for _ in range(round(2e-3 / dt))]
        e1 = sum(meter.solver.energies(meter.state).values())
        numerical, physical = meter.totals.numerical_nJ - numerical0, meter.totals.physical_nJ - physical0
        assert numerical == pytest.approx(e0 - e1 - physical, rel=1e-9, abs=1e-12)
        assert min(s.numerical_nJ for s in steps) > -1e-3 * max(s.numerical_nJ for s in steps)
        ratios.append(numerical / physical)
    assert 0.6 < observed_order(*ratios) < 1.3


def test_pushed_coil_pusher_work_equals_the_push_force_report():
    """Pushed out of a catheter: the ledger's pusher work (the catheter's constraint forces on
    the held nodes, trapezoid in time) equals the solver's own push-force report (mean over the
    steps, µN) × the pusher's advance (mm), measured at the pusher independently; and the
    released helix's stored energy is taken up (ΔE_elastic < 0)."""
    model, _ = _helix_model(2.0, catheter=True)
    speed_mm_s, steps = 100.0, 60
    dt = 0.8 * model.contact.c0_mm / speed_mm_s
    meter = DissipationMeter(make_solver(model, "implicit", dt), packed_state(model),
                             Control.create(model, active_coil=0, push_speed_mm_s=speed_mm_s))
    meter.solver.take_push_force()  # (start the report's sum here)
    ledgers = [meter.step() for _ in range(steps)]
    reported_nJ = float(meter.solver.take_push_force().mean_uN[0]) * speed_mm_s * steps * dt
    assert sum(s.elastic_nJ for s in ledgers) < 0.0
    assert abs(reported_nJ) > 100.0  # the pusher works against the coil (−669 nJ measured)
    assert meter.totals.pusher_work_nJ == pytest.approx(reported_nJ, rel=2e-3)
