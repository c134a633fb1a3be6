"""Wall mesh intake: read the lumen surface, check it, fix what is safe to fix.

The result is a closed, consistently wound triangle surface in mm whose normals
point out of the lumen (positive signed volume). What intake changed is listed
in :attr:`WallMesh.notes` for the run log; what it cannot fix raises
:class:`WallError` naming the file, the problem and the fix.

Readers: trimesh for STL/OBJ/PLY, VTK for legacy ``.vtk`` and XML ``.vtp``
PolyData (meshio reads neither PolyData flavour; imported only to read such a file).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh
from trimesh.grouping import group_rows

from .settings import WallSpec

TRIMESH_SUFFIXES = (".stl", ".obj", ".ply")
VTK_SUFFIXES = (".vtk", ".vtp")
MIN_DIAGONAL_MM = 0.5  # a sac with a smaller bounding-box diagonal was written in metres
MAX_DIAGONAL_MM = 500.0  # a wall (sac and vessels) with a larger one, in mm, was written in mm read as m, or in µm


class WallError(ValueError):
    """A wall mesh that cannot be used; the message names the file, the problem and the fix."""


def _error(path: Path | None, problem: str, fix: str) -> WallError:
    return WallError(f"{path if path is not None else 'wall'}: {problem}; fix: {fix}")


@dataclass(frozen=True)
class WallMesh:
    """Closed lumen surface, normals pointing out of the lumen."""

    vertices_mm: np.ndarray  # (V, 3) float64
    faces: np.ndarray  # (F, 3) int32, positive signed volume
    volume_mm3: float
    notes: tuple[str, ...]  # what intake changed, for the run log
    source: Path | None
    body_volumes_mm3: tuple[float, ...] = ()  # a read mesh's separate closed bodies' signed volumes (mm³), largest first


def sphere_wall(
    diameter_mm: float, center_mm: tuple[float, float, float] = (0.0, 0.0, 0.0), subdivisions: int = 4
) -> WallMesh:
    """Icosphere sac of ``diameter_mm`` centred at ``center_mm`` (vertices on the sphere)."""
    if not diameter_mm > 0.0:
        raise _error(None, f"sphere diameter must be > 0 mm, got {diameter_mm!r}", "give a positive diameter")
    sphere = trimesh.creation.icosphere(subdivisions=subdivisions, radius=0.5 * diameter_mm)
    return WallMesh(
        vertices_mm=np.asarray(sphere.vertices, dtype=np.float64) + np.asarray(center_mm, dtype=np.float64),
        faces=np.asarray(sphere.faces, dtype=np.int32),
        volume_mm3=float(sphere.volume),
        notes=(),
        source=None,
    )


def load_wall(spec: WallSpec) -> WallMesh:
    """The wall of ``spec``: a generated sphere, or its mesh file read, checked and cleaned."""
    if spec.sphere_diameter_mm is not None:
        return sphere_wall(spec.sphere_diameter_mm, spec.center_mm)
    if spec.mesh is None:
        raise _error(None, "neither a mesh file nor a sphere diameter is given", "set mesh or sphere_diameter_mm")
    path = Path(spec.mesh)
    vertices, faces = _read(path)
    notes: list[str] = []
    if spec.units == "m":
        vertices = vertices * 1000.0
        notes.append("scaled from metres to mm")
    diagonal_mm = float(np.linalg.norm(np.ptp(vertices[np.unique(faces)], axis=0)))  # (of the surface's points)
    if spec.units != "m" and diagonal_mm < MIN_DIAGONAL_MM:
        raise _error(
            path,
            f"its bounding-box diagonal is {diagonal_mm:.3g}, too small for a sac in mm: it looks like metres",
            'set [wall] units = "m" in the scene',
        )
    if diagonal_mm > MAX_DIAGONAL_MM:
        read_as = "read as metres (wall.units = \"m\")" if spec.units == "m" else "in mm"
        raise _error(
            path,
            f"its bounding-box diagonal is {diagonal_mm:.3g} mm {read_as}, larger than any vessel "
            f"(> {MAX_DIAGONAL_MM:g} mm)",
            'remove units = "m" from [wall] if the mesh is in mm' if spec.units == "m"
            else "scale the mesh to mm if it is in another unit (µm?), or crop it to the sac and its vessels",
        )
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    notes += _clean(mesh)
    notes += _orient(mesh, path)
    if not mesh.is_watertight:
        notes.append(_cap_holes(mesh, path, spec.repair))
    if mesh.volume < 0.0:
        mesh.invert()
        notes.append("flipped inward-facing normals")
    return WallMesh(
        vertices_mm=np.asarray(mesh.vertices, dtype=np.float64),
        faces=np.asarray(mesh.faces, dtype=np.int32),
        volume_mm3=float(mesh.volume),
        notes=tuple(notes),
        source=path,
        body_volumes_mm3=body_volumes_mm3(mesh),
    )


def body_volumes_mm3(mesh: trimesh.Trimesh) -> tuple[float, ...]:
    """Signed volume (mm³) of each separate body (faces joined by shared edges) of the closed
    ``mesh``, largest magnitude first: a lumen is one."""
    body = component_labels(mesh.face_adjacency, len(mesh.faces))
    v = mesh.vertices[mesh.faces]
    signed = np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2])) / 6.0
    volumes = np.bincount(np.unique(body, return_inverse=True)[1], weights=signed)
    return tuple(float(x) for x in volumes[np.argsort(-np.abs(volumes))])


# --- readers ----------------------------------------------------------------------
def _read(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(V, 3) vertices and (F, 3) triangles of the mesh file at ``path``, as stored."""
    suffix = path.suffix.lower()
    if suffix not in TRIMESH_SUFFIXES + VTK_SUFFIXES:
        supported = ", ".join(TRIMESH_SUFFIXES + VTK_SUFFIXES)
        raise _error(path, f"unsupported mesh format {suffix or 'without extension'!r}", f"convert it to {supported}")
    if not path.is_file():
        raise _error(path, "file does not exist", "check [wall] mesh in the scene")
    vertices, faces = _read_vtk(path) if suffix in VTK_SUFFIXES else _read_trimesh(path)
    if len(faces) == 0:
        raise _error(path, "contains no triangles", "export the lumen as a triangle surface")
    if not np.isfinite(vertices).all():
        raise _error(path, "has non-finite vertex coordinates", "re-export the mesh")
    return vertices.astype(np.float64), faces.astype(np.int64)


def _is_stl(path: Path) -> bool:
    """A binary STL's size is 84 + 50 × its triangle count (header); an ASCII one starts with "solid"."""
    size = path.stat().st_size
    with path.open("rb") as file:
        head = file.read(84)
    if head[:5].lower() == b"solid":
        return True
    return len(head) == 84 and size == 84 + 50 * int.from_bytes(head[80:84], "little")


def _read_trimesh(path: Path) -> tuple[np.ndarray, np.ndarray]:
    kind = path.suffix[1:].upper()
    not_a_mesh = _error(path, f"is not a mesh: it cannot be read as {kind}",
                        f"check that the file is a triangle surface saved as {kind}, or re-export it")
    if path.suffix.lower() == ".stl" and not _is_stl(path):
        raise not_a_mesh
    try:
        loaded = trimesh.load_mesh(path, process=False)
    except Exception as exc:  # trimesh's parsers raise many kinds (even ImportError) on malformed files
        raise not_a_mesh from exc
    if not hasattr(loaded, "faces"):
        raise not_a_mesh
    return np.asarray(loaded.vertices), np.asarray(loaded.faces)


def read_vtk_polydata(path: Path, triangulate: bool = False):
    """Legacy ``.vtk`` or XML ``.vtp`` PolyData read with VTK (``triangulate``:
    polygons split into triangles, line and vertex cells dropped). VTK's errors
    and warnings are collected instead of printed and raised as one ValueError."""
    from vtkmodules.util.misc import calldata_type
    from vtkmodules.vtkCommonCore import VTK_STRING, vtkCommand
    from vtkmodules.vtkFiltersCore import vtkTriangleFilter
    from vtkmodules.vtkIOLegacy import vtkPolyDataReader
    from vtkmodules.vtkIOXML import vtkXMLPolyDataReader

    if path.suffix.lower() == ".vtp":
        reader = vtkXMLPolyDataReader()
        if not reader.CanReadFile(str(path)):
            raise ValueError("not a VTK XML PolyData file")
    else:
        reader = vtkPolyDataReader()
    last = reader
    if triangulate:
        last = vtkTriangleFilter()
        last.PassVertsOff()
        last.PassLinesOff()
        last.SetInputConnection(reader.GetOutputPort())
    messages: list[str] = []

    @calldata_type(VTK_STRING)
    def collect(_caller: object, _event: str, message: str) -> None:
        messages.append(message.strip().rsplit("): ", 1)[-1])

    for algorithm in {reader, last}:  # observers also keep VTK from printing
        algorithm.AddObserver(vtkCommand.ErrorEvent, collect)
        algorithm.AddObserver(vtkCommand.WarningEvent, collect)
    reader.SetFileName(str(path))
    last.Update()
    if messages:
        raise ValueError(messages[0])
    return last.GetOutput()


def _read_vtk(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Legacy or XML VTK PolyData; polygons triangulated, line and vertex cells dropped."""
    from vtkmodules.util.numpy_support import vtk_to_numpy

    try:
        surface = read_vtk_polydata(path, triangulate=True)
    except ValueError as exc:
        raise _error(path, f"cannot be read as VTK PolyData ({exc})", "check or re-export the file as PolyData") \
            from None
    if surface.GetNumberOfPolys() == 0:  # (then it may have no points array either)
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    vertices = vtk_to_numpy(surface.GetPoints().GetData())
    faces = vtk_to_numpy(surface.GetPolys().GetConnectivityArray()).reshape(-1, 3)
    return vertices, faces


# --- checks and repairs (in place on ``mesh``; each returns its notes) --------------
def _plural(count: int, noun: str) -> str:
    return f"{count} {noun}{'' if count == 1 else 's'}"


def _clean(mesh: trimesh.Trimesh) -> list[str]:
    """Merge duplicate vertices; drop degenerate and duplicate faces."""
    mesh.merge_vertices()
    notes = []
    checks = (("degenerate", trimesh.Trimesh.nondegenerate_faces), ("duplicate", trimesh.Trimesh.unique_faces))
    for kind, kept in checks:
        mask = kept(mesh)
        if not mask.all():
            notes.append(f"removed {_plural(int((~mask).sum()), kind + ' face')}")
            mesh.update_faces(mask)
    mesh.remove_unreferenced_vertices()
    return notes


def component_labels(edges: np.ndarray, count: int) -> np.ndarray:
    """Connected-component label of each of ``count`` nodes joined by ``edges`` (E, 2).

    Min-label propagation with pointer jumping; the label is a node of the component.
    """
    labels = np.arange(count)
    while True:
        low = labels[edges].min(axis=1) if len(edges) else np.zeros(0, dtype=np.int64)
        hooked = labels.copy()
        np.minimum.at(hooked, edges[:, 0], low)
        np.minimum.at(hooked, edges[:, 1], low)
        hooked = hooked[hooked]
        if np.array_equal(hooked, labels):
            return labels
        labels = hooked


def _orient(mesh: trimesh.Trimesh, path: Path) -> list[str]:
    """Refuse non-manifold edges; re-wind faces so neighbours agree (fewest flips per body).

    Node ``2f + s`` of an auxiliary graph is face ``f`` flipped (s = 1) or not; each
    shared edge links the states of its two faces that agree. An orientable body
    gives two mirror components, and its faces take the state in the one whose
    label is lower.
    """
    counts = np.unique(mesh.edges_sorted, axis=0, return_counts=True)[1]
    if (counts > 2).any():
        raise _error(
            path,
            f"{_plural(int((counts > 2).sum()), 'edge')} shared by more than two triangles (non-manifold)",
            "make the surface a single manifold sheet in a mesh editor",
        )
    if mesh.is_winding_consistent:
        return []
    pairs = group_rows(mesh.edges_sorted, require_count=2)  # (n, 2) indices into mesh.edges
    face_a, face_b = (pairs // 3).T
    same_direction = (mesh.edges[pairs[:, 0], 0] == mesh.edges[pairs[:, 1], 0]).astype(np.int64)
    links = np.concatenate(
        [
            np.column_stack((2 * face_a, 2 * face_b + same_direction)),
            np.column_stack((2 * face_a + 1, 2 * face_b + 1 - same_direction)),
        ]
    )
    labels = component_labels(links, 2 * len(mesh.faces)).reshape(-1, 2)
    if (labels[:, 0] == labels[:, 1]).any():
        raise _error(path, "cannot be wound consistently (non-orientable surface)", "export a closed lumen surface")
    flip = labels[:, 1] < labels[:, 0]
    body = np.unique(labels.min(axis=1), return_inverse=True)[1]
    flip ^= (np.bincount(body, weights=flip) > 0.5 * np.bincount(body))[body]
    mesh.faces = np.where(flip[:, None], mesh.faces[:, ::-1], mesh.faces)
    return [f"re-wound {_plural(int(flip.sum()), 'inconsistently oriented face')}"]


def _cap_holes(mesh: trimesh.Trimesh, path: Path, repair: bool) -> str:
    """Close each boundary loop with a fan of triangles from the loop's centroid."""
    boundary = mesh.edges[group_rows(mesh.edges_sorted, require_count=1)]  # directed as in their faces
    loop_of_vertex = component_labels(boundary, len(mesh.vertices))
    loop_ids, loop_of_edge = np.unique(loop_of_vertex[boundary[:, 0]], return_inverse=True)
    holes = _plural(len(loop_ids), "hole")
    if not repair:
        raise _error(
            path,
            f"the surface is open: {len(boundary)} boundary edges in {holes}",
            "set [wall] repair = true in the scene to cap the holes, or close the mesh",
        )
    loop_vertices = np.unique(boundary)
    loop = np.searchsorted(loop_ids, loop_of_vertex[loop_vertices])
    centroids = np.zeros((len(loop_ids), 3))
    np.add.at(centroids, loop, mesh.vertices[loop_vertices])
    centroids /= np.bincount(loop)[:, None]
    cap = np.column_stack((boundary[:, 1], boundary[:, 0], len(mesh.vertices) + loop_of_edge))
    mesh.vertices = np.vstack((mesh.vertices, centroids))
    mesh.faces = np.vstack((mesh.faces, cap))
    if not (mesh.is_watertight and mesh.is_winding_consistent):
        raise _error(path, f"capping {holes} did not close the surface", "close the mesh in a mesh editor")
    return f"capped {holes}"
