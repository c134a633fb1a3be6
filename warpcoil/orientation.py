"""Directions the anatomy itself defines, so that a scene turned as a whole turns its run with it.

A coil's roll about the catheter axis, and the neck frame's first axis (from which
``catheter.azimuth_deg`` is measured), need a direction normal to an axis. Taking it from the
coordinate axes (the axis least aligned with the normal) made both depend on how the scene's
coordinates happen to lie: the same patient scene rotated rolled its coil by 160° and deployed
differently, and a 1° tilt across a boundary of that rule rolled it by up to 90°.

:func:`wall_axes` are the wall's own axes: the principal axes of its surface's second moment
(area-weighted face centres about their centroid), each signed by the surface's third moment
along it. Rotating the wall rotates them, and they do not move with the catheter. An axis whose
second moment is within AXIS_GAP of another's, or whose third moment is near zero, is not
defined by the wall (a sphere defines none) and is left out.
"""

from __future__ import annotations

import numpy as np

AXIS_GAP = 0.05  # relative gap of second moments below which two principal axes are not told apart
AXIS_SKEW = 1.0e-3  # |third moment| / (spread³ · area) below which an axis has no sign
NORMAL_SHARE = 0.3  # a reference's part normal to the axis, below which it does not define a direction


def wall_axes(vertices_mm: np.ndarray, faces: np.ndarray) -> list[np.ndarray]:
    """The wall's defined axes (unit vectors), largest spread first (see the module's note)."""
    vertices = np.asarray(vertices_mm, dtype=np.float64)
    triangles = vertices[np.asarray(faces, dtype=np.int64)]
    areas = 0.5 * np.linalg.norm(np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0]),
                                 axis=1)
    total = float(areas.sum())
    if not total > 0.0:
        return []
    offsets = triangles.mean(axis=1) - (areas[:, None] * triangles.mean(axis=1)).sum(axis=0) / total
    moments = np.einsum("f,fi,fj->ij", areas, offsets, offsets) / total
    values, vectors = np.linalg.eigh(moments)  # ascending
    axes = []
    for k in (2, 1, 0):
        others = [values[j] for j in range(3) if j != k]
        if min(abs(values[k] - v) for v in others) < AXIS_GAP * values[2]:
            continue
        axis = vectors[:, k]
        along = offsets @ axis
        skew = float((areas * along ** 3).sum()) / total
        if abs(skew) < AXIS_SKEW * values[2] ** 1.5:
            continue
        axes.append(axis if skew > 0.0 else -axis)
    return axes


def normal_part(reference: np.ndarray, axis: np.ndarray) -> np.ndarray | None:
    """``reference``'s part normal to the unit ``axis``, as a unit vector; None where that part is
    under NORMAL_SHARE of the reference (it would turn fast with a small tilt of the axis)."""
    reference = np.asarray(reference, dtype=np.float64)
    size = float(np.linalg.norm(reference))
    part = reference - (reference @ axis) * axis
    length = float(np.linalg.norm(part))
    if not size > 0.0 or length < NORMAL_SHARE * size:
        return None
    return part / length


def anatomy_normal(axis: np.ndarray, vertices_mm: np.ndarray | None, faces: np.ndarray | None,
                   point_mm: np.ndarray | None = None) -> np.ndarray | None:
    """A unit vector normal to the unit ``axis`` that the wall defines: its first axis (wall_axes) with a
    part normal to ``axis``, else the direction from ``point_mm`` to the wall's centroid (a sphere: its
    centre); None where neither does (a sphere with the axis through its centre, which then has no
    preferred roll)."""
    if vertices_mm is None or faces is None or len(faces) == 0:
        return None
    for reference in wall_axes(vertices_mm, faces):
        direction = normal_part(reference, axis)
        if direction is not None:
            return direction
    if point_mm is None:
        return None
    vertices = np.asarray(vertices_mm, dtype=np.float64)
    return normal_part(vertices.mean(axis=0) - np.asarray(point_mm, dtype=np.float64), axis)


def turned(direction: np.ndarray, axis: np.ndarray, angle_deg: float) -> np.ndarray:
    """``direction`` turned by ``angle_deg`` about the unit ``axis`` (right-handed)."""
    a = np.radians(angle_deg)
    return (np.cos(a) * direction + np.sin(a) * np.cross(axis, direction)
            + (1.0 - np.cos(a)) * (axis @ direction) * axis)
