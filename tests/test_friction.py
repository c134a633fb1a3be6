"""Regularised Coulomb friction: stick/slide on an incline, the capstan law,
energy never rising, scene keys, and ensemble members equal to single runs."""

import math

import numpy as np
import pytest

import warpcoil as wc
from warpcoil import validation_friction as vf
from warpcoil.deploy import Deployment, Ensemble
from warpcoil.scene import SceneError, load_scene


@pytest.mark.parametrize("ratio", [0.8, 0.99])
def test_incline_sticks_below_the_friction_angle_creeping_below_v_reg(ratio):
    _, _, creep, top_speed = vf.incline_motion(0.3, ratio, steps=6000)
    v_reg = wc.ContactSettings().friction_speed_mm_s
    assert creep == pytest.approx(ratio * v_reg, rel=1e-2)  # creep v_reg F_t/(μN) < v_reg
    assert top_speed < 1.01 * v_reg  # the start transient (end nodes weigh half) overshoots by < 1 %


def test_stick_converges_to_rest_as_the_regularisation_velocity_shrinks():
    """Creep = v_reg F_t/(μN): first order in v_reg, so exact stick in the limit."""
    creep = [vf.incline_motion(0.3, 0.9, steps=4000, v_reg_mm_s=v)[2] for v in (0.01, 0.001)]  # second half
    assert creep == pytest.approx([0.009, 0.0009], rel=1e-2)


def test_incline_slides_above_with_the_coulomb_acceleration():
    acceleration, reference, _, _ = vf.incline_motion(0.3, 1.5, steps=6000)
    assert acceleration == pytest.approx(reference, rel=1e-2)


def test_capstan_slips_at_the_exponential_tension_ratio():
    ratio, reference = vf.capstan_slip_ratio(0.3, 0.5 * math.pi)
    assert ratio == pytest.approx(reference, rel=2e-2)


def test_undamped_frictional_energy_never_rises_beyond_the_integrators_own_fluctuation():
    rise, fluctuation, dissipated = vf.frictional_energy()
    assert rise <= fluctuation
    assert dissipated > 5.0 * fluctuation


def test_friction_keys_are_read_and_checked(tmp_path):
    path = tmp_path / "s.toml"
    base = '[[coil]]\nwire_diameter_mm = 0.3\nloop_diameter_mm = 3\nlength_mm = 10\n[contact]\n'
    path.write_text(base + "friction_wall = 0.2\nfriction_coil = 0.1\nfriction_catheter = 0.05\n")
    c = load_scene(path).contact
    assert (c.friction_wall, c.friction_coil, c.friction_catheter) == (0.2, 0.1, 0.05)
    path.write_text(base + "friction_wall = -0.1\n")
    with pytest.raises(SceneError, match=r"contact\.friction_wall.*≥ 0"):
        load_scene(path)


def test_frictional_members_equal_their_single_runs():
    def scene(angle_deg):
        a = math.radians(angle_deg)
        return wc.Scene(
            coils=(wc.CoilSpec(shape="helix", length_mm=6.0, loop_diameter_mm=2.5, pitch_mm=0.6),),
            catheter=wc.CatheterSpec(tip_mm=(0.0, 0.0, -1.475), direction=(math.sin(a), 0.0, math.cos(a))),
            wall=wc.WallSpec(sphere_diameter_mm=3.5),
            contact=wc.ContactSettings(friction_wall=0.3, friction_coil=0.2, friction_catheter=0.1),
            simulation=wc.SimulationSettings(push_speed_mm_s=100.0, frame_interval_s=0.005))
    scenes = [scene(0.0), scene(20.0)]
    results = Ensemble(scenes).run()
    for s, member in zip(scenes, results):
        single = Deployment(s).run()
        assert member.status == single.status == "completed"
        for a, b in zip(single.positions_mm, member.positions_mm):
            assert np.array_equal(a, b)
