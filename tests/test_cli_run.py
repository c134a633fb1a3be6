"""`warpcoil run`: outputs, their contents and USD validity; bad input."""

import csv
import json

import numpy as np
import pytest
from pxr import Usd, UsdGeom

from warpcoil.cli import main
from warpcoil.recorder.usd import validate_usd

SCENE = """
[wall]
sphere_diameter_mm = 3.5

[catheter]
tip = [0.0, 0.0, -1.45]
direction = [0.0, 0.0, 1.0]

[[coil]]
name = "short"
shape = "helix"
wire_diameter_mm = 0.2921
loop_diameter_mm = 2.5
pitch_mm = 0.6
length_mm = 8.0

[simulation]
push_speed_mm_s = 100.0
frame_interval_s = 0.005

[output]
png = true
tube_mesh = true
porous = true
"""


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    root = tmp_path_factory.mktemp("run")
    scene = root / "short.toml"
    scene.write_text(SCENE)
    out = root / "out"
    assert main(["run", str(scene), "-o", str(out), "-q"]) == 0
    return out


def test_result_json_reports_the_run(run_dir):
    result = json.loads((run_dir / "result.json").read_text())
    assert result["status"] == "completed"
    for key in ("steps", "dt_s", "wall_time_s", "coil_length_mm", "deployed_length_mm", "packing_density",
                "length_outside_sac_mm", "min_wall_gap_mm", "min_coil_gap_mm", "max_wall_force_uN",
                "push_force_peak_uN", "push_force_mean_max_uN", "push_force_rms_uN", "stored_energy_nJ", "final_kinetic_nJ", "final_bend_nJ"):
        assert key in result
    assert result["deployed_length_mm"] == pytest.approx(result["coil_length_mm"])
    last = list(csv.DictReader((run_dir / "timeseries.csv").open()))[-1]  # the load at rest: the last frame's
    assert result["final_max_wall_force_uN"] == pytest.approx(float(last["max_wall_force_uN"]), rel=1e-9)
    assert 0.0 <= result["final_max_wall_force_uN"] <= result["max_wall_force_uN"]
    assert result["length_outside_sac_mm"] == 0.0
    assert result["stored_energy_nJ"] > 0


def test_centerline_csv_holds_the_final_nodes(run_dir):
    rows = list(csv.DictReader((run_dir / "centerline.csv").open()))
    assert list(rows[0]) == ["coil", "node", "x_mm", "y_mm", "z_mm"]
    x = np.array([[float(r["x_mm"]), float(r["y_mm"]), float(r["z_mm"])] for r in rows])
    assert len(rows) == round(8.0 / 0.2921) + 1
    assert np.linalg.norm(x, axis=1).max() < 1.75  # inside the sac
    seg = np.linalg.norm(np.diff(x, axis=0), axis=1)
    assert np.allclose(seg, 8.0 / (len(rows) - 1), rtol=2e-2)  # segment lengths kept


def test_timeseries_has_one_row_per_frame(run_dir):
    rows = list(csv.DictReader((run_dir / "timeseries.csv").open()))
    times = [float(r["time_s"]) for r in rows]
    assert times[0] == 0.0 and all(b > a for a, b in zip(times, times[1:]))
    deployed = [float(r["deployed_length_mm"]) for r in rows]
    assert all(b >= a for a, b in zip(deployed, deployed[1:]))
    assert {"push_force_mean_uN", "push_force_peak_uN", "push_force_rms_uN", "kinetic_nJ", "bend_nJ", "wall_contacts", "coil_contacts"} <= set(rows[0])


def test_usd_plays_back_with_prims_widths_and_time_samples(run_dir):
    path = run_dir / "deployment.usdc"
    assert validate_usd(path) == []
    stage = Usd.Stage.Open(str(path))
    assert UsdGeom.GetStageMetersPerUnit(stage) == pytest.approx(0.001)
    wall = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Wall"))
    assert wall and len(wall.GetPointsAttr().Get()) > 100
    coil = UsdGeom.BasisCurves(stage.GetPrimAtPath("/World/Coils/Coil_0"))
    assert coil
    assert np.allclose(coil.GetWidthsAttr().Get(), 0.2921)
    frames = len(list(csv.DictReader((run_dir / "timeseries.csv").open())))
    samples = coil.GetPointsAttr().GetTimeSamples()
    assert len(samples) == frames
    assert stage.GetEndTimeCode() == samples[-1]
    final = np.array(coil.GetPointsAttr().Get(samples[-1]))
    rows = list(csv.DictReader((run_dir / "centerline.csv").open()))
    assert np.allclose(final[:, 2], [float(r["z_mm"]) for r in rows], atol=1e-5)


def test_bad_scene_gives_one_clear_error_and_no_output(tmp_path, capsys):
    scene = tmp_path / "bad.toml"
    scene.write_text(SCENE.replace("length_mm = 8.0", 'length_mm = "long"'))
    out = tmp_path / "out"
    assert main(["run", str(scene), "-o", str(out), "-q"]) == 2
    err = capsys.readouterr().err
    assert "bad.toml" in err and "coil[0].length_mm" in err
    assert not out.exists()


def test_unstable_step_is_refused_before_running(tmp_path, capsys):
    scene = tmp_path / "fast.toml"
    scene.write_text(SCENE.replace("frame_interval_s = 0.005",
                                  'frame_interval_s = 0.005\nintegrator = "symplectic"\ndt_s = 1e-3'))
    assert main(["run", str(scene), "-o", str(tmp_path / "out"), "-q"]) == 2
    assert "stable bound" in capsys.readouterr().err


def test_tube_mesh_and_picture_are_written(run_dir):
    import trimesh
    from matplotlib.image import imread

    tube = trimesh.load_mesh(run_dir / "coils.stl")
    assert tube.is_watertight
    length = json.loads((run_dir / "result.json").read_text())["coil_length_mm"]
    assert tube.volume == pytest.approx(np.pi * 0.14605**2 * length, rel=0.02)  # the wire's volume (less the joints)
    assert (run_dir / "coils.vtp").stat().st_size > 1000
    assert imread(run_dir / "summary.png").shape[:2] == (900, 1200)


def test_porous_field_holds_the_coil_volume(run_dir):
    """porous.vti (no [neck]: the whole sphere is the sac): sac-weighted mean solid fraction = coil
    volume / sac volume (the capsule chain π r² L + 4/3 π r³, less what contact overlap and wall
    penetration take off: 3 %)."""
    from vtkmodules.util.numpy_support import vtk_to_numpy
    from vtkmodules.vtkIOXML import vtkXMLImageDataReader

    reader = vtkXMLImageDataReader()
    reader.SetFileName(str(run_dir / "porous.vti"))
    reader.Update()
    cells = reader.GetOutput().GetCellData()
    fraction, porosity = (vtk_to_numpy(cells.GetArray(name)) for name in ("sac_fraction", "porosity"))
    assert reader.GetOutput().GetSpacing() == pytest.approx((0.14605,) * 3)
    result = json.loads((run_dir / "result.json").read_text())
    r = 0.14605
    coil = np.pi * r**2 * result["coil_length_mm"] + 4.0 / 3.0 * np.pi * r**3
    assert float((fraction * (1 - porosity)).sum() / fraction.sum()) == pytest.approx(
        coil / result["sac_volume_mm3"], rel=0.03)
