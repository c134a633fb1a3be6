"""A one-page PNG summary of a run: the final coils in the sac, push force and packing density.

Headless: a bare :class:`~matplotlib.figure.Figure` on the Agg canvas, never
pyplot's global state. Units mm, s; push force drawn in mN (stored in µN).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from mpl_toolkits.mplot3d.art3d import Poly3DCollection

from ..measure import Frame
from .atomic import atomic_path

FIGSIZE_IN = (12.0, 9.0)
DPI = 100
VIEWS_DEG = ((20.0, -60.0), (20.0, 30.0))  # (elevation, azimuth): two views 90° apart
MAX_WALL_FACES = 20_000  # more are subsampled (drawing speed)
SMOOTHING_S = 0.05  # the push force's frame mean is drawn as a moving average over this time
VIEW_PADDING = 0.25  # the view box is the coils' bounding box grown by this fraction of its largest side


def packing_percent(
    deployed_mm: np.ndarray,
    sac_volume_mm3: float,
    wire_diameters_mm: list[float],
    coil_boundaries_mm: list[float] | None = None,
) -> np.ndarray:
    """Coil volume / sac volume (%) at each total deployed length.

    Coil k occupies the deployed length between ``coil_boundaries_mm[k-1]`` and
    ``coil_boundaries_mm[k]`` (the cumulative lengths at which each next coil
    starts); with no boundaries, all of it is the first coil's wire.
    """
    diameters = np.asarray(wire_diameters_mm[:1] if coil_boundaries_mm is None else wire_diameters_mm)
    boundaries = [] if coil_boundaries_mm is None else list(coil_boundaries_mm)
    if len(boundaries) != len(diameters) - 1:
        raise ValueError(f"{len(diameters)} coils need {len(diameters) - 1} boundaries, "
                         f"got {len(boundaries)}")
    starts = np.array([0.0, *boundaries])
    lengths = np.diff(np.r_[starts, np.inf])
    per_coil_mm = np.clip(np.asarray(deployed_mm, dtype=float)[:, None] - starts, 0.0, lengths)
    return 100.0 * per_coil_mm @ (np.pi * (0.5 * diameters) ** 2) / sac_volume_mm3


def _view_box_mm(coils_mm: list[np.ndarray], wall_vertices_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(low, high) corners around the coils (or the wall, with no coil nodes), padded."""
    points = np.vstack([np.reshape(c, (-1, 3)) for c in coils_mm] + [np.empty((0, 3))])
    if len(points) == 0:
        points = wall_vertices_mm
    low, high = points.min(axis=0), points.max(axis=0)
    pad = VIEW_PADDING * max(float((high - low).max()), 1e-3)
    return low - pad, high + pad


def _wall_triangles_mm(
    vertices_mm: np.ndarray, faces: np.ndarray, low: np.ndarray, high: np.ndarray, max_faces: int = MAX_WALL_FACES
) -> np.ndarray:
    """(F,3,3) wall triangles wholly inside the view box, at most ``max_faces`` of them."""
    triangles = vertices_mm[faces]
    triangles = triangles[np.all((triangles >= low) & (triangles <= high), axis=(1, 2))]
    return triangles[:: max(1, math.ceil(len(triangles) / max_faces))]


def wall_collection(vertices_mm: np.ndarray, faces: np.ndarray, low: np.ndarray, high: np.ndarray,
                    max_faces: int = MAX_WALL_FACES) -> Poly3DCollection:
    """The wall inside the view box as a faint see-through surface."""
    return Poly3DCollection(_wall_triangles_mm(vertices_mm, faces, low, high, max_faces),
                            facecolors=(0.6, 0.65, 0.75, 0.06), edgecolors=(0.35, 0.4, 0.5, 0.06), linewidths=0.3,
                            zorder=1)


def line_width_pt(diameter_mm: float, box_extent_mm: np.ndarray, panel_width_in: float) -> float:
    """Line width (pt) that draws a wire of ``diameter_mm`` at its true thickness in a
    3D panel ``panel_width_in`` wide whose box spans ``box_extent_mm`` (the box's
    largest side takes about half the panel's width, as measured on the summary's
    views; at least 0.5 pt)."""
    pt_per_mm = 0.49 * panel_width_in * 72.0 / max(float(np.max(box_extent_mm)), 1e-6)
    return max(diameter_mm * pt_per_mm, 0.5)


def catheter_polyline_mm(tip_mm, direction, centerline_mm, box_extent_mm: np.ndarray) -> np.ndarray | None:
    """The catheter to draw: its centerline, or a straight piece as long as the view
    box behind the tip; None when unknown."""
    if tip_mm is None or direction is None:
        return None
    if centerline_mm is not None:
        return np.asarray(centerline_mm, dtype=float)
    tip, axis = np.asarray(tip_mm, dtype=float), np.asarray(direction, dtype=float)
    return np.vstack([tip - float(np.max(box_extent_mm)) * axis, tip])


def draw_catheter(ax, polyline_mm: np.ndarray | None, width_pt: float) -> None:
    """The catheter as a grey tube-like line ending at the tip."""
    if polyline_mm is not None:
        ax.plot(*polyline_mm.T, color="0.45", alpha=0.55, lw=width_pt, solid_capstyle="round", zorder=2,
                label="catheter")


def _draw_3d(ax, triangles_mm: np.ndarray, coils_mm: list[np.ndarray], linewidths_pt: list[float],
             low: np.ndarray, high: np.ndarray, view_deg: tuple[float, float], catheter_mm: np.ndarray | None) -> list:
    """Wall, catheter and coils in one 3D axes; returns the coils' line artists."""
    ax.computed_zorder = False  # coils always over the translucent wall
    if len(triangles_mm):
        ax.add_collection3d(Poly3DCollection(
            triangles_mm, facecolors=(0.6, 0.65, 0.75, 0.06), edgecolors=(0.35, 0.4, 0.5, 0.06),
            linewidths=0.3, zorder=1))
    draw_catheter(ax, catheter_mm, 1.6 * max(linewidths_pt, default=1.0))
    lines = [ax.plot(*np.reshape(coil, (-1, 3)).T, color=f"C{k % 10}", linewidth=width, zorder=3 + k)[0]
             for k, (coil, width) in enumerate(zip(coils_mm, linewidths_pt))]
    ax.set(xlim=(low[0], high[0]), ylim=(low[1], high[1]), zlim=(low[2], high[2]),
           xlabel="x (mm)", ylabel="y (mm)", zlabel="z (mm)")
    ax.set_box_aspect(high - low)
    ax.view_init(elev=view_deg[0], azim=view_deg[1])
    ax.set_title(f"elevation {view_deg[0]:g}°, azimuth {view_deg[1]:g}°", fontsize=9)
    ax.tick_params(labelsize=7)
    return lines


def smoothed(values: np.ndarray, window: int) -> np.ndarray:
    """Centred moving average over ``window`` samples (shorter at the ends)."""
    values = np.asarray(values, dtype=float)
    if window <= 1 or len(values) < 2:
        return values
    kernel = np.ones(window)
    return np.convolve(values, kernel, "same") / np.convolve(np.ones(len(values)), kernel, "same")


def _draw_push_force(ax, frames: list[Frame]) -> None:
    """Push force against time (mN): peak per frame shaded, the frame mean smoothed over
    SMOOTHING_S, the RMS per frame thin; symmetric-log axis so ringing peaks and the
    small mean both read."""
    t = np.array([f.time_s for f in frames])
    peak = np.array([f.push_force_peak_uN for f in frames]) / 1e3
    mean = np.array([f.push_force_mean_uN for f in frames]) / 1e3
    rms = np.array([f.push_force_rms_uN for f in frames]) / 1e3
    step = float(np.median(np.diff(t))) if len(t) > 1 else 1.0
    window = max(1, round(SMOOTHING_S / step))
    mean_smooth = smoothed(mean, window)
    ax.fill_between(t, 0.0, peak, step="mid", color="C1", alpha=0.3, lw=0,
                    label="push_force_peak (largest step per frame)")
    ax.plot(t, rms, color="C3", lw=0.6, alpha=0.8, label="push_force_rms (per frame)")
    ax.plot(t, mean_smooth, color="C0", lw=1.6,
            label=f"push_force_mean (per frame, smoothed over {window * step:.2g} s)")
    scale = float(np.percentile(np.abs(mean_smooth), 95)) if len(t) else 0.0
    ax.set_yscale("symlog", linthresh=10.0 ** math.floor(math.log10(max(scale, 1e-4))))  # linear up to the mean
    ax.axhline(0.0, color="0.5", lw=0.5)
    ax.set(xlabel="time (s)", ylabel="push force (mN, compressive > 0)", title="Push force")
    ax.legend(fontsize=7, loc="best", framealpha=0.8)
    ax.grid(alpha=0.3)


REGION_MARKERS = (("neck_density", "v", "neck"), ("boundary_density", "s", "boundary"), ("core_density", "o", "core"))


def _draw_occlusion(ax, occlusion: dict, t_end_s: float) -> None:
    """The final regional densities (%) as markers at the run's end, the class threshold
    as a dotted line and the in-silico Raymond–Roy class as a note."""
    threshold = 100.0 * occlusion["threshold"]
    ax.axhline(threshold, color="0.3", lw=0.8, ls=":", label=f"occlusion threshold {threshold:g} %")
    for key, marker, name in REGION_MARKERS:
        if occlusion.get(key) is not None:
            value = 100.0 * occlusion[key]
            ax.plot([t_end_s], [value], marker=marker, ls="none", color="C4", label=f"{name} {value:.1f} % (final)")
    ax.text(0.98, 0.04, f"in-silico Raymond–Roy class {occlusion['raymond_roy_class']} "
            f"({occlusion['modified_raymond_roy_class']})", transform=ax.transAxes, ha="right", va="bottom",
            fontsize=9, bbox=dict(boxstyle="round", facecolor="white", alpha=0.8))


def write_summary_png(
    path: Path,
    wall_vertices_mm: np.ndarray,
    wall_faces: np.ndarray,
    coils_mm: list[np.ndarray],
    frames: list[Frame],
    sac_volume_mm3: float | None,
    wire_diameters_mm: list[float],
    coil_boundaries_mm: list[float] | None = None,
    title: str = "",
    catheter: tuple | None = None,
    devices: list | None = None,
    occlusion: dict | None = None,
) -> None:
    """Two 3D views of the final coils (at their wire thickness) in the wall with the
    catheter, push force and packing density against time, as one PNG of FIGSIZE_IN
    at DPI, written atomically. ``catheter``: (tip_mm, direction, centerline_mm or
    None), or None. Non-finite values are left out of every panel. ``devices``: an
    assist device as (points mm, width mm, colour, label) polylines. ``occlusion``:
    result.json's in-silico Raymond–Roy grade, drawn on the packing panel."""
    if len(coils_mm) != len(wire_diameters_mm):
        raise ValueError(f"{len(coils_mm)} coils but {len(wire_diameters_mm)} wire diameters")
    coils_mm = [np.reshape(c, (-1, 3))[np.isfinite(np.reshape(c, (-1, 3))).all(axis=1)] for c in coils_mm]
    vertices = np.asarray(wall_vertices_mm, dtype=float).reshape(-1, 3)
    faces = np.asarray(wall_faces, dtype=np.int64).reshape(-1, 3)
    low, high = _view_box_mm(coils_mm, vertices)
    triangles = _wall_triangles_mm(vertices, faces, low, high)
    catheter_mm = catheter_polyline_mm(*catheter, high - low) if catheter is not None else None

    fig = Figure(figsize=FIGSIZE_IN, dpi=DPI)
    FigureCanvasAgg(fig)
    grid = fig.add_gridspec(2, 2, height_ratios=(1.5, 1.0), left=0.07, right=0.97, bottom=0.07,
                            top=0.93 if title else 0.97, hspace=0.15, wspace=0.22)
    if title:
        fig.suptitle(title)

    diameters = np.asarray(wire_diameters_mm, dtype=float)
    linewidths_pt = [line_width_pt(d, high - low, 0.45 * FIGSIZE_IN[0]) for d in diameters]
    for column, view in enumerate(VIEWS_DEG):
        ax = fig.add_subplot(grid[0, column], projection="3d")
        lines = _draw_3d(ax, triangles, coils_mm, linewidths_pt, low, high, view, catheter_mm)
        for points, width_mm, color, label in devices or []:
            ax.plot(*np.asarray(points).T, color=color, zorder=1.5, label=label,
                    linewidth=line_width_pt(width_mm, high - low, 0.45 * FIGSIZE_IN[0]))
    if lines:
        fig.axes[0].legend(lines, [f"coil {k}, {d:g} mm wire (drawn to scale)" for k, d in enumerate(diameters)],
                           loc="upper left", fontsize=8)

    frames = [f for f in frames if math.isfinite(f.time_s) and math.isfinite(f.deployed_length_mm)]
    _draw_push_force(fig.add_subplot(grid[1, 0]), frames)

    packing = fig.add_subplot(grid[1, 1])
    if sac_volume_mm3 is None:
        packing.text(0.5, 0.5, "no sac volume", ha="center", va="center", transform=packing.transAxes)
        packing.set_axis_off()
    else:
        t = np.array([f.time_s for f in frames])
        deployed_mm = np.array([f.deployed_length_mm for f in frames])
        inside_mm = deployed_mm - np.array([f.length_outside_sac_mm for f in frames])
        percent = packing_percent(deployed_mm, sac_volume_mm3, wire_diameters_mm, coil_boundaries_mm)
        in_sac = packing_percent(np.maximum(inside_mm, 0.0), sac_volume_mm3, wire_diameters_mm, coil_boundaries_mm)
        packing.plot(t, percent, color="C2", lw=1.0, ls="--", label="all deployed coil")
        packing.plot(t, in_sac, color="C2", lw=1.6, label="coil inside the sac")
        final = f" (final in sac {in_sac[-1]:.1f} %)" if len(in_sac) else ""
        if occlusion is not None:
            _draw_occlusion(packing, occlusion, float(t[-1]) if len(t) else 0.0)
        packing.set(xlabel="time (s)", ylabel="packing density (%)", title=f"Packing density{final}")
        packing.legend(fontsize=7, loc="upper left")
        packing.grid(alpha=0.3)

    with atomic_path(Path(path)) as tmp_path:
        fig.savefig(tmp_path, format="png")
