"""porous.vti: the sac as a porous medium (docs/POROUS.md), VTK XML ImageData, written atomically.

Cell data, one value per voxel: ``sac`` (uint8 mask), ``sac_fraction``, ``porosity``,
``permeability_mm2`` and ``permeability_tensor_mm2`` (9 components, row-major);
field data ``units`` = "mm". Where a voxel holds no coil (porosity 1) there is no porous
medium and the permeabilities, +inf in :class:`~warpcoil.porous.PorousField`, are stored as
NaN: VTK's XML readers cannot parse the infinite value ranges the writer would record.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..porous import PorousField
from .atomic import atomic_path

POROUS_VTI = "porous.vti"


def _cells(values: np.ndarray, components: int = 1) -> np.ndarray:
    """(nx, ny, nz[, c]) → VTK's cell order (x fastest), (cells, c)."""
    nx, ny, nz = values.shape[:3]
    return np.ascontiguousarray(values.reshape(nx, ny, nz, components).transpose(2, 1, 0, 3).reshape(-1, components))


def _nan_for_inf(values: np.ndarray) -> np.ndarray:
    return np.where(np.isinf(values), np.nan, values)


def porous_image(field: PorousField):
    """The field as vtkImageData: voxels are cells, the origin is voxel (0, 0, 0)'s corner
    (VTK imported here: only a run that writes porous.vti needs it)."""
    from vtkmodules.util.numpy_support import numpy_to_vtk
    from vtkmodules.vtkCommonCore import vtkStringArray
    from vtkmodules.vtkCommonDataModel import vtkImageData

    image = vtkImageData()
    image.SetDimensions(*(n + 1 for n in field.shape))
    image.SetOrigin(*field.origin_mm)
    image.SetSpacing(field.voxel_mm, field.voxel_mm, field.voxel_mm)
    arrays = {
        "sac": _cells(field.sac.astype(np.uint8)),
        "sac_fraction": _cells(field.sac_fraction),
        "porosity": _cells(field.porosity),
        "permeability_mm2": _cells(_nan_for_inf(field.permeability_mm2())),
        "permeability_tensor_mm2": _cells(_nan_for_inf(field.permeability_tensor_mm2()).reshape(field.shape + (9,)),
                                          9),
    }
    for name, values in arrays.items():
        array = numpy_to_vtk(values if values.shape[1] > 1 else values[:, 0], deep=True)
        array.SetName(name)
        image.GetCellData().AddArray(array)
    units = vtkStringArray()
    units.SetName("units")
    units.InsertNextValue("mm")
    image.GetFieldData().AddArray(units)
    return image


def write_porous_vti(path: Path, field: PorousField) -> None:
    """Write ``field`` to ``path`` (binary, zlib-compressed VTK XML ImageData), all or nothing."""
    from vtkmodules.vtkIOXML import vtkXMLImageDataWriter

    with atomic_path(Path(path)) as tmp_path:
        writer = vtkXMLImageDataWriter()
        writer.SetFileName(str(tmp_path))
        writer.SetInputData(porous_image(field))
        writer.SetDataModeToBinary()
        writer.SetCompressorTypeToZLib()
        if writer.Write() != 1:
            raise OSError(f"VTK could not write {tmp_path}")
