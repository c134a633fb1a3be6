"""Closed triangle tubes around coil centerlines: the coil surface for CFD meshing.

Each coil becomes a watertight, outward-wound tube of its outer wire diameter:
a ring of ``sides`` vertices per centerline node (a regular polygon of the wire's
cross-section area, so the tubes hold the coils' volume: its corners lie 2.3 %
outside the wire surface at 12 sides, its edges' midpoints 1.2 % inside), oriented by rotation-minimising
(parallel-transport) frames so the tube does not twist, mitred at every
interior node (the ring lies in the bisector plane of its two segments, so the
wall keeps its thickness through the bend) and closed by flat end caps.
Units mm. Written as binary STL or XML PolyData (VTP), atomically.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh
from trimesh.exchange.stl import export_stl
from vtkmodules.util.numpy_support import numpy_to_vtk, numpy_to_vtkIdTypeArray
from vtkmodules.vtkCommonCore import vtkPoints, vtkStringArray
from vtkmodules.vtkCommonDataModel import vtkCellArray, vtkPolyData
from vtkmodules.vtkIOXML import vtkXMLPolyDataWriter

from .atomic import atomic_path

MAX_MITRE_SCALE = 2.0  # a ring vertex lies at most this many radii from its node (sharp bends)
MIN_SEGMENT_MM = 1e-9  # shorter segments (repeated nodes) are dropped: they have no direction
STL_HEADER = b"warpcoil coil tube surface, units mm".ljust(80)  # binary STL: must not start "solid"


def _minimal_rotations(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(M,3,3) rotations taking unit vectors ``a`` to ``b`` about ``a x b`` (Rodrigues).

    An exact reversal (a = -b) has no unique minimal rotation; it is clamped to a
    finite one (a coil centerline does not fold straight back on itself).
    """
    v = np.cross(a, b)
    k = np.zeros((len(v), 3, 3))
    k[:, 0, 1], k[:, 0, 2], k[:, 1, 2] = -v[:, 2], v[:, 1], -v[:, 0]
    k -= k.transpose(0, 2, 1)
    cos = np.einsum("ij,ij->i", a, b)
    return np.eye(3) + k + (k @ k) / np.maximum(1.0 + cos, 1e-12)[:, None, None]


def _cumulative_products(rotations: np.ndarray) -> np.ndarray:
    """P[k] = R[k] @ R[k-1] @ ... @ R[0], by a parallel prefix scan in log2(M) batched steps."""
    products = rotations.copy()
    shift = 1
    while shift < len(products):
        products[shift:] = products[shift:] @ products[:-shift]  # the right side is a new array
        shift *= 2
    return products


def _ring_vertices_mm(centerline_mm: np.ndarray, radius_mm: float, sides: int) -> np.ndarray:
    """(N, sides, 3) mitred cross-section polygons, one per node, counter-clockwise about the tangent."""
    segments = np.diff(centerline_mm, axis=0)
    tangents = segments / np.linalg.norm(segments, axis=1, keepdims=True)  # (N-1, 3)

    # Segment frames: a normal perpendicular to the first tangent, carried from
    # segment to segment by the minimal rotation between their tangents.
    first = tangents[0]
    normal = np.cross(first, np.eye(3)[np.argmin(np.abs(first))])
    normal /= np.linalg.norm(normal)
    transport = _cumulative_products(_minimal_rotations(tangents[:-1], tangents[1:]))
    normals = np.vstack([normal, transport @ normal])
    binormals = np.cross(tangents, normals)

    # Each node takes its incoming segment's circle (node 0: the first segment's)
    # and slides it along that segment onto the node's bisector plane, which the
    # outgoing segment's circle meets in the same polygon (an exact mitre).
    last = len(segments) - 1
    incoming = np.r_[0, np.arange(last + 1)]
    outgoing = np.r_[np.arange(last + 1), last]
    bisectors = tangents[incoming] + tangents[outgoing]
    length = np.linalg.norm(bisectors, axis=1, keepdims=True)
    bisectors = np.where(length > 1e-9, bisectors / np.maximum(length, 1e-9), tangents[incoming])

    angles = 2.0 * np.pi * np.arange(sides) / sides
    offsets = radius_mm * (np.cos(angles)[None, :, None] * normals[incoming][:, None, :]
                           + np.sin(angles)[None, :, None] * binormals[incoming][:, None, :])
    cos_half_bend = np.einsum("ij,ij->i", tangents[incoming], bisectors)
    slide = -np.einsum("nsk,nk->ns", offsets, bisectors) / np.maximum(cos_half_bend, 1e-9)[:, None]
    max_slide = radius_mm * np.sqrt(MAX_MITRE_SCALE**2 - 1.0)
    slide = np.clip(slide, -max_slide, max_slide)  # sharp bends: not quite on the bisector plane
    return centerline_mm[:, None, :] + offsets + slide[..., None] * tangents[incoming][:, None, :]


def _tube_faces(nodes: int, sides: int) -> np.ndarray:
    """Outward-wound triangles of the side wall and the two end-cap fans."""
    ring = np.arange(sides)
    a = (np.arange(nodes - 1)[:, None] * sides + ring).ravel()  # (node i, corner j)
    b = (np.arange(nodes - 1)[:, None] * sides + np.roll(ring, -1)).ravel()  # (i, j + 1)
    wall = np.vstack([np.column_stack([a, b, b + sides]), np.column_stack([a, b + sides, a + sides])])
    fan = np.arange(1, sides - 1)
    start = np.column_stack([np.zeros_like(fan), fan + 1, fan])  # faces -tangent
    end = (nodes - 1) * sides + np.column_stack([np.zeros_like(fan), fan, fan + 1])  # faces +tangent
    return np.vstack([wall, start, end])


def equal_area_radius_mm(radius_mm: float, sides: int) -> float:
    """Corner radius (mm) of the regular ``sides``-gon whose area is a circle's of ``radius_mm``."""
    return radius_mm * float(np.sqrt(2.0 * np.pi / (sides * np.sin(2.0 * np.pi / sides))))


def coil_tube_mesh(centerline_mm: np.ndarray, diameter_mm: float, sides: int = 12) -> trimesh.Trimesh:
    """Closed, outward-wound tube of outer diameter ``diameter_mm`` around an (N,3) polyline (mm).

    The polygon's area is the wire's, pi r**2 (its corners at :func:`equal_area_radius_mm`).
    Repeated nodes are dropped.
    """
    points = np.asarray(centerline_mm, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"centerline must be (N, 3), got {points.shape}")
    if diameter_mm <= 0.0 or sides < 3:
        raise ValueError(f"need diameter_mm > 0 and sides >= 3, got {diameter_mm}, {sides}")
    keep = np.r_[True, np.linalg.norm(np.diff(points, axis=0), axis=1) > MIN_SEGMENT_MM]
    points = points[keep]
    if len(points) < 2:
        raise ValueError("centerline needs at least two distinct nodes")
    vertices = _ring_vertices_mm(points, equal_area_radius_mm(0.5 * diameter_mm, sides), sides).reshape(-1, 3)
    return trimesh.Trimesh(vertices, _tube_faces(len(points), sides), process=False)


def coils_tube_mesh(
    centerlines: list[np.ndarray], diameters_mm: list[float], sides: int = 12
) -> trimesh.Trimesh:
    """All coils' tubes in one mesh (each closed on its own); per-face ``face_attributes["coil_id"]`` (the
    coil's index among ``centerlines``). A coil with fewer than two distinct nodes (one jammed before its tip
    left the catheter: withdrawn whole) has no tube; without any tube the mesh is empty."""
    if len(centerlines) != len(diameters_mm) or not centerlines:
        raise ValueError("need one diameter per centerline and at least one centerline")
    kept = [(k, c, d) for k, (c, d) in enumerate(zip(centerlines, diameters_mm))
            if len(c) >= 2 and np.ptp(np.asarray(c), axis=0).max() > 0.0]
    tubes = [coil_tube_mesh(c, d, sides) for _, c, d in kept]
    if not tubes:
        return trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64),
                               face_attributes={"coil_id": np.zeros(0, dtype=np.int32)}, process=False)
    vertex_offsets = np.cumsum([0] + [len(t.vertices) for t in tubes[:-1]])
    return trimesh.Trimesh(
        np.vstack([t.vertices for t in tubes]),
        np.vstack([t.faces + offset for t, offset in zip(tubes, vertex_offsets)]),
        face_attributes={"coil_id": np.repeat(np.array([k for k, _, _ in kept], dtype=np.int32),
                                              [len(t.faces) for t in tubes])},
        process=False,
    )


def write_tube_stl(path: Path, mesh: trimesh.Trimesh) -> None:
    """Binary STL (mm; the header says so), written atomically."""
    with atomic_path(Path(path)) as tmp_path:
        tmp_path.write_bytes(STL_HEADER + export_stl(mesh)[80:])


def write_tube_vtp(path: Path, mesh: trimesh.Trimesh) -> None:
    """XML PolyData with cell array ``coil_id`` and field string ``units`` = "mm", written atomically.

    ``coil_id`` comes from ``mesh.face_attributes["coil_id"]`` (all 0 when absent).
    """
    faces = np.asarray(mesh.faces, dtype=np.int64)
    coil_id = np.asarray(mesh.face_attributes.get("coil_id", np.zeros(len(faces))), dtype=np.int32)
    if coil_id.shape != (len(faces),):
        raise ValueError(f"coil_id has shape {coil_id.shape}, expected ({len(faces)},)")

    points = vtkPoints()
    points.SetData(numpy_to_vtk(np.asarray(mesh.vertices, dtype=np.float64), deep=True))
    polys = vtkCellArray()
    polys.SetData(numpy_to_vtkIdTypeArray(np.arange(0, 3 * len(faces) + 1, 3), deep=True),
                  numpy_to_vtkIdTypeArray(faces.ravel(), deep=True))
    poly = vtkPolyData()
    poly.SetPoints(points)
    poly.SetPolys(polys)
    ids = numpy_to_vtk(coil_id, deep=True)
    ids.SetName("coil_id")
    poly.GetCellData().AddArray(ids)
    units = vtkStringArray()
    units.SetName("units")
    units.InsertNextValue("mm")
    poly.GetFieldData().AddArray(units)

    with atomic_path(Path(path)) as tmp_path:
        writer = vtkXMLPolyDataWriter()
        writer.SetFileName(str(tmp_path))
        writer.SetInputData(poly)
        if writer.Write() != 1:
            raise OSError(f"VTK could not write {tmp_path}")
