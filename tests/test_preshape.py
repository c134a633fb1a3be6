"""Geometry of the coil pre-shapes and the centerline file reader."""

from __future__ import annotations

import numpy as np
import pytest

from warpcoil.coil import CoilSpec
from warpcoil.preshape import (
    PreshapeError,
    from_file,
    helix,
    read_centerline,
    resample_equal_arc,
    rest_centerline,
    spherical_spiral,
)

D_WIRE = 0.2921  # reference wire (secondary) diameter d = l0, mm


def chords(points: np.ndarray) -> np.ndarray:
    return np.linalg.norm(np.diff(points, axis=0), axis=1)


def turning_angles(points: np.ndarray) -> np.ndarray:
    t = np.diff(points, axis=0)
    t /= np.linalg.norm(t, axis=1)[:, None]
    return np.arccos(np.clip((t[1:] * t[:-1]).sum(axis=1), -1.0, 1.0))


def non_neighbour_gap(points: np.ndarray, skip: int = 3) -> float:
    """Smallest distance between nodes more than ``skip`` segments apart along the coil."""
    distance = np.linalg.norm(points[:, None] - points[None, :], axis=2)
    i, j = np.indices(distance.shape)
    return float(distance[np.abs(i - j) > skip].min())


# --- helix -------------------------------------------------------------------


def test_helix_lies_on_its_cylinder_with_equal_arc_spacing_and_pitch():
    diameter, pitch, length, l0 = 3.0, 0.6, 60.0, D_WIRE
    points = helix(diameter, pitch, length, l0)
    n = round(length / l0)
    assert points.shape == (n + 1, 3) and points.dtype == np.float64
    np.testing.assert_allclose(points[0], [1.5, 0.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(np.hypot(points[:, 0], points[:, 1]), 1.5, rtol=0, atol=1e-12)

    angle = np.unwrap(np.arctan2(points[:, 1], points[:, 0]))
    step = np.diff(angle)
    np.testing.assert_allclose(step, step[0], rtol=0, atol=1e-12)  # uniform parameter = uniform arc
    np.testing.assert_allclose(chords(points), chords(points)[0], rtol=1e-12)
    np.testing.assert_allclose(points[:, 2], pitch * angle / (2 * np.pi), atol=1e-12)  # rise per turn
    turn_length = np.hypot(np.pi * diameter, pitch)
    assert angle[-1] / (2 * np.pi) * turn_length == pytest.approx(length, rel=1e-12)  # arc length L


def test_helix_refuses_fewer_than_two_segments():
    with pytest.raises(PreshapeError, match="two segments"):
        helix(3.0, 0.6, 0.4, D_WIRE)


# --- spherical spiral --------------------------------------------------------


@pytest.fixture(scope="module")
def reference_spiral() -> np.ndarray:
    return spherical_spiral(3.0, 60.0, D_WIRE, shrink=0.6, wire_diameter_mm=D_WIRE)


def test_spherical_spiral_radius_shrinks_monotonically_within_the_ball(reference_spiral):
    radius = np.linalg.norm(reference_spiral, axis=1)
    assert reference_spiral.shape == (round(60.0 / D_WIRE) + 1, 3)
    assert radius[0] == pytest.approx(1.5, abs=1e-12)
    assert radius[-1] == pytest.approx(0.6 * 1.5, abs=1e-12)
    assert np.all((radius >= 0.9 - 1e-12) & (radius <= 1.5 + 1e-12))
    assert np.all(np.diff(radius) <= 1e-12)


def test_spherical_spiral_is_sampled_at_equal_arc_length_of_one_curve(reference_spiral):
    n = len(reference_spiral) - 1
    c = chords(reference_spiral)
    assert np.all((c <= 60.0 / n * (1 + 1e-9)) & (c >= 0.99 * 60.0 / n))
    # The same curve sampled four times finer passes through the same nodes
    # and its polyline is (to second order) the curve's length.
    fine = spherical_spiral(3.0, 60.0, 60.0 / (4 * n), shrink=0.6, wire_diameter_mm=D_WIRE)
    assert len(fine) == 4 * n + 1
    np.testing.assert_allclose(fine[::4], reference_spiral, atol=1e-6)
    assert chords(fine).sum() == pytest.approx(60.0, rel=2e-4)


def test_spherical_spiral_is_smooth_and_keeps_its_turns_apart(reference_spiral):
    assert turning_angles(reference_spiral).max() < 0.35
    assert non_neighbour_gap(reference_spiral) >= D_WIRE


@pytest.mark.parametrize(
    ("diameter", "length", "shrink"),
    [(2.0, 20.0, 0.6), (5.0, 150.0, 0.6), (10.0, 400.0, 0.6), (4.0, 100.0, 0.8), (20.0, 10.0, 0.6)],
)
def test_spherical_spiral_other_sizes(diameter, length, shrink):
    points = spherical_spiral(diameter, length, D_WIRE, shrink=shrink, wire_diameter_mm=D_WIRE)
    radius = np.linalg.norm(points, axis=1)
    assert points.shape == (round(length / D_WIRE) + 1, 3)
    assert radius.max() <= diameter / 2 + 1e-12 and radius.min() >= shrink * diameter / 2 - 1e-12
    assert np.all(np.diff(radius) <= 1e-12)
    curvature = turning_angles(points) / (length / (len(points) - 1))
    assert curvature.max() <= 3.0 / (diameter / 2)
    assert non_neighbour_gap(points) >= D_WIRE


def principal_extent(points: np.ndarray) -> float:
    """Largest extent of the points along their principal axes."""
    centred = points - points.mean(axis=0)
    along = centred @ np.linalg.svd(centred, full_matrices=False)[2].T
    return float((along.max(axis=0) - along.min(axis=0)).max())


@pytest.mark.parametrize(
    ("diameter", "length", "shrink"),
    [(3.0, 15.0, 0.6), (5.0, 25.0, 0.6), (6.0, 60.0, 0.6), (10.0, 150.0, 0.6), (2.0, 20.0, 0.6), (3.0, 60.0, 0.6),
     (4.0, 40.0, 0.6), (6.0, 150.0, 0.6), (10.0, 300.0, 0.6), (2.0, 6.3, 0.6), (2.0, 27.0, 0.6), (3.0, 9.5, 0.6),
     (3.0, 18.0, 0.6), (3.0, 77.0, 0.6), (4.0, 12.6, 0.6), (4.0, 196.0, 0.6), (6.0, 19.0, 0.6), (6.0, 36.0, 0.6),
     (10.0, 31.5, 0.6), (10.0, 60.0, 0.6), (2.0, 20.0, 0.8), (3.0, 12.0, 0.8), (3.0, 30.0, 0.8)],
)
def test_spherical_spiral_spans_its_loop_diameter(diameter, length, shrink):
    """From one loop (πD) up to the longest that fits, the first turns frame a ball of the loop diameter
    (a single sweep shrinking from the pole's side to the equator spanned only 0.71 D; at shrink 0.8 a
    2–3 mm ball holds no dive, and its one sweep now keeps D/2 to the equator), with the turns kept apart
    and the length exact."""
    points = spherical_spiral(diameter, length, D_WIRE, shrink=shrink, wire_diameter_mm=D_WIRE)
    assert principal_extent(points) >= 0.95 * diameter
    radius = np.linalg.norm(points, axis=1)
    assert radius[0] == pytest.approx(diameter / 2, abs=1e-12)
    assert radius[-1] == pytest.approx(shrink * diameter / 2, abs=1e-12)
    assert np.all(np.diff(radius) <= 1e-12)
    n = len(points) - 1
    assert n == round(length / D_WIRE) and np.all(chords(points) <= length / n * (1 + 1e-9))
    fine = spherical_spiral(diameter, length, D_WIRE / 8, shrink=shrink, wire_diameter_mm=D_WIRE)
    assert chords(fine).sum() == pytest.approx(length, rel=5e-4)  # the curve is length_mm long
    assert non_neighbour_gap(points) >= D_WIRE


def test_spherical_spiral_too_long_for_its_ball_is_refused():
    with pytest.raises(PreshapeError, match="does not fit"):
        spherical_spiral(2.0, 100.0, D_WIRE, wire_diameter_mm=D_WIRE)


# --- centerline files --------------------------------------------------------

POLYLINE = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 2.0, 0.0], [1.0, 2.0, 1.5]])


def test_read_centerline_text_csv_and_npy(tmp_path):
    txt = tmp_path / "shape.txt"
    txt.write_text("# coil centerline, mm\n\n" + "\n".join(" ".join(map(str, p)) for p in POLYLINE) + "\n")
    csv = tmp_path / "shape.csv"
    csv.write_text("x,y,z\n" + "\n".join(", ".join(map(str, p)) for p in POLYLINE) + "\n")
    npy = tmp_path / "shape.npy"
    np.save(npy, POLYLINE)
    for path in (txt, csv, npy):
        points = read_centerline(path)
        assert points.dtype == np.float64
        np.testing.assert_array_equal(points, POLYLINE)


@pytest.mark.parametrize(
    ("name", "text", "where"),
    [
        ("nan.txt", "0 0 0\n1 0 0\n1 nan 0\n", "line 3"),
        ("dup.txt", "0 0 0\n1 0 0\n1 0 0\n2 0 0\n", "line 2"),
        ("one.txt", "# one point\n0 0 0\n", "at least 2"),
        ("cols.csv", "x,y,z\n0,0,0\n1,0\n", "line 3"),
        ("word.txt", "0 0 0\n1 zero 0\n", "line 2"),
    ],
)
def test_read_centerline_errors_name_the_file_and_the_place(tmp_path, name, text, where):
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises(PreshapeError) as err:
        read_centerline(path)
    assert name in str(err.value) and where in str(err.value)


def test_read_centerline_npy_of_wrong_shape(tmp_path):
    path = tmp_path / "flat.npy"
    np.save(path, np.zeros((4, 2)))
    with pytest.raises(PreshapeError, match="flat.npy"):
        read_centerline(path)


def test_resample_equal_arc_evens_out_an_uneven_polyline():
    uneven = np.array([[0, 0, 0], [0.1, 0, 0], [0.95, 0, 0], [1, 0, 0], [1, 0.3, 0], [1, 2, 0]], dtype=float)
    points = resample_equal_arc(uneven, 6)
    expected = [[0, 0, 0], [0.5, 0, 0], [1, 0, 0], [1, 0.5, 0], [1, 1, 0], [1, 1.5, 0], [1, 2, 0]]
    np.testing.assert_allclose(points, expected, atol=1e-14)
    line = resample_equal_arc(np.array([[0, 0, 0], [0.2, 0, 0], [3, 0, 0]], dtype=float), 5)
    np.testing.assert_allclose(chords(line), 0.6, rtol=1e-14)
    np.testing.assert_array_equal(line[[0, -1]], [[0, 0, 0], [3, 0, 0]])


def test_from_file_resamples_the_files_curve(tmp_path):
    path = tmp_path / "shape.npy"
    np.save(path, POLYLINE)  # 4.5 mm long
    points = from_file(path, 4.5, 0.5)
    assert points.shape == (10, 3)
    np.testing.assert_array_equal(points[[0, -1]], POLYLINE[[0, -1]])
    np.testing.assert_allclose(resample_equal_arc(POLYLINE, 9), points)


def test_from_file_length_mismatch_and_too_short(tmp_path):
    path = tmp_path / "shape.txt"
    np.savetxt(path, POLYLINE)
    with pytest.raises(PreshapeError) as err:
        from_file(path, 4.6, 0.5)
    assert "shape.txt" in str(err.value) and "4.5 mm" in str(err.value) and "4.6 mm" in str(err.value)
    with pytest.raises(PreshapeError, match="shape.txt.*two segments"):
        from_file(path, 4.5, 4.0)


# --- dispatch ----------------------------------------------------------------


def test_rest_centerline_dispatches_on_the_shape(tmp_path):
    spec = CoilSpec()
    np.testing.assert_array_equal(rest_centerline(spec), helix(3.0, 2 * D_WIRE, 60.0, D_WIRE))
    spherical = spec.with_(shape="spherical", shrink=0.7)
    np.testing.assert_array_equal(rest_centerline(spherical), spherical_spiral(3.0, 60.0, D_WIRE, 0.7, D_WIRE))
    path = tmp_path / "shape.npy"
    np.save(path, POLYLINE)
    filed = spec.with_(shape="file", preshape_file=path, length_mm=4.5, segment_length_mm=0.5)
    np.testing.assert_array_equal(rest_centerline(filed), from_file(path, 4.5, 0.5))
    with pytest.raises(PreshapeError, match="two segments"):
        rest_centerline(spec.with_(length_mm=0.4))
