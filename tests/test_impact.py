"""A wall impact without damping: the reference step's contact is elastic (restitution 1) and the
implicit step's restitution converges to it at first order as its step shrinks
(warpcoil/validation_impact.py)."""

from warpcoil import validation
from warpcoil.solver import Solver
from warpcoil.validation_impact import impact_cases, impact_model, restitution


def test_the_reference_bounces_back_and_the_implicit_step_converges_to_it():
    rows = impact_cases()
    failed = [r for r in rows if not r.passed]
    assert not failed, validation.format_table(failed)
    assert len(rows) == 3


def test_a_slower_reference_step_bounces_the_same():
    """The law is conservative, not the step: half the reference step returns the same speed."""
    model, start = impact_model()
    full = Solver(model, coil_contact=False)
    half = Solver(model, coil_contact=False, dt_s=0.5 * full.dt_s)
    assert abs(restitution(model, start, full) - restitution(model, start, half)) < 1e-3
