"""The coil length outside the sac (``length_outside_sac_mm``) is the deployed centre line's length past the
sac's surface, each edge split where it crosses it, not the node shares of the nodes outside (which read low
by up to a segment: 0.601 mm reported for 0.779 mm below a neck plane)."""

from types import SimpleNamespace

import numpy as np
import pytest

import warpcoil as wc
from warpcoil.deploy import Deployment
from warpcoil.geometry import lengths_outside
from warpcoil.measure import Frame, Snapshot, measure_frame
from warpcoil.sac import neck_from_plane, sac_from_neck, sac_surface
from warpcoil.settings import NeckSpec
from warpcoil.wall import sphere_wall

Z_NECK = -1.2  # mm: the neck plane of a 3.5 mm sphere; the sac is above it


def length_below(points_mm: np.ndarray, z_mm: float) -> float:
    """The polyline's length below the plane z = ``z_mm`` (mm), each edge clipped at its crossing."""
    a, b = points_mm[:-1], points_mm[1:]
    length = np.linalg.norm(b - a, axis=1)
    za, zb = a[:, 2] - z_mm, b[:, 2] - z_mm
    below = ((za < 0) & (zb < 0)).astype(float)
    cross = (za < 0) != (zb < 0)
    below[cross] = -np.minimum(za, zb)[cross] / np.abs(za - zb)[cross]
    return float((below * length).sum())


def test_segments_are_split_at_the_neck_plane():
    """Sphere R 3 cut at z = -2: a tilted polyline of uneven edges crossing the neck counts exactly its length
    below the plane, and a segment wholly inside or wholly below counts none or all of itself."""
    wall = sphere_wall(6.0)
    surface = sac_surface(sac_from_neck(wall, neck_from_plane([0.0, 0.0, -2.0], [0.0, 0.0, 1.0], wall)))
    z = np.array([-2.9, -2.55, -2.13, -1.71, -1.22, -0.4])
    line = np.column_stack((0.1 + 0.2 * (z + 3.0), np.full(len(z), -0.2), z))
    k = np.arange(len(z) - 1)
    lengths = lengths_outside(surface, line, k, k + 1)
    assert lengths.sum() == pytest.approx(length_below(line, -2.0), abs=1e-4)
    assert lengths == pytest.approx(np.linalg.norm(line[1:] - line[:-1], axis=1) * [1, 1, 0.13 / 0.42, 0, 0],
                                    abs=1e-4)


def neck_deployment() -> Deployment:
    """A 10 mm and a 4 mm coil for a 3.5 mm sphere cut at z = Z_NECK."""
    return Deployment(wc.Scene(
        coils=(wc.CoilSpec(shape="helix", length_mm=10.0, loop_diameter_mm=2.5, pitch_mm=0.6),
               wc.CoilSpec(shape="helix", length_mm=4.0, loop_diameter_mm=2.0, pitch_mm=0.5)),
        catheter=wc.CatheterSpec(placement="neck", depth_mm=0.3), wall=wc.WallSpec(sphere_diameter_mm=3.5),
        neck=NeckSpec(plane_point_mm=(0.0, 0.0, Z_NECK), plane_normal=(0.0, 0.0, 1.0))))


def frame_of(deployment: Deployment, x: np.ndarray, free: np.ndarray, advance: np.ndarray) -> Frame:
    """The frame measure_frame reports for the member's nodes at ``x`` (mm), ``free`` and ``advance`` (mm)."""
    n = len(x)
    far = np.full(n, 1.0e3)  # wall gaps: the frame's other figures are not looked at
    snap = Snapshot(0.0, x, free.astype(np.int32), advance, far, np.zeros((n, 3)), far, np.zeros(n, np.int32), far)
    energies = {k: [0.0] for k in ("kinetic_nJ", "bend_nJ", "twist_nJ", "stretch_nJ")}
    return measure_frame(deployment.model, SimpleNamespace(coil_contact=False), deployment.members[0], snap,
                         energies, (0.0, 0.0, 0.0))


def test_a_frame_reports_the_centre_line_below_the_neck_to_the_crossing():
    """The first coil's nodes on a slanted straight line across the neck plane at their rest spacing: the frame
    reports the line's length below the plane, whatever the nodes' places; pushed out part way, the deployed line
    ends by arc length inside its edge into the catheter; the second coil (not yet out) counts nothing."""
    deployment = neck_deployment()
    model = deployment.model
    s = model.arc_s.numpy()
    first, last = int(model.coil_first[0]), int(model.coil_last[0])
    direction = np.array([0.6, 0.0, 0.8])
    x = np.zeros((len(s), 3))
    x[first:last + 1] = [0.0, 0.0, Z_NECK + 0.3] - s[first:last + 1, None] * direction  # tip up, going down
    x[last + 1:] = [5.0, 5.0, 5.0]  # the second coil: far off, in the catheter
    free = np.zeros(len(s), bool)
    coil_mm = s[last]
    for shift in (0.0, 0.07, 0.131, 0.2):
        moved = x + [0.0, 0.0, shift]
        free[first:last + 1] = True
        below = coil_mm - (0.3 + shift) / 0.8  # (the line crosses the plane (0.3 + shift) / 0.8 mm from its tip)
        frame = frame_of(deployment, moved, free, np.array([coil_mm, 0.0]))
        assert frame.length_outside_sac_mm == pytest.approx(below, abs=1e-4)
        pushed = 6.1  # mm: nodes up to s = 6.0 out, and a third of the next edge
        free[first:last + 1] = s[first:last + 1] <= pushed
        frame = frame_of(deployment, moved, free, np.array([pushed, 0.0]))
        assert frame.length_outside_sac_mm == pytest.approx(pushed - (0.3 + shift) / 0.8, abs=1e-4)


def test_a_coil_wholly_below_the_neck_reads_its_own_length():
    """The second coil straight down from below the neck at its rest spacing: outside the sac by its own length,
    not a segment more or less (node shares once gave 99.49 mm for a 99.31 mm coil)."""
    deployment = neck_deployment()
    model = deployment.model
    s = model.arc_s.numpy()
    first, last = int(model.coil_first[1]), int(model.coil_last[1])
    x = np.zeros((len(s), 3))
    x[:, 2] = -1.6 - s
    x[:first] = [0.0, 0.0, 0.5]  # the first coil in the sac
    free = np.ones(len(s), bool)
    frame = frame_of(deployment, x, free, s[[int(model.coil_last[0]), last]])
    assert frame.length_outside_sac_mm == pytest.approx(s[last], rel=1e-9)
