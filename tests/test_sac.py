"""Neck, sac, inside tests and regional density on synthetic walls built here (no shared data)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import trimesh

from warpcoil.sac import (
    NeckError,
    Sac,
    catheter_from_neck,
    herniated_length_mm,
    inside_sac,
    neck_from_contour,
    neck_from_plane,
    neck_frame,
    regional_density,
    sac_from_neck,
)
from warpcoil.wall import WallMesh, sphere_wall

RADIUS_MM = 5.0
UP = np.array([0.0, 0.0, 1.0])


def cap_volume(radius_mm: float, height_mm: float) -> float:
    return math.pi * height_mm**2 * (3.0 * radius_mm - height_mm) / 3.0


def wall_of(mesh: trimesh.Trimesh) -> WallMesh:
    if mesh.volume < 0.0:
        mesh.invert()
    return WallMesh(np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int32),
                    float(mesh.volume), (), None)


def revolution_wall(profile_rz: np.ndarray, sections: int = 64) -> WallMesh:
    """Surface of revolution about z of a profile from the bottom pole (r = 0) to the top pole (r = 0)."""
    rings = profile_rz[1:-1]
    theta = 2.0 * np.pi * np.arange(sections) / sections
    ring_xyz = np.stack((rings[:, :1] * np.cos(theta), rings[:, :1] * np.sin(theta),
                         np.broadcast_to(rings[:, 1:], (len(rings), sections))), axis=2).reshape(-1, 3)
    vertices = np.vstack(([0.0, 0.0, profile_rz[0, 1]], ring_xyz, [0.0, 0.0, profile_rz[-1, 1]]))
    j = np.arange(sections)
    ring = lambda k: 1 + k * sections + j  # noqa: E731
    ring_next = lambda k: 1 + k * sections + (j + 1) % sections  # noqa: E731
    faces = [np.column_stack((np.zeros(sections, dtype=int), ring_next(0), ring(0)))]
    for k in range(len(rings) - 1):  # a handful of rings
        faces.append(np.column_stack((ring(k), ring_next(k), ring_next(k + 1))))
        faces.append(np.column_stack((ring(k), ring_next(k + 1), ring(k + 1))))
    top = len(vertices) - 1
    faces.append(np.column_stack((np.full(sections, top), ring(len(rings) - 1), ring_next(len(rings) - 1))))
    mesh = trimesh.Trimesh(vertices, np.vstack(faces), process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent
    return wall_of(mesh)


# terminal-type aneurysm: a flat-capped parent vessel (r 1.5, z -20 .. -2) under a sphere (R 3)
SAC_R_MM, VESSEL_R_MM = 3.0, 1.5
SAC_CENTRE_Z = -2.0 + math.sqrt(SAC_R_MM**2 - VESSEL_R_MM**2)
NECK_Z = -1.9


@pytest.fixture(scope="module")
def vessel_wall() -> WallMesh:
    vessel_z = np.arange(-20.0, -2.0, 0.4)
    phi = np.linspace(math.asin(VESSEL_R_MM / SAC_R_MM), math.pi, 60)[:-1]
    profile = np.vstack((
        [[0.0, -20.0]],
        np.column_stack((np.full(len(vessel_z), VESSEL_R_MM), vessel_z)),
        np.column_stack((SAC_R_MM * np.sin(phi), SAC_CENTRE_Z - SAC_R_MM * np.cos(phi))),
        [[0.0, SAC_CENTRE_Z + SAC_R_MM]],
    ))
    return revolution_wall(profile)


@pytest.fixture(scope="module")
def sphere() -> WallMesh:
    return sphere_wall(2.0 * RADIUS_MM)


@pytest.fixture(scope="module")
def low_sac(sphere: WallMesh) -> Sac:
    """Sphere R 5 with the neck plane at z = -3: the sac is the big side above."""
    return sac_from_neck(sphere, neck_from_plane([0.0, 0.0, -3.0], UP, sphere))


@pytest.fixture(scope="module")
def small_sac() -> Sac:
    """Sphere R 3 with the neck plane at z = -2 (sac above, 104.7 mm³), for the voxel tests."""
    wall = sphere_wall(6.0)
    return sac_from_neck(wall, neck_from_plane([0.0, 0.0, -2.0], UP, wall))


def circle(radius_mm: float, z_mm: float, count: int = 200) -> np.ndarray:
    t = 2.0 * np.pi * np.arange(count) / count
    return np.column_stack((radius_mm * np.cos(t), radius_mm * np.sin(t), np.full(count, z_mm)))


# --- neck and sac -------------------------------------------------------------------
def test_plane_neck_on_sphere_gives_big_cap(low_sac: Sac) -> None:
    neck = low_sac.neck
    assert np.allclose(neck.normal, UP)
    assert np.allclose(neck.centroid_mm, [0.0, 0.0, -3.0], atol=1e-3)
    assert neck.area_mm2 == pytest.approx(math.pi * 4.0**2, rel=0.02)
    assert low_sac.closed_surface.is_watertight and low_sac.closed_surface.volume > 0.0
    assert low_sac.volume_mm3 == pytest.approx(cap_volume(RADIUS_MM, 8.0), rel=0.02)


def test_plane_neck_near_the_top_points_down(sphere: WallMesh) -> None:
    sac = sac_from_neck(sphere, neck_from_plane([0.0, 0.0, 3.0], UP, sphere))
    assert np.allclose(sac.neck.normal, -UP)
    assert sac.volume_mm3 == pytest.approx(cap_volume(RADIUS_MM, 8.0), rel=0.02)


def test_sac_side_point_chooses_the_small_cap(sphere: WallMesh) -> None:
    neck = neck_from_plane([0.0, 0.0, 3.0], -UP, sphere, sac_side_point_mm=[0.0, 0.0, 4.5])
    assert np.allclose(neck.normal, UP)
    assert sac_from_neck(sphere, neck).volume_mm3 == pytest.approx(cap_volume(RADIUS_MM, 2.0), rel=0.02)
    with pytest.raises(NeckError, match="neither"):
        neck_from_plane([0.0, 0.0, 3.0], UP, sphere, sac_side_point_mm=[0.0, 0.0, 9.0])


def test_capped_parent_vessel_is_not_the_sac(vessel_wall: WallMesh) -> None:
    """The vessel side is the larger volume but holds the flat inlet cap, so the sac is the dome."""
    for normal in (UP, -UP):
        sac = sac_from_neck(vessel_wall, neck_from_plane([0.0, 0.0, NECK_Z], normal, vessel_wall))
        assert np.allclose(sac.neck.normal, UP)
        expected = cap_volume(SAC_R_MM, SAC_R_MM + (SAC_CENTRE_Z - NECK_Z))
        assert sac.volume_mm3 == pytest.approx(expected, rel=0.02)
        assert vessel_wall.volume_mm3 - sac.volume_mm3 > sac.volume_mm3


def test_plane_neck_takes_the_loop_nearest_the_point(sphere: WallMesh) -> None:
    shifted = sphere.vertices_mm + [20.0, 0.0, 0.0]
    two = WallMesh(np.vstack((sphere.vertices_mm, shifted)), np.vstack((sphere.faces, sphere.faces + len(shifted))),
                   2.0 * sphere.volume_mm3, (), None)
    sac = sac_from_neck(two, neck_from_plane([20.0, 0.0, -3.0], UP, two))
    assert np.allclose(sac.neck.centroid_mm, [20.0, 0.0, -3.0], atol=1e-3)
    assert sac.volume_mm3 == pytest.approx(cap_volume(RADIUS_MM, 8.0), rel=0.02)


def test_contour_files_give_the_plane_sac(tmp_path: Path, sphere: WallMesh, low_sac: Sac) -> None:
    ring = circle(4.0, -3.0)
    csv = tmp_path / "neck.csv"
    csv.write_text("x,y,z\n" + "\n".join(",".join(f"{c:.9f}" for c in p) for p in ring) + "\n")
    vtk = tmp_path / "neck.vtk"
    vtk.write_text(
        "# vtk DataFile Version 3.0\nneck\nASCII\nDATASET POLYDATA\n"
        f"POINTS {len(ring)} double\n" + "\n".join(" ".join(f"{c:.9f}" for c in p) for p in ring)
        + f"\nPOLYGONS 1 {len(ring) + 1}\n{len(ring)} " + " ".join(map(str, range(len(ring)))) + "\n"
    )
    for path in (csv, vtk):
        neck = neck_from_contour(path, sphere)
        assert neck.contour_mm.shape == (200, 3)
        assert np.allclose(neck.normal, UP)
        assert neck.area_mm2 == pytest.approx(low_sac.neck.area_mm2, rel=0.01)
        assert sac_from_neck(sphere, neck).volume_mm3 == pytest.approx(low_sac.volume_mm3, rel=0.01)


ARC = circle(4.0, -3.0)[:60]


@pytest.mark.parametrize(
    ("name", "text", "problem"),
    [
        ("missing.csv", None, "does not exist"),
        ("neck.stl", "solid x\n", "unsupported"),
        ("two_columns.csv", "1 2\n3 4\n5 6\n", "expected 3"),
        ("far.csv", "\n".join(" ".join(map(str, p)) for p in circle(4.0, -3.0) + [100.0, 0.0, 0.0]), "from the wall"),
        ("points_only.vtk", "# vtk DataFile Version 3.0\nn\nASCII\nDATASET POLYDATA\nPOINTS 1 double\n0 0 0\n",
         "no polygon or polyline"),
        ("arc.csv", "\n".join(" ".join(map(str, p)) for p in ARC), "segment 59"),
        ("there_and_back.csv", "\n".join(" ".join(map(str, p)) for p in np.vstack((ARC, ARC[-2:0:-1]))),
         "single piece"),
    ],
)
def test_bad_contour_files_raise_neck_error_naming_the_file(
    tmp_path: Path, sphere: WallMesh, name: str, text: str | None, problem: str
) -> None:
    path = tmp_path / name
    if text is not None:
        path.write_text(text)
    with pytest.raises(NeckError, match=problem) as caught:
        neck_from_contour(path, sphere)
    assert str(path) in str(caught.value) and "fix:" in str(caught.value)


# --- where things lie ------------------------------------------------------------------
def test_inside_sac_above_and_below_the_neck(low_sac: Sac) -> None:
    points = np.array([[0.0, 0.0, 0.0], [1.0, 1.0, -2.5], [0.0, 0.0, 4.9], [0.0, 0.0, -3.5], [1.0, 0.0, -4.5],
                       [0.0, 0.0, 5.5], [9.0, 0.0, 0.0]])
    assert inside_sac(low_sac, points).tolist() == [True, True, True, False, False, False, False]


def test_herniated_length_counts_the_parent_vessel_part(vessel_wall: WallMesh) -> None:
    sac = sac_from_neck(vessel_wall, neck_from_plane([0.0, 0.0, NECK_Z], UP, vessel_wall))
    z = np.arange(-6.0, 2.0, 0.1) + 0.05  # 41 nodes below the neck plane, 39 above
    nodes = np.column_stack((np.full(len(z), 0.3), np.zeros(len(z)), z))
    lengths = np.full(len(z), 0.1)
    assert herniated_length_mm(sac, vessel_wall, nodes, lengths) == pytest.approx(4.1, abs=1e-9)
    outside = nodes + [10.0, 0.0, 0.0]  # outside the lumen: not herniated
    assert herniated_length_mm(sac, vessel_wall, outside, lengths) == 0.0


def test_catheter_from_neck_tip_and_tilt(low_sac: Sac) -> None:
    tip, direction = catheter_from_neck(low_sac, depth_mm=0.5)
    assert np.allclose(tip, [0.0, 0.0, -2.5], atol=1e-3) and inside_sac(low_sac, tip[None])[0]
    assert np.allclose(direction, UP)
    e1, e2, n = neck_frame(low_sac.neck.normal)
    for azimuth, towards in ((0.0, e1), (90.0, e2)):
        _, tilted = catheter_from_neck(low_sac, angle_deg=30.0, azimuth_deg=azimuth)
        assert math.degrees(math.acos(tilted @ n)) == pytest.approx(30.0)
        assert tilted @ towards == pytest.approx(math.sin(math.radians(30.0)))


# --- regional density -------------------------------------------------------------------
D_MM = 0.3


def test_coil_outside_the_sac_fills_nothing(small_sac: Sac) -> None:
    far = np.array([[10.0, 0.0, 0.0], [12.0, 0.0, 0.0]])
    result = regional_density(small_sac, [far], [D_MM])
    assert (result.neck, result.boundary, result.core, result.total_voxel, result.neck_coverage) == (0, 0, 0, 0, 0)
    assert (result.voxel_mm, result.neck_band_mm, result.boundary_mm) == pytest.approx((D_MM / 4, 4 * D_MM, 2 * D_MM))


def test_straight_coil_through_the_core_counts_only_in_core(small_sac: Sac) -> None:
    segment = np.array([[-1.0, 0.0, 0.5], [1.0, 0.0, 0.5]])
    result = regional_density(small_sac, [segment], [D_MM])
    assert result.core > 0.0 and result.neck == 0.0 and result.boundary == 0.0 and result.neck_coverage == 0.0


def test_voxel_density_approaches_the_clinical_packing_density(small_sac: Sac) -> None:
    """Nested helices 0.45 mm apart (no overlap): voxel total within 15 % of π(d/2)²L/V."""
    t = np.linspace(0.0, 10.0 * 2.0 * np.pi, 1000)
    coils = []
    for radius in (0.5, 0.95, 1.4, 1.85):
        coils.append(np.column_stack((radius * np.cos(t), radius * np.sin(t), -1.0 + 3.0 * t / t[-1])))
    length = sum(np.linalg.norm(np.diff(c, axis=0), axis=1).sum() for c in coils)
    result = regional_density(small_sac, coils, [D_MM] * len(coils))
    clinical = math.pi * (D_MM / 2) ** 2 * length / small_sac.volume_mm3
    assert result.total_voxel == pytest.approx(clinical, rel=0.15)


def test_coil_mat_across_the_ostium_covers_the_neck(small_sac: Sac) -> None:
    rows = np.arange(-3.0, 3.0 + 1e-9, 0.15)
    ends = np.where(np.arange(len(rows)) % 2 == 0, -3.0, 3.0)
    mat = np.column_stack((np.column_stack((ends, -ends)).ravel(), np.repeat(rows, 2), np.full(2 * len(rows), -1.95)))
    result = regional_density(small_sac, [mat], [D_MM])
    assert result.neck_coverage >= 0.999
    assert result.neck > 0.0 and result.core == 0.0


def test_a_sac_point_in_neither_piece_names_the_scenes_neck_sac_point_key(tmp_path):
    """Through a scene, a sac-side point outside both pieces the neck cuts is an error naming
    neck.sac_point_mm, and a plane beside the wall one naming the plane keys."""
    from warpcoil.anatomy import resolve_anatomy
    from warpcoil.scene import SceneError, load_scene

    path = tmp_path / "s.toml"
    base = ('[wall]\nsphere_diameter_mm = 3.5\n[[coil]]\nwire_diameter_mm = 0.3\nloop_diameter_mm = 3\n'
            'length_mm = 10\n[neck]\nplane_normal = [0.0, 0.0, 1.0]\n')
    for neck, key in (('plane_point_mm = [0.0, 0.0, 1.0]\nsac_point_mm = [0.0, 0.0, 9.0]\n', "neck.sac_point_mm"),
                      ('plane_point_mm = [0.0, 0.0, 9.0]\n', "neck.plane_point_mm / plane_normal")):
        path.write_text(base + neck)
        with pytest.raises(SceneError, match=rf"s\.toml: {key}: .*fix:"):
            resolve_anatomy(load_scene(path))


def test_a_neck_plane_along_a_flat_part_of_the_wall_is_refused() -> None:
    """A plane lying on a flat part of the wall (a helper's duct roof, here a box's top) has no
    defined cut there: "on the plane counts as above" traced its rounding across the roof into an
    ostium 4.5× too large with no word. It is refused, naming the fix; a plane across the sides cuts."""
    box = wall_of(trimesh.creation.box(extents=(4.0, 4.0, 2.0)).subdivide().subdivide().subdivide())
    with pytest.raises(NeckError, match=r"lies along 128 faces of a flat part of the wall.*fix: move the plane point"):
        neck_from_plane([0.0, 0.0, 1.0], UP, box)
    loop = neck_from_plane([0.0, 0.0, 0.1], UP, box).contour_mm
    assert np.allclose(loop[:, 2], 0.1) and np.abs(loop[:, :2]).max() == pytest.approx(2.0)


def test_a_flat_part_far_from_the_neck_in_the_same_plane_does_not_refuse_it(sphere: WallMesh) -> None:
    """Only flat faces within the loop's reach count: a sphere beside a box whose top lies in the
    neck plane, 20 mm away, cuts as the sphere alone does."""
    far_box = trimesh.creation.box(extents=(2.0, 2.0, 2.0))
    far_box.apply_translation([20.0, 0.0, -3.0 - 1.0])  # its top in the plane z = −3
    both = trimesh.util.concatenate([trimesh.Trimesh(sphere.vertices_mm, sphere.faces), far_box])
    alone = neck_from_plane([0.0, 0.0, -3.0], UP, sphere).contour_mm
    beside = neck_from_plane([0.0, 0.0, -3.0], UP, wall_of(both)).contour_mm
    assert np.allclose(np.sort(alone, axis=0), np.sort(beside, axis=0))


def test_a_sac_side_that_only_the_pieces_sizes_tell_is_refused_against_the_tip_or_warned(tmp_path):
    """A sphere sac on a rounded duct (no flat vessel cap) cut in its neck: the duct is the larger
    piece, which rule 3 took as the sac with no word (a helper's tube: everything "herniated", 0 %
    packing). An explicit tip in the smaller piece is refused (exit 2, naming neck.sac_point_mm, no
    output); a tip placed at the neck gets a warning; neck.sac_point_mm settles it."""
    from test_devices import sac_on_duct, warpcoil_run

    from warpcoil.anatomy import resolve_anatomies, resolve_anatomy
    from warpcoil.preflight import preflight
    from warpcoil.scene import SceneError, load_scene

    sac_on_duct(tmp_path / "duct.stl")
    base = ('[wall]\nmesh = "duct.stl"\n[neck]\nplane_point_mm = [0.0, 0.0, 2.0]\nplane_normal = [0.0, 0.0, 1.0]\n'
            '{point}[catheter]\n{catheter}\n[[coil]]\nwire_diameter_mm = 0.3\nloop_diameter_mm = 3\nlength_mm = 5\n')
    explicit = 'tip = [0.0, 0.0, 4.0]\ndirection = [0.0, 0.0, 1.0]'
    scene = tmp_path / "tip.toml"
    scene.write_text(base.format(point="", catheter=explicit))
    rc, text = warpcoil_run(scene, tmp_path / "o", tmp_path / "log.txt")
    assert rc == 2 and "neck.sac_point_mm" in text and "catheter.tip" in text and "fix:" in text, text
    assert not (tmp_path / "o").exists()

    sphere = 4.0 / 3.0 * math.pi * 3.0**3
    (tmp_path / "neck.toml").write_text(base.format(point="", catheter='placement = "neck"'))
    neck_scene = load_scene(tmp_path / "neck.toml")
    anatomy = resolve_anatomies([neck_scene])[0]  # (as a run resolves it: the placed tip, not a stand-in)
    assert anatomy.sac_volume_mm3 > 1.3 * sphere  # the duct, taken by size
    assert any("no flat vessel cap" in w and "neck.sac_point_mm" in w for w in preflight(neck_scene, anatomy))
    (tmp_path / "point.toml").write_text(base.format(point="sac_point_mm = [0.0, 0.0, 5.0]\n", catheter=explicit))
    point_scene = load_scene(tmp_path / "point.toml")
    anatomy = resolve_anatomy(point_scene)
    assert anatomy.sac_volume_mm3 == pytest.approx(sphere, rel=0.1)  # the sphere (and the neck's upper part)
    assert not any("no flat vessel cap" in w for w in preflight(point_scene, anatomy))
    # every member of a sweep checks its own tip; a tip in a small other piece (a sac-only wall's neck stub) is no doubt
    (tmp_path / "in_sac.toml").write_text(base.format(point="", catheter=explicit.replace("4.0]", "-0.5]")))
    with pytest.raises(SceneError, match="neck.sac_point_mm"):
        resolve_anatomies([load_scene(tmp_path / "in_sac.toml"), load_scene(tmp_path / "tip.toml")])
    (tmp_path / "stub.toml").write_text('[wall]\nsphere_diameter_mm = 8.0\n[neck]\nplane_point_mm = [0.0, 0.0, -3.0]\n'
                                        'plane_normal = [0.0, 0.0, 1.0]\n[catheter]\ntip = [0.0, 0.0, -3.3]\n'
                                        'direction = [0.0, 0.0, 1.0]\n[[coil]]\nwire_diameter_mm = 0.3\n'
                                        'loop_diameter_mm = 3\nlength_mm = 5\n')
    assert resolve_anatomies([load_scene(tmp_path / "stub.toml")])[0].sac_volume_mm3 > 200.0


@pytest.mark.parametrize("height_mm", [1.2, 0.3])
def test_a_coarse_wall_is_cut_on_its_contour(height_mm):
    """The cut gives whole faces to a side: on a wall whose faces are long next to the ostium (an 80-face
    icosphere, edges 1.3 mm across a 4.4 mm ostium; a CAD mesh's slivers) they are split first, and the
    sac is the polyhedron's part above the plane (its exact volume: the convex hull of the vertices above
    and the plane's crossings of the edges). Unsplit, this wall was refused ("leaves a single piece")."""
    from scipy.spatial import ConvexHull

    sphere = trimesh.creation.icosphere(subdivisions=1, radius=2.5)
    wall = WallMesh(np.asarray(sphere.vertices, float), np.asarray(sphere.faces, np.int32), float(sphere.volume),
                    (), None)
    v, f = wall.vertices_mm, wall.faces
    edges = np.unique(np.sort(np.stack((f, np.roll(f, -1, 1)), 2).reshape(-1, 2), 1), axis=0)
    z = v[:, 2] - height_mm
    crossing = edges[(z[edges[:, 0]] >= 0) != (z[edges[:, 1]] >= 0)]
    t = z[crossing[:, 0]] / (z[crossing[:, 0]] - z[crossing[:, 1]])
    points = np.vstack((v[z >= 0], v[crossing[:, 0]] + t[:, None] * (v[crossing[:, 1]] - v[crossing[:, 0]])))
    neck = neck_from_plane([0.0, 0.0, height_mm], [0.0, 0.0, 1.0], wall, sac_side_point_mm=[0.0, 0.0, height_mm + 0.3])
    assert sac_from_neck(wall, neck).volume_mm3 == pytest.approx(ConvexHull(points).volume, rel=5e-3)


def test_a_fan_of_slivers_is_no_vessel_cap():
    """A vessel cap is a flat disc around a hub: a flat fan of 12 slivers 4 mm long spanning 2° (0.25 mm², a
    CAD mesh's hub where a tube meets a dome) spans 0.56 mm as a disc, not its 8 mm reach; a full fan of 1 mm
    radius is a cap."""
    from warpcoil.sac import _caps

    def fan(radius_mm: float, span_rad: float, offset: int) -> tuple[np.ndarray, np.ndarray]:
        angles = np.linspace(0.0, span_rad, 13)[: 12 if span_rad >= 2 * math.pi else 13]
        rim = np.column_stack((radius_mm * np.cos(angles), radius_mm * np.sin(angles), np.zeros(len(angles))))
        count = len(rim)
        ring = [(0, 1 + k, 1 + (k + 1) % count) for k in range(count if span_rad >= 2 * math.pi else count - 1)]
        return np.vstack(([0.0, 0.0, 0.0], rim)), np.asarray(ring) + offset

    disc_v, disc_f = fan(1.0, 2 * math.pi, 0)
    sliver_v, sliver_f = fan(4.0, math.radians(2.0), len(disc_v))
    sliver_v += [10.0, 0.0, 0.0]
    wall = WallMesh(np.vstack((disc_v, sliver_v)), np.vstack((disc_f, sliver_f)).astype(np.int32), 0.0, (), None)
    cap_of_face, areas, hubs = _caps(wall, 1.0)
    assert list(hubs) == [0] and areas[0] == pytest.approx(12 * 0.5 * math.sin(2 * math.pi / 12))
    assert (cap_of_face[: len(disc_f)] == 0).all() and (cap_of_face[len(disc_f):] == -1).all()
