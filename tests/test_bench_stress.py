"""The stress benchmark's classification: refused, completed and forced-unstable tiny runs,
and the verdict rules on records with tripped checks."""

import pytest

from warpcoil.bench.stress import REFUSED, Case, Record, classify, run_case, scene, step_bound
from warpcoil.deploy import COMPLETED, FAILED, build_model

LENGTH_MM = 3.0


@pytest.fixture(scope="module")
def bound_s() -> float:
    return step_bound(build_model(scene(LENGTH_MM)))


def tiny(name: str, **simulation) -> Case:
    return Case("test", name, scene(LENGTH_MM, **simulation), {})


def test_a_dt_past_the_bound_is_refused_and_explained(bound_s):
    record = run_case(tiny("refused", dt_s=2.0 * bound_s))
    assert (record.status, record.refused_for, record.verdict) == (REFUSED, "dt", "explained")
    assert record.dt_ratio == pytest.approx(2.0)
    assert "exceeds the stable bound" in record.reason and record.steps == 0


def test_a_tiny_coil_within_the_bound_completes_clean():
    record = run_case(tiny("completed"))
    assert (record.status, record.verdict, record.problems) == (COMPLETED, "ok", [])
    assert record.dt_ratio == pytest.approx(0.9)  # the default dt_safety
    assert record.frames > 2 and record.nan_frames == record.tunnel_frames == record.crossing_frames == 0
    assert 0.0 < record.min_wall_centre_mm < 1.75 and record.max_energy_ratio < 1.0


def test_a_forced_unstable_step_fails_naming_dt(bound_s):
    record = run_case(tiny("forced", dt_s=3.0 * bound_s, allow_unstable_dt=True))
    assert (record.status, record.verdict) == (FAILED, "explained")
    assert record.dt_ratio == pytest.approx(3.0) and "dt = " in record.reason and not record.crashed


@pytest.mark.parametrize("fields, verdict", [
    (dict(status=COMPLETED, dt_ratio=0.5), "ok"),
    (dict(status=COMPLETED, dt_ratio=0.5, tunnel_frames=1, min_wall_centre_mm=-0.01), "unexplained"),
    (dict(status="jammed", dt_ratio=0.9, crossing_frames=2, min_coil_gap_mm=-0.4), "unexplained"),
    (dict(status="timeout", dt_ratio=0.5, nan_frames=1), "unexplained"),
    (dict(status=FAILED, dt_ratio=0.9, reason="dt = 1e-6 s ..."), "unexplained"),
    (dict(status=FAILED, dt_ratio=1.5, reason="runaway"), "unexplained"),
    (dict(status=FAILED, dt_ratio=1.5, reason="dt = 2e-5 s ..."), "explained"),
    (dict(status=COMPLETED, dt_ratio=1.5), "explained"),
    (dict(status=COMPLETED, dt_ratio=1.5, blowup_frames=3, max_energy_ratio=50.0), "unexplained"),
    (dict(status=REFUSED, refused_for="dt", dt_ratio=0.8), "unexplained"),
    (dict(status=REFUSED, refused_for="input"), "explained"),
    (dict(status=FAILED, dt_ratio=0.5, crashed=True, reason="crashed: KeyError"), "unexplained"),
])
def test_verdict_rules(fields, verdict):
    record = classify(Record("test", "rule", {}, **{"reason": "", **fields}))
    assert record.verdict == verdict, record.problems
    assert bool(record.problems) == (verdict == "unexplained")
