"""Scene TOML reader: mapping onto the dataclasses and one clear error per problem."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from warpcoil.coil import CoilSpec
from warpcoil.scene import SceneError, load_scene
from warpcoil.settings import CatheterSpec, ContactSettings, OutputSettings, SimulationSettings, WallSpec

MINIMAL_COIL = "[[coil]]\nwire_diameter_mm = 0.2921\nloop_diameter_mm = 3.0\nlength_mm = 60.0\n"

FULL = """
[wall]
mesh = "meshes/sac.stl"
units = "m"
repair = true

[catheter]
tip = [1.0, 2.0, 3]
direction = [0.0, 3.0, 4.0]
centerline = [[1, -4, -5], [1.0, 2.0, 3.0]]

[[coil]]
name = "framing"
shape = "spherical"
wire_diameter_mm = 0.3
loop_diameter_mm = 4.0
length_mm = 80
shrink = 0.5
segment_length_mm = 0.25
primary_wire_diameter_mm = 0.04
bending_stiffness_uN_mm2 = 2869.0
twist_stiffness_uN_mm2 = 3400.0
linear_density_g_mm = 6.4e-4
axial_stiffness_uN = 4.7e5
stretch_resistant = false

[[coil]]
shape = "file"
file = "preshape.txt"
wire_diameter_mm = 0.25
loop_diameter_mm = 2.0
length_mm = 30.0

[[coil]]
wire_diameter_mm = 0.25
loop_diameter_mm = 2.0
length_mm = 20.0
pitch_mm = 0.6

[contact]
P0_uN = 500.0
c0_mm = 0.02

[simulation]
integrator = "symplectic"
push_speed_mm_s = 10.0
damping_uN_per_mm = 25.0
damping_speed_mm_s = 15.0
dt_s = 2e-6
dt_safety = 1.0
allow_unstable_dt = true
mass_scale = 4
jam_force_uN = 2e5
rest_kinetic_energy_nJ = 1e-2
max_time_s = 3.0
frame_interval_s = 0.005

[output]
usd = false
"""


def write(folder: Path, text: str, name: str = "scene.toml") -> Path:
    path = folder / name
    path.write_text(text)
    return path


@pytest.fixture
def scene_dir(tmp_path: Path) -> Path:
    (tmp_path / "meshes").mkdir()
    (tmp_path / "meshes" / "sac.stl").write_text("solid sac\nendsolid sac\n")
    (tmp_path / "preshape.txt").write_text("0 0 0\n1 0 0\n")
    return tmp_path


def test_full_scene_maps_onto_dataclasses(scene_dir: Path) -> None:
    path = write(scene_dir, FULL)
    scene = load_scene(str(path))

    assert scene.source == path.resolve()
    assert scene.wall == WallSpec(mesh=(scene_dir / "meshes" / "sac.stl").resolve(), units="m", repair=True)
    assert scene.catheter == CatheterSpec(
        tip_mm=(1.0, 2.0, 3.0), direction=(0.0, 0.6, 0.8), centerline_mm=((1.0, -4.0, -5.0), (1.0, 2.0, 3.0))
    )
    framing, from_file, helix = scene.coils
    assert framing == CoilSpec(
        wire_diameter_mm=0.3,
        length_mm=80.0,
        loop_diameter_mm=4.0,
        shape="spherical",
        shrink=0.5,
        segment_length_mm=0.25,
        primary_wire_diameter_mm=0.04,
        bending_stiffness_uN_mm2=2869.0,
        twist_stiffness_uN_mm2=3400.0,
        linear_density_g_mm=6.4e-4,
        axial_stiffness_uN=4.7e5,
        stretch_resistant=False,
    )
    assert framing.name == "framing"
    assert isinstance(framing.length_mm, float)
    assert from_file.shape == "file"
    assert from_file.preshape_file == (scene_dir / "preshape.txt").resolve()
    assert (from_file.name, helix.name) == ("coil_1", "coil_2")
    assert (helix.shape, helix.pitch_mm) == ("helix", 0.6)
    assert scene.contact == ContactSettings(P0_uN=500.0, c0_mm=0.02)
    assert scene.simulation == SimulationSettings(
        integrator="symplectic",
        push_speed_mm_s=10.0,
        damping_uN_per_mm=25.0,
        damping_speed_mm_s=15.0,
        dt_s=2e-6,
        dt_safety=1.0,
        allow_unstable_dt=True,
        mass_scale=4.0,
        jam_force_uN=2e5,
        rest_kinetic_energy_nJ=1e-2,
        max_time_s=3.0,
        frame_interval_s=0.005,
    )
    assert scene.output == OutputSettings(usd=False)


def test_paths_resolve_against_the_scene_folder_not_the_cwd(
    scene_dir: Path, tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path_factory.mktemp("elsewhere"))
    scene = load_scene(write(scene_dir, FULL))
    assert scene.wall.mesh == (scene_dir / "meshes" / "sac.stl").resolve()


def test_minimal_scene_gives_defaults(tmp_path: Path) -> None:
    scene = load_scene(write(tmp_path, MINIMAL_COIL))
    assert scene.wall is None
    assert scene.coils == (CoilSpec(wire_diameter_mm=0.2921, loop_diameter_mm=3.0, length_mm=60.0),)
    assert scene.coils[0].name == "coil_0"
    assert scene.catheter == CatheterSpec()
    assert scene.contact == ContactSettings()
    assert scene.simulation == SimulationSettings(integrator="implicit")  # "auto" resolved: no reason for the reference
    assert scene.output == OutputSettings()


def test_sphere_wall(tmp_path: Path) -> None:
    text = MINIMAL_COIL + "[wall]\nsphere_diameter_mm = 6\ncenter_mm = [1, 2, 3.5]\n"
    assert load_scene(write(tmp_path, text)).wall == WallSpec(sphere_diameter_mm=6.0, center_mm=(1.0, 2.0, 3.5))


def with_coil(**keys: str) -> str:
    """The minimal coil with some keys replaced or added (values as TOML text)."""
    base = {"wire_diameter_mm": "0.2921", "loop_diameter_mm": "3.0", "length_mm": "60.0"} | keys
    return "[[coil]]\n" + "".join(f"{key} = {value}\n" for key, value in base.items())


def without(key: str) -> str:
    return "".join(line + "\n" for line in MINIMAL_COIL.splitlines() if not line.startswith(key))


ERRORS = {
    # id: (scene text, dotted key expected in the message, fragment of the problem)
    "invalid TOML": (MINIMAL_COIL + "[simulation]\ndt_s = = 1\n", "line 6", "not valid TOML"),
    "unknown table": (MINIMAL_COIL + "[simulaton]\n", "simulaton", "'simulation'"),
    "unknown key": (with_coil(lenght_mm="60.0"), "coil[0].lenght_mm", "'length_mm'"),
    "unknown key far off": (MINIMAL_COIL + "[output]\nzzz = 1\n", "output.zzz", "known: usd"),
    "missing required": (without("length_mm"), "coil[0].length_mm", "missing"),
    "missing wall mesh": (MINIMAL_COIL + '[wall]\nunits = "mm"\n', "wall.mesh / wall.sphere_diameter_mm", "missing"),
    "mesh and sphere": (
        MINIMAL_COIL + '[wall]\nmesh = "sac.stl"\nsphere_diameter_mm = 6.0\n',
        "wall.mesh / wall.sphere_diameter_mm",
        "both are given",
    ),
    "center for mesh": (
        MINIMAL_COIL + '[wall]\nmesh = "sac.stl"\ncenter_mm = [0, 0, 0]\n',
        "wall.center_mm",
        "only for wall.sphere_diameter_mm",
    ),
    "repair for sphere": (MINIMAL_COIL + "[wall]\nsphere_diameter_mm = 6\nrepair = true\n", "wall.repair", "only for"),
    "units for sphere": (MINIMAL_COIL + '[wall]\nsphere_diameter_mm = 6.0\nunits = "m"\n', "wall.units", "only for"),
    "repair not bool": (MINIMAL_COIL + '[wall]\nmesh = "sac.stl"\nrepair = "yes"\n', "wall.repair", "true or false"),
    "sphere diameter": (MINIMAL_COIL + "[wall]\nsphere_diameter_mm = -6.0\n", "wall.sphere_diameter_mm", "> 0"),
    "center length": (
        MINIMAL_COIL + "[wall]\nsphere_diameter_mm = 6.0\ncenter_mm = [0, 0]\n",
        "wall.center_mm",
        "3 finite numbers",
    ),
    "string for number": (with_coil(length_mm='"60"'), "coil[0].length_mm", "must be a number"),
    "bool for number": (MINIMAL_COIL + "[contact]\nP0_uN = true\n", "contact.P0_uN", "must be a number"),
    "number for bool": (MINIMAL_COIL + "[output]\nusd = 1\n", "output.usd", "true or false"),
    "negative": (with_coil(length_mm="-3.0"), "coil[0].length_mm", "> 0"),
    "coil in µm": (with_coil(length_mm="60000.0"), "coil[0].length_mm", "more than 20000"),
    "zero": (MINIMAL_COIL + "[simulation]\ndt_s = 0\n", "simulation.dt_s", "> 0"),
    "infinite": (MINIMAL_COIL + "[contact]\nc0_mm = inf\n", "contact.c0_mm", "finite"),
    "nan": (MINIMAL_COIL + "[simulation]\nmass_scale = nan\n", "simulation.mass_scale", "finite"),
    "dt_safety above 1": (MINIMAL_COIL + "[simulation]\ndt_safety = 1.5\n", "simulation.dt_safety", "(0, 1]"),
    "vector length": (MINIMAL_COIL + "[catheter]\ntip = [0.0, 1.0]\n", "catheter.tip", "3 finite numbers"),
    "zero direction": (MINIMAL_COIL + "[catheter]\ndirection = [0, 0, 0]\n", "catheter.direction", "zero"),
    "units": (MINIMAL_COIL + '[wall]\nmesh = "sac.stl"\nunits = "cm"\n', "wall.units", "'cm'"),
    "shape": (with_coil(shape='"cube"'), "coil[0].shape", "'cube'"),
    "file for helix": (with_coil(file='"sac.stl"'), "coil[0].file", "only for shape = 'file'"),
    "pitch for spherical": (with_coil(shape='"spherical"', pitch_mm="0.5"), "coil[0].pitch_mm", "only for"),
    "file missing for file shape": (with_coil(shape='"file"'), "coil[0].file", "required"),
    "mesh not found": (MINIMAL_COIL + '[wall]\nmesh = "nowhere.stl"\n', "wall.mesh", "nowhere.stl does not exist"),
    "preshape not found": (with_coil(shape='"file"', file='"nope.txt"'), "coil[0].file", "nope.txt does not exist"),
    "mesh is a folder": (MINIMAL_COIL + '[wall]\nmesh = "."\n', "wall.mesh", "is a folder, not a file"),
    "preshape is a folder": (with_coil(shape='"file"', file='"."'), "coil[0].file", "is a folder, not a file"),
    "no coil": ('[output]\nusd = true\n', "coil", "[[coil]]"),
    "empty coil list": ("coil = []\n", "coil", "[[coil]]"),
    "coil as single table": (MINIMAL_COIL.replace("[[coil]]", "[coil]"), "coil", "[[coil]]"),
    "short centerline": (MINIMAL_COIL + "[catheter]\ncenterline = [[0, 0, 0]]\n", "catheter.centerline", "2 points"),
    "centerline end off tip": (
        MINIMAL_COIL + "[catheter]\ncenterline = [[0, 0, -5], [0, 0, 1e-3]]\n",
        "catheter.centerline",
        "is not the tip",
    ),
    "direction off the centerline": (
        MINIMAL_COIL + "[catheter]\ntip = [0, 0, 1]\ndirection = [0, 0, -1]\ncenterline = [[0, 0, -5], [0, 0, 1]]\n",
        "catheter.direction", "180.0° off the centerline's last segment"),
    "centerline ending on a repeated point": (
        MINIMAL_COIL + "[catheter]\ntip = [0, 0, 1]\ncenterline = [[0, 0, -5], [0, 0, 1], [0, 0, 1]]\n",
        "catheter.centerline", "last two points coincide"),
    "loop no wider than the wire": (with_coil(wire_diameter_mm="5", loop_diameter_mm="3"), "coil[0].loop_diameter_mm",
                                    "not wider than the coil's wire diameter d = 5 mm"),
    "fewer than two segments": (with_coil(length_mm="0.1"), "coil[0].length_mm", "fewer than two segments of"),
    "segments longer than the coil": (with_coil(segment_length_mm="50"), "coil[0].segment_length_mm",
                                      "fewer than two segments of 50 mm"),
    "primary wire too thick": (with_coil(primary_wire_diameter_mm="0.3"), "coil[0].primary_wire_diameter_mm",
                               "is not thinner than the coil's wire diameter d = 0.2921 mm"),
    "shrink above 1": (with_coil(shape='"spherical"', shrink="5"), "coil[0].shrink", "must be in (0, 1], got 5"),
    "second coil": (MINIMAL_COIL + with_coil(wire_diameter_mm='"x"'), "coil[1].wire_diameter_mm", "number"),
    "porous without wall": (MINIMAL_COIL + "[output]\nporous = true\n", "output.porous", "no [wall]"),
    "porous voxel": (MINIMAL_COIL + "[output]\nporous_voxel_mm = 0\n", "output.porous_voxel_mm", "> 0"),
    "occlusion threshold in %": (MINIMAL_COIL + "[regions]\nocclusion_threshold = 31\n",
                                 "regions.occlusion_threshold", "(0, 1]"),
    "size without a product": (with_coil(size='"3 x 6"'), "coil[0].product",
                               "`warpcoil coils` lists them"),
    "regions without a neck": (MINIMAL_COIL + "[regions]\nvoxel_mm = 0.05\n", "regions", "there is no [neck]"),
}


@pytest.mark.parametrize(("text", "key", "problem"), ERRORS.values(), ids=ERRORS.keys())
def test_errors_name_file_key_and_problem(tmp_path: Path, text: str, key: str, problem: str) -> None:
    (tmp_path / "sac.stl").write_text("solid sac\nendsolid sac\n")
    with pytest.raises(SceneError) as caught:
        load_scene(write(tmp_path, text, "bad_scene.toml"))
    message = str(caught.value)
    assert "bad_scene.toml" in message
    assert key in message
    assert problem in message
    assert "fix:" in message


def test_a_centerline_sets_the_direction_the_coil_leaves_along(tmp_path: Path) -> None:
    """Without a direction, the centerline's last segment gives it; a direction within 1° of it is kept as that."""
    bent = "[catheter]\ntip = [1, 0, 1]\ncenterline = [[0, 0, -5], [0, 0, 0], [1, 0, 1]]\n"
    assert load_scene(write(tmp_path, MINIMAL_COIL + bent)).catheter.direction == pytest.approx(
        (math.sqrt(0.5), 0.0, math.sqrt(0.5)))
    close = bent.replace("tip =", "direction = [1, 0, 1.01]\ntip =")
    assert load_scene(write(tmp_path, MINIMAL_COIL + close)).catheter.direction == pytest.approx(
        (math.sqrt(0.5), 0.0, math.sqrt(0.5)))


def test_centerline_end_within_tolerance_is_accepted(tmp_path: Path) -> None:
    text = MINIMAL_COIL + "[catheter]\ntip = [0, 0, 1]\ncenterline = [[0, 0, -5], [0, 0, 1.0000000001]]\n"
    assert math.isclose(load_scene(write(tmp_path, text)).catheter.centerline_mm[-1][2], 1.0)


@pytest.mark.parametrize("make", [lambda tmp: tmp / "absent.toml", lambda tmp: tmp])
def test_unreadable_file(tmp_path: Path, make) -> None:
    path = make(tmp_path)
    with pytest.raises(SceneError, match="cannot be read") as caught:
        load_scene(path)
    assert str(path.resolve()) in str(caught.value)


def test_scene_error_is_a_value_error() -> None:
    assert issubclass(SceneError, ValueError)


def test_neck_and_catheter_placement_keys(tmp_path):
    from warpcoil.scene import load_scene

    neck_file = tmp_path / "neck.csv"
    neck_file.write_text("1,0,0\n0,1,0\n-1,0,0\n0,-1,0\n")
    scene_file = tmp_path / "neck.toml"
    scene_file.write_text(
        '[wall]\nsphere_diameter_mm = 3.0\n[neck]\ncontour = "neck.csv"\n'
        '[catheter]\nplacement = "neck"\ndepth_mm = 0.4\nangle_deg = 10.0\nazimuth_deg = 90.0\n'
        '[[coil]]\nwire_diameter_mm = 0.2921\nloop_diameter_mm = 2.0\nlength_mm = 5.0\n'
        '[regions]\nvoxel_mm = 0.05\nocclusion_threshold = 0.24\n')
    scene = load_scene(scene_file)
    assert scene.neck.contour == neck_file.resolve()
    assert (scene.catheter.placement, scene.catheter.depth_mm, scene.catheter.angle_deg) == ("neck", 0.4, 10.0)
    assert (scene.regions.voxel_mm, scene.regions.occlusion_threshold) == (0.05, 0.24)


@pytest.mark.parametrize("text, key", [
    ('[wall]\nsphere_diameter_mm = 3.0\n[catheter]\nplacement = "neck"\n', "catheter.placement"),
    ('[wall]\nsphere_diameter_mm = 3.0\n[neck]\nplane_point_mm = [0, 0, 0]\n', "neck.contour / neck.plane_point_mm"),
    ('[neck]\nplane_point_mm = [0, 0, 0]\nplane_normal = [0, 0, 1]\n', "neck"),
    ('[wall]\nsphere_diameter_mm = 3.0\n[neck]\nplane_point_mm = [0, 0, 0]\nplane_normal = [0, 0, 1]\n'
     '[catheter]\nplacement = "neck"\ntip = [0, 0, 0]\n', "catheter.tip"),
])
def test_neck_errors_name_the_key(tmp_path, text, key):
    from warpcoil.scene import SceneError, load_scene

    scene_file = tmp_path / "bad.toml"
    scene_file.write_text(text + '[[coil]]\nwire_diameter_mm = 0.2921\nloop_diameter_mm = 2.0\nlength_mm = 5.0\n')
    with pytest.raises(SceneError, match="bad.toml") as info:
        load_scene(scene_file)
    assert key in str(info.value)


@pytest.mark.parametrize(("coil", "simulation", "integrator"), [
    ("segment_length_mm = 0.15\n", "", "implicit"),  # l0 = d/2: within the implicit step's validated range
    ("segment_length_mm = 0.1\n", "", "symplectic"),  # below d/2, no integrator named: the reference
    ("segment_length_mm = 0.1\n", 'integrator = "implicit"\n', "implicit"),  # named: as named, with a warning
    ("segment_length_mm = 0.1\n", "dt_s = 1e-5\n", "implicit"),  # a step chosen for one integrator: not switched
])
def test_segments_below_half_the_diameter_choose_the_reference_where_the_scene_names_no_integrator(
        tmp_path: Path, coil: str, simulation: str, integrator: str) -> None:
    """The implicit step is validated for d/2 ≤ l0 ≤ 2d (below, a released coil gains energy): a scene with
    finer segments that names no integrator runs the reference and says why; one that names the
    implicit step keeps it with a warning before the run."""
    from warpcoil.preflight import check_integrator

    path = write(tmp_path, f"[[coil]]\nwire_diameter_mm = 0.3\nloop_diameter_mm = 3\nlength_mm = 10\n{coil}"
                           f"[simulation]\n{simulation}")
    scene = load_scene(path)
    assert scene.simulation.integrator == integrator
    chose = [note for note in scene.notes if "coil[0].segment_length_mm = 0.1 mm is below d/2" in note]
    assert bool(chose) == (integrator == "symplectic")
    warned = [w for w in check_integrator(scene, 0.0) if "below d/2" in w]
    assert bool(warned) == (integrator == "implicit" and "= 0.1\n" in coil)


def test_a_coil_its_segments_shorten_by_more_than_one_percent_is_warned_about(tmp_path: Path) -> None:
    """A 2 mm helix sampled at 1 mm: its chords are ~4 % shorter than the 20 mm asked for; the warning
    says so (as measured on the rest centerline) and which segment length keeps it within 1 %, and that
    one does. At the default l0 = d the shortfall (κ l0)²/24 is 0.2 %: no warning."""
    from warpcoil.preflight import check_coil_lengths
    from warpcoil.preshape import rest_centerline

    coarse = load_scene(write(tmp_path, with_coil(loop_diameter_mm="2.0", length_mm="20.0", segment_length_mm="1.0")))
    chords_mm = np.linalg.norm(np.diff(rest_centerline(coarse.coils[0]), axis=0), axis=1).sum()
    assert 0.95 < chords_mm / 20.0 < 0.97
    said = check_coil_lengths(coarse)
    assert len(said) == 1  # 1 mm segments of a 0.2921 mm wire: their contact samples keep coils apart, no word
    short = f"{100 * (1 - chords_mm / 20.0):.1f} % shorter than length_mm ({chords_mm:.4g} of 20 mm)"
    assert short in said[0], said
    suggested = float(said[0].split("segment_length_mm = ")[1].split(" ")[0])
    finer = replace(coarse, coils=(replace(coarse.coils[0], segment_length_mm=suggested),))
    assert [w for w in check_coil_lengths(finer) if "shorter than length_mm" in w] == []
    assert check_coil_lengths(load_scene(write(tmp_path, with_coil(loop_diameter_mm="2.0")))) == []


@pytest.mark.parametrize(("segment_mm", "simulation", "warned"), [
    ("0.6", "", True),  # 2d (+) on the implicit step: outside bench accuracy's range, said before the run
    ("0.6", 'integrator = "symplectic"\n', False),  # the reference: nothing to say
    ("1.0", 'integrator = "implicit"\n', True),
    ("0.59", "", False),  # within 2d: no word
])
def test_segments_above_twice_the_diameter_on_the_implicit_step_are_warned_about(
        tmp_path: Path, segment_mm: str, simulation: str, warned: bool) -> None:
    """The implicit step's accuracy is measured for d/2 ≤ l0 ≤ 2d (`bench accuracy`); coarser coils run
    (their coil–coil contact holds with its contact samples) with a warning that names the fix."""
    from warpcoil.preflight import check_integrator

    path = write(tmp_path, f"[[coil]]\nwire_diameter_mm = 0.295\nloop_diameter_mm = 3\nlength_mm = 10\n"
                           f"segment_length_mm = {segment_mm}\n[simulation]\n{simulation}")
    said = [w for w in check_integrator(load_scene(path), 0.0) if "above 2d" in w]
    assert bool(said) == warned
    if warned:
        assert "is above 2d = 0.59 mm" in said[0] and "fix: segment_length_mm ≤ 0.59, or integrator" in said[0]
