"""Directions the anatomy itself defines, so that a scene turned as a whole turns its run with it.

A coil's roll about the catheter axis, and the neck frame's first axis (from which
``catheter.azimuth_deg`` is measured), need a direction normal to an axis. Taking it from the
coordinate axes (the axis least aligned with the normal) made both depend on how the scene's
coordinates happen to lie: the same patient scene rotated rolled its coil by 160° and deployed
differently, and a 1° tilt across a boundary of that rule rolled it by up to 90°.

The wall's skew vector v = Σ a_f |d_f|² d_f / Σ a_f (mm³; a_f each face's area, d_f its centre
less the area-weighted centroid) turns with the wall and does not move with the catheter; its
part normal to the axis turns continuously with the axis, except where the axis runs along v
(any rule for a direction normal to every axis must fail somewhere: the hairy-ball theorem; on
the five shipped patients v lies 34–61° off the catheter). A wall whose v is below
SKEW_FLOOR of its spread cubed (a sphere: v = 0 by symmetry) defines none: then the direction
from the tip (neck centroid) to the wall's centroid, and where that runs along the axis too (a
catheter through a sphere's centre, which has no preferred roll), none at all.
"""

from __future__ import annotations

import numpy as np

SKEW_FLOOR = 1.0e-6  # |v| / spread³ below which a wall defines no skew vector (a sphere's is rounding)
ALONG_AXIS = 1.0e-9  # a reference's part normal to the axis, relative, below which it runs along it


def skew_vector(vertices_mm: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray | None, np.ndarray]:
    """The wall's skew vector (mm³; None where it defines none) and its area-weighted centroid (mm)."""
    vertices = np.asarray(vertices_mm, dtype=np.float64)
    triangles = vertices[np.asarray(faces, dtype=np.int64)]
    areas = 0.5 * np.linalg.norm(np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0]),
                                 axis=1)
    total = float(areas.sum())
    centres = triangles.mean(axis=1)
    centroid = (areas[:, None] * centres).sum(axis=0) / total
    offsets = centres - centroid
    squared = np.einsum("fi,fi->f", offsets, offsets)
    skew = (areas * squared) @ offsets / total
    spread = float(np.sqrt((areas * squared).sum() / total))
    return (skew if np.linalg.norm(skew) > SKEW_FLOOR * spread ** 3 else None), centroid


def normal_part(reference: np.ndarray, axis: np.ndarray) -> np.ndarray | None:
    """``reference``'s part normal to the unit ``axis``, as a unit vector; None where it runs along it."""
    reference = np.asarray(reference, dtype=np.float64)
    part = reference - (reference @ axis) * axis
    length = float(np.linalg.norm(part))
    if not length > ALONG_AXIS * float(np.linalg.norm(reference)):
        return None
    return part / length


def anatomy_normal(axis: np.ndarray, vertices_mm: np.ndarray | None, faces: np.ndarray | None,
                   point_mm: np.ndarray | None = None) -> np.ndarray | None:
    """A unit vector normal to the unit ``axis`` that the wall defines (the module's note): its skew vector's
    part normal to it, else the direction from ``point_mm`` to the wall's centroid; None where neither."""
    if vertices_mm is None or faces is None or len(faces) == 0:
        return None
    skew, centroid = skew_vector(vertices_mm, faces)
    direction = None if skew is None else normal_part(skew, axis)
    if direction is None and point_mm is not None:
        direction = normal_part(centroid - np.asarray(point_mm, dtype=np.float64), axis)
    return direction


def tip_axis(catheter) -> np.ndarray:
    """A catheter's unit axis at its tip (a centerline's last piece, else its direction)."""
    line = catheter.centerline_mm
    axis = np.asarray(catheter.direction if line is None else np.subtract(line[-1], line[-2]), dtype=np.float64)
    return axis / np.linalg.norm(axis)


def turned(direction: np.ndarray, axis: np.ndarray, angle_deg: float) -> np.ndarray:
    """``direction`` turned by ``angle_deg`` about the unit ``axis`` (right-handed)."""
    a = np.radians(angle_deg)
    return (np.cos(a) * direction + np.sin(a) * np.cross(axis, direction)
            + (1.0 - np.cos(a)) * (axis @ direction) * axis)
