"""`warpcoil sweep`: --vary parsing, one folder per member, the summary, bad input."""

import csv
import json

import pytest
from pxr import Usd, UsdGeom

from warpcoil.cli import main
from warpcoil.recorder import validate_usd
from warpcoil.sweep import SweepError, parse_vary

SCENE = """
[[coil]]
shape = "helix"
length_mm = 5.0
loop_diameter_mm = 2.5
pitch_mm = 0.6
wire_diameter_mm = 0.2921

[catheter]
tip = [0.0, 0.0, -1.4]
direction = [0.0, 0.0, 1.0]

[wall]
sphere_diameter_mm = 3.5

[simulation]
push_speed_mm_s = 100.0
frame_interval_s = 0.005
"""


def test_parse_vary():
    assert parse_vary("catheter.angle_deg=0:30:5") == ("catheter.angle_deg", [0.0, 5.0, 10.0, 15.0, 20.0, 25.0, 30.0])
    assert parse_vary("coil.0.length_mm=40,50") == ("coil.0.length_mm", [40.0, 50.0])
    for bad in ("catheter.angle_deg", "x=1:0:1", "x=0:1:0", "x=a:b:c"):
        with pytest.raises(SweepError, match="--vary"):
            parse_vary(bad)


def test_sweep_writes_each_member_and_a_summary(tmp_path, capsys):
    scene = tmp_path / "s.toml"
    scene.write_text(SCENE)
    out = tmp_path / "out"
    code = main(["sweep", str(scene), "--vary", "simulation.push_speed_mm_s=100,150", "-o", str(out), "-q"])
    assert code == 0
    rows = list(csv.DictReader((out / "summary.csv").open()))
    assert [r["simulation.push_speed_mm_s"] for r in rows] == ["100", "150"]
    assert [r["status"] for r in rows] == ["completed", "completed"]
    for k, speed in enumerate((100.0, 150.0)):
        result = json.loads((out / f"member_{k:03d}" / "result.json").read_text())
        assert result["varied"] == {"simulation.push_speed_mm_s": speed}
        assert result["steps"] == int(rows[k]["steps"])
    assert "2 members in 1 ensemble(s)" in (out / "summary.md").read_text()
    split = tmp_path / "split"  # two worker processes, one member each: the same results, and a USD each
    assert main(["sweep", str(scene), "--vary", "simulation.push_speed_mm_s=100,150", "-o", str(split), "-q",
                 "--jobs", "2", "--usd"]) == 0
    for k in range(2):
        name = f"member_{k:03d}/centerline.csv"
        assert (split / name).read_bytes() == (out / name).read_bytes()
        usd = split / f"member_{k:03d}" / "deployment.usdc"
        assert validate_usd(usd) == []
        stage = Usd.Stage.Open(str(usd))
        curves = [p for p in stage.Traverse() if p.IsA(UsdGeom.BasisCurves)]
        frames = len(list(csv.DictReader((split / f"member_{k:03d}" / "timeseries.csv").open())))
        assert len(curves) == 1 and len(curves[0].GetAttribute("points").GetTimeSamples()) == frames


def test_a_bad_key_names_it_and_writes_nothing(tmp_path, capsys):
    scene = tmp_path / "s.toml"
    scene.write_text(SCENE)
    out = tmp_path / "out"
    assert main(["sweep", str(scene), "--vary", "catheter.angel_deg=0:10:5", "-o", str(out), "-q"]) == 2
    assert "catheter.angel_deg" in capsys.readouterr().err
    assert not out.exists()
