"""The Python API's one-call controls: stop the pusher, read the push force without
counting steps, Stepper chunks of any size (issue 13, item 12)."""

import re
from pathlib import Path

import numpy as np
import pytest

import warpcoil as wc


def pushed_coil():
    spec = wc.CoilSpec(length_mm=6.0, loop_diameter_mm=2.0, pitch_mm=0.6)
    builder = wc.ModelBuilder(catheter=wc.CatheterSpec(), settings=wc.SimulationSettings(push_speed_mm_s=100.0))
    builder.add_coil(spec)
    model = builder.finalize("cpu")
    return model, wc.Solver(model), wc.Control.create(model, active_coil=0, push_speed_mm_s=100.0)


def test_odd_chunks_give_the_same_states_as_even_ones_bit_for_bit():
    """21 steps as 3 chunks of 7 (odd: graph of 6 + one step and a copy), as 21 of 1
    and as one plain chunk of 21 without a graph: the same state, bit for bit."""
    results = []
    for chunk, use_graph in ((7, True), (1, True), (21, False)):
        model, solver, control = pushed_coil()
        stepper = wc.Stepper(solver, wc.packed_state(model), control, chunk=chunk, use_graph=use_graph)
        while stepper.steps < 21:
            stepper.run_chunk()
        assert stepper.steps == 21
        assert stepper.state.time_s == pytest.approx(21 * solver.dt_s, rel=1e-12)
        results.append((stepper.state.x.numpy().copy(), stepper.state.advance.numpy().copy()))
    for x, advance in results[1:]:
        assert np.array_equal(x, results[0][0]) and np.array_equal(advance, results[0][1])
    assert results[0][1][0] == pytest.approx(100.0 * 21 * solver.dt_s, rel=1e-9)  # pushed 21 steps


def test_take_push_force_counts_its_steps():
    """Over 12 steps read at once: mean = the mean of the 12 step values, peak = the
    largest compressive one (≥ 0), RMS = sqrt(mean of squares)."""
    model, solver, control = pushed_coil()
    one = wc.Stepper(solver, wc.packed_state(model), control, chunk=1)
    steps = []
    for _ in range(12):
        one.run_chunk()
        push = solver.take_push_force()
        assert push.rms_uN[0] == pytest.approx(abs(push.mean_uN[0]), rel=1e-12, abs=1e-300)  # one step
        steps.append(float(push.mean_uN[0]))
    model, solver, control = pushed_coil()
    wc.Stepper(solver, wc.packed_state(model), control, chunk=12).run_chunk()
    push = solver.take_push_force()
    steps = np.array(steps)
    assert push.mean_uN[0] == pytest.approx(steps.mean(), rel=1e-12, abs=1e-12)
    assert push.peak_uN[0] == pytest.approx(max(steps.max(), 0.0), rel=1e-12, abs=1e-12)
    assert push.rms_uN[0] == pytest.approx(np.sqrt(np.mean(steps**2)), rel=1e-12)
    assert np.abs(steps).max() > 0.0  # the pusher did push


def test_set_push_speed_zero_stops_the_pusher():
    model, solver, control = pushed_coil()
    stepper = wc.Stepper(solver, wc.packed_state(model), control, chunk=50)
    stepper.run_chunk()
    moved = float(stepper.state.advance.numpy()[0])
    assert moved == pytest.approx(100.0 * 50 * solver.dt_s, rel=1e-9)
    control.set_push_speed(0.0)
    stepper.run_chunk()
    assert float(stepper.state.advance.numpy()[0]) == moved  # not one step further
    control.set_push_speed(50.0, world=0)
    stepper.run_chunk()
    assert float(stepper.state.advance.numpy()[0]) == pytest.approx(moved + 50.0 * 50 * solver.dt_s, rel=1e-9)


def test_a_chunk_below_one_step_is_refused():
    model, solver, control = pushed_coil()
    with pytest.raises(ValueError, match="1 or more"):
        wc.Stepper(solver, wc.packed_state(model), control, chunk=0)


# --- a Scene built in Python gets the checks of a scene file (deploy.Ensemble) -----------------------
SAC_MESH = Path(__file__).resolve().parents[1] / "scenes" / "aneurisk" / "C0003_closed.stl"


def python_scene(**changes):
    """A 10 mm coil into a 3.5 mm sphere, built in Python, with ``changes`` (Scene fields) made."""
    from dataclasses import replace

    scene = wc.Scene(coils=(wc.CoilSpec(wire_diameter_mm=0.2921, loop_diameter_mm=3.0, length_mm=10.0),),
                     catheter=wc.CatheterSpec(tip_mm=(0.0, 0.0, -1.45), direction=(0.0, 0.0, 1.0)),
                     wall=wc.WallSpec(sphere_diameter_mm=3.5))
    return replace(scene, **changes)


@pytest.mark.parametrize("changes, key", [
    ({"simulation": wc.SimulationSettings(dt_s=-1e-4)}, "simulation.dt_s"),  # ran backwards for ever
    ({"simulation": wc.SimulationSettings(push_speed_mm_s=-50.0)}, "simulation.push_speed_mm_s"),
    ({"simulation": wc.SimulationSettings(push_speed_mm_s=float("nan"))}, "simulation.push_speed_mm_s"),
    ({"simulation": wc.SimulationSettings(mass_scale=0.0)}, "simulation.mass_scale"),
    ({"contact": wc.ContactSettings(friction_wall=-0.2)}, "contact.friction_wall"),
    ({"contact": wc.ContactSettings(P0_uN=-1.0)}, "contact.P0_uN"),
    ({"wall": wc.WallSpec(sphere_diameter_mm=3.5, mesh=SAC_MESH)}, "wall.mesh / wall.sphere_diameter_mm: both"),
    ({"catheter": wc.CatheterSpec(direction=(0.0, 0.0, 0.0))}, "catheter.direction"),
    ({"catheter": wc.CatheterSpec(placement="neck")}, "catheter.placement"),  # no neck: was an AttributeError
    ({"catheter": wc.CatheterSpec(tip_mm=(0.0, 0.0, -1.45), direction=(0.0, 1.0, 0.0),
                                  centerline_mm=((-5.0, 0.0, -1.45), (0.0, 0.0, -1.45)))},
     "catheter.direction"),  # the centerline leaves along x, the direction says y
    ({"coils": (wc.CoilSpec(wire_diameter_mm=0.3, loop_diameter_mm=0.2, length_mm=10.0),)}, "coil[0].loop_diameter_mm"),
])
def test_a_scene_built_in_python_is_refused_where_its_file_would_be(changes, key):
    """Each value the scene reader refuses in a file is refused from Python too, naming its table and
    key, before anything is built (before: runs that hung, timed out, "completed" or raised deep inside)."""
    from warpcoil.deploy import Deployment
    from warpcoil.scene import SceneError

    with pytest.raises(SceneError, match="<Scene built in Python>: " + re.escape(key)):
        Deployment(python_scene(**changes))


def test_a_scene_built_in_python_gets_the_runs_checks_and_warnings():
    """preflight as `warpcoil run` does it: a tip outside the sac is refused (SetupError, where the run
    used to fail with advice to reduce dt_s), and warnings (segments whose chords make the coil over 1 %
    shorter than asked) are SceneWarnings; a deployment runs once."""
    import warnings

    from warpcoil.deploy import Deployment, SceneWarning
    from warpcoil.preflight import SetupError

    with pytest.raises(SetupError, match="catheter"):
        Deployment(python_scene(catheter=wc.CatheterSpec(tip_mm=(0.0, 0.0, -3.0), direction=(0.0, 0.0, 1.0))))
    coarse = wc.CoilSpec(wire_diameter_mm=0.2921, loop_diameter_mm=2.0, length_mm=10.0, segment_length_mm=1.0)
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        deployment = Deployment(python_scene(coils=(coarse,), output=wc.settings.OutputSettings(usd=False)))
    assert any(issubclass(w.category, SceneWarning) and "shorter than length_mm" in str(w.message) for w in said)
    deployment.run()
    with pytest.raises(RuntimeError, match="has run"):
        deployment.run()


def test_numpy_values_and_a_centerline_without_a_direction_pass_the_checks_of_a_python_scene():
    """What the model takes from Python passes check_built_scene as it did before it: numpy arrays and
    scalars (a tip, a length), and a centerline with the default direction (the TOML catheter without
    a direction: the centerline sets it)."""
    from warpcoil.scene import check_built_scene

    check_built_scene(python_scene(
        coils=(wc.CoilSpec(wire_diameter_mm=0.2921, loop_diameter_mm=3.0, length_mm=np.float32(10.0)),),
        catheter=wc.CatheterSpec(tip_mm=np.array([0.0, 0.0, -1.45]),
                                 centerline_mm=np.array([[-5.0, 0.0, -1.45], [0.0, 0.0, -1.45]]))))
