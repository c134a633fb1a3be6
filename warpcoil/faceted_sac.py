"""Irregular, faceted, non-convex test sacs (for validation and tests; no patient data).

A coarse icosphere whose radius varies with direction — a few low-order lobes
and one bleb (a daughter sac) — scaled to a given volume. Its faces are large
(edges ≈ 0.3–0.6 mm at 20 mm³, about the coil's segment), so a coil pressed
against it meets real facet edges and vertices, and the lobes make it
non-convex. Units: mm.
"""

from __future__ import annotations

import numpy as np
import trimesh

from .wall import WallMesh

BOTTOM = np.array([0.0, 0.0, -1.0])  # the catheter enters here (the radius function keeps it smooth)


def _radius_factor(directions: np.ndarray, seed: int) -> np.ndarray:
    """Relative radius in each unit direction: 1 + lobes + a bleb (deterministic in ``seed``)."""
    rng = np.random.default_rng(seed)
    lobes = np.zeros(len(directions))
    for _ in range(4):  # a few smooth bumps and dents
        axis = rng.standard_normal(3)
        axis /= np.linalg.norm(axis)
        lobes += rng.uniform(-0.12, 0.18) * np.exp(-(1.0 - directions @ axis) / 0.25)
    bleb_axis = np.array([0.7, 0.2, 0.68])
    bleb_axis /= np.linalg.norm(bleb_axis)
    bleb = 0.35 * np.exp(-(1.0 - directions @ bleb_axis) / 0.06)  # a narrow daughter sac: the wall folds in at its base
    return 1.0 + lobes + bleb


def lobulated_sac(volume_mm3: float, subdivisions: int = 3, seed: int = 1) -> WallMesh:
    """Closed, outward-wound, lobulated icosphere with a bleb of ``volume_mm3``.

    ``subdivisions`` 2 gives 320 faces, 3 gives 1280 (the default). The sac is
    centred near the origin; :func:`catheter_tip` gives a tip just inside its
    bottom (−z)."""
    sphere = trimesh.creation.icosphere(subdivisions=subdivisions, radius=1.0)
    directions = sphere.vertices / np.linalg.norm(sphere.vertices, axis=1)[:, None]
    mesh = trimesh.Trimesh(directions * _radius_factor(directions, seed)[:, None], sphere.faces, process=False)
    if not mesh.is_watertight or mesh.volume <= 0.0:
        raise RuntimeError("lobulated sac is not a closed, outward-wound surface")
    mesh.apply_scale((volume_mm3 / mesh.volume) ** (1.0 / 3.0))
    return WallMesh(vertices_mm=np.asarray(mesh.vertices, np.float64), faces=np.asarray(mesh.faces, np.int32),
                    volume_mm3=float(mesh.volume), notes=(), source=None)


def catheter_tip(wall: WallMesh, seed: int = 1, depth_mm: float = 0.4) -> tuple[float, float, float]:
    """A catheter tip about ``depth_mm`` inside the bottom of :func:`lobulated_sac`'s
    ``wall`` (made with ``seed``), on the −z axis; point it along +z. The bottom is
    the smooth radius function there (the facets lie within a few µm of it)."""
    directions = wall.vertices_mm / np.linalg.norm(wall.vertices_mm, axis=1)[:, None]
    scale = float(np.median(np.linalg.norm(wall.vertices_mm, axis=1) / _radius_factor(directions, seed)))
    bottom = scale * float(_radius_factor(BOTTOM[None], seed)[0])
    return (0.0, 0.0, -bottom + depth_mm)
