"""Geometric queries on Warp's BVH (warpcoil.geometry) against closed-form geometry."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from warpcoil.geometry import SurfaceBVH, inside_points, inside_voxels, points_near_segments, ray_hits, surface_voxels

R_MM = 2.0


@pytest.fixture(scope="module")
def sphere() -> tuple[trimesh.Trimesh, SurfaceBVH]:
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=R_MM)
    return mesh, SurfaceBVH(np.asarray(mesh.vertices) + [10.0, -5.0, 3.0], np.asarray(mesh.faces))


CENTRE = np.array([10.0, -5.0, 3.0])


def test_inside_points_away_from_the_surface(sphere) -> None:
    """Points inside / outside the icosphere (vertices on radius R, faces within 0.5 % of it), any direction."""
    rng = np.random.default_rng(1)
    directions = rng.normal(size=(2000, 3))
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    radius = rng.uniform(0.0, 2.0 * R_MM, len(directions))
    keep = np.abs(radius - R_MM) > 0.01 * R_MM
    points = CENTRE + radius[keep, None] * directions[keep]
    assert np.array_equal(inside_points(sphere[1], points), radius[keep] < R_MM)


def test_inside_voxels_count_the_volume_and_agree_with_points(sphere) -> None:
    """Voxel count × h³ → the mesh volume as h shrinks; each voxel agrees with the per-point test."""
    mesh, surface = sphere
    errors = []
    for h in (0.4, 0.2, 0.1):
        origin = CENTRE - R_MM - h
        shape = (int(np.ceil(2 * R_MM / h)) + 2,) * 3
        voxels = inside_voxels(surface, origin, h, shape)
        errors.append(abs(voxels.sum() * h**3 / mesh.volume - 1.0))
        centres = origin + h * (np.indices(shape).reshape(3, -1).T + 0.5)
        assert np.array_equal(voxels.ravel(), inside_points(surface, centres))
    assert errors[-1] < 0.01 and errors[-1] < errors[0]


def test_points_near_segments_equals_brute_force() -> None:
    rng = np.random.default_rng(2)
    a = rng.uniform(-1.0, 1.0, (40, 3))
    b = a + rng.normal(scale=0.5, size=(40, 3))
    radius = rng.uniform(0.05, 0.2, 40)
    points = rng.uniform(-1.5, 1.5, (5000, 3))
    step = b - a
    t = np.clip(np.einsum("psk,sk->ps", points[:, None] - a[None], step) / np.einsum("sk,sk->s", step, step), 0, 1)
    gap = points[:, None] - a[None] - t[..., None] * step[None]
    expected = (np.einsum("psk,psk->ps", gap, gap) <= radius**2).any(axis=1)
    assert 100 < expected.sum() < 4900
    assert np.array_equal(points_near_segments(points, a, b, radius), expected)


def test_ray_hits_cross_the_sphere_twice(sphere) -> None:
    """Rays along +z at offset ρ < R cross at z = ±√(R² − ρ²) (to the facets' 0.5 %); rays outside miss."""
    rho = np.array([0.0, 0.7, 1.5, 2.5])
    starts = CENTRE + np.column_stack((rho, np.zeros(4), np.full(4, -5.0)))
    ray, _, t, normal = ray_hits(sphere[1], starts, np.array([0.0, 0.0, 1.0]), 1e-6)
    assert np.array_equal(np.bincount(ray, minlength=4), [2, 2, 2, 0])
    half = np.sqrt(R_MM**2 - rho[:3] ** 2)
    assert np.allclose(t.reshape(3, 2), np.column_stack((5.0 - half, 5.0 + half)), atol=0.01 * R_MM)
    assert np.all(normal.reshape(3, 2, 3)[:, 0, 2] < 0) and np.all(normal.reshape(3, 2, 3)[:, 1, 2] > 0)


def test_surface_voxels_lie_on_the_surface(sphere) -> None:
    """A flagged voxel's centre is within half its diagonal of the sphere; one within h/2 is flagged;
    the flagged shell holds about the sphere's area / h² voxels."""
    h = 0.1
    origin = CENTRE - R_MM - h
    shape = (int(np.ceil(2 * R_MM / h)) + 2,) * 3
    flagged = surface_voxels(sphere[1], origin, h, shape)
    distance = np.abs(np.linalg.norm(origin + h * (np.indices(shape).transpose(1, 2, 3, 0) + 0.5) - CENTRE, axis=-1)
                      - R_MM)
    facets = 0.005 * R_MM
    assert distance[flagged].max() <= math.sqrt(3) / 2 * h + facets
    assert flagged[distance < 0.5 * h - facets].all()
    assert flagged.sum() == pytest.approx(4 * math.pi * R_MM**2 / h**2, rel=0.5)
