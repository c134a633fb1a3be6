"""The linearly implicit BDF2 step: L-stable (a stiff mode decays), second order in
its slow-mode damping, its history carried by the State (copies, restarts, changed
steps), and an ensemble member equal to its single run."""


import numpy as np
import pytest

from test_ensemble import assert_same_run
from test_implicit import implicit_scene
from warpcoil import validation_bdf2
from warpcoil.coil import CoilSpec
from warpcoil.model import ModelBuilder
from warpcoil.settings import SimulationSettings
from warpcoil.deploy import Deployment, Ensemble
from warpcoil.implicit import make_solver
from warpcoil.solver import Control, Stepper
from warpcoil.state import new_state_like, state_from_positions
from warpcoil.validation import bdf2_principal_root

BDF2 = {"method": "bdf2"}


def test_a_stiff_mode_decays_at_bdf2s_rate_where_the_theta_method_rings():
    offsets, w = validation_bdf2.stiff_mode_history("bdf2")
    assert w > 10.0  # a stiff mode at the default step
    ratio = abs(offsets[-1] / offsets[-3]) ** 0.5
    assert ratio == pytest.approx(abs(bdf2_principal_root(w)), rel=0.1)  # ≈ (2 ω dt)^(−1/2) → 0
    assert abs(offsets[-1]) < 1e-4 * 1e-3  # 1 µm start: gone in 6 steps
    ringing, _ = validation_bdf2.stiff_mode_history("theta", theta=0.7)
    assert np.all(np.sign(ringing[1:]) != np.sign(ringing[:-1]))  # θ 0.7: −(1 − θ)/θ per step
    assert abs(ringing[-1] / ringing[-2]) > 2.5 * ratio  # (the stiff limit: (1 − θ)/θ = 0.43)


def test_the_lowest_bending_mode_keeps_its_amplitude():
    """Euler loses 2.7 % per period at the default step; BDF2 ≈ π (ω dt)³ / 2 ≈ 1e-6."""
    loss, omega, w = validation_bdf2.mode_loss_per_period("bdf2", periods=2)
    assert abs(loss) < 2e-4
    euler, _, _ = validation_bdf2.mode_loss_per_period("theta", periods=2)
    assert euler > 100 * abs(loss)


def test_uniform_acceleration_is_integrated_exactly_after_the_start():
    """Free fall: the velocity gains g dt every step; positions follow BDF2's
    x' = 4/3 x − 1/3 x₋₁ + 2/3 dt v' after the Euler start (x₁ = dt v₁)."""
    rest = np.zeros((5, 3))
    rest[:, 0] = np.arange(5) * 0.5
    builder = ModelBuilder(settings=SimulationSettings(damping_uN_per_mm=0.0))
    builder.add_coil(CoilSpec(length_mm=2.0, segment_length_mm=0.5), rest)
    g, dt = np.array([0.0, 0.0, -1000.0]), 1e-3
    builder.body_acceleration(g)
    model = builder.finalize()
    solver = make_solver(model, "implicit", dt, coil_contact=False, **BDF2)
    a, b, control = state_from_positions(model, rest), new_state_like(model), Control.create(model)
    xs = [rest[:, 2].copy()]
    for k in range(4):
        solver.step(a, b, control)
        a, b = b, a
        assert a.history_dt_s == dt
        xs.append(a.x.numpy()[:, 2].copy())
    assert xs[1] == pytest.approx(xs[0] + dt * g[2] * dt)
    for k in range(2, 5):
        assert xs[k] == pytest.approx(4 / 3 * xs[k - 1] - 1 / 3 * xs[k - 2] + 2 / 3 * dt * k * g[2] * dt, abs=1e-12)


def test_history_travels_with_the_state_and_a_changed_step_restarts():
    """Steps one by one (each through a copy) equal one chunk; after a change of
    step the next one is an Euler start."""
    model, rest, _ = validation_bdf2._cantilever()
    start = rest.copy()
    start[:, 1] = 0.1 * (rest[:, 0] / rest[-1, 0]) ** 2
    dt = 2e-4
    one = Stepper(make_solver(model, "implicit", dt, coil_contact=False, **BDF2), state_from_positions(model, start),
                  Control.create(model), chunk=12)
    single = Stepper(make_solver(model, "implicit", dt, coil_contact=False, **BDF2),
                     state_from_positions(model, start), Control.create(model), chunk=1)
    one.run_chunk()
    for _ in range(12):
        single.run_chunk()
    assert np.array_equal(one.state.x.numpy(), single.state.x.numpy())
    assert np.array_equal(one.state.x_prev.numpy(), single.state.x_prev.numpy())
    solver = one.solver
    assert not solver.needs_start(one.state)
    solver.dt_s = 2 * dt
    assert solver.needs_start(one.state)


def test_bdf2_ensemble_members_equal_their_single_runs():
    scenes = [implicit_scene(), implicit_scene(angle_deg=15.0)]
    results = Ensemble(scenes, solver_options=BDF2).run()
    assert [r.status for r in results] == ["completed"] * 2
    for s, member in zip(scenes, results):
        assert_same_run(Deployment(s, solver_options=BDF2).run(), member)


def test_bdf2_is_refused_with_a_theta():
    model, _, _ = validation_bdf2._cantilever()
    with pytest.raises(ValueError, match="theta"):
        make_solver(model, "implicit", 1e-4, method="bdf2", theta=0.7)
    with pytest.raises(ValueError, match="method"):
        make_solver(model, "implicit", 1e-4, method="bdf3")
