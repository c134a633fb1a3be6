"""A scene turned as a whole turns its run with it (warpcoil/orientation.py): the wall's own axes
turn with the wall, a sphere defines none, and a coil deployed into a turned faceted sac stays the
turned copy of the coil deployed into the original (its roll about the catheter is the wall's, not
the coordinate axes'); ``catheter.roll_deg`` turns the coil about the catheter."""

import math
from dataclasses import replace

import numpy as np
import pytest

from warpcoil.anatomy import Anatomy
from warpcoil.coil import CoilSpec
from warpcoil.deploy import Ensemble
from warpcoil.faceted_sac import catheter_tip, lobulated_sac
from warpcoil.orientation import anatomy_normal, skew_vector
from warpcoil.settings import CatheterSpec, ContactSettings, OutputSettings, Scene, SimulationSettings
from warpcoil.wall import sphere_wall

D = 0.2921


def rotation(seed: int = 3) -> np.ndarray:
    """A proper rotation with no special axis (QR of a random matrix)."""
    q, r = np.linalg.qr(np.random.default_rng(seed).standard_normal((3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def sac():
    return lobulated_sac(math.pi * (D / 2.0) ** 2 * 12.0 / 0.2, seed=2)


def test_the_walls_skew_vector_turns_with_it_and_a_sphere_has_none():
    wall, turn = sac(), rotation()
    skew, centroid = skew_vector(wall.vertices_mm, wall.faces)
    turned, turned_centroid = skew_vector(wall.vertices_mm @ turn.T, wall.faces)
    assert skew is not None and np.allclose(turn @ skew, turned, rtol=1e-9, atol=1e-12)
    assert np.allclose(turn @ centroid, turned_centroid, atol=1e-12)
    sphere = sphere_wall(3.5)
    assert skew_vector(sphere.vertices_mm, sphere.faces)[0] is None


def tilts(axis: np.ndarray, degrees: float) -> np.ndarray:
    """``axis`` tilted by ``degrees`` towards a fixed normal of it."""
    normal = np.cross(axis, [0.3, -0.5, 0.8])
    normal /= np.linalg.norm(normal)
    a = np.radians(degrees)
    return np.cos(a) * axis + np.sin(a) * normal


def test_the_roll_turns_little_for_a_small_tilt():
    """The reference normal to the catheter turns by less than 1° for a 0.1° tilt at 400 random directions
    more than 10° from the skew vector's line (the old rule jumped by 90–180° across its boundaries), and
    in a sphere (the tip off its centre) across the 17.5° tilt where the first version of this rule jumped."""
    wall = sac()
    skew, _ = skew_vector(wall.vertices_mm, wall.faces)
    skew = skew / np.linalg.norm(skew)
    rng = np.random.default_rng(7)
    checked = 0
    for axis in rng.standard_normal((400, 3)):
        axis /= np.linalg.norm(axis)
        if abs(axis @ skew) > math.cos(math.radians(10.0)):
            continue
        before = anatomy_normal(axis, wall.vertices_mm, wall.faces)
        after = anatomy_normal(tilts(axis, 0.1), wall.vertices_mm, wall.faces)
        assert np.degrees(np.arccos(min(1.0, before @ after))) < 1.0
        checked += 1
    assert checked > 300
    sphere, tip = sphere_wall(3.5), np.array([0.0, 0.0, -1.475])
    for degrees in (17.4, 17.6):
        a = np.radians(degrees)
        axis = np.array([np.sin(a), 0.0, np.cos(a)])
        reference = anatomy_normal(axis, sphere.vertices_mm, sphere.faces, tip)
        assert reference @ np.array([-1.0, 0.0, 0.0]) > 0.95  # towards the centre, on both sides


def run(wall, tip, direction, roll_deg: float = 0.0, max_time_s: float | None = 0.03):
    """12 mm of a 2.5 mm helix pushed into ``wall`` from ``tip`` along ``direction`` (BVH wall: a field's
    voxels would not turn with it) for ``max_time_s`` (None: not run): the ensemble and its result."""
    catheter = CatheterSpec(tip_mm=tuple(map(float, tip)), direction=tuple(map(float, direction)), roll_deg=roll_deg)
    scene = Scene(coils=(CoilSpec(wire_diameter_mm=D, length_mm=12.0, loop_diameter_mm=2.5, shape="helix",
                                  pitch_mm=0.6),),
                  catheter=catheter, output=OutputSettings(usd=False), contact=ContactSettings(wall_query="bvh"),
                  simulation=SimulationSettings(max_time_s=max_time_s or 1.0))
    ensemble = Ensemble([scene], anatomies=[Anatomy(wall=wall, sac=None, catheter=catheter)])
    return ensemble, ensemble.run()[0] if max_time_s else None


def test_a_turned_scene_deploys_the_turned_coil():
    wall, turn = sac(), rotation()
    tip, direction = np.array(catheter_tip(wall, 2)), np.array([0.0, 0.0, 1.0])
    first, result = run(wall, tip, direction)
    turned_wall = replace(wall, vertices_mm=wall.vertices_mm @ turn.T)
    second, turned_result = run(turned_wall, turn @ tip, turn @ direction)
    assert result.status == turned_result.status and result.steps == turned_result.steps
    assert result.min_wall_gap_mm < 0.0  # the coil has met the wall (its float32 BVH rounds differently when turned,
    x, y = result.positions_mm[0], turned_result.positions_mm[0]  # and contact amplifies it from here on)
    out = np.linalg.norm(x - tip, axis=1) > 1.0  # the curled part, out of the catheter
    assert out.sum() > 10
    assert np.abs(x @ turn.T - y).max() < 1e-6  # (8e-9 mm; rolled by the coordinate axes it was 0.57 mm apart)


def test_roll_deg_turns_the_coil_about_the_catheter():
    wall = sac()
    tip, direction = np.array(catheter_tip(wall, 2)), np.array([0.0, 0.0, 1.0])
    ensemble, _ = run(wall, tip, direction, max_time_s=None)
    rolled, _ = run(wall, tip, direction, roll_deg=90.0, max_time_s=None)
    m1, m1_rolled = ensemble.stepper.state.m1.numpy()[0], rolled.stepper.state.m1.numpy()[0]
    assert abs(m1 @ direction) < 1e-12 and m1 @ m1_rolled == pytest.approx(0.0, abs=1e-12)
    assert np.cross(m1, m1_rolled) @ direction == pytest.approx(1.0)  # right-handed about the catheter direction


def test_a_tilted_neck_catheter_turns_with_the_scene():
    """placement = "neck" with angle_deg 30 and azimuth_deg 45 on C0003: the azimuth is counted from the
    wall's own axis, so the turned patient places the turned catheter (it was counted from the coordinate
    axis least aligned with the neck normal)."""
    from pathlib import Path

    from warpcoil.anatomy import _placed_catheter, _wall_and_sac
    from warpcoil.sac import sac_from_neck
    from warpcoil.scene import load_scene

    scene = load_scene(Path(__file__).resolve().parents[1] / "scenes" / "aneurisk_C0003.toml",
                       {"catheter.angle_deg": 30.0, "catheter.azimuth_deg": 45.0})
    wall, sac_ = _wall_and_sac(scene)
    turn = rotation(5)
    turned_wall = replace(wall, vertices_mm=wall.vertices_mm @ turn.T)
    neck = sac_.neck
    turned_neck = replace(neck, contour_mm=neck.contour_mm @ turn.T, centroid_mm=turn @ neck.centroid_mm,
                          normal=turn @ neck.normal)
    placed = _placed_catheter(scene, wall, sac_)
    turned = _placed_catheter(scene, turned_wall, sac_from_neck(turned_wall, turned_neck))
    assert np.allclose(turn @ np.array(placed.tip_mm), turned.tip_mm, atol=1e-9)
    assert np.allclose(turn @ np.array(placed.direction), turned.direction, atol=1e-9)
    assert np.degrees(np.arccos(np.array(placed.direction) @ neck.normal)) == pytest.approx(30.0)


def test_the_roll_is_about_a_centerlines_last_piece():
    """A scene built in Python with a centerline tilted 50° from its (default) direction, in an 8 mm sphere:
    the coil's first director is normal to the centerline at the tip, and roll_deg turns it by 90° about that
    axis (it was turned about the direction, then projected)."""
    wall, tip = sphere_wall(8.0), np.array([0.0, 0.0, 0.5])  # (its reference: from the tip to the centre)
    axis = np.array([math.sin(math.radians(50.0)), 0.0, math.cos(math.radians(50.0))])
    line = (tuple(tip - 3.0 * axis), tuple(tip - 1.0 * axis), tuple(tip))
    directors = []
    for roll in (0.0, 90.0):
        catheter = CatheterSpec(tip_mm=tuple(tip), centerline_mm=line, roll_deg=roll)
        scene = Scene(coils=(CoilSpec(wire_diameter_mm=D, length_mm=12.0, loop_diameter_mm=2.5, shape="helix",
                                      pitch_mm=0.6),), catheter=catheter, output=OutputSettings(usd=False))
        ensemble = Ensemble([scene], anatomies=[Anatomy(wall=wall, sac=None, catheter=catheter)])
        directors.append(ensemble.stepper.state.m1.numpy()[0])
    plain, rolled = directors
    assert abs(plain @ axis) < 1e-12 and abs(rolled @ axis) < 1e-12
    assert np.cross(plain, rolled) @ axis == pytest.approx(1.0)


def quarter_arc(radius_mm: float = 3.0, straight_mm: float = 30.0, pieces: int = 60) -> tuple:
    """A catheter centerline: straight along −x, then a quarter arc of ``radius_mm`` ending at the origin along +z."""
    phi = np.linspace(np.pi / 2.0, 0.0, pieces + 1)
    arc = np.column_stack([radius_mm - radius_mm * np.cos(phi), np.zeros_like(phi), -radius_mm * np.sin(phi)])
    points = np.vstack([[radius_mm + straight_mm, 0.0, -radius_mm], arc])
    return tuple(tuple(map(float, p)) for p in points)


def test_a_curved_catheter_packs_the_coil_at_its_least_energy_roll():
    """A 30 mm helix (3 mm loops) through a quarter arc of radius 3 mm: packed at the roll where its pre-curvature
    follows the bend, the least stored energy (EI/2 (1/R² − 2κ₀/R) L_arc over the arc: 16 607 nJ; against the bend
    22 508 nJ, where the coordinate axes' roll put it: 22 421), and roll_deg 180 turns it against the bend."""
    stored = {}
    for roll in (0.0, 90.0, 180.0):
        catheter = CatheterSpec(tip_mm=(0.0, 0.0, 0.0), centerline_mm=quarter_arc(), roll_deg=roll)
        scene = Scene(coils=(CoilSpec(wire_diameter_mm=D, length_mm=30.0, loop_diameter_mm=3.0, shape="helix",
                                      pitch_mm=0.6),), catheter=catheter, output=OutputSettings(usd=False))
        ensemble = Ensemble([scene])
        energies, _ = ensemble.solver.world_energies(ensemble.stepper.state)
        stored[roll] = float(energies["bend_nJ"][0] + energies["twist_nJ"][0] + energies["stretch_nJ"][0])
    assert stored[0.0] == pytest.approx(16607.0, rel=0.01)
    assert stored[0.0] < stored[90.0] < stored[180.0]
    assert stored[180.0] == pytest.approx(22508.0, rel=0.01)


def test_a_plans_explicit_perturbations_turn_with_the_scene(tmp_path):
    """plan.perturbed_keys for an explicit catheter counts its azimuths from the direction the wall defines
    (plan.explicit_reference): the turned scene's perturbed directions are the turned ones (they were
    counted from the coordinate axes, a differently phased set)."""
    import trimesh

    from warpcoil.plan import explicit_reference, perturbed_keys
    from warpcoil.settings import WallSpec

    wall, turn = sac(), rotation(11)
    tip, direction = np.array(catheter_tip(wall, 2)), np.array([0.0, 0.0, 1.0])
    sets = []
    for vertices, t, d, name in ((wall.vertices_mm, tip, direction, "a.stl"),
                                 (wall.vertices_mm @ turn.T, turn @ tip, turn @ direction, "b.stl")):
        trimesh.Trimesh(vertices, wall.faces, process=False).export(tmp_path / name)
        scene = Scene(coils=(CoilSpec(),), wall=WallSpec(mesh=tmp_path / name),
                      catheter=CatheterSpec(tip_mm=tuple(map(float, t)), direction=tuple(map(float, d))))
        keys = perturbed_keys(scene.catheter, 4, 1.0, explicit_reference(scene))
        sets.append(np.array([k["catheter.direction"] for k in keys]))
    plain, turned = sets
    assert np.abs(plain @ turn.T - turned).max() < 1e-6  # (the STL's float32 vertices)


def test_a_coil_behind_another_in_a_curved_catheter_rolls_with_it():
    """Two coils (5 and 20 mm) through the quarter arc: the second one's first director is the roll carried back
    along the catheter, so roll_deg −8° and −4° turn it by 4° (projecting the tip's direction onto its first edge,
    which lies round the bend, flipped it by ~140°)."""
    directors = []
    for roll in (-8.0, -4.0):
        catheter = CatheterSpec(tip_mm=(0.0, 0.0, 0.0), centerline_mm=quarter_arc(), roll_deg=roll)
        coils = tuple(CoilSpec(name=f"c{k}", wire_diameter_mm=D, length_mm=length, loop_diameter_mm=3.0, shape="helix",
                               pitch_mm=0.6) for k, length in enumerate((5.0, 20.0)))
        ensemble = Ensemble([Scene(coils=coils, catheter=catheter, output=OutputSettings(usd=False))])
        first = int(ensemble.model.coil_first[1])
        directors.append(ensemble.stepper.state.m1.numpy()[first])
    turned_deg = np.degrees(np.arccos(np.clip(directors[0] @ directors[1], -1.0, 1.0)))
    assert turned_deg == pytest.approx(4.0, abs=0.5)
