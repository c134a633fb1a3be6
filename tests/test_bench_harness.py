"""The benchmarks that time a run from inside (``benchmarks.outside_steps``,
``benchmarks.implicit_cost.timed_run``) wrap ``Stepper.run_chunk``: the wrapped run is the
plain run (the same status and steps; a wrapper out of step with run_chunk's signature raised
TypeError at the first chunk) and its parts add up to its whole. ``benchmarks.tight_sac``'s
reference run rests in the coil's pre-shape."""

from dataclasses import replace

import pytest

from benchmarks import confined_shape, implicit_cost, outside_steps, tight_sac
from warpcoil.deploy import Deployment
from warpcoil.scene import load_scene

from test_cli_run import SCENE


@pytest.fixture(scope="module")
def scene_path(tmp_path_factory):
    path = tmp_path_factory.mktemp("bench") / "short.toml"
    path.write_text(SCENE)
    return path


def plain(scene_path):
    scene = load_scene(scene_path)
    return Deployment(replace(scene, output=replace(scene.output, usd=False, png=False, tube_mesh=False)))


def test_outside_steps_times_the_plain_run(scene_path):
    reference = plain(scene_path).run()
    timed = outside_steps.main(str(scene_path))
    assert timed["steps"] == reference.steps > 0
    assert 0.0 < timed["steps_s"] < timed["wall_s"]
    assert timed["outside_s"] == pytest.approx(timed["wall_s"] - timed["steps_s"], abs=2e-3)


def test_implicit_cost_timed_run_times_the_plain_run(scene_path):
    reference = plain(scene_path).run()
    timed = implicit_cost.timed_run(plain(scene_path))
    assert timed["status"] == reference.status == "completed"
    assert timed["steps"] == reference.steps
    assert 0.0 < timed["steps_s"] <= timed["cpu_s"]
    assert timed["frames_s"] == pytest.approx(timed["cpu_s"] - timed["steps_s"])


def test_tight_sac_reference_rests_in_the_preshape():
    """``benchmarks.tight_sac``'s premise: the coil's pre-shape fits the 3.2 mm sphere without
    touching itself (0 nJ), and the reference (symplectic) step brings a perturbed deployment
    to rest in it: no bend or twist left (< 0.1 nJ), no coil contact."""
    found = tight_sac.main(scheme="reference", runs=1)
    run = found["runs"][0]
    assert run["status"] == "completed"
    assert found["in_preshape"] == 1 and run["rest_bend_twist_nJ"] < 0.1
    assert run["coil_contacts"] == 0


def test_confined_shape_converges_to_the_references_rest_with_the_step():
    """``benchmarks.confined_shape``'s premise: the 18-system coil's pre-shape fits the 4 mm sphere, the
    reference brings it to rest there (< 0.1 nJ of bend and twist), and so does the implicit step at a
    quarter of its push step: the resting shape is a matter of the step (the default's is not asserted:
    it is the defect the benchmark measures)."""
    rows = confined_shape.main(reference=True, cases=("sphere18",))
    assert [row["status"] for row in rows] == ["completed"] * 4
    assert rows[-1]["rest_bend_twist_nJ"] < 0.1 and rows[-2]["rest_bend_twist_nJ"] < 0.1
    assert rows[1]["dt_s"] == pytest.approx(0.5 * rows[0]["dt_s"]) and rows[2]["dt_s"] == pytest.approx(
        0.25 * rows[0]["dt_s"])
