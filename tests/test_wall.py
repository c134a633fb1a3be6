"""Wall mesh intake: every check on a malformed mesh built here from trimesh primitives."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import trimesh
from vtkmodules.util.numpy_support import numpy_to_vtk, numpy_to_vtkIdTypeArray
from vtkmodules.vtkCommonCore import vtkPoints
from vtkmodules.vtkCommonDataModel import vtkCellArray, vtkPolyData
from vtkmodules.vtkIOLegacy import vtkPolyDataWriter
from vtkmodules.vtkIOXML import vtkXMLPolyDataWriter

from warpcoil.settings import WallSpec
from warpcoil.wall import WallError, WallMesh, load_wall, sphere_wall

RADIUS_MM = 3.0
SPHERE_VOLUME_MM3 = 4.0 / 3.0 * math.pi * RADIUS_MM**3


def sphere() -> trimesh.Trimesh:
    return trimesh.creation.icosphere(subdivisions=4, radius=RADIUS_MM)


def export(tmp_path: Path, mesh: trimesh.Trimesh, name: str = "sac.stl") -> Path:
    path = tmp_path / name
    mesh.export(path)
    return path


def load(path: Path, **spec: object) -> WallMesh:
    return load_wall(WallSpec(mesh=path, **spec))


def with_faces(mesh: trimesh.Trimesh, faces: np.ndarray, vertices: np.ndarray | None = None) -> trimesh.Trimesh:
    return trimesh.Trimesh(mesh.vertices if vertices is None else vertices, faces, process=False)


def write_vtk_polydata(path: Path, vertices: np.ndarray, cells: dict[str, list[list[int]]]) -> Path:
    """Write PolyData with ``cells`` keyed 'polys', 'lines' or 'verts' (legacy .vtk or XML .vtp)."""
    polydata = vtkPolyData()
    points = vtkPoints()
    points.SetData(numpy_to_vtk(np.asarray(vertices, dtype=np.float64), deep=True))
    polydata.SetPoints(points)
    for kind, connectivity in cells.items():
        array = vtkCellArray()
        offsets = np.cumsum([0] + [len(cell) for cell in connectivity])
        ids = numpy_to_vtkIdTypeArray(np.concatenate(connectivity), deep=True)
        array.SetData(numpy_to_vtkIdTypeArray(offsets, deep=True), ids)
        getattr(polydata, f"Set{kind.capitalize()}")(array)
    writer = vtkXMLPolyDataWriter() if path.suffix == ".vtp" else vtkPolyDataWriter()
    writer.SetFileName(str(path))
    writer.SetInputData(polydata)
    assert writer.Write() == 1
    return path


def assert_closed_outward(wall: WallMesh, center_mm: np.ndarray = np.zeros(3)) -> None:
    mesh = trimesh.Trimesh(wall.vertices_mm, wall.faces, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert wall.volume_mm3 > 0.0
    assert wall.vertices_mm.dtype == np.float64 and wall.faces.dtype == np.int32
    outward = np.einsum("ij,ij->i", mesh.face_normals, mesh.triangles_center - center_mm)
    assert (outward > 0.0).all()


def test_closed_icosphere_loads_unchanged(tmp_path: Path) -> None:
    path = export(tmp_path, sphere())
    wall = load(path)
    assert wall.volume_mm3 == pytest.approx(SPHERE_VOLUME_MM3, rel=0.01)
    assert_closed_outward(wall)
    assert wall.notes == ()
    assert wall.source == path
    assert len(wall.vertices_mm) == len(sphere().vertices)  # STL's per-triangle copies merged


@pytest.mark.parametrize("offset_mm", [8.0, 1.5])  # beside the sac, inside it
def test_separate_bodies_are_counted_and_warned_about(tmp_path: Path, offset_mm: float) -> None:
    """A lumen is one closed body: a second one (beside the sac or inside it) is counted, each with its
    signed volume, and the run's preflight warns that the sac volume counts them all (it was silent)."""
    from types import SimpleNamespace

    from warpcoil.preflight import check_wall_bodies
    from warpcoil.settings import Scene

    small = trimesh.creation.icosphere(subdivisions=2, radius=0.5)
    small.apply_translation((offset_mm, 0.0, 0.0))
    wall = load(export(tmp_path, trimesh.util.concatenate([sphere(), small])))
    assert len(wall.body_volumes_mm3) == 2
    assert wall.body_volumes_mm3 == pytest.approx((sphere().volume, small.volume), rel=1e-5)  # (STL: float32)
    assert wall.volume_mm3 == pytest.approx(sum(wall.body_volumes_mm3), rel=1e-9)
    scene = Scene(coils=())
    warning, = check_wall_bodies(scene, SimpleNamespace(wall=wall))
    assert "2 separate closed bodies" in warning and "fix: keep only the lumen surface" in warning
    single = load(export(tmp_path, sphere(), "one.stl"))
    assert single.body_volumes_mm3 == pytest.approx((sphere().volume,), rel=1e-5) and check_wall_bodies(
        scene, SimpleNamespace(wall=single)) == []


def test_metres_without_units_is_refused(tmp_path: Path) -> None:
    path = export(tmp_path, sphere().apply_scale(1e-3), "sac_m.stl")
    with pytest.raises(WallError, match='units = "m"') as caught:
        load(path)
    assert "sac_m.stl" in str(caught.value) and "metres" in str(caught.value)


@pytest.mark.parametrize("scale, units, fix", [(1.0, "m", 'remove units = "m"'), (1e3, "mm", "µm?")])
def test_a_wall_larger_than_any_vessel_is_refused(tmp_path: Path, scale: float, units: str, fix: str) -> None:
    """A mesh in mm read as metres (a 4 m sac), or one in µm read as mm: refused, naming the fix."""
    path = export(tmp_path, sphere().apply_scale(scale), "sac_big.stl")
    with pytest.raises(WallError, match="larger than any vessel") as caught:
        load(path, units=units)
    assert "sac_big.stl" in str(caught.value) and fix in str(caught.value)


def test_metres_with_units_are_scaled(tmp_path: Path) -> None:
    wall = load(export(tmp_path, sphere().apply_scale(1e-3)), units="m")
    assert wall.volume_mm3 == pytest.approx(sphere().volume, rel=1e-6)
    assert np.ptp(wall.vertices_mm, axis=0) == pytest.approx([2 * RADIUS_MM] * 3, rel=1e-6)
    assert "scaled from metres to mm" in wall.notes


def open_sphere() -> trimesh.Trimesh:
    """The icosphere less the faces round its top and bottom vertices: two holes."""
    mesh = sphere()
    poles = mesh.vertices[:, 2].argsort()[[0, -1]]
    return with_faces(mesh, mesh.faces[~np.isin(mesh.faces, poles).any(axis=1)])


def test_open_mesh_is_refused_naming_holes_and_repair(tmp_path: Path) -> None:
    path = export(tmp_path, open_sphere(), "open.stl")
    with pytest.raises(WallError) as caught:
        load(path)
    message = str(caught.value)
    assert "open.stl" in message and "2 holes" in message and "repair = true" in message


def test_open_mesh_is_capped_with_repair(tmp_path: Path) -> None:
    wall = load(export(tmp_path, open_sphere()), repair=True)
    assert_closed_outward(wall)
    assert wall.volume_mm3 == pytest.approx(sphere().volume, rel=1e-3)
    assert wall.notes == ("capped 2 holes",)


def test_inverted_mesh_is_flipped(tmp_path: Path) -> None:
    wall = load(export(tmp_path, sphere().invert()))
    assert wall.volume_mm3 == pytest.approx(sphere().volume, rel=1e-6)
    assert_closed_outward(wall)
    assert wall.notes == ("flipped inward-facing normals",)


def test_inconsistent_winding_is_repaired(tmp_path: Path) -> None:
    faces = sphere().faces.copy()
    faces[[3, 100, 2000]] = faces[[3, 100, 2000], ::-1]
    wall = load(export(tmp_path, with_faces(sphere(), faces), "sac.ply"))
    assert wall.volume_mm3 == pytest.approx(sphere().volume, rel=1e-6)
    assert_closed_outward(wall)
    assert wall.notes == ("re-wound 3 inconsistently oriented faces",)


def test_degenerate_and_duplicate_faces_are_removed(tmp_path: Path) -> None:
    faces = sphere().faces
    bad = np.vstack((faces, [[0, 0, 1], faces[7], faces[9][::-1]]))
    wall = load(export(tmp_path, with_faces(sphere(), bad), "sac.ply"))
    assert len(wall.faces) == len(faces)
    assert wall.volume_mm3 == pytest.approx(sphere().volume, rel=1e-6)
    assert wall.notes == ("removed 1 degenerate face", "removed 2 duplicate faces")


def test_non_manifold_edge_is_refused(tmp_path: Path) -> None:
    mesh = sphere()
    a, b = mesh.faces[0, :2]
    vertices = np.vstack((mesh.vertices, mesh.vertices[[a, b]].mean(axis=0) * 1.5))
    fin = np.vstack((mesh.faces, [[b, a, len(mesh.vertices)]]))  # a third triangle on edge a-b
    path = export(tmp_path, with_faces(mesh, fin, vertices), "fin.ply")
    with pytest.raises(WallError, match="1 edge shared by more than two triangles") as caught:
        load(path, repair=True)
    assert "fin.ply" in str(caught.value)


def test_non_orientable_surface_is_refused(tmp_path: Path) -> None:
    count = 24
    angle = np.linspace(0.0, 2.0 * np.pi, count, endpoint=False)
    circle = np.column_stack((10 * np.cos(angle), 10 * np.sin(angle), np.zeros(count)))
    across = np.column_stack((np.cos(angle / 2) * np.cos(angle), np.cos(angle / 2) * np.sin(angle), np.sin(angle / 2)))
    vertices = np.vstack((circle + 2 * across, circle - 2 * across))  # a Möbius strip
    top, bottom = np.arange(count), np.arange(count) + count
    next_top, next_bottom = np.roll(top, -1), np.roll(bottom, -1)
    next_top[-1], next_bottom[-1] = bottom[0], top[0]  # the half twist joins top to bottom
    faces = np.vstack((np.column_stack((top, bottom, next_bottom)), np.column_stack((top, next_bottom, next_top))))
    path = export(tmp_path, trimesh.Trimesh(vertices, faces, process=False), "moebius.ply")
    with pytest.raises(WallError, match="non-orientable"):
        load(path, repair=True)


def test_hole_pinched_at_a_vertex_cannot_be_capped(tmp_path: Path) -> None:
    mesh = sphere()
    ring = np.flatnonzero(np.isin(mesh.faces, [0]).any(axis=1))  # the 5 faces round vertex 0
    path = export(tmp_path, with_faces(mesh, np.delete(mesh.faces, ring[[0, 2]], axis=0)), "pinched.stl")
    with pytest.raises(WallError, match="capping 1 hole did not close the surface") as caught:
        load(path, repair=True)
    assert "pinched.stl" in str(caught.value)


@pytest.mark.parametrize("suffix", [".obj", ".ply", ".vtk", ".vtp"])
def test_formats_round_trip(tmp_path: Path, suffix: str) -> None:
    mesh = sphere()
    path = tmp_path / f"sac{suffix}"
    if suffix in (".vtk", ".vtp"):
        write_vtk_polydata(path, mesh.vertices, {"polys": mesh.faces.tolist()})
    else:
        mesh.export(path)
    wall = load(path)
    assert wall.volume_mm3 == pytest.approx(mesh.volume, rel=1e-6)
    assert len(wall.faces) == len(mesh.faces) and wall.notes == ()


@pytest.mark.parametrize("suffix", [".vtk", ".vtp"])
def test_vtk_polygons_are_triangulated_and_lines_ignored(tmp_path: Path, suffix: str) -> None:
    cube = trimesh.creation.box(extents=(2.0, 2.0, 2.0))
    quads = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
    cells = {"polys": quads, "lines": [[0, 7]], "verts": [[3]]}
    wall = load(write_vtk_polydata(tmp_path / f"cube{suffix}", cube.vertices, cells))
    assert len(wall.faces) == 12
    assert wall.volume_mm3 == pytest.approx(8.0)
    assert_closed_outward(wall)


@pytest.mark.parametrize(
    ("name", "content", "problem"),
    [
        ("sac.off", "OFF\n", "unsupported mesh format '.off'"),
        ("empty.stl", "solid sac\nendsolid sac\n", "no triangles"),
        ("junk.ply", "not a ply", "cannot be read as PLY"),
        ("junk.vtk", "junk\n", "cannot be read as VTK PolyData"),
        ("junk.vtp", "junk\n", "not a VTK XML PolyData file"),
    ],
)
def test_unreadable_files_are_refused(tmp_path: Path, name: str, content: str, problem: str) -> None:
    path = tmp_path / name
    path.write_text(content)
    with pytest.raises(WallError, match=problem) as caught:
        load(path)
    assert name in str(caught.value) and "fix:" in str(caught.value)


@pytest.mark.parametrize("suffix", [".vtk", ".vtp"])
def test_vtk_without_polygons_is_refused(tmp_path: Path, suffix: str) -> None:
    centerline = write_vtk_polydata(tmp_path / f"centerline{suffix}", np.eye(3), {"lines": [[0, 1, 2]]})
    with pytest.raises(WallError, match="contains no triangles"):
        load(centerline)


def test_unsupported_extension_lists_the_supported_ones(tmp_path: Path) -> None:
    with pytest.raises(WallError, match=r"\.stl, \.obj, \.ply, \.vtk, \.vtp"):
        load(tmp_path / "sac.off")


def test_missing_file_is_refused(tmp_path: Path) -> None:
    with pytest.raises(WallError, match="nowhere.stl: file does not exist"):
        load(tmp_path / "nowhere.stl")


def test_sphere_wall() -> None:
    center = np.array([1.0, -2.0, 3.0])
    wall = sphere_wall(3.5, tuple(center))
    assert wall.volume_mm3 == pytest.approx(math.pi * 3.5**3 / 6.0, rel=0.01)
    assert np.linalg.norm(wall.vertices_mm - center, axis=1) == pytest.approx(1.75)
    assert_closed_outward(wall, center)
    assert wall.source is None and wall.notes == ()


def test_load_wall_with_sphere_diameter_generates_it() -> None:
    wall = load_wall(WallSpec(sphere_diameter_mm=3.5, center_mm=(1.0, 0.0, 0.0)))
    assert np.array_equal(wall.vertices_mm, sphere_wall(3.5, (1.0, 0.0, 0.0)).vertices_mm)


def test_spec_without_mesh_or_sphere_is_refused() -> None:
    with pytest.raises(WallError, match="sphere_diameter_mm"):
        load_wall(WallSpec())


@pytest.mark.parametrize("diameter_mm", [0.0, -1.0, math.nan])
def test_sphere_wall_refuses_non_positive_diameter(diameter_mm: float) -> None:
    with pytest.raises(WallError, match="> 0"):
        sphere_wall(diameter_mm)


def test_medial_axis_of_a_tube_is_inside() -> None:
    """Points on a straight tube's axis are equidistant from opposite facets; Warp's
    pseudo-normal sign sums their normals (ties within 1e-3 edge lengths) and called
    most of them outside by ~1 mm (C0091 frame readings). The wall query's distance
    is the facet apothem r cos(π/n) inside, and stays negative outside."""
    from warpcoil.devices import wall_distances_mm

    sections, radius = 48, 1.0
    tube = trimesh.creation.cylinder(radius=radius, height=8.0, sections=sections)
    wall = WallMesh(vertices_mm=np.asarray(tube.vertices), faces=np.asarray(tube.faces, np.int32),
                    volume_mm3=float(tube.volume), notes=(), source=None)
    z = np.linspace(-3.0, 3.0, 61)
    axis = np.stack([np.zeros_like(z), np.zeros_like(z), z], axis=1)
    np.testing.assert_allclose(wall_distances_mm(wall, axis), radius * math.cos(math.pi / sections), rtol=1e-9)
    outside = axis + np.array([1.5 * radius, 0.0, 0.0])
    np.testing.assert_allclose(wall_distances_mm(wall, outside), -0.5 * radius, atol=1e-9)
