"""In-silico Raymond–Roy class (warpcoil.occlusion) and the regional densities it reads,
on a cut sphere with analytic regions (warpcoil.validation_regions)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from warpcoil.occlusion import SCENE_THRESHOLD_SOURCE, THRESHOLD, occlusion_grade, occlusion_of_regions
from warpcoil.sac import regional_density
from warpcoil.validation_regions import SphereSac, region_cases, sphere_sac

T = THRESHOLD
EPS = 1e-9


@pytest.fixture(scope="module")
def geometry() -> SphereSac:
    return sphere_sac()


def assert_rows_pass(rows) -> None:
    failed = [f"{r.case}: {r.result:.4g} vs {r.reference:.4g}" for r in rows if not r.passed]
    assert not failed, failed


def test_analytic_region_volumes_match_a_point_count(geometry: SphereSac) -> None:
    """The references themselves: region_of on a uniform point grid gives the volumes."""
    step = 0.05
    axis = np.arange(-3.0 + step / 2, 3.0, step)
    grid = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), axis=-1).reshape(-1, 3)
    region = geometry.region_of(grid)
    counted = {name: float((region == k).sum()) * step**3 for k, name in enumerate(("neck", "boundary", "core"))}
    volumes = geometry.volumes_mm3()
    for name, volume in volumes.items():
        assert counted[name] == pytest.approx(volume, rel=0.01), name
    assert sum(volumes.values()) == pytest.approx(math.pi * 5.0**2 * (9.0 - 5.0) / 3.0)  # cap of height 5


def test_helix_in_each_region_gives_its_analytic_density_at_first_order() -> None:
    rows = region_cases((2, 4))
    assert_rows_pass(rows)
    assert rows[-1].result == pytest.approx(1.0, abs=0.5)


# --- class boundaries on given densities ----------------------------------------------
@pytest.mark.parametrize("densities, klass, modified", [
    ((T, T, T), 1, "I"),
    ((T - EPS, T, T), 2, "II"),
    ((0.0, 0.9, 0.9), 2, "II"),
    ((T, T, T - EPS), 3, "IIIa"),
    ((T, T - EPS, T), 3, "IIIb"),
    ((T, T - EPS, T - EPS), 3, "IIIb"),  # contrast along the wall is the worse residual
    ((T - EPS, T, T - EPS), 3, "IIIa"),  # a residual sac outranks a residual neck
    ((T, T, math.nan), 1, "I"),  # a sac too small for a core: the core is not judged
    ((T - EPS, T, math.nan), 2, "II"),
])
def test_class_changes_exactly_at_the_threshold(densities, klass, modified) -> None:
    grade = occlusion_grade(*densities)
    assert (grade["raymond_roy_class"], grade["modified_raymond_roy_class"]) == (klass, modified)
    assert grade["threshold"] == T and "Mascitelli" in grade["source"] and "Holzberger" in grade["source"]
    assert [grade[k] for k in ("neck_density", "boundary_density", "core_density")] == [
        None if math.isnan(d) else d for d in densities]


def test_no_region_no_grade_and_a_scene_threshold() -> None:
    assert occlusion_grade(math.nan, math.nan, math.nan) is None
    assert occlusion_of_regions(None) is None
    regions = {"neck": 0.2, "boundary": 0.3, "core": 0.3}
    assert occlusion_of_regions(regions)["raymond_roy_class"] == 3
    scene = occlusion_of_regions(regions, 0.2)
    assert scene["raymond_roy_class"] == 1 and scene["source"].startswith(SCENE_THRESHOLD_SOURCE)
    with pytest.raises(ValueError, match="threshold"):
        occlusion_grade(0.5, 0.5, 0.5, threshold=1.5)


# --- class boundaries on coils laid by hand ---------------------------------------------
def vertical_lattice(geometry: SphereSac, fractions: dict[str, float]) -> list[np.ndarray]:
    """Straight vertical wires on a square lattice per region, spaced so that their
    volume fraction in the region is ``fractions[region]``: π(d/2)²/s² = f. Each wire
    is cut to the runs of its line that lie in its region (analytic regions), less
    2/3 of a wire radius where a run meets another region: the round end (volume
    (2/3)π(d/2)³) then makes up the cut, so each region holds its fraction."""
    d = geometry.wire_d_mm
    names = ("neck", "boundary", "core")
    z = np.arange(geometry.neck_z_mm, geometry.radius_mm, 0.01)
    wires = []
    for index, name in enumerate(names):
        spacing = 0.5 * d * math.sqrt(math.pi / fractions[name])
        offset = 0.137 * (index + 1)  # the lattices of different regions do not line up
        ticks = np.arange(-geometry.radius_mm + offset, geometry.radius_mm, spacing)
        for x in ticks:
            for y in ticks:
                region = geometry.region_of(np.column_stack((np.full_like(z, x), np.full_like(z, y), z)))
                edges = np.flatnonzero(np.diff(np.r_[0, (region == index).astype(int), 0]))
                for start, stop in zip(edges[::2], edges[1::2]):
                    low = z[start] + (d / 3.0 if start > 0 and region[start - 1] >= 0 else 0.0)
                    high = z[stop - 1] - (d / 3.0 if stop < len(z) and region[stop] >= 0 else 0.0)
                    if high > low:
                        wires.append(np.array([[x, y, low], [x, y, high]]))
    return wires


@pytest.mark.parametrize("fractions, klass, modified", [
    ({"neck": 1.2 * T, "boundary": 1.2 * T, "core": 1.2 * T}, 1, "I"),
    ({"neck": 0.8 * T, "boundary": 1.2 * T, "core": 1.2 * T}, 2, "II"),
    ({"neck": 1.2 * T, "boundary": 1.2 * T, "core": 0.8 * T}, 3, "IIIa"),
    ({"neck": 1.2 * T, "boundary": 0.8 * T, "core": 1.2 * T}, 3, "IIIb"),
])
def test_wire_lattices_just_above_or_below_the_threshold_get_their_class(
        geometry: SphereSac, fractions, klass, modified) -> None:
    """±20 % about the threshold: clear of the ≤ 8 % voxel error of the densities."""
    wires = vertical_lattice(geometry, fractions)
    density = regional_density(geometry.sac, wires, [geometry.wire_d_mm] * len(wires))
    for name, fraction in fractions.items():
        assert getattr(density, name) == pytest.approx(fraction, rel=0.1), name
    grade = occlusion_grade(density.neck, density.boundary, density.core)
    assert (grade["raymond_roy_class"], grade["modified_raymond_roy_class"]) == (klass, modified)


# --- as a user meets it -------------------------------------------------------------------
def test_run_writes_the_grade_to_result_json_and_rejects_a_threshold_in_percent(tmp_path) -> None:
    """``warpcoil run`` of a tiny sphere sac with a [neck]: result.json's ``occlusion``
    is the grade of its own regional densities; a threshold of 31 (meant as %) exits 2."""
    from test_cli_user import SPHERE, cli, scene

    text = SPHERE.replace("usd = false", "usd = false\npng = true") + (
        "\n[neck]\nplane_point_mm = [0.0, 0.0, -1.5]\nplane_normal = [0.0, 0.0, 1.0]\n")
    code, out, err = cli(tmp_path, "run", str(scene(tmp_path, text)), "-o", "run")
    assert code == 0, err
    result = json.loads((tmp_path / "run" / "result.json").read_text())
    regions, grade = result["regions"], result["occlusion"]
    assert grade == occlusion_grade(regions["neck"], regions["boundary"], regions["core"])
    assert grade["raymond_roy_class"] in (1, 2, 3) and (tmp_path / "run" / "summary.png").is_file()

    bad = scene(tmp_path, text + "\n[regions]\nocclusion_threshold = 31\n", name="bad.toml")
    code, out, err = cli(tmp_path, "run", str(bad), "-o", "bad")
    assert code == 2 and "bad.toml" in err and "regions.occlusion_threshold" in err and "fix:" in err
    assert not (tmp_path / "bad").exists()
