"""Validation of the regional packing densities (``warpcoil validate regions``) on a
sac with analytic regions: a sphere of radius R cut by the plane z = z0 (the sac is
above it, the ostium a disc of radius √(R² − z0²)). With neck band n and boundary b
(docs/REGIONS.md) the regions are

- neck: the cylinder over the ostium, z0 ≤ z ≤ z0 + n, volume π (R² − z0²) n;
- core: the ball of radius R − b above z0 + n, a spherical cap;
- boundary: the rest of the sac.

A helix of wire diameter d laid by hand inside one region (pitch > d, so its turns
do not overlap) fills the volume π (d/2)² L, L its length; the region's density is
that over the region's volume. The error is first order in the voxel edge h (the
boundary is a voxel-resolution distance). Units mm.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .sac import Sac, neck_from_plane, regional_density, sac_from_neck
from .validation import CaseResult, _row, observed_order
from .wall import sphere_wall

SPHERE_R_MM, NECK_Z_MM, WIRE_D_MM = 3.0, -2.0, 0.3
HELIX_PITCH_MM = 0.5


@dataclass(frozen=True)
class SphereSac:
    """The cut sphere and its analytic regions at the default bands (4 d, 2 d)."""

    sac: Sac
    radius_mm: float = SPHERE_R_MM
    neck_z_mm: float = NECK_Z_MM
    wire_d_mm: float = WIRE_D_MM

    @property
    def neck_band_mm(self) -> float:
        return 4.0 * self.wire_d_mm

    @property
    def boundary_mm(self) -> float:
        return 2.0 * self.wire_d_mm

    @property
    def ostium_radius_mm(self) -> float:
        return math.sqrt(self.radius_mm**2 - self.neck_z_mm**2)

    def volumes_mm3(self) -> dict[str, float]:
        """Analytic neck, boundary and core volumes (mm³)."""
        cap = lambda r, z: math.pi * (r - z) ** 2 * (2.0 * r + z) / 3.0  # noqa: E731  (ball r above plane z)
        top = self.neck_z_mm + self.neck_band_mm
        neck = math.pi * self.ostium_radius_mm**2 * self.neck_band_mm
        core = cap(self.radius_mm - self.boundary_mm, top)
        return {"neck": neck, "boundary": cap(self.radius_mm, self.neck_z_mm) - neck - core, "core": core}

    def region_of(self, points_mm: np.ndarray) -> np.ndarray:
        """Analytic region of each point: 0 neck, 1 boundary, 2 core, -1 outside the sac."""
        p = np.asarray(points_mm, dtype=float)
        rho, z, r = np.hypot(p[:, 0], p[:, 1]), p[:, 2], np.linalg.norm(p, axis=1)
        top = self.neck_z_mm + self.neck_band_mm
        region = np.where(r <= self.radius_mm - self.boundary_mm, 2, 1)
        region[(z <= top) & (rho <= self.ostium_radius_mm)] = 0
        region[(z <= top) & (rho > self.ostium_radius_mm) & (r <= self.radius_mm)] = 1
        region[(r > self.radius_mm) | (z < self.neck_z_mm)] = -1
        return region


def sphere_sac(subdivisions: int = 5) -> SphereSac:
    """The sphere of radius 3 mm cut at z = −2 mm (sac above, 104.7 mm³)."""
    wall = sphere_wall(2.0 * SPHERE_R_MM, subdivisions=subdivisions)
    return SphereSac(sac_from_neck(wall, neck_from_plane([0.0, 0.0, NECK_Z_MM], [0.0, 0.0, 1.0], wall)))


def helix(radius_mm, z_from_mm: float, z_to_mm: float, pitch_mm: float = HELIX_PITCH_MM,
          points_per_turn: int = 360) -> np.ndarray:
    """Helix about z from z_from to z_to; ``radius_mm(z)`` gives its radius at each height."""
    turns = (z_to_mm - z_from_mm) / pitch_mm
    t = np.linspace(0.0, 2.0 * math.pi * turns, int(turns * points_per_turn) + 1)
    z = z_from_mm + pitch_mm * t / (2.0 * math.pi)
    r = radius_mm(z)
    return np.column_stack((r * np.cos(t), r * np.sin(t), z))


def region_helices(geometry: SphereSac) -> dict[str, np.ndarray]:
    """One helix well inside each region: 1.2 mm about the axis in the neck and in
    the core; on the sphere of radius R − b/2 (mid-boundary) above the neck band."""
    mid = geometry.radius_mm - 0.5 * geometry.boundary_mm
    top = geometry.neck_z_mm + geometry.neck_band_mm
    margin = geometry.wire_d_mm  # the tube stays a radius clear of every region's edge
    return {
        "neck": helix(lambda z: np.full_like(z, 1.2), geometry.neck_z_mm + margin, top - margin),
        "boundary": helix(lambda z: np.sqrt(mid**2 - z * z), top + margin, 2.0),
        "core": helix(lambda z: np.full_like(z, 1.2), top + 2.0 * margin, 1.5),
    }


def length_mm(points_mm: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(points_mm, axis=0), axis=1).sum())


def region_cases(voxel_fractions: tuple[int, ...] = (2, 4, 8)) -> list[CaseResult]:
    """Each region's density of its hand-laid helix against π(d/2)²L / V_region at
    voxel edges h = d/k (tolerance 8 % from h = d/4), and the observed order of the
    largest error (first order: the boundary is a voxel-resolution distance)."""
    geometry = sphere_sac()
    d = geometry.wire_d_mm
    helices = region_helices(geometry)
    volumes = geometry.volumes_mm3()
    reference = {k: math.pi * (0.5 * d) ** 2 * length_mm(p) / volumes[k] for k, p in helices.items()}
    rows, worst = [], []
    for k in voxel_fractions:
        result = regional_density(geometry.sac, list(helices.values()), [d] * 3, voxel_mm=d / k)
        errors = []
        for name in ("neck", "boundary", "core"):
            row = _row(f"region density, helix in the {name}, h = d/{k}", reference[name], getattr(result, name),
                       0.08 if k >= 4 else 0.2)
            rows.append(row)
            errors.append(row.error)
        worst.append(max(errors))
    if len(voxel_fractions) >= 2:
        ratio = voxel_fractions[-1] / voxel_fractions[0]
        order = observed_order([worst[0], worst[-1]], ratio)
        rows.append(CaseResult(f"region density: observed order of the largest error, h = d/{voxel_fractions[0]}"
                               f" → d/{voxel_fractions[-1]}", 1.0, order, abs(order - 1.0), 0.5))
    return rows
