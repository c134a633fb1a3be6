"""Anatomy: the wall, the sac cut at the neck, and the catheter placed at it (mm).

Scene → anatomy → model: read once per wall and neck, shared by every deployment
of them (one wall mesh and BVH for an ensemble).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np

from .model import default_director
from .orientation import anatomy_normal, tip_axis, turned
from .sac import (NeckError, Sac, catheter_from_neck, in_other_piece, neck_from_contour, neck_from_plane,
                  sac_from_neck, side_in_doubt)
from .settings import CatheterSpec, Scene
from .scene import SceneError
from .wall import WallError, WallMesh, load_wall


@dataclass
class Anatomy:
    """The wall and, with a [neck], the sac it closes off; the catheter as placed."""

    wall: WallMesh | None
    sac: Sac | None
    catheter: CatheterSpec
    balloon: tuple | None = None  # (stations mm, capped radii mm), warpcoil.devices.balloon_geometry
    stent: tuple | None = None  # (strut starts, ends mm, strut radius mm), warpcoil.devices.stent_struts

    @property
    def sac_volume_mm3(self) -> float | None:
        if self.sac is not None:
            return self.sac.volume_mm3
        return self.wall.volume_mm3 if self.wall is not None else None

    def roll_reference(self) -> np.ndarray | None:
        """The direction normal to the catheter at its tip from which the coil's roll about it is counted
        (unit): the one the wall defines (orientation.anatomy_normal: it turns with the scene), turned by
        ``catheter.roll_deg``; None (the model's default roll) where the wall defines none and roll_deg is 0.
        (A curved catheter's roll is the least-energy one: catheter_roll.packed_rolls.)"""
        axis = tip_axis(self.catheter)
        wall = self.wall
        reference = anatomy_normal(axis, None if wall is None else wall.vertices_mm,
                                   None if wall is None else wall.faces, np.asarray(self.catheter.tip_mm))
        if reference is None:
            if self.catheter.roll_deg == 0.0:
                return None
            reference = default_director(-axis)  # (the coil's first edge points back into the catheter)
        return turned(reference, axis, self.catheter.roll_deg)


def resolve_anatomy(scene: Scene) -> Anatomy:
    """Read the wall, cut the sac at the neck, and place the catheter (MODEL.md, Deployment)."""
    wall, sac = _wall_and_sac(scene)
    balloon, stent = _devices(scene, wall)
    return Anatomy(wall=wall, sac=sac, catheter=_placed_catheter(scene, wall, sac), balloon=balloon, stent=stent)


def _wall_and_sac(scene: Scene) -> tuple[WallMesh | None, Sac | None]:
    """The scene's wall mesh and the sac its neck cuts off (None without them); errors name the scene's keys."""
    try:
        wall = load_wall(scene.wall) if scene.wall is not None else None
    except WallError as error:  # the mesh's own problem, said with the scene file and key that name it
        raise WallError(f"{scene.where}: wall.mesh: {error}") from None
    if scene.neck is None:
        return wall, None
    hint = None if scene.neck.sac_point_mm is None else np.asarray(scene.neck.sac_point_mm)
    key = "neck.contour" if scene.neck.contour is not None else "neck.plane_point_mm / plane_normal"
    try:
        if scene.neck.contour is not None:
            neck = neck_from_contour(scene.neck.contour, wall, sac_side_point_mm=hint)
        else:
            neck = neck_from_plane(np.asarray(scene.neck.plane_point_mm), np.asarray(scene.neck.plane_normal),
                                   wall, sac_side_point_mm=hint)
        return wall, sac_from_neck(wall, neck)
    except NeckError as error:  # one line naming the scene and its key (exit 2), not a traceback
        raise SceneError(f"{scene.where}: {'neck.sac_point_mm' if error.sac_point else key}: {error}") from None


def _placed_catheter(scene: Scene, wall: WallMesh | None, sac: Sac | None) -> CatheterSpec:
    """The scene's catheter with its tip and direction (placed at the neck, or as given). An explicit tip in
    the piece of the lumen the neck did not take as the sac, where only the pieces' sizes told the sac's side
    and the other piece is not small (sac.side_in_doubt), is a SceneError naming neck.sac_point_mm."""
    catheter = scene.catheter
    if catheter.placement == "neck":
        normal = sac.neck.normal / np.linalg.norm(sac.neck.normal)
        reference = anatomy_normal(normal, wall.vertices_mm, wall.faces, sac.neck.centroid_mm)  # (turns with the wall)
        tip, direction = catheter_from_neck(sac, catheter.depth_mm, catheter.angle_deg, catheter.azimuth_deg,
                                            reference)
        return replace(catheter, tip_mm=tuple(map(float, tip)), direction=tuple(map(float, direction)))
    if side_in_doubt(sac) and in_other_piece(sac, wall, np.asarray(catheter.tip_mm, dtype=np.float64)):
        raise SceneError(
            f"{scene.where}: neck.sac_point_mm: the neck cuts the lumen into two pieces and the wall has no flat "
            f"vessel cap to tell which is the sac, so the larger ({sac.volume_mm3:.4g} mm³) would be taken; "
            f"catheter.tip {list(map(float, catheter.tip_mm))} mm lies in the other "
            f"({sac.neck.other_volume_mm3:.4g} mm³); fix: give neck.sac_point_mm, a point inside the sac (e.g. the "
            "tip, if it is in the sac)")
    return catheter


def _devices(scene: Scene, wall: WallMesh | None) -> tuple[tuple | None, tuple | None]:
    """The scene's balloon (stations, capped radii) and stent (strut starts, ends, radius), fitted to the wall."""
    from .devices import balloon_geometry, stent_struts

    balloon = balloon_geometry(scene.balloon, wall, str(scene.source)) if scene.balloon is not None else None
    stent = None
    if scene.stent is not None:
        stent = (*stent_struts(scene.stent, wall, str(scene.source)), 0.5 * scene.stent.strut_diameter_mm)
    return balloon, stent


def resolve_anatomies(scenes: Sequence[Scene], shared: dict[tuple, tuple] | None = None) -> list[Anatomy]:
    """:func:`resolve_anatomy` for each scene; scenes with the same wall, neck and
    device share one wall mesh, sac and device (read, cut and fitted once, one BVH
    on the device); each places its own catheter. ``shared``: those already read by
    earlier calls (filled in), for scenes resolved one at a time."""
    shared = {} if shared is None else shared
    anatomies = []
    for scene in scenes:
        key = (repr(scene.wall), repr(scene.neck), repr(scene.balloon), repr(scene.stent))
        if key not in shared:
            wall, sac = _wall_and_sac(scene)
            shared[key] = (wall, sac, *_devices(scene, wall))
        wall, sac, balloon, stent = shared[key]
        anatomies.append(Anatomy(wall=wall, sac=sac, catheter=_placed_catheter(scene, wall, sac), balloon=balloon,
                                 stent=stent))
    return anatomies
