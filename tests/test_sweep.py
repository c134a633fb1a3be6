"""`warpcoil sweep` on Dask: --vary parsing, members equal to their single runs on
two local workers and on a separately started scheduler and worker, a killed
worker's task retried, --resume, files shipped to workers, bad input."""

import csv
import io
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import dask
import distributed  # noqa: F401  (its config defaults loaded before any dask.config.set here: leaving one that
#                                  created the "distributed" table deleted the defaults with it)
import pytest
import trimesh
from pxr import Usd, UsdGeom

from warpcoil.cli import main
from warpcoil.deploy import deploy
from warpcoil.recorder import validate_usd
from warpcoil.recorder.outputs import write_run
from warpcoil.scene import load_scene
from warpcoil.sweep import Member, SweepError, SweepProgress, complete_result, parse_vary, run_sweep
from warpcoil.sweep_task import make_task, run_task, worker_device

ROOT = Path(__file__).resolve().parents[1]
SPEEDS = (100.0, 150.0)
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
mesh = "walls/sphere.stl"

[simulation]
push_speed_mm_s = 100.0
frame_interval_s = 0.005
"""
# timing and what a sweep adds: all else must equal the single run's
UNCOMPARED_KEYS = ("wall_time_s", "scene", "varied", "scene_sha256", "warnings", "files")


def _scene(folder: Path) -> Path:
    """The test scene, its wall a 3.5 mm sphere mesh in a file beside it (shipped to the workers)."""
    (folder / "walls").mkdir(parents=True, exist_ok=True)
    trimesh.creation.icosphere(subdivisions=3, radius=1.75).export(folder / "walls" / "sphere.stl")
    (folder / "s.toml").write_text(SCENE)
    return folder / "s.toml"


def _env() -> dict:
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}


@pytest.fixture(scope="module")
def single_runs(tmp_path_factory):
    """Each member run alone in this process: its output folder."""
    root = tmp_path_factory.mktemp("single")
    scene_path = _scene(root)
    folders = []
    for k, speed in enumerate(SPEEDS):
        scene = load_scene(scene_path, {"simulation.push_speed_mm_s": speed})
        result = deploy(scene)
        folders.append(root / f"run_{k}")
        folders[-1].mkdir()
        write_run(folders[-1], scene, None, result)
    return folders


def _assert_equals_single_runs(out: Path, single_runs, members=range(len(SPEEDS))):
    for k in members:
        member = out / f"member_{k:03d}"
        for name in ("centerline.csv", "timeseries.csv"):
            assert (member / name).read_bytes() == (single_runs[k] / name).read_bytes(), (member, name)
        swept = json.loads((member / "result.json").read_text())
        alone = json.loads((single_runs[k] / "result.json").read_text())
        assert {k: v for k, v in swept.items() if k not in UNCOMPARED_KEYS} == \
            {k: v for k, v in alone.items() if k not in UNCOMPARED_KEYS}
        assert swept["varied"] == {"simulation.push_speed_mm_s": SPEEDS[k]}
        assert swept["warnings"] == []  # this scene warns of nothing (a member's own warnings: test_cli_user)
        assert complete_result(member) == swept


def _sweep_cli(args: list[str], stdout: Path, timeout_s: float = 300) -> subprocess.CompletedProcess:
    with stdout.open("w") as file:
        return subprocess.run([sys.executable, "-m", "warpcoil.cli", "sweep", *args], stdout=file,
                              stderr=subprocess.PIPE, text=True, env=_env(), cwd=stdout.parent, timeout=timeout_s)


def test_parse_vary():
    assert parse_vary("catheter.angle_deg=0:30:5") == ("catheter.angle_deg", [0.0, 5.0, 10.0, 15.0, 20.0, 25.0, 30.0])
    assert parse_vary("coil.0.length_mm=40,50") == ("coil.0.length_mm", [40.0, 50.0])
    assert parse_vary("coil.length_mm = 6, 8") == ("coil.length_mm", [6.0, 8.0])  # (spaces around = as in TOML)
    with pytest.raises(SweepError, match=r"'coil\.length_mm=6:8': a range is three numbers, start:stop:step, and "
                                         r"'6:8' has 2; write"):
        parse_vary("coil.length_mm=6:8")  # (once a Python unpacking message)
    with pytest.raises(SweepError, match=r"start, stop and step must be finite numbers"):
        parse_vary("coil.length_mm=6:inf:1")  # (once a traceback: an OverflowError)
    for bad in ("catheter.angle_deg", "x=1:0:1", "x=0:1:0", "x=a:b:c"):
        with pytest.raises(SweepError, match="--vary"):
            parse_vary(bad)
    with pytest.raises(SweepError, match=r"200,001 values, more than a sweep's 20,000 members; fix: a coarser step"):
        parse_vary("coil.length_mm=10:30:0.0001")  # a mistyped step: refused at once, not loaded for minutes


def test_a_product_of_values_beyond_a_sweeps_members_is_refused():
    from warpcoil.sweep import members

    assert len(members([("a", list(range(100))), ("b", list(range(200)))])) == 20_000
    with pytest.raises(SweepError, match=r"--vary a b: 20,100 members, more than a sweep's 20,000; fix: coarser"):
        members([("a", list(range(100))), ("b", list(range(201)))])


def test_a_key_varied_twice_or_a_value_given_twice_is_refused():
    """`--vary k=30 --vary k=40` ran only k=40 (the last won) and `--vary k=30,30` two identical
    members, unseen: both refused, naming the key and the fix."""
    from warpcoil.sweep import members

    with pytest.raises(SweepError, match=r"--vary coil.length_mm: given 2 times; fix: one --vary per key"):
        members([("coil.length_mm", [30.0]), ("catheter.angle_deg", [0.0]), ("coil.length_mm", [40.0])])
    with pytest.raises(SweepError, match=r"--vary coil.length_mm: the value 30.0 is given twice"):
        members([("coil.length_mm", [30.0, 40.0, 30.0])])
    assert len(members([("coil.length_mm", [30.0, 40.0]), ("catheter.angle_deg", [0.0, 30.0])])) == 4


def test_resume_and_overwrite_together_are_refused(tmp_path):
    run = _sweep_cli([str(_scene(tmp_path)), "--vary", "simulation.push_speed_mm_s=100,150", "-o",
                      str(tmp_path / "out"), "--resume", "--overwrite"], tmp_path / "stdout.txt")
    assert run.returncode == 2 and "--resume and --overwrite" in run.stderr and "fix:" in run.stderr
    assert not (tmp_path / "out").exists()


def test_a_task_carries_its_files(tmp_path, single_runs):
    """No shared filesystem: the task runs with the scene's files gone from their paths."""
    scene = load_scene(_scene(tmp_path), {"simulation.push_speed_mm_s": SPEEDS[0]})
    task = make_task([0], [scene], usd=False, device=None)
    assert list(task.files) == [str(tmp_path / "walls" / "sphere.stl")]
    shutil.rmtree(tmp_path / "walls")
    (output,) = run_task(task)
    assert output.files["centerline.csv"] == (single_runs[0] / "centerline.csv").read_bytes()
    assert output.result["steps"] == json.loads((single_runs[0] / "result.json").read_text())["steps"]


def test_two_local_workers_equal_single_runs_and_resume(tmp_path, single_runs):
    scene = _scene(tmp_path)
    out = tmp_path / "out"
    vary = ["--vary", "simulation.push_speed_mm_s=100,150", "-o", str(out)]
    run = _sweep_cli([str(scene), *vary, "--workers", "2", "--usd"], tmp_path / "stdout.txt")
    assert run.returncode == 0, run.stderr
    summary = (tmp_path / "stdout.txt").read_text()
    assert "2 members (0 resumed) in 2 ensemble task(s) on 2 Dask worker thread(s)" in summary
    for k in range(2):  # not a terminal: one line per finished member
        assert f"member_{k:03d} simulation.push_speed_mm_s={SPEEDS[k]:g}: completed" in run.stderr
    _assert_equals_single_runs(out, single_runs)
    rows = list(csv.DictReader((out / "summary.csv").open()))
    assert [r["status"] for r in rows] == ["completed", "completed"]
    for k in range(2):
        usd = out / f"member_{k:03d}" / "deployment.usdc"
        assert validate_usd(usd) == []
        stage = Usd.Stage.Open(str(usd))
        curves = [p for p in stage.Traverse() if p.IsA(UsdGeom.BasisCurves)]
        frames = len(list(csv.DictReader((out / f"member_{k:03d}" / "timeseries.csv").open())))
        assert len(curves) == 1 and len(curves[0].GetAttribute("points").GetTimeSamples()) == frames

    kept = (out / "member_000" / "result.json").stat()
    (out / "member_001" / "centerline.csv").unlink()  # incomplete: a file result.json lists is missing
    assert complete_result(out / "member_001") is None
    run = _sweep_cli([str(scene), *vary, "--workers", "1", "--resume", "--usd"], tmp_path / "stdout.txt")
    assert run.returncode == 0, run.stderr
    assert "2 members (1 resumed) in 1 ensemble task(s)" in (tmp_path / "stdout.txt").read_text()
    assert "member_000 simulation.push_speed_mm_s=100: completed" in run.stderr and "resumed" in run.stderr
    again = (out / "member_000" / "result.json").stat()
    assert (again.st_ino, again.st_mtime_ns) == (kept.st_ino, kept.st_mtime_ns)  # not rerun
    _assert_equals_single_runs(out, single_runs)

    other = _sweep_cli([str(scene), "--vary", "simulation.push_speed_mm_s=120,150", "-o", str(out), "--resume"],
                       tmp_path / "stdout.txt")
    assert other.returncode == 2 and "another sweep's member" in other.stderr

    # the same scene file edited (a value no member varies), or its wall mesh changed: every member made from the
    # other version runs again (a resume mixed them: a helper's loop 4.0 → 2.5 mm in the same file)
    scene.write_text(scene.read_text().replace("frame_interval_s = 0.005", "frame_interval_s = 0.004"))
    edited = _sweep_cli([str(scene), *vary, "--workers", "1", "--resume"], tmp_path / "stdout.txt")
    assert edited.returncode == 0, edited.stderr
    assert "2 members (0 resumed)" in (tmp_path / "stdout.txt").read_text()
    # (a changed mesh changes the fingerprint as an edited value does: the wall's bytes are in it)
    from warpcoil.sweep import scene_fingerprint

    before = scene_fingerprint(load_scene(scene))
    trimesh.creation.icosphere(subdivisions=3, radius=1.8).export(tmp_path / "walls" / "sphere.stl")
    assert scene_fingerprint(load_scene(scene)) != before


def test_resume_with_usd_reruns_members_made_without_it(tmp_path):
    """Members kept by `--resume` had no deployment.usdc when the first sweep ran with --no-usd (no word): a
    member made without the USD the resumed sweep asks for (the scene's [output] usd, default true) runs again."""
    scene = _scene(tmp_path)
    out = tmp_path / "out"
    vary = ["--vary", "simulation.push_speed_mm_s=100,150", "-o", str(out), "--workers", "1"]
    assert _sweep_cli([str(scene), *vary, "--no-usd"], tmp_path / "stdout.txt").returncode == 0
    assert not list(out.glob("member_*/deployment.usdc"))
    run = _sweep_cli([str(scene), *vary, "--resume"], tmp_path / "stdout.txt")
    assert run.returncode == 0, run.stderr
    assert "2 members (0 resumed)" in (tmp_path / "stdout.txt").read_text()
    assert len(list(out.glob("member_*/deployment.usdc"))) == 2


def test_members_write_the_usd_and_animation_their_scene_asks_for(tmp_path):
    """A sweep's members write what `warpcoil run` of them writes: the scene's [output] usd (default true) and
    animation (both were left out unless --usd, the animation always); --no-usd skips the USD, as for run."""
    scene = _scene(tmp_path)
    scene.write_text(SCENE + "\n[output]\nanimation = true\n")
    for flags, written in (([], ["deployment.gif", "deployment.usdc"]), (["--no-usd"], ["deployment.gif"])):
        out = tmp_path / f"out{len(flags)}"
        run = _sweep_cli([str(scene), "--vary", "simulation.push_speed_mm_s=100", "-o", str(out), "--workers", "1",
                          "-q", *flags], tmp_path / "stdout.txt")
        assert run.returncode == 0, run.stderr
        member = out / "member_000"
        assert sorted(p.name for p in member.glob("deployment.*")) == written
        assert set(written) <= set(json.loads((member / "result.json").read_text())["files"])
    from PIL import Image

    with Image.open(tmp_path / "out0" / "member_000" / "deployment.gif") as gif:
        frames = len(list(csv.DictReader((tmp_path / "out0" / "member_000" / "timeseries.csv").open())))
        assert gif.n_frames == min(60, frames)
    assert validate_usd(tmp_path / "out0" / "member_000" / "deployment.usdc") == []


def test_a_killed_workers_task_is_retried(tmp_path, single_runs, monkeypatch):
    marker = tmp_path / "killed"
    monkeypatch.setenv("WARPCOIL_TEST_KILL_MARKER", str(marker))
    with dask.config.set({"distributed.worker.preload": [str(Path(__file__).with_name("dask_kill_once.py"))]}):
        todo = run_sweep(_scene(tmp_path), [("simulation.push_speed_mm_s", list(SPEEDS))], tmp_path / "out",
                         workers=1, retries=1)
    assert marker.read_text().startswith("warpcoil-ensemble")  # the first try's worker died
    assert [m.result["status"] for m in todo] == ["completed", "completed"]
    _assert_equals_single_runs(tmp_path / "out", single_runs)


def test_a_worker_that_dies_without_a_retry_is_said_in_plain_words(tmp_path, monkeypatch):
    """No retry left (retries 0): the member is not run, and the sweep says a worker process died and what
    usually kills one (the cluster's own log is silenced, and Dask's KilledWorker names only the task)."""
    from warpcoil.sweep import SweepIncomplete

    monkeypatch.setenv("WARPCOIL_TEST_KILL_MARKER", str(tmp_path / "killed"))
    with dask.config.set({"distributed.worker.preload": [str(Path(__file__).with_name("dask_kill_once.py"))]}):
        with pytest.raises(SweepIncomplete) as refused:
            run_sweep(_scene(tmp_path), [("simulation.push_speed_mm_s", list(SPEEDS))], tmp_path / "out",
                      workers=1, retries=0)
    said = str(refused.value)
    assert "a Dask worker process died running it 1 time(s) (out of memory" in said and "--resume" in said


def test_scheduler_sweep_on_a_separately_started_cluster(tmp_path, single_runs):
    scheduler_file = tmp_path / "scheduler.json"
    started = []
    try:
        started.append(subprocess.Popen(
            [sys.executable, "-m", "dask", "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
             "--scheduler-file", str(scheduler_file)], env=_env(), cwd=tmp_path, stderr=subprocess.DEVNULL))
        deadline = time.monotonic() + 120
        while not scheduler_file.exists() and time.monotonic() < deadline:
            time.sleep(0.2)
        address = json.loads(scheduler_file.read_text())["address"]
        started.append(subprocess.Popen(
            [sys.executable, "-m", "dask", "worker", address, "--nthreads", "1", "--nworkers", "1", "--no-dashboard",
             "--host", "127.0.0.1"], env=_env(), cwd=tmp_path, stderr=subprocess.DEVNULL))
        run = _sweep_cli([str(_scene(tmp_path)), "--vary", "simulation.push_speed_mm_s=100", "-o",
                          str(tmp_path / "out"), "--scheduler", address], tmp_path / "stdout.txt")
        assert run.returncode == 0, run.stderr
        assert "on 1 Dask worker thread(s)" in (tmp_path / "stdout.txt").read_text()
        _assert_equals_single_runs(tmp_path / "out", single_runs, members=[0])
    finally:
        for process in reversed(started):
            process.terminate()
            try:
                process.wait(timeout=30)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()


def test_bad_input_names_the_fix_and_writes_nothing(tmp_path, capsys):
    scene = _scene(tmp_path)
    out = tmp_path / "out"
    assert main(["sweep", str(scene), "--vary", "catheter.angel_deg=0:10:5", "-o", str(out), "-q"]) == 2
    assert "catheter.angel_deg" in capsys.readouterr().err
    assert main(["sweep", str(scene), "--vary", "simulation.push_speed_mm_s=100,150", "-o", str(out), "-q", "--jobs", "2"]) == 2
    assert "--workers 2" in capsys.readouterr().err
    with dask.config.set({"distributed.comm.timeouts.connect": "1s"}):
        assert main(["sweep", str(scene), "--vary", "simulation.push_speed_mm_s=100", "-o", str(out), "-q",
                     "--scheduler", "tcp://127.0.0.1:9"]) == 2
    assert "cannot connect" in capsys.readouterr().err
    assert not (out / "summary.md").exists() and not (out / "member_000").exists()


def test_progress_on_a_terminal_is_one_bar_with_a_line_per_member():
    class Terminal(io.StringIO):
        def isatty(self):
            return True

    stream = Terminal()
    progress = SweepProgress(stream=stream)
    progress.start(3)
    for k, status in enumerate(("completed", "jammed", "completed")):
        progress(Member(k, {"catheter.angle_deg": 10.0 * k},
                        {"status": status, "packing_density": 0.2, "steps": 100, "wall_time_s": 1.0}))
    progress.close()
    text = stream.getvalue()
    assert "member_001 catheter.angle_deg=10: jammed, packing 20.0 %, 100 steps" in text
    assert "3/3" in text and "2 completed, 1 jammed" in text
    quiet = Terminal()
    progress = SweepProgress(quiet=True, stream=quiet)
    progress.start(1)
    progress(Member(0, {}, {"status": "completed"}))
    progress.close()
    assert quiet.getvalue() == ""


def test_gpu_workers_of_a_local_cluster_each_take_their_gpu():
    assert [worker_device(None, k, 2) for k in range(3)] == ["cuda:0", "cuda:1", "cuda:0"]
    assert worker_device("cuda", 1, 4) == "cuda:1"
    assert worker_device("cuda:3", 1, 4) == "cuda:3" and worker_device("cpu", 1, 4) == "cpu"
    assert worker_device(None, "SLURMCluster-0-1", 4) is None and worker_device(None, 0, 0) is None


@pytest.mark.parametrize("device", ["balloon", "stent"])
def test_a_swept_members_usd_holds_its_device(tmp_path, device):
    """A member's deployment.usdc shows its balloon (inflation sampled per frame,
    deflated at the end) or its stent, as a single run's does."""
    table = ('[balloon]\naxis = [[-1.2, 0.8, -0.3], [1.2, 0.8, -0.3]]\ndiameter_mm = 0.8\ndeflation_time_s = 0.01\n'
             if device == "balloon" else
             '[stent]\naxis = [[-0.02, 0.013, -1.5], [0.02, 0.013, 1.5]]\ndiameter_mm = 4.5\ncell_size_mm = 1.5\n')
    path = tmp_path / "s.toml"
    path.write_text('[wall]\nsphere_diameter_mm = 4.0\n[catheter]\ntip = [0.0, 0.0, -1.5]\n[[coil]]\n'
                    'wire_diameter_mm = 0.2921\nloop_diameter_mm = 2.0\nlength_mm = 2.0\n[simulation]\n'
                    'push_speed_mm_s = 100.0\nframe_interval_s = 0.005\nintegrator = "implicit"\n' + table)
    (output,) = run_task(make_task([0], [load_scene(path)], usd=True, device=None))
    usd = tmp_path / "deployment.usdc"
    usd.write_bytes(output.files["deployment.usdc"])
    assert validate_usd(usd) == []
    stage = Usd.Stage.Open(str(usd))
    prim = stage.GetPrimAtPath("/World/Balloon" if device == "balloon" else "/World/Stent")
    assert prim.IsValid()
    if device == "balloon":
        widths = UsdGeom.BasisCurves(prim).GetWidthsAttr()
        samples = widths.GetTimeSamples()
        assert len(samples) > 2
        assert max(widths.Get(samples[0])) == pytest.approx(0.8, rel=0.05)  # inflated (capped by the wall)
        assert max(widths.Get(samples[-1])) < 0.01  # deflated (drawn 1 µm wide)
    else:
        struts = output.result["device"]["struts"]
        assert len(UsdGeom.BasisCurves(prim).GetCurveVertexCountsAttr().Get()) == struts
