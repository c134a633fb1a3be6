"""Rest centerline ("pre-shape") of a coil: helix, spherical spiral or a file.

Every builder returns the ``n + 1`` nodes of ``n = round(L / l0)`` segments,
an ``(n + 1, 3)`` float64 array in mm, sampled at equal arc length ``L / n``
along the continuous curve. On curved parts the chords are therefore slightly
shorter than ``L / n``; the solver takes the chords as rest lengths.
"""

from __future__ import annotations

import functools
import re
from collections.abc import Callable
from math import ceil
from pathlib import Path

import numpy as np

from warpcoil.coil import CoilSpec


class PreshapeError(ValueError):
    """A pre-shape that cannot be built; the message says what to change."""


def _segment_count(length_mm: float, segment_length_mm: float, what: str) -> int:
    """n = round(L / l0), refused below two segments."""
    for name, value in (("length_mm", length_mm), ("segment_length_mm", segment_length_mm)):
        if not (np.isfinite(value) and value > 0.0):
            raise PreshapeError(f"{what}: {name} must be a positive number, got {value}")
    n = round(length_mm / segment_length_mm)
    if n < 2:
        raise PreshapeError(
            f"{what}: length {length_mm:g} mm is shorter than two segments of {segment_length_mm:g} mm; "
            "use a longer coil or a shorter segment length"
        )
    return n


# --- helix -----------------------------------------------------------------


def helix(loop_diameter_mm: float, pitch_mm: float, length_mm: float, segment_length_mm: float) -> np.ndarray:
    """Circular helix of diameter D (mm) rising ``pitch_mm`` per turn along +z.

    Starts at (D/2, 0, 0) and winds counter-clockwise about the z axis. The arc
    length is linear in the winding angle, so equal-arc sampling is exact.
    """
    n = _segment_count(length_mm, segment_length_mm, "helix")
    if not (np.isfinite(loop_diameter_mm) and loop_diameter_mm > 0.0):
        raise PreshapeError(f"helix: loop_diameter_mm must be a positive number, got {loop_diameter_mm}")
    if not (np.isfinite(pitch_mm) and pitch_mm >= 0.0):
        raise PreshapeError(f"helix: pitch_mm must be a number >= 0, got {pitch_mm}")
    radius = 0.5 * loop_diameter_mm
    turn_length = np.hypot(2.0 * np.pi * radius, pitch_mm)  # arc length of one turn, mm
    angle = 2.0 * np.pi * np.linspace(0.0, length_mm, n + 1) / turn_length
    return np.column_stack((radius * np.cos(angle), radius * np.sin(angle), pitch_mm * angle / (2.0 * np.pi)))


# --- spherical spiral ------------------------------------------------------

# Design constants of spherical_spiral (see its docstring).
_LOOP_RADIUS_MIN = 2.0 / 3.0  # smallest loop radius ρ_min, in ball radii (capped at shrink)
_DIVE_WIRES = 1.1  # radial dive where two sweeps cross, in wire diameters
_SETTLE_DIVES = 0.05  # radius decline within each sweep but the last, in dives
_DIVE_HALF_TURNS = 0.25  # half-duration of a dive, in turns
_REVERSAL_HALF_TURNS = 0.1  # half-width of the rounded θ reversal, in turns
_SPACING_MIN_WIRES = 1.05  # smallest spacing of neighbouring turns, in wire diameters
_SPACING_MAX_RADII = 0.5  # largest spacing (a short coil narrows its band), in ball radii
_SWEEP_MIN_TURNS = 0.4  # fewest turns of a sweep when there are several


def _smooth_ramp(x: np.ndarray, half_width: float) -> np.ndarray:
    """C² version of max(x, 0): a quartic blend on |x| < half_width, exact outside."""
    t = np.clip((x + half_width) / (2.0 * half_width), 0.0, 1.0)
    return np.where(x >= half_width, x, 2.0 * half_width * (t**3 - 0.5 * t**4))


def _smooth_polyline(w: np.ndarray, knots_w: np.ndarray, knots_v: np.ndarray, half_width: float) -> np.ndarray:
    """Piecewise-linear interpolation of (knots_w, knots_v), interior corners rounded over ±half_width."""
    slopes = np.diff(knots_v) / np.diff(knots_w)
    bends = np.diff(slopes)[:, None] * _smooth_ramp(w[None, :] - knots_w[1:-1, None], half_width)
    return knots_v[0] + slopes[0] * (w - knots_w[0]) + bends.sum(axis=0)


def spherical_spiral(
    loop_diameter_mm: float,
    length_mm: float,
    segment_length_mm: float,
    shrink: float = 0.6,
    wire_diameter_mm: float = 0.2921,
) -> np.ndarray:
    """3D framing shape: loops laid on a ball of diameter D whose radius shrinks to shrink·D/2.

    Spherical coordinates about the ball's centre (the origin), with the turn
    count ``w`` in ``[0, W]`` as parameter::

        φ = 2π w,   θ(w) and r(w) smoothed polylines in w,
        x = r sinθ cosφ,   y = r sinθ sinφ,   z = r cosθ.

    The coil winds about the z axis in ``m`` sweeps. A sweep moves θ linearly
    in w across its band, so neighbouring turns lie ``s`` mm apart on the ball
    and never cross; the next sweep comes back. The band keeps every loop at
    least ``ρ_min = min(shrink, 2/3)·D/2`` in radius (``r sinθ >= ρ_min``,
    i.e. ``|θ - π/2| <= arccos(ρ_min / r)``), so the curve stays off the
    poles and its curvature is about ``1/ρ_min`` at most. Where a sweep
    reverses, and starts crossing the previous one, the radius dives by
    ``1.1·d`` within ±¼ turn; within a sweep it decreases by ``0.055·d``,
    and the last sweep takes the rest of the shrink, ending at
    ``shrink·D/2`` (on the equator when shrink <= 2/3). The first sweep
    starts at r = D/2 on the northern edge of its band. Corners of the
    polylines are rounded with a C² blend, so tangent and curvature are
    continuous.

    The spacing ``s`` is fitted (secant iterations on the numerically
    integrated arc length) so that the curve is exactly ``length_mm`` long,
    with the fewest sweeps, at least two, giving ``s >= 1.05·d``; parts of
    the coil not within a few segments of each other then stay about ``d``
    or more apart, centre to centre. With two or more sweeps the first one
    crosses the equator at r ≈ D/2, so the first turns frame a ball of
    diameter D (largest extent 0.95–1.0 D from one loop, L ≈ πD, up). A
    single sweep is left to a coil too short for two sweeps of 0.4 turns
    (L below about 2.5 D) or whose shrink cannot hold one dive
    (``(1 - shrink)·D/2 <= 1.155·d``); it keeps r = D/2 until it crosses
    the equator, or at the latest until its last half turn, and shrinks
    after that (under half a turn it shrinks all along, eased in up to one
    turn). A short coil, whose spacing would exceed D/4, narrows its band
    about the equator instead. A coil too long for its ball (turns closer
    than ``1.05·d`` even with as many sweeps as ``1.1·d`` dives fit in
    ``(1 - shrink)·D/2``) raises PreshapeError; with d = 0.2921 mm and shrink 0.6 the limit is about
    27 mm for D = 2 mm, 77 mm for D = 3 mm, 196 mm for D = 4 mm and over
    400 mm from D = 6 mm.

    Args (mm): loop diameter D, coil length L, nominal segment length l0 and
    wire (secondary) diameter d; ``shrink`` in (0, 1]. Returns the
    ``(round(L/l0) + 1, 3)`` nodes, mm.
    """
    n = _segment_count(length_mm, segment_length_mm, "spherical spiral")
    for name, value in (("loop_diameter_mm", loop_diameter_mm), ("wire_diameter_mm", wire_diameter_mm)):
        if not (np.isfinite(value) and value > 0.0):
            raise PreshapeError(f"spherical spiral: {name} must be a positive number, got {value}")
    if not (0.0 < shrink <= 1.0):
        raise PreshapeError(f"spherical spiral: shrink must be in (0, 1], got {shrink}")
    radius = 0.5 * loop_diameter_mm
    if length_mm < 2.0 * (1.0 - shrink) * radius:
        raise PreshapeError(
            f"spherical spiral: a {length_mm:g} mm coil is too short to shrink from {radius:g} mm to "
            f"{shrink * radius:g} mm in radius; use a longer coil or a shrink closer to 1"
        )

    dive = _DIVE_WIRES * wire_diameter_mm
    max_sweeps = max(1, ceil((1.0 - shrink) * radius / ((1.0 + _SETTLE_DIVES) * dive)))
    # Two sweeps first (the first then frames the whole ball), one if two cannot be that short, then more.
    for sweeps in [*range(min(2, max_sweeps), 0, -1), *range(3, max_sweeps + 1)]:
        spacing, sample = _fit_spiral(radius, shrink, dive, sweeps, length_mm)
        if spacing >= _SPACING_MIN_WIRES * wire_diameter_mm:
            return sample(np.linspace(0.0, length_mm, n + 1))
    raise PreshapeError(
        f"spherical spiral: {length_mm:g} mm of coil does not fit on a ball of diameter {loop_diameter_mm:g} mm "
        f"shrinking to {shrink:g}×: even with {max_sweeps} sweep(s), each {dive:.3g} mm inside the previous, "
        f"its turns come closer than 1.05 × the wire diameter {wire_diameter_mm:g} mm; use a shorter coil, "
        "a larger loop diameter, a smaller shrink, or a helix/file pre-shape"
    )


def _spiral(
    radius: float, shrink: float, dive: float, sweeps: int, spacing: float
) -> tuple[float, float, Callable[[np.ndarray], np.ndarray]]:
    """The spiral of ``sweeps`` sweeps with turns ``spacing`` mm apart (see spherical_spiral).

    Returns the closest spacing of neighbouring turns in any sweep (mm), the
    total turn count W and ``position(w) -> (k, 3)`` in mm.
    """
    r_end = shrink * radius
    # Radius at the start, right after each dive, and at the end; each sets a band edge.
    r_edge = np.concatenate(([radius], radius - np.arange(1, sweeps) * (1.0 + _SETTLE_DIVES) * dive, [r_end]))
    half_band = np.arccos(np.minimum(min(shrink, _LOOP_RADIUS_MIN) * radius / r_edge, 1.0))
    side = (-1.0) ** np.arange(1, sweeps + 2)  # northern edge first, then alternate
    narrow = min(1.0, _SPACING_MAX_RADII * radius / spacing)
    theta_knots = 0.5 * np.pi + side * narrow * half_band
    r_low = np.concatenate((r_edge[1:-1] + dive, [r_end]))  # smallest radius of each sweep before its dive
    band = r_low * np.abs(np.diff(theta_knots))  # width of each sweep's band, mm
    turns = np.maximum(band / spacing, _SWEEP_MIN_TURNS if sweeps > 1 else 0.0)
    w_knots = np.concatenate(([0.0], np.cumsum(turns)))
    ramp = min(_DIVE_HALF_TURNS, 0.4 * turns.min())  # each dive, rounding included, fits in its sweeps
    w_r = np.concatenate(([0.0], np.repeat(w_knots[1:-1], 2) + np.tile([-ramp, ramp], sweeps - 1), [w_knots[-1]]))
    r_knots = np.concatenate(([radius], np.repeat(r_edge[1:-1], 2) + np.tile([dive, 0.0], sweeps - 1), [r_end]))
    if sweeps == 1:  # D/2 until the equator or the last half turn, then the shrink; eased in from ½ to 1 turn
        turns_all = w_knots[1]
        w_hold = min(turns_all * half_band[0] / half_band.sum(), max(turns_all - 0.5, 0.5 * turns_all))
        r_hold = radius - (1.0 - np.clip(2.0 * turns_all - 1.0, 0.0, 1.0)) * (radius - r_end) * w_hold / turns_all
        w_r, r_knots = np.array([0.0, w_hold, turns_all]), np.array([radius, r_hold, r_end])

    def position(w: np.ndarray) -> np.ndarray:
        theta = _smooth_polyline(w, w_knots, theta_knots, _REVERSAL_HALF_TURNS)
        r = _smooth_polyline(w, w_r, r_knots, 0.25 * ramp)
        rho, phi = r * np.sin(theta), 2.0 * np.pi * w  # distance from the z axis, azimuth
        return np.column_stack((rho * np.cos(phi), rho * np.sin(phi), r * np.cos(theta)))

    return (band / turns).min(), w_knots[-1], position


def _fit_spiral(
    radius: float, shrink: float, dive: float, sweeps: int, length_mm: float
) -> tuple[float, Callable[[np.ndarray], np.ndarray]]:
    """Fit the turn spacing so that the spiral is ``length_mm`` long.

    Returns the closest spacing of neighbouring turns (mm; 0 if no spacing
    gives that length) and ``sample(arc_mm) -> (k, 3)``, the points at arc
    lengths ``arc_mm`` along the curve.
    """
    spacing, slope, previous = _SPACING_MAX_RADII * radius, -1.0, None
    for _ in range(30):  # secant steps on log(length) against log(spacing); length ~ 1/spacing
        closest, turns, position = _spiral(radius, shrink, dive, sweeps, spacing)
        w = np.linspace(0.0, turns, 8192 + 2048 * ceil(turns))
        arc = np.concatenate(([0.0], np.cumsum(np.linalg.norm(np.diff(position(w), axis=0), axis=1))))
        error = np.log(arc[-1] / length_mm)
        if abs(error) < 1e-9:
            break
        if previous is not None:
            slope = min((error - previous[1]) / np.log(spacing / previous[0]), -0.1)
        previous = (spacing, error)
        spacing *= np.exp(min(-error / slope, 5.0))  # bounded: a spiral longer than length_mm at any spacing
    else:
        closest = 0.0

    def sample(arc_mm: np.ndarray) -> np.ndarray:
        return position(np.interp(arc_mm * (arc[-1] / length_mm), arc, w))

    return closest, sample


# --- centerline files ------------------------------------------------------

_FORMAT = "one point 'x y z' (mm) per line, whitespace- or comma-separated, or a .npy array of shape (M, 3)"


def _number(token: str) -> float | None:
    """The token as a float, or None if it is not a number."""
    try:
        return float(token)
    except ValueError:
        return None


def _read_text(path: Path) -> tuple[np.ndarray, list[str]]:
    """Points of a text centerline and, per point, where it is ("line k")."""
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as err:
        raise PreshapeError(f"{path}: cannot read the centerline file ({err}); give {_FORMAT}") from None
    rows = [(k, re.split(r"\s*,\s*|\s+", line.strip())) for k, line in enumerate(text.splitlines(), 1)]
    rows = [(k, fields) for k, fields in rows if fields != [""] and not fields[0].startswith("#")]
    if rows and all(_number(token) is None for token in rows[0][1]):
        rows = rows[1:]  # a header such as "x y z"
    points = []
    for k, fields in rows:
        if len(fields) != 3:
            raise PreshapeError(f"{path}: line {k}: found {len(fields)} columns, expected 3; give {_FORMAT}")
        values = [_number(token) for token in fields]
        if None in values:
            bad = fields[values.index(None)]
            raise PreshapeError(f"{path}: line {k}: {bad!r} is not a number; give {_FORMAT}")
        points.append(values)
    return np.array(points, dtype=np.float64).reshape(-1, 3), [f"line {k}" for k, _ in rows]


def _read_npy(path: Path) -> tuple[np.ndarray, list[str]]:
    """Points of a .npy centerline and, per point, where it is ("row i")."""
    try:
        data = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as err:
        raise PreshapeError(f"{path}: cannot read the centerline file ({err}); give {_FORMAT}") from None
    if data.ndim != 2 or data.shape[1] != 3 or not np.issubdtype(data.dtype, np.number):
        raise PreshapeError(f"{path}: array of shape {data.shape} and type {data.dtype}; give {_FORMAT}")
    return data.astype(np.float64), [f"row {i}" for i in range(len(data))]


def read_centerline(path: str | Path) -> np.ndarray:
    """Read a centerline, (M, 3) float64 in mm, from a text/CSV or a .npy file.

    Text: one point ``x y z`` per line, separated by whitespace or commas;
    blank lines, lines starting with '#' and one header line of non-numeric
    text are skipped. Raises PreshapeError naming the file, the place and
    the fix for an unreadable file, a wrong column count, a non-finite
    value, two identical consecutive points or fewer than two points.
    """
    path = Path(path)
    points, where = _read_npy(path) if path.suffix.lower() == ".npy" else _read_text(path)
    bad = np.flatnonzero(~np.isfinite(points).all(axis=1))
    if bad.size:
        i = bad[0]
        raise PreshapeError(f"{path}: {where[i]}: non-finite coordinate in {points[i]}; give finite numbers in mm")
    if len(points) < 2:
        raise PreshapeError(f"{path}: {len(points)} point(s); a centerline needs at least 2 ({_FORMAT})")
    same = np.flatnonzero((points[1:] == points[:-1]).all(axis=1))
    if same.size:
        i = same[0]
        raise PreshapeError(f"{path}: {where[i]} and {where[i + 1]} hold the same point {points[i]}; remove one")
    return points


def resample_equal_arc(points: np.ndarray, n_segments: int) -> np.ndarray:
    """Resample a polyline (M, 3) to ``n_segments + 1`` points at equal arc length along it.

    Piecewise-linear in arc length; the first and last points are kept. Units
    are those of ``points`` (mm).
    """
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3 or len(points) < 2:
        raise PreshapeError(f"resample_equal_arc: points must have shape (M >= 2, 3), got {points.shape}")
    if n_segments < 1:
        raise PreshapeError(f"resample_equal_arc: n_segments must be >= 1, got {n_segments}")
    arc = np.concatenate(([0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))))
    if np.any(np.diff(arc) <= 0.0):
        raise PreshapeError("resample_equal_arc: the polyline has zero-length segments (repeated points)")
    target = np.linspace(0.0, arc[-1], n_segments + 1)
    return np.column_stack([np.interp(target, arc, points[:, k]) for k in range(3)])


def from_file(path: str | Path, length_mm: float, segment_length_mm: float) -> np.ndarray:
    """Pre-shape given as a centerline file (see read_centerline), resampled to round(L/l0) segments.

    The file's polyline defines the shape and its length; ``length_mm`` (the
    catalogue length) must agree with it within 1 %.
    """
    points = read_centerline(path)
    curve_mm = float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())
    if abs(length_mm - curve_mm) > 0.01 * curve_mm:
        raise PreshapeError(
            f"file {path}: the centerline is {curve_mm:.4g} mm long but the coil length is {length_mm:g} mm "
            f"(more than 1 % apart); fix: length_mm = {curve_mm:.4g}, or a centerline {length_mm:g} mm long"
        )
    return resample_equal_arc(points, _segment_count(length_mm, segment_length_mm, str(path)))


def rest_centerline(spec: CoilSpec) -> np.ndarray:
    """Rest centerline of a coil, (round(L/l0) + 1, 3) float64 in mm, from its pre-shape fields."""
    if spec.shape == "file":  # read every time: the file may change
        return from_file(spec.preshape_file, spec.length_mm, spec.l0)
    return _generated_centerline(spec).copy()


@functools.lru_cache(maxsize=256)
def _generated_centerline(spec: CoilSpec) -> np.ndarray:
    """A generated pre-shape, computed once per distinct spec (an ensemble repeats them)."""
    if spec.shape == "helix":
        return helix(spec.loop_diameter_mm, spec.helix_pitch_mm, spec.length_mm, spec.l0)
    return spherical_spiral(spec.loop_diameter_mm, spec.length_mm, spec.l0, spec.shrink, spec.wire_diameter_mm)
