"""A one-page PNG summary of a run: the final coils in the sac, push force and packing density.

Headless: a bare :class:`~matplotlib.figure.Figure` on the Agg canvas, never
pyplot's global state. Units mm, µN.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from mpl_toolkits.mplot3d.art3d import Poly3DCollection

from ..deploy import Frame
from .atomic import atomic_path

FIGSIZE_IN = (12.0, 9.0)
DPI = 100
VIEWS_DEG = ((20.0, -60.0), (20.0, 30.0))  # (elevation, azimuth): two views 90° apart
MAX_WALL_FACES = 20_000  # more are subsampled (drawing speed)
MAX_LINEWIDTH_PT = 2.5  # the thickest wire's line
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
    vertices_mm: np.ndarray, faces: np.ndarray, low: np.ndarray, high: np.ndarray
) -> np.ndarray:
    """(F,3,3) wall triangles wholly inside the view box, at most MAX_WALL_FACES of them."""
    triangles = vertices_mm[faces]
    triangles = triangles[np.all((triangles >= low) & (triangles <= high), axis=(1, 2))]
    return triangles[:: max(1, math.ceil(len(triangles) / MAX_WALL_FACES))]


def _draw_3d(ax, triangles_mm: np.ndarray, coils_mm: list[np.ndarray], linewidths_pt: list[float],
             low: np.ndarray, high: np.ndarray, view_deg: tuple[float, float]) -> list:
    """Wall and coils in one 3D axes; returns the coils' line artists."""
    ax.computed_zorder = False  # coils always over the translucent wall
    if len(triangles_mm):
        ax.add_collection3d(Poly3DCollection(
            triangles_mm, facecolors=(0.6, 0.65, 0.75, 0.06), edgecolors=(0.35, 0.4, 0.5, 0.06),
            linewidths=0.3, zorder=1))
    lines = [ax.plot(*np.reshape(coil, (-1, 3)).T, color=f"C{k % 10}", linewidth=width, zorder=2 + k)[0]
             for k, (coil, width) in enumerate(zip(coils_mm, linewidths_pt))]
    ax.set(xlim=(low[0], high[0]), ylim=(low[1], high[1]), zlim=(low[2], high[2]),
           xlabel="x (mm)", ylabel="y (mm)", zlabel="z (mm)")
    ax.set_box_aspect(high - low)
    ax.view_init(elev=view_deg[0], azim=view_deg[1])
    ax.set_title(f"elevation {view_deg[0]:g}°, azimuth {view_deg[1]:g}°", fontsize=9)
    ax.tick_params(labelsize=7)
    return lines


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
    devices: list | None = None,
) -> None:
    """Two 3D views of the final coils in the wall, push force and packing density
    against deployed length, as one PNG of FIGSIZE_IN at DPI, written atomically.
    ``devices``: an assist device as (points mm, width mm, colour, label) polylines."""
    if len(coils_mm) != len(wire_diameters_mm):
        raise ValueError(f"{len(coils_mm)} coils but {len(wire_diameters_mm)} wire diameters")
    vertices = np.asarray(wall_vertices_mm, dtype=float).reshape(-1, 3)
    faces = np.asarray(wall_faces, dtype=np.int64).reshape(-1, 3)
    low, high = _view_box_mm(coils_mm, vertices)
    triangles = _wall_triangles_mm(vertices, faces, low, high)

    fig = Figure(figsize=FIGSIZE_IN, dpi=DPI)
    FigureCanvasAgg(fig)
    grid = fig.add_gridspec(2, 2, height_ratios=(1.5, 1.0), left=0.07, right=0.97, bottom=0.07,
                            top=0.93 if title else 0.97, hspace=0.15, wspace=0.22)
    if title:
        fig.suptitle(title)

    # Line widths follow the wire diameters: to scale (a 3D panel spans ~60% of its
    # ~5 in width) but at most MAX_LINEWIDTH_PT, so that dense packings stay legible.
    pt_per_mm = 0.6 * 0.45 * FIGSIZE_IN[0] * 72.0 / float((high - low).max())
    diameters = np.asarray(wire_diameters_mm, dtype=float)
    scale = min(pt_per_mm, MAX_LINEWIDTH_PT / diameters.max()) if len(diameters) else 0.0
    linewidths_pt = np.maximum(diameters * scale, 0.5).tolist()
    for column, view in enumerate(VIEWS_DEG):
        ax = fig.add_subplot(grid[0, column], projection="3d")
        lines = _draw_3d(ax, triangles, coils_mm, linewidths_pt, low, high, view)
        for points, width_mm, color, label in devices or []:
            ax.plot(*np.asarray(points).T, color=color, linewidth=max(width_mm * pt_per_mm, 0.4), zorder=1.5,
                    label=label)
    if lines:
        fig.axes[0].legend(lines, [f"coil {k}, {d:g} mm wire" for k, d in enumerate(diameters)],
                           loc="upper left", fontsize=8)

    deployed_mm = np.array([f.deployed_length_mm for f in frames])
    force = fig.add_subplot(grid[1, 0])
    force.plot(deployed_mm, [f.push_force_max_uN for f in frames], color="C1", lw=0.7, alpha=0.6,
               label="max per frame")
    force.plot(deployed_mm, [f.push_force_uN for f in frames], color="C0", lw=1.2, label="frame mean")
    force.set(xlabel="deployed length (mm)", ylabel="push force (µN)", title="Push force")
    force.legend(fontsize=8)
    force.grid(alpha=0.3)

    packing = fig.add_subplot(grid[1, 1])
    if sac_volume_mm3 is None:
        packing.text(0.5, 0.5, "no sac volume", ha="center", va="center", transform=packing.transAxes)
        packing.set_axis_off()
    else:
        percent = packing_percent(deployed_mm, sac_volume_mm3, wire_diameters_mm, coil_boundaries_mm)
        packing.plot(deployed_mm, percent, color="C2", lw=1.2)
        final = f" (final {percent[-1]:.1f} %)" if len(percent) else ""
        packing.set(xlabel="deployed length (mm)", ylabel="packing density (%)",
                    title=f"Packing density{final}")
        packing.grid(alpha=0.3)

    with atomic_path(Path(path)) as tmp_path:
        fig.savefig(tmp_path, format="png")
