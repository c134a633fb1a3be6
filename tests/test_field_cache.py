"""The on-disk wall field cache (warpcoil/field_cache.py): a loaded field is the
built one bit for bit, every input changes the key, a bad file is rebuilt, and
a second run of a scene loads its field and repeats the first run exactly."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh
import warp as wp

from warpcoil import _warp  # noqa: F401  (Warp initialised, kernel cache chosen)
from warpcoil.field_cache import (FIELD_CACHE_ENV, TEMPORARY_PREFIX, cached_wall_field, field_cache_dir, field_key,
                                  load_volume)
from warpcoil.kernels import wall_field as field_kernels
from warpcoil.model import WallModel
from warpcoil.wall_field import DEFAULT_CREASE_MM, GRAD_TOLERANCE, band_points

ROOT = Path(__file__).resolve().parents[1]
BAND_MM, VOXEL_MM = 0.2, 0.08  # a coarse field: cheap to build, same code path


def sphere_wall(radius_mm: float = 1.75, shift=(0.0, 0.0, 0.0)) -> WallModel:
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=radius_mm)
    return WallModel.create(np.asarray(sphere.vertices) + shift, np.asarray(sphere.faces), float(sphere.volume),
                            wp.get_device("cpu"))


def field_of(wall, region=None):
    return cached_wall_field(wall, BAND_MM, VOXEL_MM, DEFAULT_CREASE_MM, region)


def samples(wall, field) -> tuple[np.ndarray, ...]:
    """Trusted flag, distance (mm) and normal of the field at 4000 points of its band."""
    pts = band_points(wall, (-0.1, BAND_MM), 4000, seed=3)
    n = len(pts)
    trusted, d, normal = wp.zeros(n, dtype=wp.int32), wp.zeros(n, dtype=wp.float64), wp.zeros(n, dtype=wp.vec3d)
    wp.launch(field_kernels.sample_field, n, inputs=[field.id, wp.array(pts, dtype=wp.vec3d), GRAD_TOLERANCE,
                                                     trusted, d, normal])
    return trusted.numpy(), d.numpy(), normal.numpy()


def assert_same_samples(wall, a, b):
    sa, sb = samples(wall, a), samples(wall, b)
    assert sa[0].sum() > 500  # trusted samples to compare (the rest fall back to the BVH in a run)
    for x, y in zip(sa, sb):
        assert np.array_equal(x, y, equal_nan=True)


@pytest.fixture
def cache(tmp_path, monkeypatch) -> Path:
    monkeypatch.setenv(FIELD_CACHE_ENV, str(tmp_path / "fields"))
    return tmp_path / "fields"


def test_a_loaded_field_samples_bit_identical_to_the_built_one(cache):
    wall = sphere_wall()
    built = field_of(wall)
    assert not built.from_cache and len(list(cache.glob("*.nvdb"))) == 1
    loaded = field_of(sphere_wall())  # a fresh process would hold a fresh WallModel
    assert loaded.from_cache and loaded.voxels == built.voxels and loaded.inner_mm == built.inner_mm
    assert_same_samples(wall, built, loaded)


def test_every_input_of_the_field_changes_its_key():
    wall = sphere_wall()
    base = field_key(wall, BAND_MM, VOXEL_MM, DEFAULT_CREASE_MM, None)
    assert field_key(sphere_wall(), BAND_MM, VOXEL_MM, DEFAULT_CREASE_MM, None) == base  # same inputs, same file
    moved = sphere_wall()
    moved.vertices_mm[7, 0] += 1e-9
    flipped = sphere_wall()
    flipped.faces_np[:] = flipped.faces_np[:, ::-1]
    region = ((0.0, 0.0, -1.45), 3.5)
    keys = [base, field_key(moved, BAND_MM, VOXEL_MM, DEFAULT_CREASE_MM, None),
            field_key(flipped, BAND_MM, VOXEL_MM, DEFAULT_CREASE_MM, None),
            field_key(sphere_wall(shift=(0.5, 0.0, 0.0)), BAND_MM, VOXEL_MM, DEFAULT_CREASE_MM, None),
            field_key(wall, BAND_MM * 1.5, VOXEL_MM, DEFAULT_CREASE_MM, None),
            field_key(wall, BAND_MM, VOXEL_MM / 2, DEFAULT_CREASE_MM, None),
            field_key(wall, BAND_MM, VOXEL_MM, DEFAULT_CREASE_MM * 2, None),
            field_key(wall, BAND_MM, VOXEL_MM, DEFAULT_CREASE_MM, region),
            field_key(wall, BAND_MM, VOXEL_MM, DEFAULT_CREASE_MM, (region[0], 3.0)),
            field_key(wall, BAND_MM, VOXEL_MM, DEFAULT_CREASE_MM, ((0.0, 0.0, -1.4), 3.5))]
    assert len(set(keys)) == len(keys)


@pytest.mark.parametrize("damage", ["truncated", "flipped byte", "empty"])
def test_a_damaged_cache_file_is_rebuilt_and_replaced(cache, damage):
    wall = sphere_wall()
    built = field_of(wall)
    (path,) = cache.glob("*.nvdb")
    data = path.read_bytes()
    if damage == "truncated":
        path.write_bytes(data[: len(data) // 2])
    elif damage == "flipped byte":
        path.write_bytes(data[:5000] + bytes([data[5000] ^ 0x10]) + data[5001:])
    else:
        path.write_bytes(b"")
    assert load_volume(path, wall.vertices.device) is None
    rebuilt = field_of(sphere_wall())
    assert not rebuilt.from_cache
    assert path.read_bytes() == data  # replaced by a whole file again
    assert_same_samples(wall, built, rebuilt)


def test_a_writer_leaves_only_whole_files_and_old_temporaries_are_removed(cache):
    cache.mkdir(parents=True)
    old, fresh = cache / f"{TEMPORARY_PREFIX}killed.1.tmp", cache / f"{TEMPORARY_PREFIX}writing.2.tmp"
    others = cache / "another_program.tmp"  # the folder may be shared: not ours, never removed
    for f in (old, fresh, others):
        f.write_bytes(b"half")
    os.utime(old, (0.0, 0.0))  # left by a writer killed long ago; the fresh one may still be renamed
    os.utime(others, (0.0, 0.0))
    field_of(sphere_wall())
    assert fresh.exists() and others.exists() and not old.exists() and len(list(cache.glob("*.tmp"))) == 2
    (path,) = cache.glob("*.nvdb")
    assert load_volume(path, wp.get_device("cpu")) is not None


def test_the_disabled_cache_builds_every_time_and_writes_nothing(tmp_path, monkeypatch):
    monkeypatch.setenv(FIELD_CACHE_ENV, "off")
    monkeypatch.setattr(wp.config, "kernel_cache_dir", str(tmp_path))  # where the default folder would be
    assert field_cache_dir() is None
    assert not field_of(sphere_wall()).from_cache
    assert not field_of(sphere_wall()).from_cache
    assert not any(tmp_path.iterdir())


def test_an_unwritable_cache_folder_warns_and_builds(tmp_path, monkeypatch):
    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder")
    monkeypatch.setenv(FIELD_CACHE_ENV, str(blocker / "fields"))
    with pytest.warns(UserWarning, match=FIELD_CACHE_ENV):
        field = field_of(sphere_wall())
    assert not field.from_cache and field.voxels > 0


def test_the_second_run_of_a_scene_loads_its_field_and_repeats_the_first(tmp_path):
    """The CLI as a user runs it, twice, with a fresh field cache: the first run
    builds and stores the field, the second loads it and writes the same results."""
    scene = (ROOT / "scenes" / "seed_sphere.toml").read_text()
    assert 'wall_query = "sdf"' in scene  # the seed scene samples the wall from the field
    scene = scene.replace("length_mm = 60.0", "length_mm = 12.0").replace(
        'wall_query = "sdf"', 'wall_query = "sdf"\nwall_voxel_mm = 0.08')
    (tmp_path / "seed_sdf.toml").write_text(scene)
    env = dict(os.environ, **{FIELD_CACHE_ENV: str(tmp_path / "fields"), "PYTHONPATH": str(ROOT)})
    results = []
    for run in ("first", "second"):
        with open(tmp_path / f"{run}.log", "w") as log:
            code = subprocess.run([sys.executable, "-m", "warpcoil.cli", "run", "seed_sdf.toml", "-o", run, "--no-usd",
                                   "-q"], cwd=tmp_path, env=env, stdout=log, stderr=subprocess.STDOUT).returncode
        message = (tmp_path / f"{run}.log").read_text()
        assert code == 0, message
        assert "completed" in message and f"-> {run}" in message
        results.append(json.loads((tmp_path / run / "result.json").read_text()))
    assert len(list((tmp_path / "fields").glob("*.nvdb"))) == 1
    first, second = results
    assert first["wall_field"]["from_cache"] is False and second["wall_field"]["from_cache"] is True
    assert second["wall_field"]["build_s"] < first["wall_field"]["build_s"]
    for r in results:
        for key in ("wall_time_s", "scene"):
            r.pop(key)
        r["wall_field"].pop("build_s")
        r["wall_field"].pop("from_cache")
    assert first == second
    for name in ("centerline.csv", "timeseries.csv"):
        assert (tmp_path / "first" / name).read_bytes() == (tmp_path / "second" / name).read_bytes()


@pytest.mark.parametrize("region", [(np.zeros(3), 1.0e9), (np.array([0.0, 0.0, -1.45]), 1.5)])
def test_the_host_tile_count_is_the_builds_own(region):
    """wall_field.candidate_tiles (the preflight's count of what the build allocates) sums the build's
    per-face tile counts (kernels.count_face_tiles), whole wall or a region."""
    from warpcoil.wall_field import INNER_MM_VOXELS, candidate_tiles

    wall = sphere_wall(shift=(0.3, 0.0, 0.0))
    tile = 8.0 * VOXEL_MM
    reach = max(BAND_MM, INNER_MM_VOXELS * VOXEL_MM) + np.sqrt(3.0) * tile + VOXEL_MM
    centre = region[0] - wall.origin
    counts = wp.zeros(len(wall.faces_np), dtype=wp.int32)
    wp.launch(field_kernels.count_face_tiles, len(wall.faces_np), inputs=[
        wall.vertices, wall.faces, tile, reach, wp.vec3d(*centre), region[1], counts])
    expected = int(counts.numpy().astype(np.int64).sum())
    assert 0 < expected == candidate_tiles(wall.vertices.numpy(), wall.faces_np, BAND_MM, VOXEL_MM,
                                           (centre, region[1]))
