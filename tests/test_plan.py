"""`warpcoil plan`: the ranking rule (criterion order, ties within the spread, a missing
occlusion grade), the catheter-tip perturbations (tilt angle and even spacing), and the
CLI as a user runs it on a small sphere scene (2 options × 2 perturbations): outputs,
the ranking against the rows of plan.csv, and a bad [plan] key."""

import csv
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from warpcoil.plan import PlanError, perturbed_keys, read_plan, tilted
from warpcoil.plan_rank import CRITERIA, Stats, rank, raymond_roy_number
from warpcoil.settings import CatheterSpec
from warpcoil.sweep import SweepError

ROOT = Path(__file__).resolve().parents[1]
SCENE = """
[wall]
sphere_diameter_mm = 3.5

[neck]
plane_point_mm = [0.0, 0.0, -1.2]
plane_normal = [0.0, 0.0, 1.0]

[catheter]
placement = "neck"
depth_mm = 0.3

[[coil]]
shape = "helix"
length_mm = 8.0
loop_diameter_mm = 2.5
pitch_mm = 0.6
wire_diameter_mm = 0.2921

[simulation]
push_speed_mm_s = 100.0
frame_interval_s = 0.005

[output]
usd = false

[plan]
perturbations = 2
perturbation_deg = 2.0

[[plan.option]]
name = "tip deep in the sac"
catheter.depth_mm = 1.0

[[plan.option]]
name = "tip below the neck, tilted"
catheter.depth_mm = -0.3
catheter.angle_deg = 20.0
"""


def _options(**criteria) -> list[dict]:
    """Options from {criterion key: [values of option 0, values of option 1, ...]}."""
    count = len(next(iter(criteria.values())))
    return [{c.key: Stats(tuple(criteria[c.key][k]) if c.key in criteria else ()) for c in CRITERIA}
            for k in range(count)]


def test_herniation_decides_first_whatever_the_other_criteria():
    options = _options(herniated_length_mm=[[5.0, 6.0, 7.0], [0.0, 0.1, 0.0]],
                       packing_density_percent=[[30.0, 31.0, 30.0], [10.0, 11.0, 10.0]])
    ranked = rank(options)
    assert [r.index for r in ranked] == [1, 0]
    assert ranked[1].beaten_by == (1, "herniated length")


def test_means_within_the_spread_tie_and_the_next_criterion_decides():
    # herniated means 2.0 and 3.0 differ by less than the larger standard deviation (2.0): a tie
    options = _options(herniated_length_mm=[[0.0, 2.0, 4.0], [2.0, 3.0, 4.0]],
                       neck_coverage_percent=[[10.0, 11.0, 12.0], [30.0, 31.0, 32.0]])
    ranked = rank(options)
    assert [r.index for r in ranked] == [1, 0]
    assert ranked[1].beaten_by == (1, "neck coverage")
    # beyond the spread the herniation decides again
    options = _options(herniated_length_mm=[[0.0, 0.1, 0.2], [2.0, 3.0, 4.0]],
                       neck_coverage_percent=[[10.0, 11.0, 12.0], [30.0, 31.0, 32.0]])
    assert [r.index for r in rank(options)] == [0, 1]


def test_options_tied_on_every_criterion_share_a_rank():
    options = _options(herniated_length_mm=[[1.0, 2.0], [1.5, 1.6], [9.0, 9.5]],
                       packing_density_percent=[[20.0, 20.4], [20.2, 20.1], [20.0, 20.0]])
    ranked = rank(options)
    assert [(r.index, r.rank) for r in ranked] == [(0, 1), (1, 1), (2, 3)]  # inside a rank: by the means
    assert ranked[0].tied_with == (1,) and ranked[1].tied_with == (0,) and ranked[2].tied_with == ()


def test_push_forces_below_the_push_readings_accuracy_tie():
    """Two options equal but for push forces of ~29 against ~0 µN (0.029 mN) ranked 1 and 2 on that
    alone: forces closer than the implicit step's push-force accuracy (PUSH_FORCE_RESOLUTION_MN) tie;
    a difference of 1 mN still decides."""
    options = _options(peak_push_force_mN=[[0.029, 0.030], [0.0, 0.001]])
    assert [r.rank for r in rank(options)] == [1, 1]
    options = _options(peak_push_force_mN=[[2.0, 2.05], [1.0, 1.02]])
    ranked = rank(options)
    assert [(r.index, r.rank) for r in ranked] == [(1, 1), (0, 2)]
    assert ranked[1].beaten_by == (1, "peak push force (largest frame mean)")


def test_occlusion_grade_ranks_before_neck_coverage_and_is_skipped_when_absent():
    grades = {"modified_raymond_roy_class": [[raymond_roy_number("III")] * 2, [raymond_roy_number("I")] * 2]}
    coverage = {"neck_coverage_percent": [[50.0, 50.0], [10.0, 10.0]]}
    assert [r.index for r in rank(_options(**grades, **coverage))] == [1, 0]
    assert [r.index for r in rank(_options(**coverage))] == [0, 1]  # no grade: coverage decides
    assert [raymond_roy_number(v) for v in ("I", "II", "IIIa", "IIIb", 2)] == [1.0, 2.0, 3.0, 4.0, 2.0]
    with pytest.raises(ValueError):
        raymond_roy_number("IV")


def test_an_option_without_a_usable_run_is_unranked_and_last():
    options = _options(herniated_length_mm=[[], [3.0, 3.0]])
    ranked = rank(options, usable=[False, True])
    assert [(r.index, r.rank) for r in ranked] == [(1, 1), (0, 0)]


@pytest.mark.parametrize("angle_deg, azimuth_deg", [(0.0, 0.0), (25.0, 70.0)])
def test_neck_perturbations_tilt_the_axis_by_the_angle_evenly_around_it(angle_deg, azimuth_deg):
    def axis(a_deg, phi_deg):  # catheter_from_neck's direction in the neck frame (e1, e2, n)
        a, phi = math.radians(a_deg), math.radians(phi_deg)
        return np.array([math.sin(a) * math.cos(phi), math.sin(a) * math.sin(phi), math.cos(a)])

    nominal = axis(angle_deg, azimuth_deg)
    keys = perturbed_keys(CatheterSpec(placement="neck", angle_deg=angle_deg, azimuth_deg=azimuth_deg), 3, 1.5)
    directions = np.array([axis(k["catheter.angle_deg"], k["catheter.azimuth_deg"]) for k in keys])
    tilts = np.degrees(np.arccos(np.clip(directions @ nominal, -1, 1)))
    np.testing.assert_allclose(tilts, 1.5, atol=1e-6)
    # evenly spaced around the nominal axis: their mean lies on it
    mean = directions.mean(axis=0)
    np.testing.assert_allclose(mean / np.linalg.norm(mean), nominal, atol=1e-9)


def test_explicit_perturbations_tilt_the_direction():
    keys = perturbed_keys(CatheterSpec(direction=(0.0, 0.6, 0.8)), 4, 3.0)
    directions = np.array([k["catheter.direction"] for k in keys])
    np.testing.assert_allclose(directions @ [0.0, 0.6, 0.8], math.cos(math.radians(3.0)), atol=1e-9)
    np.testing.assert_allclose(directions[0] + directions[2], 2 * math.cos(math.radians(3.0)) *
                               np.array([0.0, 0.6, 0.8]), atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(tilted([1.0, 0.0, 0.0], 7.0, 40.0)), 1.0)


def _env() -> dict:
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}


def _plan(tmp_path: Path, text: str, out: Path, *extra: str) -> tuple[int, str, str]:
    scene = tmp_path / "plan.toml"
    scene.write_text(text)
    log, err = tmp_path / "stdout.txt", tmp_path / "stderr.txt"
    with log.open("w") as stdout, err.open("w") as stderr:
        code = subprocess.run([sys.executable, "-m", "warpcoil.cli", "plan", str(scene), "-o", str(out),
                               "--workers", "1", *extra], stdout=stdout, stderr=stderr, env=_env(),
                              timeout=600).returncode
    return code, log.read_text(), err.read_text()


def _beats(a: dict, b: dict) -> bool:
    """The stated rule, from plan.csv's columns: at the first criterion on which a and b do
    not tie (|Δmean| > max(sd_a, sd_b, resolution)), a's mean is better."""
    for c in CRITERIA:
        if not a[f"{c.key}_mean"] or not b[f"{c.key}_mean"]:
            continue
        ma, mb = float(a[f"{c.key}_mean"]), float(b[f"{c.key}_mean"])
        bound = max(float(a[f"{c.key}_sd"]), float(b[f"{c.key}_sd"]), c.resolution + c.relative * max(abs(ma), abs(mb)))
        if abs(ma - mb) > bound:
            return (ma < mb) == c.lower_is_better
    return False


def test_plan_cli_ranks_the_options_as_plan_csv_says(tmp_path):
    out = tmp_path / "out"
    code, stdout, stderr = _plan(tmp_path, SCENE, out)
    assert code == 0, stderr
    for name in ("plan.md", "plan.csv", "plan.png", "summary.csv"):
        assert (out / name).stat().st_size > 0, name
    assert sorted(p.name for p in out.glob("member_*")) == [f"member_{k:03d}" for k in range(4)]
    assert (out / "plan.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    rows = list(csv.DictReader((out / "plan.csv").open()))
    assert sorted(r["option"] for r in rows) == ["tip below the neck, tilted", "tip deep in the sac"]
    for row in rows:  # mean and sd are those of the runs' values
        values = [float(v) for v in row["herniated_length_mm_values"].split(";")]
        assert len(values) == 2 and row["runs"] == "2"
        assert float(row["herniated_length_mm_mean"]) == pytest.approx(np.mean(values), rel=1e-5, abs=1e-9)
        assert float(row["herniated_length_mm_sd"]) == pytest.approx(np.std(values, ddof=1), rel=1e-5, abs=1e-9)
    ranks = [int(r["rank"].lstrip("=")) for r in rows]
    assert ranks == sorted(ranks) and ranks[0] == 1
    for i, a in enumerate(rows):
        for b in rows[i + 1:]:
            assert not _beats(b, a), (a["option"], b["option"])  # nothing ranked below beats one above
            if int(b["rank"].lstrip("=")) > int(a["rank"].lstrip("=")):
                assert _beats(a, b) and b["beaten_by"] == a["option"]
            else:
                assert a["rank"] == b["rank"] == "=1" and not _beats(a, b)
    text = (out / "plan.md").read_text()
    assert text in stdout and "Tie rule" in text and "herniated length" in text
    assert "lower is better; resolution 0.25 mN + 10 % of the larger mean" in text  # the rule plan_rank applies
    # the occlusion grade is each run's result.json modified class (IIIb after IIIa), in plan order (said to be missing if no run has it)
    results = [json.loads((out / f"member_{k:03d}" / "result.json").read_text()) for k in range(4)]
    classes = [raymond_roy_number((r.get("occlusion") or {}).get("modified_raymond_roy_class")) for r in results]
    by_option = {row["option"]: row["modified_raymond_roy_class_values"] for row in rows}
    for k, name in enumerate(["tip deep in the sac", "tip below the neck, tilted"]):
        assert by_option[name] == ";".join("" if c is None else f"{c:g}" for c in classes[2 * k: 2 * k + 2])
    assert ("Occlusion grade not available" in text) == all(c is None for c in classes)
    for row in rows:
        assert f"| {row['rank']} | {row['option']} |" in text
    # each run's catheter axis, as its result reports it, is 2° off its option's nominal axis (the neck
    # normal +z; tilted 20° towards the neck frame's first axis, +x, for the second option)
    tilted_axis = [math.sin(math.radians(20.0)), 0.0, math.cos(math.radians(20.0))]
    for k, nominal in enumerate([[0.0, 0.0, 1.0]] * 2 + [tilted_axis] * 2):
        direction = json.loads((out / f"member_{k:03d}" / "result.json").read_text())["catheter_direction"]
        assert math.degrees(math.acos(min(1.0, np.dot(direction, nominal)))) == pytest.approx(2.0, abs=1e-4)


def test_a_bad_plan_key_names_file_key_and_fix(tmp_path):
    out = tmp_path / "out"
    code, _, stderr = _plan(tmp_path, SCENE.replace("perturbations = 2", "perturbation = 2"), out)
    assert code == 2
    assert stderr.count("\n") == 1 and "plan.toml: plan.perturbation: unknown key" in stderr and "fix:" in stderr
    assert not out.exists()
    code, _, stderr = _plan(tmp_path, SCENE, out, "--retries", "-1")  # as a sweep takes it
    assert code == 2 and stderr == "warpcoil plan: --retries -1: give 0 or more\n" and not out.exists()


def test_plan_errors_name_the_option_and_key(tmp_path):
    scene = tmp_path / "plan.toml"
    scene.write_text(SCENE.replace("catheter.angle_deg = 20.0", "catheter.angle_dg = 20.0"))
    with pytest.raises(PlanError, match=r"plan\.option\[1\].*catheter\.angle_dg.*fix"):
        read_plan(scene)
    scene.write_text(SCENE + '\n[[plan.option]]\nname = "balloon"\ndevice = "balloon"\n')
    with pytest.raises(PlanError, match=r"plan\.balloon: plan\.option\[2\] uses a balloon.*fix: add \[plan\.balloon\]"):
        read_plan(scene)
    scene.write_text(SCENE.replace("perturbations = 2", "perturbations = 1"))
    with pytest.raises(PlanError, match=r"plan\.perturbations: must be a whole number ≥ 2"):
        read_plan(scene)
    # a plan setting as an option key (or a --vary key) would change nothing: refused, naming it
    scene.write_text(SCENE.replace('catheter.depth_mm = 1.0', 'catheter.depth_mm = 1.0\nplan.perturbations = 4'))
    with pytest.raises(PlanError, match=r"plan\.option\[0\].*plan\.perturbations: is a setting of the plan"):
        read_plan(scene)
    scene.write_text(SCENE.replace("catheter.depth_mm = -0.3\ncatheter.angle_deg = 20.0", "catheter.depth_mm = 1"))
    with pytest.raises(PlanError, match=r"plan\.option\[1\]: \(tip below the neck, tilted\) is the treatment of "
                                        r"plan\.option\[0\] \(tip deep in the sac\).*fix"):
        read_plan(scene)  # (1 and 1.0: one value)
    # coil.KEY and coil.0.KEY set one coil's same key (one overriding the other, unseen): refused
    scene.write_text(SCENE.replace("catheter.depth_mm = 1.0", "catheter.depth_mm = 1.0\ncoil.length_mm = 6.0\n"
                                   "coil.0.length_mm = 7.0"))
    with pytest.raises(PlanError, match=r"plan\.option\[0\]: sets coil\.length_mm and coil\.0\.length_mm: the same key "
                                        r"of one coil.*fix: keep one of them"):
        read_plan(scene)
    scene.write_text(SCENE.split("[[plan.option]]")[0])  # (--vary gives the options)
    with pytest.raises(SweepError, match=r"--vary coil\.0\.length_mm and --vary coil\.length_mm: both set the same "
                                         r"key of one coil.*fix: vary one of them"):
        read_plan(scene, [("coil.0.length_mm", [6.0, 8.0]), ("coil.length_mm", [7.0, 9.0])])
    scene.write_text(SCENE.split("[[plan.option]]")[0])  # (--vary gives the options)
    with pytest.raises(PlanError, match=r"plan\.perturbations: is a setting of the plan"):
        read_plan(scene, [("plan.perturbations", [2, 3])])


def test_an_options_tip_outside_the_lumen_names_the_option_and_a_depth_that_fits(tmp_path):
    """A depth past the far wall: refused before any run (exit 2, one line, no folder), naming the option
    and its perturbation (not a member folder that never exists) and, as the fix, a smaller depth (the
    hint suggested 0.5 whatever the depth that failed)."""
    out = tmp_path / "out"
    code, _, stderr = _plan(tmp_path, SCENE.replace("catheter.depth_mm = 1.0", "catheter.depth_mm = 4.0"), out)
    lines = [line for line in stderr.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1, stderr
    assert lines[0].startswith('warpcoil plan: option "tip deep in the sac (tip 1)": ')
    assert "catheter.depth_mm = 4 puts the tip at" in lines[0] and "less than 4 mm" in lines[0]
    assert not out.exists()


def test_a_scene_device_is_reported_as_every_options_device(tmp_path):
    """A [balloon] in the scene (no option naming a device) is every option's: plan.md and plan.csv say so."""
    scene = tmp_path / "plan.toml"
    balloon = "[balloon]\naxis = [[0.0, -1.0, -1.5], [0.0, 1.0, -1.5]]\ndiameter_mm = 1.0\n\n[plan]"
    scene.write_text(SCENE.replace("[plan]", balloon, 1))
    assert {o.device for o in read_plan(scene).options} == {"balloon (the scene's)"}


def test_the_shipped_c0001_plan_compares_six_options_with_a_balloon():
    plan = read_plan(ROOT / "scenes" / "plan_C0001.toml")
    assert len(plan.options) >= 6 and plan.perturbations >= 3
    assert {"none", "balloon"} <= {o.device for o in plan.options}
    balloon = next(o for o in plan.options if o.device == "balloon")
    assert balloon.keys["balloon.diameter_mm"] == 4.0 and len(balloon.keys["balloon.axis"]) == 7


def test_vary_gives_the_product_of_options_devices_included(tmp_path):
    scene = tmp_path / "plan.toml"
    balloon = "\n[plan.balloon]\naxis = [[0.0, -1.0, -1.5], [0.0, 1.0, -1.5]]\ndiameter_mm = 1.0\n"
    scene.write_text(SCENE + balloon)
    with pytest.raises(PlanError, match=r"plan.option: given beside --vary, which would replace these options"):
        read_plan(scene, [("catheter.depth_mm", [0.5, 1.0])])  # the scene's options were dropped unseen
    scene.write_text(SCENE.split("[[plan.option]]")[0] + balloon)
    with pytest.raises(SweepError, match=r"--vary device: the value 'none' is given twice"):
        read_plan(scene, [("device", ["none", "balloon", "none"])])
    plan = read_plan(scene, [("catheter.depth_mm", [0.5, 1.0]), ("device", ["none", "balloon"])])
    assert [o.name for o in plan.options] == ["catheter.depth_mm=0.5, device=none", "catheter.depth_mm=0.5, "
                                              "device=balloon", "catheter.depth_mm=1, device=none",
                                              "catheter.depth_mm=1, device=balloon"]
    assert plan.options[1].keys == {"catheter.depth_mm": 0.5, "balloon.axis": [[0.0, -1.0, -1.5], [0.0, 1.0, -1.5]],
                                    "balloon.diameter_mm": 1.0}
    assert "balloon.axis" not in plan.options[2].keys and plan.perturbations == 2


def test_a_plan_beyond_a_sweeps_members_is_refused_before_any_scene_is_read(tmp_path):
    from warpcoil.plan import Option, Plan, PlanError, plan_members
    from warpcoil.sweep import MAX_MEMBERS

    options = tuple(Option(f"o{k}", "none", {}) for k in range(MAX_MEMBERS // 3 + 1))
    with pytest.raises(PlanError, match=r"6,667 options × 3 catheter perturbations are more than a sweep's 20,000"):
        plan_members(tmp_path / "never_read.toml", Plan(options, perturbations=3))


def test_an_option_that_did_not_deploy_its_coil_ranks_below_one_that_did():
    """A jammed option (its coil withdrawn at 10 of 15 mm, so nothing herniated) must not rank first
    on herniation: the deployed share comes first."""
    options = _options(deployed_percent=[[66.7, 66.7], [100.0, 100.0]],
                       herniated_length_mm=[[0.0, 0.0], [1.5, 2.2]])
    ranked = rank(options)
    assert [r.index for r in ranked] == [1, 0]
    assert ranked[1].beaten_by == (1, "coil deployed")
