"""The command line as a user meets it (issue 13): each test runs ``warpcoil`` as a
subprocess with stdout and stderr redirected to files, and checks the exit code,
the message and the output folder. Tiny scenes keep them fast."""

from __future__ import annotations

import csv
import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import trimesh

import warpcoil as wc

ROOT = Path(__file__).resolve().parents[1]

SPHERE = """
[wall]
sphere_diameter_mm = 3.5

[catheter]
tip = [0.0, 0.0, -1.45]
direction = [0.0, 0.0, 1.0]

[[coil]]
shape = "helix"
wire_diameter_mm = 0.2921
loop_diameter_mm = 2.5
pitch_mm = 0.6
length_mm = 4.0

[simulation]
push_speed_mm_s = 100.0
frame_interval_s = 0.005

[output]
usd = false
"""


def scene(tmp_path: Path, text: str = SPHERE, name: str = "tiny.toml", **replace: str) -> Path:
    """The scene ``text`` with each key of ``replace`` (a line of it) replaced, as tmp_path/name."""
    for old, new in replace.items():
        assert old in text, old
        text = text.replace(old, new)
    path = tmp_path / name
    path.write_text(text)
    return path


def program_env() -> dict[str, str]:
    """The environment a test runs the program in: this checkout first on the path, the shared kernel cache."""
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    env.setdefault("WARPCOIL_KERNEL_CACHE", str(ROOT / ".warp_cache"))
    return env


def cli(tmp_path: Path, *args: str, wait: bool = True, log: str = "log", group: bool = False):
    """``warpcoil ARGS`` with stdout and stderr in files under tmp_path; (exit code, stdout, stderr).
    ``group``: in a process group of its own (a terminal's Ctrl-C signals the whole group: os.killpg)."""
    env = program_env()
    out, err = tmp_path / f"{log}.out", tmp_path / f"{log}.err"
    with out.open("w") as stdout, err.open("w") as stderr:
        process = subprocess.Popen([sys.executable, "-m", "warpcoil.cli", *args], stdout=stdout, stderr=stderr,
                                   cwd=tmp_path, env=env, start_new_session=group)
        if not wait:
            return process, out, err
        code = process.wait(timeout=600)
    return code, out.read_text(), err.read_text()


def one_line(err: str) -> str:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert "Traceback" not in err
    return lines[0]


def leftovers(folder: Path) -> list[str]:
    """Temporary files and locks left in a folder (there must be none)."""
    return [p.name for p in folder.rglob(".*")]


# --- 1, 9: sweep and run progress, redirected or quiet ------------------------------
def test_sweep_without_q_prints_progress_lines_to_a_log(tmp_path):
    code, out, err = cli(tmp_path, "sweep", str(scene(tmp_path)), "--vary", "simulation.push_speed_mm_s=100,150",
                         "-o", "sweep")
    assert code == 0, err
    assert "\r" not in err and "Traceback" not in err
    assert "sweep 2/2 deployments (100 %)" in err
    assert "2 completed" in out
    rows = list(csv.DictReader((tmp_path / "sweep" / "summary.csv").open()))
    assert [r["status"] for r in rows] == ["completed", "completed"]
    assert leftovers(tmp_path / "sweep") == []


# --- 2, 7, 8, 9, 10, 11, 13: a run into a folder, and again --------------------------
def damaged_sphere_stl(path: Path) -> None:
    """A 3.5 mm sphere written with inward normals and one face twice (intake repairs both)."""
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=1.75)
    faces = np.vstack([sphere.faces[:, ::-1], sphere.faces[:1, ::-1]])
    trimesh.Trimesh(sphere.vertices, faces, process=False).export(path)


@pytest.fixture(scope="module")
def first_run(tmp_path_factory):
    tmp_path = tmp_path_factory.mktemp("user")
    damaged_sphere_stl(tmp_path / "sac.stl")
    text = SPHERE.replace("sphere_diameter_mm = 3.5", 'mesh = "sac.stl"').replace(
        "usd = false", "usd = true\npng = true\nanimation = true")
    path = scene(tmp_path, text)
    code, out, err = cli(tmp_path, "run", str(path), "-o", "run")
    return tmp_path, path, code, out, err


def test_run_reports_repairs_push_forces_and_plays_in_real_time(first_run):
    tmp_path, _, code, out, err = first_run
    folder = tmp_path / "run"
    assert code == 0, err
    assert out.startswith("completed: ")
    # 7: repairs printed and kept
    assert "removed 1 duplicate face" in err and "flipped inward-facing normals" in err
    result = json.loads((folder / "result.json").read_text())
    assert result["wall_repairs"] == ["removed 1 duplicate face", "flipped inward-facing normals"]
    # 9, 11: progress as plain lines, no carriage returns, no CUDA driver notice
    assert "\r" not in err and "CUDA" not in err
    progress = [line for line in err.splitlines() if line.startswith("deployed ")]
    assert progress and progress[-1].startswith("deployed 4.0/4.0 mm (100 %), push mean")
    # 8: one definition each, in result.json and the CSV
    rows = list(csv.DictReader((folder / "timeseries.csv").open()))
    peak = [float(r["push_force_peak_uN"]) for r in rows]
    mean = [float(r["push_force_mean_uN"]) for r in rows]
    rms = [float(r["push_force_rms_uN"]) for r in rows]
    assert all(r >= abs(m) * (1 - 1e-9) and p >= m * (1 - 1e-9) for m, p, r in zip(mean, peak, rms))  # RMS ≥ |mean|
    deployed = [float(r["deployed_length_mm"]) for r in rows]
    pushed = [k for k in range(1, len(rows)) if deployed[k] > deployed[k - 1]]  # (the frames the pusher pushed)
    assert result["push_force_peak_uN"] == pytest.approx(max(peak[k] for k in pushed), rel=1e-6) and max(peak) > 0.0
    assert result["push_force_mean_max_uN"] == pytest.approx(max(mean[k] for k in pushed), rel=1e-6)
    assert result["push_force_rms_uN"] == pytest.approx(math.sqrt(np.mean(np.square([rms[k] for k in pushed]))),
                                                        rel=1e-4)
    # 10: one USD time code per frame, played at as many frames per second: real time
    from pxr import Usd

    stage = Usd.Stage.Open(str(folder / "deployment.usdc"))
    per_second = stage.GetTimeCodesPerSecond()
    assert per_second == pytest.approx(1.0 / 0.005) and stage.GetFramesPerSecond() == per_second
    # a frame is whole steps (the implicit push frame 22 × 0.234 ms): each sits at its own time's code
    codes = stage.GetPrimAtPath("/World/Coils/Coil_0").GetAttribute("points").GetTimeSamples()
    times = [float(r["time_s"]) for r in rows]
    assert len(codes) == len(times)
    assert all(abs(c / per_second - t) <= 1e-6 / per_second for c, t in zip(codes, times))
    # 13: an animated GIF of the frames
    from PIL import Image

    with Image.open(folder / "deployment.gif") as gif:
        assert gif.n_frames == min(60, len(rows)) and gif.size[0] >= 300
    assert (folder / "summary.png").stat().st_size > 10_000
    assert leftovers(folder) == []


def test_a_used_folder_is_refused_then_overwritten_with_only_the_new_run(first_run):
    tmp_path, path, first_code, _, _ = first_run
    folder = tmp_path / "run"
    assert first_code == 0
    (folder / "notes.txt").write_text("mine")  # not warpcoil's: must survive
    code, out, err = cli(tmp_path, "run", str(path), "-o", "run", "-q", log="again")
    assert code == 2
    assert "Traceback" not in err
    line = err.strip().splitlines()[-1]  # after the two wall-repair lines
    assert "already holds the outputs of an earlier run" in line and "--overwrite" in line
    before = {p.name: p.stat().st_mtime_ns for p in folder.iterdir()}
    assert "summary.png" in before and "deployment.gif" in before
    lean = path.read_text().replace("png = true\nanimation = true", "png = false")
    path.write_text(lean)
    code, out, err = cli(tmp_path, "run", str(path), "-o", "run", "-q", "--overwrite", log="overwrite")
    assert code == 0, err
    assert "deployed " not in err  # -q: no progress at all
    names = sorted(p.name for p in folder.iterdir())
    assert names == ["centerline.csv", "deployment.usdc", "notes.txt", "result.json", "timeseries.csv"]


def test_a_folder_in_use_by_another_run_is_refused(tmp_path):
    path = scene(tmp_path)
    (tmp_path / "busy").mkdir()
    sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        import socket

        (tmp_path / "busy" / ".warpcoil.lock").write_text(f"{sleeper.pid} {socket.gethostname()}\n")
        code, _, err = cli(tmp_path, "run", str(path), "-o", "busy", "-q")
        assert code == 2 and f"another warpcoil run (process {sleeper.pid}" in one_line(err)
    finally:
        sleeper.kill()
        sleeper.wait()
    code, _, err = cli(tmp_path, "run", str(path), "-o", "busy", "-q")  # its lock is stale now: taken over
    assert code == 0, err
    assert json.loads((tmp_path / "busy" / "result.json").read_text())["status"] == "completed"
    assert leftovers(tmp_path / "busy") == []


# --- 3: an unstable run ---------------------------------------------------------------
def test_an_unstable_run_fails_with_a_reason_and_finite_outputs(tmp_path):
    path = scene(tmp_path, **{"frame_interval_s = 0.005": "frame_interval_s = 0.005\nintegrator = \"symplectic\"\n"
                              "dt_s = 5e-5\nallow_unstable_dt = true", "usd = false": "usd = true\npng = true\ntube_mesh = true"})
    code, out, err = cli(tmp_path, "run", str(path), "-o", "bad", "-q")
    assert code == 1, err
    assert "Traceback" not in err
    folder = tmp_path / "bad"
    result = json.loads((folder / "result.json").read_text())
    assert result["status"] == "failed" and "simulation.dt_s" in result["reason"]
    assert out.startswith("failed: ")
    x = np.loadtxt(folder / "centerline.csv", delimiter=",", skiprows=1)
    assert np.isfinite(x).all() and len(x) > 10
    assert np.isfinite(trimesh.load_mesh(folder / "coils.stl").vertices).all()
    assert (folder / "summary.png").stat().st_size > 10_000
    assert leftovers(folder) == []


# --- 5: the catheter ---------------------------------------------------------------------
def test_a_tip_outside_the_lumen_is_refused_before_stepping(tmp_path):
    path = scene(tmp_path, **{"tip = [0.0, 0.0, -1.45]": "tip = [0.0, 0.0, -2.0]"})
    code, out, err = cli(tmp_path, "run", str(path), "-o", "never")
    assert code == 2
    line = one_line(err)
    assert "tiny.toml" in line and "catheter.tip" in line and "outside the lumen" in line and "fix:" in line
    assert not (tmp_path / "never").exists()


def test_a_centerline_leaving_the_lumen_is_refused(tmp_path):
    path = scene(tmp_path, **{"direction = [0.0, 0.0, 1.0]": "direction = [0.0, 0.0, 1.0]\n"
                              "centerline = [[0.0, 0.0, -3.0], [0.0, 0.0, -1.45]]"})
    code, _, err = cli(tmp_path, "run", str(path), "-o", "never")
    assert code == 2
    assert "catheter.centerline leaves the lumen" in one_line(err)
    assert not (tmp_path / "never").exists()


def test_a_catheter_pointing_out_of_the_sac_is_warned_about(tmp_path):
    path = scene(tmp_path, **{"direction = [0.0, 0.0, 1.0]": "direction = [0.3, 0.0, -1.0]",
                              "frame_interval_s = 0.005": "frame_interval_s = 0.005\nmax_time_s = 0.01"})
    code, _, err = cli(tmp_path, "run", str(path), "-o", "out", "-q")
    assert code == 3  # the short time limit: ran, and timed out
    assert "warning:" in err and "points away from the sac" in err
    assert json.loads((tmp_path / "out" / "result.json").read_text())["warnings"][0].endswith("catheter.angle_deg)")


@pytest.mark.parametrize("command", ["run", "sweep"])
def test_a_neck_that_does_not_cut_the_wall_is_one_line_naming_the_key(tmp_path, command):
    """A neck plane beside the wall (the sac cannot be cut): one line naming the scene file and the
    neck key, exit 2, no traceback and no output folder, from run and sweep alike."""
    path = scene(tmp_path, **{"[output]": "[neck]\nplane_point_mm = [0.0, 0.0, 10.0]\n"
                                          "plane_normal = [0.0, 0.0, 1.0]\n\n[output]"})
    extra = ["--vary", "simulation.push_speed_mm_s=100,150"] if command == "sweep" else []
    code, _, err = cli(tmp_path, command, str(path), *extra, "-o", "never")
    line = [line for line in err.splitlines() if line.startswith(f"warpcoil {command}: ")]
    assert code == 2 and len(line) == 1 and "Traceback" not in err, err
    assert "tiny.toml: neck.plane_point_mm / plane_normal: " in line[0] and "fix:" in line[0], line[0]
    assert not (tmp_path / "never").exists()


def test_a_porous_field_too_fine_to_hold_is_refused_before_the_run(tmp_path):
    """porous_voxel_mm = 0.001 over a 3.5 mm sphere: ~4e10 voxels; refused before the run (exit 2, one
    line naming the key and a voxel size that fits), not after it."""
    path = scene(tmp_path, **{"usd = false": "usd = false\nporous = true\nporous_voxel_mm = 0.001"})
    code, _, err = cli(tmp_path, "run", str(path), "-o", "never")
    line = one_line(err)
    assert code == 2 and "tiny.toml: output.porous_voxel_mm: voxels of 0.001 mm make" in line and "fix:" in line
    assert not (tmp_path / "never").exists()


NECK = "[neck]\nplane_point_mm = [0.0, 0.0, -1.2]\nplane_normal = [0.0, 0.0, 1.0]\n\n"


@pytest.mark.parametrize("command", ["run", "sweep"])
@pytest.mark.parametrize("voxel, said", [
    ("0.0001", "regions.voxel_mm: voxels of 0.0001 mm make 3.61e+13 over the sac's bounding box"),
    ("10", "regions.voxel_mm: voxels of 10 mm are too coarse to resolve the regions: boundary_mm = 0.584 mm")])
def test_a_regions_voxel_too_fine_or_too_coarse_is_refused_before_the_run(tmp_path, command, voxel, said):
    """[regions] voxel_mm = 0.0001 (3.6e13 voxels: once an int32 traceback after the whole run) or 10 (coarser
    than the sac: regions and occlusion silently null): exit 2 before any step, from run and sweep alike,
    one line naming the key and a workable voxel, no output folder."""
    path = scene(tmp_path, **{"[output]": f"{NECK}[regions]\nvoxel_mm = {voxel}\n\n[output]"})
    extra = ["--vary", "simulation.push_speed_mm_s=100,150"] if command == "sweep" else []
    code, _, err = cli(tmp_path, command, str(path), *extra, "-o", "never")
    line = one_line(err)
    assert code == 2 and f"tiny.toml: {said}" in line, line
    assert ("fix: voxel_mm = 0.013 or more" if voxel == "0.0001" else "fix: voxel_mm = 0.29 or less") in line
    assert not (tmp_path / "never").exists()


@pytest.mark.parametrize("command", ["run", "sweep"])
def test_a_wall_field_too_fine_to_build_is_refused_before_the_run(tmp_path, command):
    """[contact] wall_voxel_mm = 0.0001 with wall_query = "sdf": its faces would propose 2.8e12 tiles (once a
    traceback, a negative array size from an int32 overflow); exit 2, one line naming the key and a voxel
    that fits, no output folder, from run and sweep alike."""
    path = scene(tmp_path, **{"[output]": '[contact]\nwall_query = "sdf"\nwall_voxel_mm = 0.0001\n\n[output]'})
    extra = ["--vary", "simulation.push_speed_mm_s=100,150"] if command == "sweep" else []
    code, _, err = cli(tmp_path, command, str(path), *extra, "-o", "never")
    line = one_line(err)
    assert code == 2 and "tiny.toml: contact.wall_voxel_mm: voxels of 0.0001 mm make the wall field's" in line, line
    assert "more than 2e+07; fix: wall_voxel_mm = 0.0077 or more" in line
    assert not (tmp_path / "never").exists()


@pytest.mark.parametrize("command", ["sweep", "plan"])
@pytest.mark.parametrize("address, said", [
    ("notanaddress", "missing port number"), ("tcp://localhost", "missing port number"),
    ("foo://x:1", "unknown address scheme 'foo'"), ("tcp://[::1", "invalid address '[::1'"),
    ("tcp://h:x", "the port is not a number"), ("", "empty")])
def test_a_scheduler_address_dask_cannot_read_is_one_line(tmp_path, command, address, said):
    """A malformed --scheduler (once a 30-line traceback, exit 1) or an empty one (once the local cluster
    ran the whole plan): exit 2, one line naming --scheduler, the problem and the fix, nothing run."""
    code, _, err = cli(tmp_path, command, str(scene(tmp_path)), "--vary", "coil.length_mm=3,4",
                       "--scheduler", address, "-o", "never")
    line = one_line(err)
    assert code == 2 and line.startswith(f"warpcoil {command}: --scheduler '{address}': {said}"), line
    assert "fix: give the address `dask scheduler` prints" in line
    assert not (tmp_path / "never").exists()


def test_two_spellings_of_one_coils_key_are_refused_like_a_key_given_twice(tmp_path):
    """--vary coil.length_mm and --vary coil.0.length_mm on a one-coil scene both set its length (once: four
    members, two of them duplicates, and a summary column of values never run): exit 2 before anything runs."""
    code, _, err = cli(tmp_path, "sweep", str(scene(tmp_path)), "--vary", "coil.length_mm=3,4", "--vary",
                       "coil.0.length_mm=3.5,4.5", "-o", "never")
    line = one_line(err)
    assert code == 2 and line.startswith("warpcoil sweep: --vary coil.length_mm and --vary coil.0.length_mm: both "
                                         "set the same key of one coil") and "fix: vary one of them" in line, line
    assert not (tmp_path / "never").exists()


@pytest.mark.parametrize("varies, said", [
    (["coil.length_mm = 3,4", "coil.length_mm=5"], "--vary coil.length_mm: given 2 times"),  # (the key stripped)
    (["coil.length_mm=3:4"], "--vary 'coil.length_mm=3:4': a range is three numbers, start:stop:step, and "
                             "'3:4' has 2")])
def test_a_vary_written_loosely_is_read_or_said_in_words(tmp_path, varies, said):
    """Spaces around = are read as TOML's (once: "unknown key 'length_mm '"); a range of two numbers is
    said as such (once: a Python unpacking message). Exit 2, one line, nothing run."""
    code, _, err = cli(tmp_path, "sweep", str(scene(tmp_path)), *(a for v in varies for a in ("--vary", v)),
                       "-o", "never")
    line = one_line(err)
    assert code == 2 and line.startswith(f"warpcoil sweep: {said}") and "unpack" not in line, line
    assert not (tmp_path / "never").exists()


def test_a_tip_closer_to_the_wall_than_the_coils_radius_is_refused(tmp_path):
    """The tip 0.06 mm inside a 3.5 mm sphere (its icosphere's faces a little nearer), a coil of d/2 = 0.146 mm:
    the coil would leave the catheter inside the wall, and the wall then shoves every node leaving it for the
    whole push (a physicist's audit: a tensile mean push force in every push frame, so no jam could be seen).
    Refused before the run: exit 2, one line naming the key and how far to move the tip, no output."""
    path = scene(tmp_path, **{"tip = [0.0, 0.0, -1.45]": "tip = [0.0, 0.0, -1.69]"})
    code, _, err = cli(tmp_path, "run", str(path), "-o", "out")
    line = one_line(err)
    assert code == 2 and "less than the coil's radius d/2 = 0.146 mm" in line
    assert "tiny.toml: catheter.tip" in line and "fix: move the tip at least" in line
    assert not (tmp_path / "out").exists()


# --- 6: bad command lines and Ctrl-C ------------------------------------------------------
@pytest.mark.parametrize("interval", ["0", "-0.01", "nan"])
def test_a_bad_frame_interval_is_one_line(tmp_path, interval):
    code, _, err = cli(tmp_path, "run", "any.toml", f"--frame-interval={interval}")
    assert code == 2
    assert "--frame-interval" in one_line(err) and "> 0" in err


def test_an_output_path_that_is_a_file_is_one_line(tmp_path):
    (tmp_path / "taken").write_text("a file")
    code, _, err = cli(tmp_path, "run", str(scene(tmp_path)), "-o", "taken")
    assert code == 2
    assert "is an existing file, not a folder" in one_line(err)
    code, _, err = cli(tmp_path, "run", str(scene(tmp_path)), "-o", "taken/run")
    assert code == 2
    assert "taken is a file, so the folder cannot be created" in one_line(err)
    assert (tmp_path / "taken").read_text() == "a file"


@pytest.mark.skipif(os.geteuid() == 0, reason="root may write anywhere")
def test_an_output_folder_that_is_not_writable_is_one_line(tmp_path):
    (tmp_path / "locked").mkdir(mode=0o555)
    code, _, err = cli(tmp_path, "run", str(scene(tmp_path)), "-o", "locked/run")
    assert code == 2 and "is not writable" in one_line(err)


def test_an_output_folder_that_cannot_be_created_is_one_line(tmp_path):
    """Paths that pass the permission check as root but cannot be made: a name over the file
    system's limit, and (where the machine has one) a folder in /proc; no folder is left."""
    code, _, err = cli(tmp_path, "run", str(scene(tmp_path)), "-o", "x" * 300)
    assert code == 2 and "cannot be used (File name too long)" in one_line(err)
    code, _, err = cli(tmp_path, "run", str(scene(tmp_path)), "-o", "new/" + "x" * 300)
    assert code == 2 and "is longer than the file system allows" in one_line(err)
    if Path("/proc/self").exists():
        code, _, err = cli(tmp_path, "run", str(scene(tmp_path)), "-o", "/proc/warpcoil_out")
        assert code == 2 and "/proc/warpcoil_out cannot be created" in one_line(err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["log.err", "log.out", "tiny.toml"]  # (no new/)


def test_a_frame_longer_than_the_time_limit_is_refused(tmp_path):
    """The time limit is checked at frame ends: a frame longer than max_time_s (given, or the push
    time + 2 s) would run past it and end `completed` where the limit should stop it: exit 2, the
    key and a fix, no folder."""
    path = scene(tmp_path, **{"frame_interval_s = 0.005": "frame_interval_s = 0.005\nmax_time_s = 0.02"})
    code, _, err = cli(tmp_path, "run", str(path), "-o", "long", "--frame-interval", "0.05")
    line = one_line(err)
    assert code == 2 and "simulation.frame_interval_s = 0.05 s is longer than max_time_s = 0.02 s" in line
    assert "fix: frame_interval_s = " in line and line.endswith(" or less")
    code, _, err = cli(tmp_path, "run", str(scene(tmp_path)), "-o", "long", "--frame-interval", "100")
    assert code == 2 and "its default time limit, the push time + 2 s" in one_line(err)
    assert one_line(err).startswith("warpcoil run: --frame-interval 100: ")  # the flag's value, not the file's
    assert not (tmp_path / "long").exists()


def stepping_run(tmp_path: Path, folder: str):
    """A 20 mm run into ``folder``, returned once it steps (its first progress line): (process, stdout, stderr)."""
    path = scene(tmp_path, **{"length_mm = 4.0": "length_mm = 20.0", "push_speed_mm_s = 100.0":
                              "push_speed_mm_s = 20.0", "usd = false": "usd = true"})
    process, out, err = cli(tmp_path, "run", str(path), "-o", folder, wait=False, log=folder)
    deadline = time.monotonic() + 300
    while "deployed " not in err.read_text() and time.monotonic() < deadline and process.poll() is None:
        time.sleep(0.2)
    return process, out, err


@pytest.mark.parametrize("stop", [signal.SIGINT, signal.SIGTERM])
def test_ctrl_c_or_a_schedulers_sigterm_ends_the_run_as_interrupted(tmp_path, stop):
    process, out, err = stepping_run(tmp_path, "stopped")
    process.send_signal(stop)
    assert process.wait(timeout=300) == 130
    folder = tmp_path / "stopped"
    result = json.loads((folder / "result.json").read_text())
    assert result["status"] == "interrupted" and "Ctrl-C or SIGTERM" in result["reason"]
    assert 0.0 < result["deployed_length_mm"] < 20.0
    assert out.read_text().startswith("interrupted: stopped by ")
    assert "Traceback" not in err.read_text()
    assert (folder / "deployment.usdc").exists() and leftovers(folder) == []


def test_ctrl_c_while_the_outputs_are_written_waits_for_them(tmp_path):
    """The program, with its outputs' writer sending itself a Ctrl-C first (a user's Ctrl-C after the
    last frame): the run's outputs are written all the same (its status its own), it says it was
    interrupted, and it exits 130 (so a script's next step does not start)."""
    path = scene(tmp_path)
    program = ("import os, signal, sys\n"
               "from warpcoil.recorder import outputs\n"
               "write_run = outputs.write_run\n"
               "def interrupted(*args, **kwargs):\n"
               "    os.kill(os.getpid(), signal.SIGINT)\n"
               "    return write_run(*args, **kwargs)\n"
               "outputs.write_run = interrupted\n"
               "from warpcoil.cli import main\n"
               f"sys.exit(main(['run', {str(path)!r}, '-o', 'late']))\n")
    with (tmp_path / "late.out").open("w") as stdout, (tmp_path / "late.err").open("w") as stderr:
        code = subprocess.run([sys.executable, "-c", program], stdout=stdout, stderr=stderr, cwd=tmp_path,
                              env=program_env(), timeout=600).returncode
    err = (tmp_path / "late.err").read_text()
    result = json.loads((tmp_path / "late" / "result.json").read_text())
    assert code == 130 and result["status"] == "completed", err
    assert "interrupted after the last frame: the outputs were written first" in err and "Traceback" not in err
    assert (tmp_path / "late.out").read_text().startswith("completed: ")
    assert (tmp_path / "late" / "centerline.csv").exists() and leftovers(tmp_path / "late") == []


@pytest.mark.parametrize("stop", [signal.SIGINT, signal.SIGTERM])
def test_ctrl_c_while_the_command_starts_is_one_line_not_a_traceback(tmp_path, stop):
    """The installed command (its entry point warpcoil_cli.main, as the console script calls it) stopped
    0.8 s after its start, inside its imports (Warp, USD, VTK, trimesh: seconds; a stop raised inside USD's
    plug-in loading was swallowed and the run went on to exit 0): exit 130, one line, no traceback, no
    outputs."""
    import warpcoil_cli
    from warpcoil.cli import EXIT_INTERRUPTED
    from warpcoil.deploy import STOP_SIGNALS

    assert (warpcoil_cli.EXIT_INTERRUPTED, warpcoil_cli.STOP_SIGNALS) == (EXIT_INTERRUPTED, STOP_SIGNALS)
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    with (tmp_path / "log.out").open("w") as stdout, (tmp_path / "log.err").open("w") as stderr:
        process = subprocess.Popen([sys.executable, "-c", "import sys, warpcoil_cli; sys.exit(warpcoil_cli.main())",
                                    "run", str(scene(tmp_path)), "-o", "started"], stdout=stdout, stderr=stderr,
                                   cwd=tmp_path, env=env)
        time.sleep(0.8)
        process.send_signal(stop)
        assert process.wait(timeout=300) == 130
    err = (tmp_path / "log.err").read_text()
    assert "Traceback" not in err and "interrupted" in one_line(err)
    assert not (tmp_path / "started").exists() or leftovers(tmp_path / "started") == []


@pytest.mark.parametrize("stop", [signal.SIGINT, signal.SIGTERM, "terminal"])
def test_a_stopped_sweep_ends_interrupted_and_resumes(tmp_path, stop):
    """A sweep stopped once its first member is written: exit 130 with one line, no traceback and no
    lock left in its folder (SIGTERM killed it with 143, no word and the lock left: Python's default
    action); `--resume` then completes it. "terminal": a Ctrl-C at a terminal, which signals the whole
    process group, the Dask worker processes too (each printed its traceback)."""
    path = scene(tmp_path, **{"length_mm = 4.0": "length_mm = 20.0", "push_speed_mm_s = 100.0":
                              "push_speed_mm_s = 20.0"})
    args = ("sweep", str(path), "--vary", "coil.length_mm=20,21,22,23,24,25", "--workers", "1", "-o", "sw")
    process, out, err = cli(tmp_path, *args, wait=False, group=stop == "terminal")
    deadline = time.monotonic() + 300
    while not (tmp_path / "sw" / "member_000" / "result.json").exists() and time.monotonic() < deadline:
        assert process.poll() is None, err.read_text()
        time.sleep(0.2)
    if stop == "terminal":
        os.killpg(process.pid, signal.SIGINT)
    else:
        process.send_signal(stop)
    assert process.wait(timeout=120) == 130
    assert "Traceback" not in err.read_text() and "warpcoil sweep: interrupted" in err.read_text()
    assert not list((tmp_path / "sw").glob(".*lock*"))
    code, _, err_text = cli(tmp_path, *args, "--resume", log="resumed")
    assert code == 0, err_text
    assert len(list((tmp_path / "sw").glob("member_*/result.json"))) == 6


def test_a_folder_of_the_other_kind_is_refused(tmp_path):
    """`run -o` into a sweep's folder wrote a run beside its member folders and summary; `sweep --resume -o`
    into a run's folder mixed a sweep into it. Both refused (exit 2, one line naming the fix), nothing touched."""
    sweep_folder = tmp_path / "swept"
    (sweep_folder / "member_000").mkdir(parents=True)
    (sweep_folder / "member_000" / "result.json").write_text("{}")
    (sweep_folder / "summary.csv").write_text("member\n")
    code, _, err = cli(tmp_path, "run", str(scene(tmp_path)), "-o", "swept", "--no-usd")
    assert code == 2 and "member_000" in one_line(err) and "fix:" in err
    assert sorted(p.name for p in sweep_folder.iterdir()) == ["member_000", "summary.csv"]
    run_folder = tmp_path / "ran"
    run_folder.mkdir()
    (run_folder / "result.json").write_text("{}")
    code, _, err = cli(tmp_path, "sweep", str(scene(tmp_path)), "--vary", "coil.length_mm=4,5", "--resume", "-o", "ran")
    assert code == 2 and "holds a single run's outputs" in one_line(err)
    assert [p.name for p in run_folder.iterdir()] == ["result.json"]


def test_overwrite_clears_every_commands_outputs(tmp_path):
    """`sweep --overwrite` into a plan's folder kept plan.md, plan.csv and plan.png beside the new
    members, describing deployments that were gone: --overwrite clears every command's outputs."""
    folder = tmp_path / "planned"
    (folder / "member_000").mkdir(parents=True)
    (folder / "member_000" / "result.json").write_text("{}")
    for name in ("plan.md", "plan.csv", "plan.png", "summary.csv", "summary.md"):
        (folder / name).write_text("old\n")
    code, _, err = cli(tmp_path, "sweep", str(scene(tmp_path)), "--vary", "coil.length_mm=4,5", "--workers", "1",
                       "--overwrite", "-o", "planned")
    assert code == 0, err
    assert sorted(p.name for p in folder.iterdir()) == ["member_000", "member_001", "summary.csv", "summary.md"]
    assert "old" not in (folder / "summary.md").read_text()


@pytest.mark.parametrize("command, bad", [
    ("sweep", ("--vary", "coil.length_mm=4,-5")),  # a member's value
    ("sweep", ("--vary", "coil.lenght_mm=4,5")),  # a key
    ("plan", ("--vary", "simulation.frame_interval_s=0.01,0.00001")),  # a run's pre-run check (frame < 2 steps)
])
def test_overwrite_keeps_the_earlier_outputs_when_the_input_is_bad(tmp_path, command, bad):
    """`sweep --overwrite` and `plan --overwrite` deleted the earlier results before the input was checked:
    a bad input left the folder empty (exit 2). They are cleared only once every member is checked."""
    folder = tmp_path / "earlier"
    (folder / "member_000").mkdir(parents=True)
    (folder / "member_000" / "result.json").write_text('{"old": 1}')
    (folder / "summary.md").write_text("old\n")
    code, _, err = cli(tmp_path, command, str(scene(tmp_path)), *bad, "--workers", "1", "--overwrite",
                       "-o", "earlier")
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert sorted(p.name for p in folder.iterdir()) == ["member_000", "summary.md"]
    assert (folder / "member_000" / "result.json").read_text() == '{"old": 1}'


def test_a_killed_run_leaves_no_outputs_and_the_next_run_takes_its_folder(tmp_path):
    """SIGKILL while stepping (no chance to write anything): the folder holds none of the run's
    outputs, only its hidden working folder and lock, and the next run into it needs no --overwrite
    and leaves neither."""
    process, _, _ = stepping_run(tmp_path, "killed")
    process.kill()
    process.wait(timeout=60)
    folder = tmp_path / "killed"
    assert [p.name for p in folder.iterdir() if not p.name.startswith(".")] == []
    assert leftovers(folder)  # the lock and the hidden folder of the killed run
    code, out, err = cli(tmp_path, "run", str(scene(tmp_path, name="short.toml")), "-o", "killed", log="next")
    assert code == 0, err
    assert json.loads((folder / "result.json").read_text())["status"] == "completed"
    assert leftovers(folder) == []


# --- 11: smaller things ---------------------------------------------------------------------
def test_bench_help_names_all_four_kinds(tmp_path):
    code, out, _ = cli(tmp_path, "bench", "--help")
    assert code == 0
    for kind in ("accuracy", "stress", "peers", "ensemble"):
        assert f"{kind}:" in out


@pytest.mark.parametrize("args, said", [
    (("ensemble", "--device", "gpu7"), "--device gpu7"),
    (("stress", "--device", "cpu"), "applies to `bench ensemble` only"),
    (("ensemble", "--repeats", "5"), "--repeats does not apply"),
    (("steps", "--repeats", "0"), "--repeats 0: "),  # (ran, its timing table inf, its JSON a bare Infinity)
])
def test_bench_refuses_options_it_cannot_use_in_one_line(tmp_path, args, said):
    """A bad device, a device for a CPU benchmark or repeats for the ensemble: one line, exit 2, no folder."""
    code, _, err = cli(tmp_path, "bench", *args, "--quick", "-o", "report")
    assert code == 2
    assert said in one_line(err) and "fix:" in err
    assert not (tmp_path / "report").exists()


def test_bench_refuses_an_output_path_it_cannot_use_in_one_line(tmp_path):
    """`bench -o` naming a file, or as root a folder that cannot be made, ended in a traceback (exit 1)."""
    (tmp_path / "afile").write_text("mine\n")
    code, _, err = cli(tmp_path, "bench", "steps", "--quick", "-o", "afile")
    assert code == 2 and "afile" in one_line(err) and "fix:" in err
    assert (tmp_path / "afile").read_text() == "mine\n"
    if Path("/proc/self").exists():
        code, _, err = cli(tmp_path, "bench", "steps", "--quick", "-o", "/proc/warpcoil_bench")
        assert code == 2 and "/proc/warpcoil_bench" in one_line(err)


def test_cuda_asked_for_without_a_driver_is_said_once(tmp_path):
    import warp as wp

    if wp.is_cuda_available():
        pytest.skip("this machine has CUDA")
    code, _, err = cli(tmp_path, "run", str(scene(tmp_path)), "--device", "cuda:0", "-o", "never")
    assert code == 2
    line = one_line(err)
    assert "--device cuda:0" in line and "no NVIDIA CUDA driver" in line and "--device cpu" in line


def test_a_binary_garbage_stl_is_not_a_mesh(tmp_path):
    (tmp_path / "sac.stl").write_bytes(np.random.default_rng(1).bytes(3000))
    path = scene(tmp_path, **{"sphere_diameter_mm = 3.5": 'mesh = "sac.stl"'})
    code, _, err = cli(tmp_path, "run", str(path), "-o", "never")
    assert code == 2
    assert "sac.stl: is not a mesh" in one_line(err) and "charset" not in err


def test_a_step_above_the_bound_names_the_scene_file_and_key(tmp_path):
    path = scene(tmp_path, **{"frame_interval_s = 0.005": "frame_interval_s = 0.005\nintegrator = \"symplectic\"\n"
                                                          "dt_s = 1e-3"})
    code, _, err = cli(tmp_path, "run", str(path), "-o", "never")
    assert code == 2
    line = one_line(err)
    assert "tiny.toml: simulation.dt_s" in line and "stable bound" in line


def test_a_reference_sized_step_on_the_implicit_step_is_warned_about(tmp_path):
    """dt_s within the explicit bound and no integrator key: the implicit step runs it (as given)
    and says that it gains nothing there; the warning is kept in result.json."""
    path = scene(tmp_path, **{"frame_interval_s = 0.005": "frame_interval_s = 0.005\ndt_s = 5e-6\n"
                                                          "max_time_s = 0.005"})
    code, out, err = cli(tmp_path, "run", str(path), "-o", "small")
    assert code == 3, err  # the time limit, one frame in
    assert "warning:" in err and "simulation.dt_s = 5e-06 s is within the explicit step bound" in err
    result = json.loads((tmp_path / "small" / "result.json").read_text())
    assert result["scheme"]["integrator"] == "implicit" and result["dt_s"] == 5e-6 < result["step_bound_s"]
    assert any("within the explicit step bound" in w for w in result["warnings"])
    assert out.startswith("timeout: ")


@pytest.mark.parametrize("integrator, runs, said", [
    ("", "symplectic", "no simulation.integrator, implicit_scheme or dt_s: the reference (symplectic) step runs it"),
    ('integrator = "implicit"\n', "implicit", "contact.friction_wall on the implicit step"),
    ('implicit_scheme = "euler"\n', "implicit", "contact.friction_wall on the implicit step"),
    ('integrator = "symplectic"\n', "symplectic", None)])
def test_wall_friction_runs_the_reference_unless_the_scene_names_an_integrator(tmp_path, integrator, runs, said):
    """The implicit step's push force with wall friction is several times the reference's
    (inelastic impacts): a frictional scene that names no integrator runs the reference and says
    why; one that names the implicit step (or a scheme of it) runs it with a warning; both said
    before the run and kept in result.json. Nothing is said on a reference named by the scene."""
    path = scene(tmp_path, **{"frame_interval_s = 0.005\n": "frame_interval_s = 0.005\n" + integrator,
                              "[output]": "[contact]\nfriction_wall = 0.3\n\n[output]"})
    code, out, err = cli(tmp_path, "run", str(path), "-o", "run")
    assert code == 0, err
    result = json.loads((tmp_path / "run" / "result.json").read_text())
    assert result["scheme"]["integrator"] == runs and f"{result['steps']} {runs} steps" in out
    warned = [w for w in result["warnings"] if "friction_wall" in w]
    if said is None:
        assert not warned and "friction_wall" not in err
    else:
        assert len(warned) == 1 and said in warned[0] and f"warning: {warned[0]}" in err
    assert out.startswith("completed: ")


def test_a_sweep_of_wall_friction_runs_every_member_on_one_integrator(tmp_path):
    """--vary contact.friction_wall=0,0.3 on a scene that names no integrator: the frictional member
    would run the reference and the other the implicit step; every member runs the reference, and
    the summary says so once."""
    path = scene(tmp_path)
    code, out, err = cli(tmp_path, "sweep", str(path), "--vary", "contact.friction_wall=0,0.3", "-o", "sweep")
    assert code == 0, err
    summary = (tmp_path / "sweep" / "summary.md").read_text()
    assert summary.count("Warning: ") == 2 and "1 of 2 members have wall friction" in summary
    assert summary.count("the reference (symplectic) step runs it") == 1
    assert err.count("warpcoil sweep: warning: ") == 2
    for member, friction in (("member_000", False), ("member_001", True)):
        result = json.loads((tmp_path / "sweep" / member / "result.json").read_text())
        assert result["scheme"]["integrator"] == "symplectic" and result["status"] == "completed"
        # each member's result.json keeps its own warnings, as `warpcoil run` keeps them
        assert "1 of 2 members have wall friction" in result["warnings"][0]
        assert any("the reference (symplectic) step runs it" in w for w in result["warnings"]) == friction
    assert "Warning: " in out  # the summary printed


def test_a_frictional_sweep_says_why_it_runs_the_reference_once(tmp_path):
    """Every member has wall friction and the scene names no integrator: each runs the reference,
    and the note is said once on stderr and once in the summary, not once per member."""
    path = scene(tmp_path, **{"[output]": "[contact]\nfriction_wall = 0.3\n\n[output]"})
    code, out, err = cli(tmp_path, "sweep", str(path), "--vary", "simulation.push_speed_mm_s=100,150", "-o", "sweep")
    assert code == 0, err
    summary = (tmp_path / "sweep" / "summary.md").read_text()
    assert summary.count("Warning: ") == 1 and "the reference (symplectic) step runs it" in summary
    assert err.count("warpcoil sweep: warning: ") == 1


def test_resume_reruns_a_member_written_on_another_integrator(tmp_path):
    """A sweep folder written when the scene named the implicit step, resumed once it names none:
    both members now run the reference (wall friction), so neither earlier result is kept."""
    named = 'frame_interval_s = 0.005\nintegrator = "implicit"\n'
    path = scene(tmp_path, **{"frame_interval_s = 0.005\n": named,
                              "[output]": "[contact]\nfriction_wall = 0.3\n\n[output]"})
    vary = ("--vary", "simulation.push_speed_mm_s=100,150", "-o", "sweep")
    assert cli(tmp_path, "sweep", str(path), *vary)[0] == 0
    path.write_text(path.read_text().replace(named, "frame_interval_s = 0.005\n"))
    code, out, err = cli(tmp_path, "sweep", str(path), *vary, "--resume", log="resume")
    assert code == 0, err
    assert "(0 resumed)" in (tmp_path / "sweep" / "summary.md").read_text()
    for member in ("member_000", "member_001"):
        result = json.loads((tmp_path / "sweep" / member / "result.json").read_text())
        assert result["scheme"]["integrator"] == "symplectic"


def test_a_resume_of_another_sweep_is_refused_and_touches_nothing(tmp_path):
    """A sweep folder resumed with other values, or with fewer members: one line naming the member and
    the fix (--overwrite, not --resume), exit 2, and the earlier sweep's folders and summary as they were."""
    path = scene(tmp_path)
    assert cli(tmp_path, "sweep", str(path), "--vary", "simulation.push_speed_mm_s=100,150", "-o", "sweep")[0] == 0
    before = {p.relative_to(tmp_path / "sweep"): p.read_bytes() for p in (tmp_path / "sweep").rglob("*") if p.is_file()}
    other = tmp_path / "other.toml"  # the same scene under another name: another sweep's folder too
    other.write_text(path.read_text())
    for scene_path, values, says in (
            (path, "100,200", "member_001 holds {'simulation.push_speed_mm_s': 150.0}"),
            (path, "100", "holds member_001, which this sweep of 1 members does not have"),
            (other, "100,150", f"member_000 was made from {path}, not {other}")):
        code, out, err = cli(tmp_path, "sweep", str(scene_path), "--vary", f"simulation.push_speed_mm_s={values}",
                             "-o", "sweep", "--resume", log=f"resume_{scene_path.stem}_{values}")
        line = [line for line in err.splitlines() if line.startswith("warpcoil sweep: ")]
        assert code == 2 and len(line) == 1 and "Traceback" not in err, err
        assert says in line[0] and "add --overwrite (without --resume)" in line[0], line[0]
        after = {p.relative_to(tmp_path / "sweep"): p.read_bytes() for p in (tmp_path / "sweep").rglob("*")
                 if p.is_file()}
        assert after == before  # the summary too


def test_a_frictional_sweep_on_the_implicit_step_says_so_once_in_its_summary(tmp_path):
    path = scene(tmp_path, **{"frame_interval_s = 0.005\n": 'frame_interval_s = 0.005\nintegrator = "implicit"\n',
                              "[output]": "[contact]\nfriction_wall = 0.3\n\n[output]"})
    code, out, err = cli(tmp_path, "sweep", str(path), "--vary", "simulation.push_speed_mm_s=100,150", "-o", "sweep")
    assert code == 0, err
    summary = (tmp_path / "sweep" / "summary.md").read_text()
    assert summary.count("Warning: ") == 1 and "contact.friction_wall on the implicit step" in summary
    assert "Warning: " in out  # the summary printed
    said = [line for line in err.splitlines() if line.startswith("warpcoil sweep: warning: ")]
    assert len(said) == 1 and "contact.friction_wall on the implicit step" in said[0]  # and before the run
    assert err.index(said[0]) < err.index("member_000")


# --- 4: an impossible deployment ------------------------------------------------------------
def test_an_overfull_sac_is_warned_about_and_ends_as_jammed(tmp_path):
    """40 mm of coil (2.7 mm³) for a 2 mm sac (4.2 mm³, 64 %): warned before the run;
    it ends as jammed ("stalled") once the coil in the sac fills half of it
    (stall_packing), well before the coil is in."""
    path = scene(tmp_path, **{"sphere_diameter_mm = 3.5": "sphere_diameter_mm = 2.0",
                              "tip = [0.0, 0.0, -1.45]": "tip = [0.0, 0.0, -0.8]",
                              "loop_diameter_mm = 2.5": "loop_diameter_mm = 1.5",
                              "length_mm = 4.0": "length_mm = 40.0"})
    code, out, err = cli(tmp_path, "run", str(path), "-o", "full", "-q")
    assert code == 3, err
    assert "warning:" in err and "64 % of the sac's" in err and "fills 50 % of it, after about 31 mm" in err
    result = json.loads((tmp_path / "full" / "result.json").read_text())
    assert result["status"] == "jammed" and result["reason"].startswith("stalled: coil 0")
    assert "stall_packing = 0.5" in result["reason"]
    area = math.pi * 0.14605**2
    in_sac = area * (result["deployed_length_mm"] - result["length_outside_sac_mm"]) / result["sac_volume_mm3"]
    assert 0.5 < in_sac < 0.5 + area * 0.5 / result["sac_volume_mm3"]  # stopped in the frame that crossed 50 %
    assert out.startswith("jammed: stalled")


def test_a_loop_far_larger_than_the_sac_is_warned_about_and_stalls_on_push_force(tmp_path):
    """A 35 mm loop for the 3.5 mm sac: warned before the run. Its self-deployment force (elastic energy
    per mm straightened in the catheter) is about 9 µN for so flat a loop, but no coil fills the sac
    without bending to its curvature, EI/(2 R²) ≈ 490 µN: the stall force is stall_force_ratio (here 1)
    × that, and the run ends as jammed ("stalled") once the frame-mean push force has stayed above it for
    the whole stall window (0.1 s)."""
    path = scene(tmp_path, **{"loop_diameter_mm = 2.5": "loop_diameter_mm = 35.0",
                              "length_mm = 4.0": "length_mm = 20.0",
                              "frame_interval_s = 0.005": "frame_interval_s = 0.005\nstall_force_ratio = 1.0"})
    code, out, err = cli(tmp_path, "run", str(path), "-o", "big", "-q")
    assert code == 3, err
    assert "coil[0].loop_diameter_mm = 35 is 10.0× the sac's size" in err
    result = json.loads((tmp_path / "big" / "result.json").read_text())
    self_force = result["stored_energy_nJ"] / result["coil_length_mm"]  # nJ/mm = µN
    sac_radius = (3.0 * result["sac_volume_mm3"] / (4.0 * math.pi)) ** (1.0 / 3.0)
    sac_bend = wc.CoilSpec(wire_diameter_mm=0.2921, loop_diameter_mm=35.0, length_mm=20.0).EI / (2.0 * sac_radius**2)
    stall_force = sac_bend
    assert 400.0 < sac_bend < 600.0 and self_force < 0.05 * sac_bend
    assert result["status"] == "jammed" and "stall_force_ratio = 1 ×" in result["reason"], result["reason"]
    assert (f"self-deployment force {self_force:.4g} µN (or the force that bends it to the sac's curvature, "
            f"{sac_bend:.4g} µN, where larger), at least 2 × the pushed coil's damping drag at the push speed, "
            f"= {stall_force:.4g} µN") in result["reason"]
    assert out.startswith("jammed: stalled") and "stall_force_ratio" in out
    rows = list(csv.DictReader((tmp_path / "big" / "timeseries.csv").open()))
    frame_s = float(rows[-1]["time_s"]) - float(rows[-2]["time_s"])
    count = math.ceil(0.1 / frame_s - 1e-9)  # frames that span the window
    mean = [float(r["push_force_mean_uN"]) for r in rows]
    assert min(mean[-count:]) > stall_force and mean[-count - 1] <= stall_force  # every frame of the window, no more
    assert result["deployed_length_mm"] < 19.0


def test_an_absolute_stall_force_replaces_the_ratio(tmp_path):
    """stall_force_uN (µN), when set, is the stall force instead of the ratio."""
    path = scene(tmp_path, **{"loop_diameter_mm = 2.5": "loop_diameter_mm = 35.0",
                              "length_mm = 4.0": "length_mm = 20.0",
                              "frame_interval_s = 0.005": "frame_interval_s = 0.005\nstall_force_uN = 500.0\n"
                              "stall_window_s = 0.05"})
    code, _, err = cli(tmp_path, "run", str(path), "-o", "big", "-q")
    assert code == 3, err
    result = json.loads((tmp_path / "big" / "result.json").read_text())
    assert result["status"] == "jammed" and "stall_force_uN = 500 µN" in result["reason"], result["reason"]
    rows = list(csv.DictReader((tmp_path / "big" / "timeseries.csv").open()))
    count = math.ceil(0.05 / (float(rows[-1]["time_s"]) - float(rows[-2]["time_s"])) - 1e-9)  # frames in the window
    mean = [float(r["push_force_mean_uN"]) for r in rows]
    assert min(mean[-count:]) > 500.0 and mean[-count - 1] <= 500.0


def test_a_coil_that_fits_completes_well_below_the_stall_force(tmp_path):
    """15 mm of the 2.5 mm helix (4.5 % packing) fills the sphere without a stall: it
    completes, its largest frame-mean push force far below the stall force (100 × its self-deployment force)."""
    path = scene(tmp_path, **{"length_mm = 4.0": "length_mm = 15.0"})
    code, out, err = cli(tmp_path, "run", str(path), "-o", "fits", "-q")
    assert code == 0, err
    result = json.loads((tmp_path / "fits" / "result.json").read_text())
    assert result["status"] == "completed" and out.startswith("completed")
    self_force = result["stored_energy_nJ"] / result["coil_length_mm"]
    assert result["push_force_mean_max_uN"] < 0.1 * 100.0 * self_force  # margin ≥ 10×


@pytest.mark.parametrize("shape", ["straight", "loop 10x the sac"])
def test_a_coil_without_a_pre_shape_that_fits_fills_the_sac_instead_of_stalling(tmp_path, shape):
    """A straight coil (self-deployment force 0) or a 35 mm loop (9 µN), 30 mm into the 3.5 mm sphere: each must
    bend to the sac's curvature, EI/(2 R²) ≈ 490 µN per mm, to fill it; held to 100 × its self-deployment force (or
    the drag floor, 551 µN) the straight one stalled at 8.2 mm, 2.5 % packing (a physicist's audit). The stall force
    is 100 × the larger of the two now: both deploy the whole coil, every node inside the wall."""
    (tmp_path / "straight.txt").write_text("\n".join(f"0 0 {0.1 * k:.1f}" for k in range(301)) + "\n")
    coil = ('shape = "file"\nfile = "straight.txt"\nloop_diameter_mm = 3.0' if shape == "straight" else
            'shape = "helix"\nloop_diameter_mm = 35.0\npitch_mm = 0.6')
    path = scene(tmp_path, **{'shape = "helix"\nwire_diameter_mm = 0.2921\nloop_diameter_mm = 2.5\npitch_mm = 0.6\n'
                              'length_mm = 4.0': f"{coil}\nwire_diameter_mm = 0.2921\nlength_mm = 30.0",
                              "push_speed_mm_s = 100.0": "push_speed_mm_s = 50.0"})
    code, out, err = cli(tmp_path, "run", str(path), "-o", "out")
    assert code == 0, err
    result = json.loads((tmp_path / "out" / "result.json").read_text())
    assert result["status"] == "completed", result["reason"]
    assert result["deployed_length_mm"] == pytest.approx(30.0, abs=1e-3) and result["length_outside_sac_mm"] == 0.0
    assert result["min_wall_gap_mm"] > -0.5 * 0.2921


def test_a_straight_coil_in_free_space_completes_instead_of_stalling(tmp_path):
    """A straight pre-shape (self-deployment force 0 µN) pushed 12 mm into free space: its free part's damping
    drag (tens of µN) stayed above 100 × 0 µN, so it stalled at once (a physicist's audit); the stall force is
    at least twice the coils' whole drag at the push speed now (2 × 9.2 µN/mm × 12 mm), and it completes."""
    points = "\n".join(f"0 0 {0.1 * k:.1f}" for k in range(121))
    (tmp_path / "straight.txt").write_text(points + "\n")
    text = """
[catheter]
tip = [0.0, 0.0, 0.0]
direction = [0.0, 0.0, 1.0]

[[coil]]
shape = "file"
file = "straight.txt"
wire_diameter_mm = 0.2921
loop_diameter_mm = 3.0
length_mm = 12.0

[simulation]
push_speed_mm_s = 50.0

[output]
usd = false
"""
    code, out, err = cli(tmp_path, "run", str(scene(tmp_path, text, name="straight.toml")), "-o", "out")
    assert code == 0, err
    result = json.loads((tmp_path / "out" / "result.json").read_text())
    assert result["status"] == "completed" and result["stored_energy_nJ"] < 1e-6
    assert 0.0 < result["push_force_mean_max_uN"] < 2.0 * 10.0 * (1.0 - math.exp(-2.5)) * 12.0  # the drag


def test_a_sweep_whose_tip_is_outside_is_refused_before_stepping(tmp_path):
    path = scene(tmp_path, **{"tip = [0.0, 0.0, -1.45]": "tip = [0.0, 0.0, -2.0]"})
    code, _, err = cli(tmp_path, "sweep", str(path), "--vary", "simulation.push_speed_mm_s=100,150", "-o", "never")
    assert code == 2
    assert "catheter.tip [0, 0, -2] mm is 0.25 mm outside the lumen" in one_line(err)
    assert not (tmp_path / "never").exists()


def test_a_sweep_error_names_the_member_and_its_varied_value(tmp_path):
    """The key a member's error names may hold a --vary value (not the file's), or follow from one
    (a tip outside a varied sphere): the line names the member and its values."""
    code, _, err = cli(tmp_path, "sweep", str(scene(tmp_path)), "--vary", "coil.length_mm=4,-5", "-o", "never")
    line = one_line(err)
    assert code == 2 and line.startswith("warpcoil sweep: member_001 (coil.length_mm=-5): ")
    assert "coil[0].length_mm" in line and "fix:" in line
    code, _, err = cli(tmp_path, "sweep", str(scene(tmp_path)), "--vary", "wall.sphere_diameter_mm=4,0.5",
                       "-o", "never")
    line = one_line(err)
    assert code == 2 and line.startswith("warpcoil sweep: member_001 (wall.sphere_diameter_mm=0.5): ")
    assert "catheter.tip" in line and "outside the lumen" in line
    assert not (tmp_path / "never").exists()


def test_an_unwritable_parent_is_refused_in_one_line(tmp_path, monkeypatch):
    """(The subprocess test above is skipped as root, who may write anywhere.)"""
    from warpcoil.recorder import folder

    monkeypatch.setattr(folder.os, "access", lambda path, mode: False)
    with pytest.raises(folder.OutputFolderError, match=r"is not writable; fix: choose a folder you can write to"):
        folder.check_output_path(tmp_path / "run")


def test_varying_a_neck_placement_key_of_an_explicit_catheter_is_refused(tmp_path):
    """catheter.angle_deg tilts a catheter placed from the neck; on an explicit tip and
    direction it would change nothing, so every member would be the same run."""
    path = scene(tmp_path)
    code, _, err = cli(tmp_path, "sweep", str(path), "--vary", "catheter.angle_deg=0,10", "-o", "never")
    assert code == 2
    line = one_line(err)
    assert str(path) in line and "catheter.angle_deg: applies only with placement = 'neck'" in line
    assert "catheter.tip and catheter.direction" in line
    assert not (tmp_path / "never").exists()


# --- the implicit step's scheme: the default (gated_chord), euler by name, and bad values ---------------
GATED_CHORD_SCHEME = {"method": "theta", "theta": 0.65, "near_theta": 1.0, "turn_gate_rad": 0.01,
                      "contact_stiffness": "chord", "chord_end": "flight"}


@pytest.mark.parametrize("lines, expected", [
    ("", {"integrator": "implicit", **GATED_CHORD_SCHEME}),
    ('integrator = "implicit"\nimplicit_scheme = "gated_chord"\n', {"integrator": "implicit", **GATED_CHORD_SCHEME}),
    ('integrator = "implicit"\nimplicit_scheme = "euler"\n',
     {"integrator": "implicit", "method": "theta", "theta": 1.0, "near_theta": None, "turn_gate_rad": None,
      "contact_stiffness": "tangent", "chord_end": None}),
    ('integrator = "symplectic"\n', {"integrator": "symplectic"})])
def test_a_run_reports_its_scheme_the_implicit_default_or_one_chosen_by_name(tmp_path, lines, expected):
    """No key: the implicit step's default scheme (gated_chord: θ 0.65 gated, chord); named,
    linearly implicit Euler or the symplectic reference. result.json's "scheme" says which ran
    the push, and the step count shows it (the reference's step is ~30× shorter here)."""
    path = scene(tmp_path, **{"frame_interval_s = 0.005\n": "frame_interval_s = 0.005\n" + lines})
    code, out, err = cli(tmp_path, "run", str(path), "-o", "run")
    assert code == 0, err
    assert out.startswith("completed: ")
    result = json.loads((tmp_path / "run" / "result.json").read_text())
    assert result["scheme"] == expected
    assert f" {expected['integrator']} steps of " in out.splitlines()[1]  # the summary line names it
    implicit = expected["integrator"] == "implicit"
    assert (result["dt_s"] > 1e-4) == implicit and (result["dt_s"] < result["step_bound_s"]) != implicit


@pytest.mark.parametrize("lines, message", [
    ('integrator = "implicit"\nimplicit_scheme = "rk4"\n', "simulation.implicit_scheme: must be one of 'euler', "
                                                           "'gated_chord', 'bdf2', got 'rk4'"),
    ('integrator = "symplectic"\nimplicit_scheme = "euler"\n',
     "simulation.implicit_scheme: applies only to integrator = 'implicit'")])
def test_a_bad_implicit_scheme_is_one_line_naming_file_and_key(tmp_path, lines, message):
    path = scene(tmp_path, **{"frame_interval_s = 0.005\n": "frame_interval_s = 0.005\n" + lines})
    code, _, err = cli(tmp_path, "run", str(path), "-o", "never")
    assert code == 2
    line = one_line(err)
    assert str(path) in line and message in line and "fix:" in line
    assert not (tmp_path / "never").exists()


def test_a_preshape_that_cannot_be_made_names_its_file_and_coil(tmp_path):
    """A second coil whose spherical pre-shape cannot hold its length: one line naming the scene file
    and coil[1] (the pre-shape's own message names neither), exit 2, no outputs."""
    second = ('[[coil]]\nshape = "spherical"\nwire_diameter_mm = 0.2921\nloop_diameter_mm = 2.0\n'
              "length_mm = 100.0\n\n[simulation]")
    path = scene(tmp_path, **{"[simulation]": second})
    code, out, err = cli(tmp_path, "run", str(path), "-o", "ps")
    line = one_line(err)
    assert code == 2 and str(path) in line and "coil[1]" in line and "does not fit" in line
    assert not (tmp_path / "ps").exists() or leftovers(tmp_path / "ps") == []


def test_validate_runs_each_named_case_once(tmp_path):
    """`validate contact contact` ran the case twice ("10 passed"), and `wall_field` was the only name
    with an underscore (`wall-field` unknown): each case runs once, and either spelling names it."""
    from warpcoil.validation import contact_law

    rows = len(contact_law())
    code, out, err = cli(tmp_path, "validate", "contact", "contact", "contact")
    assert code == 0, err
    assert out.rstrip().endswith(f"{rows} passed, 0 failed")
    code, _, err = cli(tmp_path, "validate", "wall_feld")
    assert code == 2 and "unknown case(s) wall_feld;" in one_line(err) and "wall-field" in err  # (as typed)
    from warpcoil.validation import run

    assert [r.case for r in run(["wall_field"])] == [r.case for r in run(["wall-field"])]


@pytest.mark.parametrize("stop", [signal.SIGINT, signal.SIGTERM])
def test_a_stop_ends_validate_not_only_the_case_that_runs(tmp_path, stop):
    """`warpcoil validate` (every case, minutes) stopped 8 s in: the whole command ends (exit 130,
    one line, no traceback) instead of one run ending as interrupted and the next case beginning."""
    process, out, err = cli(tmp_path, "validate", wait=False)
    time.sleep(8.0)
    process.send_signal(stop)
    assert process.wait(timeout=120) == 130
    assert "Traceback" not in err.read_text() and "interrupted" in one_line(err.read_text())


@pytest.mark.parametrize("integrator", ["implicit", "symplectic"])
def test_frames_shorter_than_two_steps_are_refused(tmp_path, integrator):
    """frame_interval_s = 1e-9 s: the implicit step's settling, which splits frames into steps, ran at
    5e-10 s steps and never ended; a frame is at least two steps on either integrator. Refused before the
    run: one line naming the file, key and the interval that fixes it, exit 2, no outputs; that interval runs."""
    path = scene(tmp_path, **{"frame_interval_s = 0.005": f'frame_interval_s = 1e-9\nintegrator = "{integrator}"'})
    code, out, err = cli(tmp_path, "run", str(path), "-o", "fast")
    line = one_line(err)
    assert code == 2 and f"{path}: simulation.frame_interval_s = 1e-09 s is shorter than two" in line, err
    assert not (tmp_path / "fast").exists() or leftovers(tmp_path / "fast") == []
    fixed = line.split("fix: frame_interval_s = ")[1].split(" ")[0]
    path.write_text(path.read_text().replace("frame_interval_s = 1e-9", f"frame_interval_s = {fixed}"))
    code, _, err = cli(tmp_path, "run", str(path), "-o", "fixed", "--no-usd", log="fixed")
    assert code == 0, err


def test_a_run_without_a_tube_mesh_needs_no_vtk(tmp_path, monkeypatch):
    """VTK is loaded only to write tube meshes and porous fields (and read VTK walls): a run that
    writes neither completes with VTK unimportable (the GPU image has none), result.json last."""
    blocked = tmp_path / "no_vtk"
    (blocked / "vtkmodules").mkdir(parents=True)
    (blocked / "vtkmodules" / "__init__.py").write_text("raise ImportError('VTK is not installed here')\n")
    monkeypatch.setenv("PYTHONPATH", str(blocked) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    path = scene(tmp_path, **{"usd = false": "usd = false\ntube_mesh = false\npng = true"})
    code, out, err = cli(tmp_path, "run", str(path), "-o", "out")
    assert code == 0, err
    written = sorted(p.name for p in (tmp_path / "out").iterdir())
    assert "result.json" in written and "summary.png" in written and "coils.stl" not in written
    assert json.loads((tmp_path / "out" / "result.json").read_text())["status"] == "completed"


def _file_size_limit(limit_bytes: int):
    """preexec_fn: writes past ``limit_bytes`` fail with EFBIG (as on a full disk: ENOSPC), not with SIGXFSZ."""
    import resource

    def limit():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit_bytes, limit_bytes))
    return limit


def test_outputs_that_cannot_be_written_are_one_line_exit_4_and_leave_nothing(tmp_path):
    path = scene(tmp_path, **{"usd = false": "usd = false\npng = true"})
    code, _, err = cli(tmp_path, "run", str(path), "-o", "warm", "-q")  # (the kernels cached, unlimited)
    assert code == 0, err
    assert (tmp_path / "warm" / "summary.png").stat().st_size > 20_000  # (more than the limit below)
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "notes.txt").write_text("mine")
    with (tmp_path / "full.out").open("w") as stdout, (tmp_path / "full.err").open("w") as stderr:
        code = subprocess.run([sys.executable, "-m", "warpcoil.cli", "run", str(path), "-o", "full", "-q"],
                              stdout=stdout, stderr=stderr, cwd=tmp_path, env=program_env(),
                              preexec_fn=_file_size_limit(20_000), timeout=600).returncode
    line = one_line((tmp_path / "full.err").read_text())
    assert code == 4
    assert line.startswith("warpcoil run: full: writing the outputs failed (File too large, EFBIG)"), line
    assert "fix: free space" in line
    assert sorted(p.name for p in (tmp_path / "full").iterdir()) == ["notes.txt"]  # no output, no lock, no stage


def test_free_space_reports_no_length_outside_a_sac(tmp_path):
    """With no [wall] there is no sac to be outside of: length_outside_sac_mm is null (result.json, each coil),
    an empty cell in timeseries.csv and a sweep's summary.csv, as the packing densities are, not 0."""
    free = SPHERE.replace("[wall]\nsphere_diameter_mm = 3.5\n", "")
    code, _, err = cli(tmp_path, "run", str(scene(tmp_path, free)), "-o", "run", "-q")
    assert code == 0, err
    result = json.loads((tmp_path / "run" / "result.json").read_text())
    assert result["packing_density"] is None and result["length_outside_sac_mm"] is None
    assert [c["length_outside_sac_mm"] for c in result["coils"]] == [None]
    rows = list(csv.DictReader((tmp_path / "run" / "timeseries.csv").open()))
    assert {r["length_outside_sac_mm"] for r in rows} == {""}
    code, _, err = cli(tmp_path, "sweep", str(scene(tmp_path, free)), "--vary", "coil.length_mm=4,5", "-o", "sweep",
                       "-q", "--workers", "1")
    assert code == 0, err
    rows = list(csv.DictReader((tmp_path / "sweep" / "summary.csv").open()))
    assert [(r["packing_density"], r["length_outside_sac_mm"]) for r in rows] == [("", "")] * 2


def test_a_sweep_with_a_jammed_member_exits_3_as_its_help_says(tmp_path):
    """Exit codes are documented (sweep --help, docs/SWEEPS.md): no member failed, one jammed → 3."""
    code, out, _ = cli(tmp_path, "sweep", "--help", log="help")
    assert code == 0 and "3 no member failed but one jammed or timed out" in " ".join(out.split())
    code, out, err = cli(tmp_path, "sweep", str(scene(tmp_path)), "--vary", "simulation.stall_packing=0.002,0.5",
                         "-o", "sweep", "-q", "--workers", "1")
    assert code == 3, err
    rows = list(csv.DictReader((tmp_path / "sweep" / "summary.csv").open()))
    assert [r["status"] for r in rows] == ["jammed", "completed"]


def test_a_step_far_longer_than_the_default_is_warned_about(tmp_path):
    """dt_s = 2 ms at 100 mm/s moves the pusher 6.8 c0 a step (the default 0.8 c0): one line at the start,
    kept in result.json; the run goes on."""
    path = scene(tmp_path, **{"frame_interval_s = 0.005": "frame_interval_s = 0.005\ndt_s = 2e-3"})
    code, _, err = cli(tmp_path, "run", str(path), "-o", "coarse")
    assert code in (0, 3), err
    said = [line for line in err.splitlines() if "warning:" in line]
    assert len(said) == 1 and "simulation.dt_s = 0.002 s moves the pusher 6.8 c0 a step" in said[0], err
    assert "the default step here, 0.000234 s" in said[0] and "0.00058 s or less" in said[0]
    assert said[0].split("warning: ")[1] in json.loads((tmp_path / "coarse" / "result.json").read_text())["warnings"]


def test_a_step_that_would_take_hours_is_warned_about_before_stepping(tmp_path):
    """dt_s = 1e-8 s: 2e8 steps to the default time limit (2.05 s); said once at the start with the
    default step, before the run steps (stopped here at its first progress line by a Ctrl-C)."""
    path = scene(tmp_path, **{"frame_interval_s = 0.005": "frame_interval_s = 1e-7\ndt_s = 1e-8"})
    process, _, err = cli(tmp_path, "run", str(path), "-o", "fine", wait=False, log="fine")
    deadline = time.monotonic() + 300
    while "deployed " not in err.read_text() and time.monotonic() < deadline and process.poll() is None:
        time.sleep(0.2)
    process.send_signal(signal.SIGINT)
    assert process.wait(timeout=300) == 130
    text = err.read_text()
    assert text.index("steps to the time limit") < text.index("deployed ")  # said before it steps
    said = [line for line in text.splitlines() if "steps to the time limit" in line]
    assert len(said) == 1 and "simulation.dt_s = 1e-08 s takes up to 2e+08 steps" in said[0]
    assert "the default step here is 0.000234 s" in said[0] and "remove dt_s" in said[0]
