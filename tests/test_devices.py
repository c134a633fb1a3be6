"""Balloon and stent: geometry fitted to the vessel, contact through the wall /
coil–coil law, fit errors naming the key, and the balloon's deflation."""

import math
import subprocess
import sys

import numpy as np
import pytest
import trimesh
import warp as wp

from warpcoil.devices import DeviceError, balloon_geometry, deflation, stent_struts
from warpcoil.kernels import devices as kernels
from warpcoil.settings import BalloonSpec, StentSpec
from warpcoil.wall import WallMesh

VESSEL_R_MM = 1.5
OFF = (0.013, 0.007)  # off the exact axis, where every side face is equally close (the BVH sign is ambiguous)
AXIS = ((*OFF, -6.0), (*OFF, 6.0))


@pytest.fixture(scope="module")
def vessel():
    """A straight vessel of radius 1.5 mm along z, 20 mm long (closed ends)."""
    tube = trimesh.creation.cylinder(radius=VESSEL_R_MM, height=20.0, sections=256)
    return WallMesh(np.asarray(tube.vertices, float), np.asarray(tube.faces, np.int32), float(tube.volume), (), None)


def test_balloon_grows_to_its_diameter_but_is_capped_by_the_wall(vessel):
    stations, radius = balloon_geometry(BalloonSpec(axis_mm=AXIS, diameter_mm=4.0), vessel)
    assert np.all(np.linalg.norm(np.diff(stations, axis=0), axis=1) <= 0.25 + 1e-12)
    # the inscribed radius of a 256-gon is R cos(π/256), less the axis offset
    assert radius == pytest.approx(np.full(len(radius), VESSEL_R_MM * math.cos(math.pi / 256) - math.hypot(*OFF)),
                                   abs=2e-3)
    _, small = balloon_geometry(BalloonSpec(axis_mm=AXIS, diameter_mm=2.0), vessel)
    assert np.all(small == 1.0)


def test_a_balloon_axis_outside_the_vessel_names_the_key(vessel):
    with pytest.raises(DeviceError, match=r"balloon\.axis.*outside the lumen.*fix"):
        balloon_geometry(BalloonSpec(axis_mm=((0.0, 2.0, 0.0), (0.0, 2.0, 5.0))), vessel)


def test_a_device_too_wide_for_the_vessel_names_its_size_and_a_degenerate_axis_its_axis(vessel):
    """A 40 mm balloon (its cap 5 % of it, 2 mm, beyond the 1.5 mm vessel) names balloon.diameter_mm, not
    the axis on the centreline; a stent of 2 mm struts names strut_diameter_mm; an axis whose points
    coincide names the axis."""
    with pytest.raises(DeviceError, match=r"balloon\.diameter_mm: 40 mm needs more than the 1\.4\d\d mm.*fix"):
        balloon_geometry(BalloonSpec(axis_mm=AXIS, diameter_mm=40.0), vessel)
    with pytest.raises(DeviceError, match=r"stent\.strut_diameter_mm: 2 mm needs more than"):
        stent_struts(StentSpec(axis_mm=AXIS, diameter_mm=4.0, strut_diameter_mm=2.0), vessel)
    point = (*OFF, 0.0)
    for make, spec in ((balloon_geometry, BalloonSpec(axis_mm=(point, point))),
                       (stent_struts, StentSpec(axis_mm=(point, point), diameter_mm=4.0))):
        with pytest.raises(DeviceError, match=r"\.axis: its points .* coincide: the axis has no length; fix"):
            make(spec, vessel)


def test_balloon_contact_is_the_law_along_the_radius_and_vanishes_deflated():
    p0, c0, r_node = 1.0e3, 0.03, 0.15
    stations = np.array([[0.0, 0.0, -2.0], [0.0, 0.0, 2.0]])
    gaps = np.array([0.0, -0.01, 0.02, 0.05])
    x = np.stack([1.0 + r_node + gaps, np.zeros(4), np.linspace(-1, 1, 4)], 1)

    def forces(inflation):
        out = wp.zeros(4, dtype=wp.vec3d)
        wp.launch(kernels.balloon_contact, 4, inputs=[
            wp.array(x, dtype=wp.vec3d), wp.ones(4, dtype=wp.int32), wp.zeros(4, dtype=wp.int32),
            wp.ones(1, dtype=wp.int32), wp.full(4, r_node, dtype=wp.float64), wp.ones(4, dtype=wp.float64),
            wp.array(stations, dtype=wp.vec3d),
            wp.full(2, 1.0, dtype=wp.float64), wp.zeros(1, dtype=wp.int32), wp.full(1, 2, dtype=wp.int32),
            wp.full(1, inflation, dtype=wp.float64), p0, c0, 7.0, out])
        return out.numpy()

    f = forces(1.0)
    u = 1.0 - gaps / c0
    law = np.where(gaps < c0, p0 / (math.e - 1.0) * u * (np.exp(u) - 1.0), 0.0)
    assert f[:, 0] == pytest.approx(law, rel=1e-12, abs=1e-12)
    assert np.abs(f[:, 1:]).max() < 1e-9 * law.max()
    assert np.all(forces(0.0) == 0.0)


def test_deflation_starts_when_told_and_takes_its_time():
    spec = BalloonSpec(axis_mm=AXIS, deflation_time_s=0.1)
    assert deflation(spec, 5.0, None) == 1.0
    assert deflation(spec, 1.05, 1.0) == pytest.approx(0.5)
    assert deflation(spec, 1.2, 1.0) == 0.0


def test_stent_cells_are_closed_diamonds_apposed_to_the_wall(vessel):
    spec = StentSpec(axis_mm=AXIS, diameter_mm=3.5, cell_size_mm=1.5, strut_diameter_mm=0.07)
    starts, ends = stent_struts(spec, vessel)
    r_expected = VESSEL_R_MM * math.cos(math.pi / 256) - 0.035
    r_lattice = r_expected - math.hypot(*OFF)  # radius = the station's wall distance − strut radius
    for p in (starts, ends):
        assert np.linalg.norm(p[:, :2] - OFF, axis=1) == pytest.approx(r_lattice, abs=2e-3)
    r_expected = r_lattice
    around = round(2 * math.pi * r_expected / 1.5)
    half_cell = 2 * r_expected * math.sin(math.pi / (2 * around))  # chord to the next ring's node
    assert np.linalg.norm(ends - starts, axis=1) == pytest.approx(math.hypot(0.75, half_cell), rel=1e-3)
    # interior lattice nodes join four struts: every cell is closed
    nodes, degree = np.unique(np.round(np.concatenate([starts, ends]), 9), axis=0, return_counts=True)
    interior = (nodes[:, 2] > nodes[:, 2].min() + 1e-6) & (nodes[:, 2] < nodes[:, 2].max() - 1e-6)
    assert np.all(degree[interior] == 4)


def test_a_stent_smaller_than_the_vessel_names_the_key_and_the_fix(vessel):
    with pytest.raises(DeviceError, match=r"stent\.diameter_mm = 2.*smaller than the vessel.*fix: diameter_mm ≥ 2\.9"):
        stent_struts(StentSpec(axis_mm=AXIS, diameter_mm=2.0), vessel)


def test_strut_contact_is_the_coil_coil_law_and_a_small_loop_passes_a_cell():
    """A coil edge across one strut feels the segment law; an edge in the middle of a
    cell (farther than c0 from every strut) feels nothing: it can prolapse."""
    p0, c0, r_coil, r_strut = 1.0e3, 0.03, 0.15, 0.035
    strut_a = np.array([[-1.0, 0.0, 0.0]])
    strut_b = np.array([[1.0, 0.0, 0.0]])
    gap = 0.01
    z = r_coil + r_strut + gap
    x = np.array([[0.0, -0.5, z], [0.0, 0.5, z], [0.0, 0.6, 0.5], [0.0, 1.0, 0.5]])  # edges 0 (across) and 2 (away)
    has_next = np.array([1, 0, 1, 0], np.int32)
    grid = wp.HashGrid(4, 4, 4, dtype=wp.float64)
    grid.build(wp.array(0.5 * (strut_a + strut_b), dtype=wp.vec3d), 2.0, groups=wp.zeros(1, dtype=wp.int32))
    start, end = wp.zeros(4, dtype=wp.vec3d), wp.zeros(4, dtype=wp.vec3d)
    wp.launch(kernels.strut_contact, 4, inputs=[
        wp.array(x, dtype=wp.vec3d), wp.ones(4, dtype=wp.int32), wp.array(has_next, dtype=wp.int32),
        wp.zeros(4, dtype=wp.int32), wp.ones(1, dtype=wp.int32), wp.full(4, r_coil, dtype=wp.float64), grid.id,
        wp.array(strut_a, dtype=wp.vec3d), wp.array(strut_b, dtype=wp.vec3d), r_strut, 2.0, p0, c0, 7.0, start, end])
    u = 1.0 - gap / c0
    law = p0 / (math.e - 1.0) * u * (math.exp(u) - 1.0)
    total = start.numpy()[0] + end.numpy()[0]
    assert total == pytest.approx([0.0, 0.0, law], rel=1e-7, abs=1e-6)  # fixed-point resolution 1.5e-8 µN
    assert np.all(start.numpy()[2] == 0.0) and np.all(end.numpy()[2] == 0.0)


def test_cli_refuses_a_balloon_outside_the_vessel(tmp_path):
    scene = tmp_path / "s.toml"
    scene.write_text('[wall]\nsphere_diameter_mm = 6.0\n[[coil]]\nwire_diameter_mm = 0.3\nloop_diameter_mm = 3\n'
                     'length_mm = 5\n[balloon]\naxis = [[0.0, 0.0, 4.0], [0.0, 0.0, 5.0]]\n')
    log = tmp_path / "log.txt"
    with log.open("w") as out:
        rc = subprocess.call([sys.executable, "-m", "warpcoil.cli", "run", str(scene), "-o", str(tmp_path / "o"),
                              "--quiet", "--no-usd"], stdout=out, stderr=subprocess.STDOUT)
    assert rc == 2
    assert "balloon.axis" in log.read_text() and "fix:" in log.read_text()


def warpcoil_run(scene, out, log) -> tuple[int, str]:
    """`warpcoil run SCENE -o OUT` as a user runs it, stdout and stderr into ``log``: (exit code, log text)."""
    with log.open("w") as stream:
        rc = subprocess.call([sys.executable, "-m", "warpcoil.cli", "run", str(scene), "-o", str(out)],
                             stdout=stream, stderr=subprocess.STDOUT)
    return rc, log.read_text()


def test_cli_refuses_a_catheter_tip_inside_the_inflated_balloon(tmp_path):
    """A balloon whose round end cap holds the tip (a helper's scene: its axis along the catheter's path,
    ending 0.7 mm below the tip) squeezed the coil out at −305 mN and reported it completed; refused,
    exit 2, naming the keys and the fix, no output folder; the tip is measured against the capsule chain."""
    from warpcoil.preflight import balloon_gap_mm

    scene = tmp_path / "s.toml"
    scene.write_text('[wall]\nsphere_diameter_mm = 8.0\n[catheter]\ntip = [0.0, 0.0, 0.0]\n'
                     'direction = [0.0, 0.0, 1.0]\n[[coil]]\nwire_diameter_mm = 0.3\nloop_diameter_mm = 3\n'
                     'length_mm = 5\n[balloon]\naxis = [[0.0, 0.0, -3.0], [0.0, 0.0, -0.7]]\ndiameter_mm = 2.0\n')
    rc, text = warpcoil_run(scene, tmp_path / "o", tmp_path / "log.txt")
    assert rc == 2 and "balloon.axis" in text and "catheter.tip" in text and "fix:" in text, text
    assert "0.45 mm within its surface" in text  # 1.0 − 0.7 − 0.15: cap radius − distance + d/2
    assert not (tmp_path / "o").exists()

    class Anatomy:
        balloon = (np.array([[0.0, 0.0, -3.0], [0.0, 0.0, -1.0]]), np.array([1.0, 1.0]))
    assert balloon_gap_mm(Anatomy, np.array([0.0, 0.0, 0.5]), 0.15) == pytest.approx(0.35)  # cap at −1 + 1 = 0
    assert balloon_gap_mm(Anatomy, np.array([2.0, 0.0, -2.0]), 0.15) == pytest.approx(0.85)  # beside the tube


def test_cli_runs_the_implicit_step_with_a_device(tmp_path):
    """The implicit step carries the device contact stiffness (tests/test_implicit_devices.py):
    a stented run completes from the command line at several times the explicit bound."""
    import json

    scene = tmp_path / "s.toml"
    scene.write_text('[wall]\nsphere_diameter_mm = 4.0\n[catheter]\ntip = [0.0, 0.0, -1.5]\n[[coil]]\n'
                     'wire_diameter_mm = 0.2921\nloop_diameter_mm = 2.0\nlength_mm = 3\n[simulation]\n'
                     'push_speed_mm_s = 100.0\nintegrator = "implicit"\n'
                     '[stent]\naxis = [[-0.02, 0.013, -1.5], [0.02, 0.013, 1.5]]\ndiameter_mm = 4.5\n')
    log, out = tmp_path / "log.txt", tmp_path / "o"
    with log.open("w") as stream:
        rc = subprocess.call([sys.executable, "-m", "warpcoil.cli", "run", str(scene), "-o", str(out), "--no-usd"],
                             stdout=stream, stderr=subprocess.STDOUT)
    assert rc == 0, log.read_text()
    assert "completed" in log.read_text()
    result = json.loads((out / "result.json").read_text())
    assert result["status"] == "completed" and result["device"]["kind"] == "stent"
    assert result["dt_s"] > 5.0 * result["step_bound_s"]


@pytest.mark.parametrize("device", ["balloon", "stent"])
def test_cli_runs_an_assisted_scene_and_reports_the_device(tmp_path, device):
    """A 5 mm coil into a 4 mm sphere with the device through it, clear of the catheter path."""
    from pxr import Usd
    import json

    table = ('[balloon]\naxis = [[-1.2, 0.8, -0.3], [1.2, 0.8, -0.3]]\ndiameter_mm = 0.8\ndeflation_time_s = 0.02\n'
             if device == "balloon" else
             '[stent]\naxis = [[-0.02, 0.013, -1.5], [0.02, 0.013, 1.5]]\ndiameter_mm = 4.5\ncell_size_mm = 1.5\n')
    scene = tmp_path / "s.toml"
    scene.write_text('[wall]\nsphere_diameter_mm = 4.0\n[catheter]\ntip = [0.0, 0.0, -1.5]\n'
                     '[[coil]]\nshape = "helix"\nwire_diameter_mm = 0.2921\nloop_diameter_mm = 2.0\n'
                     'length_mm = 5\n[simulation]\npush_speed_mm_s = 100.0\nframe_interval_s = 0.005\n'
                     '[output]\npng = true\n' + table)
    out, log = tmp_path / "out", tmp_path / "log.txt"
    with log.open("w") as stream:
        rc = subprocess.call([sys.executable, "-m", "warpcoil.cli", "run", str(scene), "-o", str(out), "--quiet"],
                             stdout=stream, stderr=subprocess.STDOUT)
    assert rc == 0, log.read_text()
    result = json.loads((out / "result.json").read_text())
    assert result["device"]["kind"] == device
    assert 0.0 <= result["packing_density_in_sac"] <= result["packing_density"] + 1e-12
    stage = Usd.Stage.Open(str(out / "deployment.usdc"))
    prim = stage.GetPrimAtPath("/World/Balloon" if device == "balloon" else "/World/Stent")
    assert prim.IsValid()
    assert (out / "summary.png").stat().st_size > 0
    if device == "balloon":
        inflation = [f for _, f in result["device"]["inflation_over_time"]]
        assert inflation[0] == 1.0 and inflation[-1] == 0.0  # deflated before the run ended
        start = result["device"]["deflation_started_s"]
        assert start is not None
        for time_s, value in result["device"]["inflation_over_time"]:  # each frame its own time's inflation
            assert value == pytest.approx(min(1.0, max(0.0, 1.0 - (time_s - start) / 0.02)), abs=1e-9), time_s


def test_the_balloon_deflates_with_the_clock_not_the_frames(tmp_path):
    """A 0.05 s deflation recorded in 0.02 s frames: the solver's inflation is set before every graph
    replay (≤ 8 steps) to the schedule at its middle, so within a frame it steps down in many small
    decrements (the largest ≤ 8 steps' share of the schedule), not once a frame."""
    from warpcoil.deploy import Deployment
    from warpcoil.scene import load_scene
    from warpcoil.solver import GRAPH_STEPS_MAX

    scene = tmp_path / "s.toml"
    scene.write_text('[wall]\nsphere_diameter_mm = 4.0\n[catheter]\ntip = [0.0, 0.0, -1.5]\n'
                     '[[coil]]\nshape = "helix"\nwire_diameter_mm = 0.2921\nloop_diameter_mm = 2.0\n'
                     'length_mm = 5\n[simulation]\npush_speed_mm_s = 100.0\nframe_interval_s = 0.02\n'
                     '[output]\nusd = false\n[balloon]\naxis = [[-1.2, 0.8, -0.3], [1.2, 0.8, -0.3]]\n'
                     'diameter_mm = 0.8\ndeflation_time_s = 0.05\n')
    run = Deployment(load_scene(scene))
    seen: list[float] = []
    set_inflation = run.model.set_inflation

    def record(world, fraction):
        seen.append(fraction)
        set_inflation(world, fraction)

    run.model.set_inflation = record
    result = run.run()
    assert result.status == "completed", result.reason
    falling = [f for f in seen if 0.0 < f < 1.0]
    assert len(falling) > 3 * 0.05 / 0.02  # many more levels than the deflation's frames
    steps_s = max(run.solver.dt_s, result.settle_dt_s or 0.0)
    drops = -np.diff([1.0] + falling + [0.0])
    assert drops.max() <= GRAPH_STEPS_MAX * steps_s / 0.05 + 1e-9


def sac_on_duct(path, h_mm: float = 0.1) -> None:
    """A sphere sac (radius 3 mm) joined by a neck (radius 1.75 mm) to the flat top (z = 1.5 mm)
    of a rounded rectangular duct 12 × 5 × 3 mm along x: a surface of a signed distance, VTK's
    flying edges at ``h_mm``, written as STL."""
    from vtkmodules.util import numpy_support
    from vtkmodules.vtkCommonDataModel import vtkImageData
    from vtkmodules.vtkFiltersCore import vtkFlyingEdges3D

    radius, neck, joint = 3.0, 1.75, 2.5
    centre = joint + math.sqrt(radius**2 - neck**2)
    axes = [np.arange(lo, hi + 1e-9, h_mm) + off for lo, hi, off in
            ((-6.6, 6.6, 0.01234), (-3.2, 3.2, 0.00731), (-2.2, centre + radius + 0.4, 0.00417))]
    x, y, z = np.meshgrid(*axes, indexing="ij")
    q = [np.abs(x) - 5.5, np.abs(y) - 2.0, np.abs(z) - 1.0]  # the duct: half sizes less its 0.5 mm edge radius
    duct = np.sqrt(sum(np.maximum(v, 0.0) ** 2 for v in q)) + np.minimum(np.maximum.reduce(q), 0.0) - 0.5
    sac = np.sqrt(x**2 + y**2 + (z - centre) ** 2) - radius
    neck_tube = np.maximum(np.hypot(x, y) - neck, np.maximum(1.0 - z, z - (joint + 0.5)))
    image = vtkImageData()
    image.SetDimensions(*(len(a) for a in axes))
    image.SetSpacing(h_mm, h_mm, h_mm)
    image.SetOrigin(*(a[0] for a in axes))
    distance = np.minimum(np.minimum(duct, sac), neck_tube)
    image.GetPointData().SetScalars(numpy_support.numpy_to_vtk(distance.ravel(order="F"), deep=True))
    surface = vtkFlyingEdges3D()
    surface.SetInputData(image)
    surface.SetValue(0, 0.0)
    surface.Update()
    poly = surface.GetOutput()
    faces = numpy_support.vtk_to_numpy(poly.GetPolys().GetConnectivityArray()).reshape(-1, 3)
    mesh = trimesh.Trimesh(numpy_support.vtk_to_numpy(poly.GetPoints().GetData()), faces, process=True)
    mesh.fix_normals()
    mesh.export(path)


def test_a_coil_pushed_past_a_stent_under_the_tip_completes_instead_of_stalling(tmp_path):
    """A helper's case: a 5 mm helix (a flat loop: its self-deployment force F₀ is only ~230 µN)
    pushed from a catheter at the neck, 0.14 mm above a stent's struts in the parent duct, needs
    ~50 F₀ for a while (13–16 mN, a light push clinically) and then fills the sac. The stall rule
    at its old ratio (30) ended it as jammed at 11.8 of 200 mm; at 100 it completes, with no node
    left outside the sac."""
    import csv
    import json

    sac_on_duct(tmp_path / "duct.stl")
    scene = tmp_path / "s.toml"
    scene.write_text('[wall]\nmesh = "duct.stl"\n[neck]\nplane_point_mm = [0.0, 0.0, 1.6]\n'
                     'plane_normal = [0.0, 0.0, 1.0]\nsac_point_mm = [0.0, 0.0, 5.0]\n'
                     '[catheter]\nplacement = "neck"\ndepth_mm = 0.0\n'
                     '[[coil]]\nshape = "helix"\nwire_diameter_mm = 0.2921\nloop_diameter_mm = 5.0\nlength_mm = 30.0\n'
                     '[stent]\naxis = [[-5.0, 0.0, 0.0], [5.0, 0.0, 0.0]]\ndiameter_mm = 5.5\ncell_size_mm = 1.0\n'
                     '[simulation]\npush_speed_mm_s = 100.0\n[output]\nusd = false\n')
    out, log = tmp_path / "out", tmp_path / "log.txt"
    with log.open("w") as stream:
        rc = subprocess.call([sys.executable, "-m", "warpcoil.cli", "run", str(scene), "-o", str(out)],
                             stdout=stream, stderr=subprocess.STDOUT)
    assert rc == 0, log.read_text()
    result = json.loads((out / "result.json").read_text())
    assert result["status"] == "completed" and result["device"]["kind"] == "stent"
    assert result["deployed_length_mm"] == pytest.approx(result["coil_length_mm"])
    self_force = result["stored_energy_nJ"] / result["coil_length_mm"]
    rows = list(csv.DictReader((out / "timeseries.csv").open()))
    mean = [float(r["push_force_mean_uN"]) for r in rows]
    window = round(0.1 / (float(rows[1]["time_s"]) - float(rows[0]["time_s"])))  # frames of the stall window
    held = max(min(mean[i:i + window]) for i in range(len(mean) - window + 1))
    assert 30.0 * self_force < held < 100.0 * self_force  # the old ratio would have stopped it; the new does not


def test_the_shipped_balloon_scenes_keep_their_tips_out_of_the_balloon():
    """The tip placed at the neck (`placement = "neck"`) is checked against the inflated balloon as an explicit one
    is: the shipped balloon scenes pass with room to spare."""
    from pathlib import Path

    from warpcoil.anatomy import resolve_anatomies
    from warpcoil.preflight import balloon_gap_mm, check_balloon
    from warpcoil.scene import load_scene

    scenes = Path(__file__).resolve().parents[1] / "scenes"
    for name in ("aneurisk_C0001_balloon.toml",):  # (C0091's: 0.84 mm to spare)
        scene = load_scene(scenes / name)
        anatomy = resolve_anatomies([scene])[0]
        check_balloon(scene, anatomy)  # no SetupError
        radius = 0.5 * max(c.wire_diameter_mm for c in scene.coils)
        assert balloon_gap_mm(anatomy, np.asarray(anatomy.catheter.tip_mm), radius) > 0.3


BALLOON_SCENE = ('[wall]\nsphere_diameter_mm = 4.0\n[catheter]\ntip = [0.0, 0.0, -1.5]\n[[coil]]\nshape = "helix"\n'
                 'wire_diameter_mm = 0.2921\nloop_diameter_mm = 2.0\nlength_mm = 5\n[simulation]\n'
                 'push_speed_mm_s = 100.0\nframe_interval_s = 0.005\n{simulation}\n[output]\nusd = false\n'
                 '[balloon]\naxis = [[-1.2, 0.8, -0.3], [1.2, 0.8, -0.3]]\ndiameter_mm = 0.8\n'
                 'deflation_time_s = 0.02\ndeflate_at_s = {deflate_at_s}\n')


def test_a_deflation_after_the_time_limit_is_refused(tmp_path):
    """deflate_at_s = 2 s with max_time_s = 0.5 s ran, timed out (the run waits for the deflation) and reported
    deflation_started_s = 2.0, a deflation that never happened; now refused before the run, one line."""
    scene = tmp_path / "s.toml"
    scene.write_text(BALLOON_SCENE.format(simulation="max_time_s = 0.5", deflate_at_s=2.0))
    rc, text = warpcoil_run(scene, tmp_path / "o", tmp_path / "log.txt")
    lines = text.strip().splitlines()
    assert rc == 2 and len(lines) == 1 and "Traceback" not in text, text
    assert f"{scene}: balloon.deflate_at_s = 2 s" in lines[0] and "simulation.max_time_s = 0.5 s" in lines[0]
    assert "fix: deflate_at_s = 0.48 or less, or max_time_s = 4.02 or more" in lines[0]
    assert not (tmp_path / "o").exists()


def test_a_deflation_the_run_did_not_reach_is_reported_as_not_started(tmp_path):
    """A run that ends (here stalled at 0.01 s) before its deflate_at_s (1 s) reports deflation_started_s null."""
    import json

    scene = tmp_path / "s.toml"
    scene.write_text(BALLOON_SCENE.format(simulation="stall_packing = 0.002", deflate_at_s=1.0))
    rc, text = warpcoil_run(scene, tmp_path / "o", tmp_path / "log.txt")
    assert rc == 3, text
    result = json.loads((tmp_path / "o" / "result.json").read_text())
    assert result["status"] == "jammed" and result["simulated_time_s"] < 1.0
    assert result["device"]["deflation_started_s"] is None
    assert {f for _, f in result["device"]["inflation_over_time"]} == {1.0}
