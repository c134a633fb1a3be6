"""Coil tube surfaces (STL/VTP for CFD) and the PNG run summary."""

import math
from dataclasses import fields
from pathlib import Path

import matplotlib.image
import numpy as np
import pytest
import trimesh
from matplotlib.figure import Figure
from vtkmodules.util.numpy_support import vtk_to_numpy
from vtkmodules.vtkIOXML import vtkXMLPolyDataReader

from warpcoil.deploy import Frame
from warpcoil.recorder import figures, tube
from warpcoil.recorder.figures import packing_percent, write_summary_png
from warpcoil.recorder.tube import (coil_tube_mesh, coils_tube_mesh, equal_area_radius_mm, write_tube_stl,
                                   write_tube_vtp)

SIDES = 12


def helix_mm(
    turns: float = 3.0, nodes: int = 240, radius_mm: float = 2.0, pitch_mm: float = 0.6
) -> np.ndarray:
    angle = np.linspace(0.0, 2 * np.pi * turns, nodes)
    return np.column_stack(
        [radius_mm * np.cos(angle), radius_mm * np.sin(angle), pitch_mm * angle / (2 * np.pi)]
    )


def distance_to_polyline_mm(points: np.ndarray, polyline: np.ndarray) -> np.ndarray:
    a, b = polyline[:-1], polyline[1:]
    ab = b - a
    t = np.clip(np.einsum("psk,sk->ps", points[:, None] - a, ab) / np.einsum("sk,sk->s", ab, ab), 0.0, 1.0)
    return np.linalg.norm(points[:, None] - (a + t[..., None] * ab), axis=2).min(axis=1)


def test_straight_tube_volume_and_closure():
    length_mm, diameter_mm = 5.0, 0.3
    line = np.column_stack([np.linspace(0, length_mm, 9), np.zeros(9), np.zeros(9)])
    mesh = coil_tube_mesh(line, diameter_mm, SIDES)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume > 0.0  # outward winding
    expected = math.pi * (diameter_mm / 2) ** 2 * length_mm  # the wire's volume: the polygon has its area
    assert mesh.volume == pytest.approx(expected, rel=1e-9)


def test_helix_tube_wall_at_wire_radius():
    centerline, wire_mm = helix_mm(), 0.15
    radius_mm = equal_area_radius_mm(wire_mm, SIDES)  # the corners of the polygon of the wire's area
    assert 0.5 * SIDES * math.sin(2 * math.pi / SIDES) * radius_mm**2 == pytest.approx(math.pi * wire_mm**2)
    mesh = coil_tube_mesh(centerline, 2 * wire_mm, SIDES)
    assert mesh.is_watertight and mesh.volume > 0.0
    assert len(mesh.vertices) == len(centerline) * SIDES
    tangents = np.diff(centerline, axis=0)
    tangents /= np.linalg.norm(tangents, axis=1, keepdims=True)
    max_bend = np.arccos(np.einsum("ij,ij->i", tangents[:-1], tangents[1:]).min())
    distance = distance_to_polyline_mm(mesh.vertices, centerline)
    assert distance.min() == pytest.approx(radius_mm, rel=1e-9)
    assert distance.max() <= radius_mm / math.cos(max_bend / 2) * (1 + 1e-9)  # mitre stretch


def test_planar_tube_does_not_twist():
    """Parallel transport along a curve in z = 0 keeps each polygon corner at one height."""
    angle = np.linspace(0.0, 1.5 * np.pi, 50)
    wiggly = np.column_stack([angle, np.sin(3 * angle), np.zeros_like(angle)])
    rings = coil_tube_mesh(wiggly, 0.2, SIDES).vertices.reshape(len(angle), SIDES, 3)
    np.testing.assert_allclose(rings[:, :, 2], np.broadcast_to(rings[0, :, 2], rings.shape[:2]), atol=1e-12)


def test_sharp_bend_is_clamped_and_still_closed():
    corner = np.array([[0.0, 0, 0], [1, 0, 0], [0.1, 0.1, 0]])  # ~170° turn
    mesh = coil_tube_mesh(corner, 0.2, SIDES)
    assert mesh.is_watertight and mesh.is_winding_consistent
    corner_ring_mm = np.linalg.norm(mesh.vertices[SIDES : 2 * SIDES] - corner[1], axis=1)
    assert corner_ring_mm.max() == pytest.approx(tube.MAX_MITRE_SCALE * equal_area_radius_mm(0.1, SIDES), rel=1e-6)  # unclamped: ~11x


def test_two_coils_two_closed_bodies():
    mesh = coils_tube_mesh([helix_mm(), helix_mm(radius_mm=1.0) + [0, 0, 3]], [0.3, 0.254], SIDES)
    assert mesh.is_watertight and mesh.volume > 0.0
    assert mesh.euler_number == 4  # two closed genus-0 surfaces
    coil_id = mesh.face_attributes["coil_id"]
    assert np.array_equal(np.bincount(coil_id), [len(coil_tube_mesh(helix_mm(), 0.3).faces)] * 2)


@pytest.fixture
def two_coil_mesh() -> trimesh.Trimesh:
    return coils_tube_mesh([helix_mm(nodes=60), helix_mm(nodes=40) + [5, 0, 0]], [0.3, 0.254], SIDES)


def test_stl_round_trip(tmp_path: Path, two_coil_mesh: trimesh.Trimesh):
    path = tmp_path / "coils.stl"
    write_tube_stl(path, two_coil_mesh)
    assert b"units mm" in path.read_bytes()[:80]
    back = trimesh.load(path)
    assert len(back.faces) == len(two_coil_mesh.faces)
    assert back.volume == pytest.approx(two_coil_mesh.volume, rel=1e-5)
    assert [p.name for p in tmp_path.iterdir()] == ["coils.stl"]


def test_vtp_round_trip(tmp_path: Path, two_coil_mesh: trimesh.Trimesh):
    path = tmp_path / "coils.vtp"
    write_tube_vtp(path, two_coil_mesh)
    reader = vtkXMLPolyDataReader()
    reader.SetFileName(str(path))
    reader.Update()
    poly = reader.GetOutput()
    assert poly.GetNumberOfCells() == len(two_coil_mesh.faces)
    assert poly.GetNumberOfPoints() == len(two_coil_mesh.vertices)
    coil_id = vtk_to_numpy(poly.GetCellData().GetArray("coil_id"))
    assert np.array_equal(coil_id, two_coil_mesh.face_attributes["coil_id"])
    assert poly.GetFieldData().GetAbstractArray("units").GetValue(0) == "mm"
    assert [p.name for p in tmp_path.iterdir()] == ["coils.vtp"]


def test_failed_tube_writes_leave_no_file(tmp_path: Path, two_coil_mesh: trimesh.Trimesh, monkeypatch):
    def half_write(self: Path, data: bytes) -> int:
        with open(self, "wb") as handle:
            handle.write(data[: len(data) // 2])
        raise OSError("disk full")

    class FailingWriter:
        def SetFileName(self, name: str) -> None:
            Path(name).write_text("<VTKFile")

        def SetInputData(self, data) -> None:
            pass

        def Write(self) -> int:
            return 0

    monkeypatch.setattr(Path, "write_bytes", half_write)
    monkeypatch.setattr(tube, "vtkXMLPolyDataWriter", FailingWriter)
    with pytest.raises(OSError):
        write_tube_stl(tmp_path / "coils.stl", two_coil_mesh)
    with pytest.raises(OSError):
        write_tube_vtp(tmp_path / "coils.vtp", two_coil_mesh)
    assert list(tmp_path.iterdir()) == []


def frames_to(deployed_mm: np.ndarray) -> list[Frame]:
    zeros = {f.name: 0.0 for f in fields(Frame)}
    return [
        Frame(**{**zeros, "deployed_length_mm": x, "push_force_mean_uN": 50.0 * x, "push_force_peak_uN": 60.0 * x,
                    "push_force_rms_uN": 55.0 * x, "time_s": x / 50.0})
        for x in deployed_mm
    ]


def summary_inputs() -> dict:
    wall = trimesh.creation.icosphere(subdivisions=3, radius=3.0)
    angle = np.linspace(0.0, 1.0, 600)
    polar, azimuth = np.arccos(1 - 2 * angle), 30 * np.pi * angle  # a spiral on a 2.8 mm sphere
    coil = 2.8 * np.column_stack(
        [np.sin(polar) * np.cos(azimuth), np.sin(polar) * np.sin(azimuth), np.cos(polar)]
    )
    return dict(wall_vertices_mm=wall.vertices, wall_faces=wall.faces, coils_mm=[coil, 0.5 * coil[:300]],
                frames=frames_to(np.linspace(0.0, 150.0, 100)), wire_diameters_mm=[0.3, 0.254],
                coil_boundaries_mm=[120.0], title="synthetic")


def test_packing_percent_accumulates_per_coil():
    area = [math.pi * 0.15**2, math.pi * 0.127**2]
    percent = packing_percent(np.array([0.0, 60.0, 150.0]), 100.0, [0.3, 0.254], [120.0])
    np.testing.assert_allclose(percent, [0.0, 60 * area[0], 120 * area[0] + 30 * area[1]])
    np.testing.assert_allclose(packing_percent(np.array([10.0]), 100.0, [0.3, 0.254]), [10 * area[0]])
    with pytest.raises(ValueError):
        packing_percent(np.array([1.0]), 100.0, [0.3, 0.254, 0.2], [120.0])


@pytest.mark.parametrize("sac_volume_mm3", [4 / 3 * math.pi * 27.0, None])
def test_summary_png(tmp_path: Path, sac_volume_mm3: float | None):
    path = tmp_path / "summary.png"
    write_summary_png(path, sac_volume_mm3=sac_volume_mm3, **summary_inputs())
    assert path.stat().st_size > 10_000
    height, width = matplotlib.image.imread(path).shape[:2]
    assert (width, height) == tuple(round(x * figures.DPI) for x in figures.FIGSIZE_IN)
    assert [p.name for p in tmp_path.iterdir()] == ["summary.png"]


def test_summary_draws_the_occlusion_grade(tmp_path: Path):
    """The packing panel carries the regional densities, the threshold and the class."""
    from warpcoil.occlusion import occlusion_grade

    grade = occlusion_grade(0.12, 0.33, 0.40)
    ax = Figure().add_subplot()
    figures._draw_occlusion(ax, grade, 2.0)
    assert [t.get_text() for t in ax.texts] == ["in-silico Raymond–Roy class 2 (II)"]
    markers = {line.get_label(): (line.get_xdata()[0], line.get_ydata()[0]) for line in ax.lines[1:]}
    assert markers == {"neck 12.0 % (final)": (2.0, pytest.approx(12.0)),
                       "boundary 33.0 % (final)": (2.0, pytest.approx(33.0)),
                       "core 40.0 % (final)": (2.0, pytest.approx(40.0))}
    assert ax.lines[0].get_ydata()[0] == pytest.approx(31.0)
    path = tmp_path / "summary.png"
    write_summary_png(path, sac_volume_mm3=100.0, occlusion=grade, **summary_inputs())
    assert path.stat().st_size > 10_000


def test_failed_summary_leaves_no_file(tmp_path: Path, monkeypatch):
    def half_save(self: Figure, fname, **kwargs) -> None:
        Path(fname).write_bytes(b"\x89PNG partial")
        raise RuntimeError("renderer crashed")

    monkeypatch.setattr(Figure, "savefig", half_save)
    with pytest.raises(RuntimeError):
        write_summary_png(tmp_path / "summary.png", sac_volume_mm3=None, **summary_inputs())
    assert list(tmp_path.iterdir()) == []


def test_summary_png_headlines_the_packing_in_the_sac():
    """The headline is the clinically meaningful figure, result.json's packing_density_in_sac (coil
    herniated into the parent vessel does not pack the sac), with the deployed coil's beside it."""
    from types import SimpleNamespace

    from warpcoil.recorder.outputs import summary_title

    herniated = SimpleNamespace(status="completed", packing_density=0.30, packing_density_in_sac=0.20, occlusion=None)
    title = summary_title(SimpleNamespace(source=Path("/x/C0001.toml")), herniated)
    assert title == "C0001: completed, packing density in sac 20.0 % (all deployed coil 30.0 %)"
    free = SimpleNamespace(status="completed", packing_density=None, packing_density_in_sac=None, occlusion=None)
    assert summary_title(SimpleNamespace(source=None), free) == "scene: completed, no sac"


def test_a_coil_withdrawn_whole_or_to_one_node_has_no_tube():
    """A coil jammed before its tip left the catheter keeps 0 nodes (one node if it jammed just after): no
    tube for it — the mesh of the others keeps their coil ids — and an empty mesh where none is left; the
    first version raised (IndexError, ValueError) from a run's outputs."""
    line = np.column_stack([np.zeros(5), np.zeros(5), np.linspace(0.0, 1.0, 5)])
    mesh = coils_tube_mesh([np.zeros((0, 3)), line[:1], line], [0.3, 0.3, 0.3])
    assert set(mesh.face_attributes["coil_id"]) == {2} and mesh.is_watertight
    assert len(coils_tube_mesh([np.zeros((0, 3))], [0.3]).faces) == 0
