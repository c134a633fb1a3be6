"""Shape measurements of coil centerlines (mm)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class HelixFit:
    loop_diameter_mm: float
    pitch_mm: float  # rise per turn along the axis
    axis: np.ndarray  # unit


def fit_helix(points_mm: np.ndarray) -> HelixFit:
    """Least-squares circular helix through a polyline.

    Axis: the direction along which the unit tangents vary least (a helix's
    tangents keep a constant angle to its axis). Diameter: algebraic circle fit
    (Kåsa) of the points projected normal to the axis. Pitch: slope of axial
    position against unwrapped polar angle, × 2π.
    """
    p = np.asarray(points_mm, dtype=np.float64)
    t = np.diff(p, axis=0)
    t /= np.linalg.norm(t, axis=1)[:, None]
    axis = np.linalg.eigh(np.cov(t.T))[1][:, 0]
    helper = np.eye(3)[int(np.argmin(np.abs(axis)))]
    u = np.cross(axis, helper)
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    q = p - p.mean(axis=0)
    planar = np.stack([q @ u, q @ v], axis=1)
    lhs = np.column_stack([2.0 * planar, np.ones(len(planar))])
    (cx, cy, k), *_ = np.linalg.lstsq(lhs, (planar**2).sum(axis=1), rcond=None)
    radius = float(np.sqrt(k + cx**2 + cy**2))
    angle = np.unwrap(np.arctan2(planar[:, 1] - cy, planar[:, 0] - cx))
    slope = np.polyfit(angle, q @ axis, 1)[0]
    return HelixFit(loop_diameter_mm=2.0 * radius, pitch_mm=float(abs(slope) * 2.0 * np.pi), axis=axis)
