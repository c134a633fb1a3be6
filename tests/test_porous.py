"""The porous-medium field (warpcoil.porous, recorder/porous.py): coil volume, Happel's
fibre-array permeabilities along and across aligned coil pieces, and the VTI file
(read back with VTK; meshio reads no ImageData, so it is not tried)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import trimesh
from vtkmodules.util.numpy_support import vtk_to_numpy
from vtkmodules.vtkIOXML import vtkXMLImageDataReader

from warpcoil.porous import happel_permeabilities_mm2, porous_field
from warpcoil.recorder.porous import write_porous_vti
from warpcoil.sac import neck_from_plane, sac_from_neck
from warpcoil.wall import sphere_wall

D_MM = 0.3
R_MM = D_MM / 2


def test_happel_values_and_limits() -> None:
    """Happel (1959) at φ = 0.2, evaluated by hand: K∥/a² = (ln 5 − 1.12)/0.8, K⊥/a² = (ln 5 − 0.96/1.04)/1.6;
    K∥/K⊥ → 2 as φ → 0 (both ~ −a² ln φ / 4φ, −a² ln φ / 8φ); no flow through solid wire (φ = 1)."""
    parallel, transverse = happel_permeabilities_mm2(np.array([0.2, 1e-12, 1.0, 0.0]), np.full(4, 2.0))
    assert parallel[0] / 4.0 == pytest.approx((math.log(5.0) - 1.12) / 0.8, rel=1e-12)
    assert transverse[0] / 4.0 == pytest.approx((math.log(5.0) - 0.96 / 1.04) / 1.6, rel=1e-12)
    assert parallel[1] / transverse[1] == pytest.approx(2.0, rel=0.05)
    assert parallel[2] == transverse[2] == 0.0
    assert parallel[3] == transverse[3] == np.inf


@pytest.fixture(scope="module")
def small_sac():
    """Sphere R 3 cut by the plane z = -2: the sac is the part above (104.5 mm³)."""
    wall = sphere_wall(6.0)
    return sac_from_neck(wall, neck_from_plane([0.0, 0.0, -2.0], [0.0, 0.0, 1.0], wall))


def test_mean_solid_fraction_is_the_coil_volume_in_the_sac(small_sac) -> None:
    """Σ sac_fraction·(1 − ε) / Σ sac_fraction = (coil volume inside the sac) / V_sac within 1 %.

    Coils: four nested helices (no overlaps, wholly inside) and a straight herniated
    piece along z from 1 mm above the neck plane to 0.8 mm below it: only its part
    above the plane (and its upper cap) is coil in the sac."""
    t = np.linspace(0.0, 10.0 * 2.0 * np.pi, 3000)
    helices = [np.column_stack((r * np.cos(t), r * np.sin(t), -1.0 + 3.0 * t / t[-1])) for r in (0.5, 0.95, 1.4, 1.85)]
    straight = np.column_stack((np.full(19, 2.3), np.zeros(19), np.linspace(-1.0, -2.8, 19)))
    field = porous_field(np.asarray(small_sac.closed_surface.vertices), np.asarray(small_sac.closed_surface.faces),
                         helices + [straight], [D_MM] * 5)
    assert field.voxel_mm == D_MM / 2
    capsule = lambda length: math.pi * R_MM**2 * length + 4.0 / 3.0 * math.pi * R_MM**3  # noqa: E731
    length = sum(np.linalg.norm(np.diff(h, axis=0), axis=1).sum() for h in helices)
    in_sac = 4 * capsule(length / 4) + (math.pi * R_MM**2 * 1.0 + 2.0 / 3.0 * math.pi * R_MM**3)
    weight = field.sac_fraction
    mean_solid = float((weight * (1.0 - field.porosity)).sum() / weight.sum())
    assert mean_solid == pytest.approx(in_sac / small_sac.volume_mm3, rel=0.01)
    assert weight.sum() * field.voxel_mm**3 == pytest.approx(small_sac.volume_mm3, rel=0.01)
    assert np.all(field.porosity[weight == 0.0] == 1.0)


def box_surface(size_mm: float) -> trimesh.Trimesh:
    return trimesh.creation.box(extents=[size_mm] * 3)


@pytest.mark.parametrize("direction", [(0.0, 0.0, 1.0), (1.0, 2.0, 2.0)])
def test_aligned_coil_pieces_give_happel_along_and_across(direction: tuple[float, float, float]) -> None:
    """Parallel straight pieces (a square array, spacing 0.6 mm, through a 4 mm box): in every voxel
    with coil, K·t = K∥(φ) t and K·u = K⊥(φ) u for u ⟂ t, φ the voxel's own solid fraction; the
    box's mean solid fraction is 36 π a² / (4 mm)² (axis-aligned case: 6 × 6 pieces right through)."""
    t = np.asarray(direction) / np.linalg.norm(direction)
    u = np.cross(t, [1.0, 0.0, 0.0] if abs(t[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    w = np.cross(t, u)
    spacing, size = 0.6, 4.0
    offsets = np.arange(-3, 3) * spacing + 0.137  # off the voxel lattice; the axis-aligned pieces lie inside the box
    pieces = [np.vstack((c * u + e * w - 4.0 * t, c * u + e * w + 4.0 * t)) for c in offsets for e in offsets]
    box = box_surface(size)
    field = porous_field(np.asarray(box.vertices), np.asarray(box.faces), pieces, [D_MM] * len(pieces), 0.2)
    tensor = field.permeability_tensor_mm2()
    parallel, transverse = field.permeabilities_mm2()
    coil = (field.porosity < 1.0) & (field.sac_fraction == 1.0)
    assert coil.sum() > 500
    assert np.allclose(field.fibre_radius_mm[coil], R_MM)
    for vector, expected in ((t, parallel), (u, transverse), (w, transverse)):
        applied = tensor[coil] @ vector
        assert np.allclose(applied, expected[coil][:, None] * vector, rtol=1e-9, atol=1e-15)
    assert np.allclose(np.trace(tensor[coil], axis1=1, axis2=2) / 3.0, field.permeability_mm2()[coil], rtol=1e-12)
    if direction == (0.0, 0.0, 1.0):
        assert np.abs(offsets).max() + R_MM < size / 2
        mean_solid = float(((1.0 - field.porosity) * field.sac_fraction).sum() / field.sac_fraction.sum())
        assert mean_solid == pytest.approx(len(pieces) * math.pi * R_MM**2 / size**2, rel=0.01)


def test_porosity_converges_with_the_voxel_size() -> None:
    """One straight piece in a box: the sampled coil volume tends to the capsule's as h shrinks."""
    box = box_surface(3.0)
    piece = np.array([[-1.0, 0.1234, -0.0771], [1.0, -0.0567, 0.0913]])
    exact = math.pi * R_MM**2 * np.linalg.norm(piece[1] - piece[0]) + 4.0 / 3.0 * math.pi * R_MM**3
    errors = []
    for h in (0.3, 0.15, 0.075):
        field = porous_field(np.asarray(box.vertices), np.asarray(box.faces), [piece], [D_MM], h)
        volume = float(((1.0 - field.porosity) * field.sac_fraction).sum() * h**3)
        errors.append(abs(volume / exact - 1.0))
    assert errors[-1] < 0.01 and errors[-1] < errors[0]


def test_vti_opens_with_vtk_and_holds_the_fields(tmp_path: Path, small_sac) -> None:
    helix = np.column_stack((np.cos(np.linspace(0, 12, 400)), np.sin(np.linspace(0, 12, 400)),
                             np.linspace(-1.0, 1.5, 400)))
    field = porous_field(np.asarray(small_sac.closed_surface.vertices), np.asarray(small_sac.closed_surface.faces),
                         [helix], [D_MM], 0.25)
    path = tmp_path / "porous.vti"
    write_porous_vti(path, field)
    assert [p.name for p in tmp_path.iterdir()] == ["porous.vti"]
    reader = vtkXMLImageDataReader()
    errors: list[str] = []
    reader.AddObserver("ErrorEvent", lambda _caller, event: errors.append(event))
    reader.SetFileName(str(path))
    reader.Update()
    assert not errors
    image = reader.GetOutput()
    assert image.GetDimensions() == tuple(n + 1 for n in field.shape)
    assert np.allclose(image.GetSpacing(), 0.25) and np.allclose(image.GetOrigin(), field.origin_mm)
    cells = image.GetCellData()
    read = {name: vtk_to_numpy(cells.GetArray(name)) for name in
            ("sac", "sac_fraction", "porosity", "permeability_mm2", "permeability_tensor_mm2")}
    assert np.array_equal(read["porosity"], vtk_order(field.porosity))
    assert np.array_equal(read["sac"], vtk_order(field.sac.astype(np.uint8)))
    no_coil = read["porosity"] == 1.0
    tensor = vtk_order(field.permeability_tensor_mm2()).reshape(-1, 9)
    assert np.array_equal(read["permeability_tensor_mm2"][~no_coil], tensor[~no_coil])
    assert np.isnan(read["permeability_tensor_mm2"][no_coil]).all() and np.isinf(tensor[no_coil]).all()
    cell = image.ComputeCellId([3, 5, 7])  # voxel (i, j, k) = (3, 5, 7)
    assert read["porosity"][cell] == field.porosity[3, 5, 7]
    assert read["sac"].sum() > 0 and np.isnan(read["permeability_mm2"][no_coil]).all()
    assert np.isfinite(read["permeability_mm2"][~no_coil]).all()
    assert image.GetFieldData().GetAbstractArray("units").GetValue(0) == "mm"


def vtk_order(values: np.ndarray) -> np.ndarray:
    """(nx, ny, nz, ...) → VTK cell order (x fastest)."""
    return np.moveaxis(values, (0, 1, 2), (2, 1, 0)).reshape((-1,) + values.shape[3:])
