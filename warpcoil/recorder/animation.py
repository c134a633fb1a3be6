"""``deployment.gif``: the deployment as an animated GIF from a fixed view, for
anyone without a USD viewer (``[output] animation = true``).

Made from the recorded frames (at most MAX_FRAMES, evenly picked) with
matplotlib's PillowWriter (Pillow comes with matplotlib): the wall, the coils
outside the catheter at their wire diameter, the catheter, and the time and
deployed length. Units mm, s.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.animation import PillowWriter
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from .atomic import atomic_path
from .figures import catheter_polyline_mm, draw_catheter, line_width_pt, wall_collection

MAX_FRAMES = 60  # GIF frames (evenly picked from the recorded ones)
GIF_FPS = 10
FIGSIZE_IN, DPI = (5.0, 4.5), 80
VIEW_DEG = (20.0, -60.0)  # elevation, azimuth
MAX_WALL_FACES = 1500


class AnimationFrames:
    """``on_frame`` callback keeping every recorded frame's coil nodes (those in
    the catheter hidden); :meth:`close` writes the GIF."""

    def __init__(self, path: Path, coil_nodes: list[slice], widths_mm: list[float], wall_vertices_mm, wall_faces,
                 catheter: tuple, frame_interval_s: float):
        self.path, self.coil_nodes, self.widths_mm = Path(path), coil_nodes, list(widths_mm)
        self.wall = (None if wall_vertices_mm is None
                     else (np.asarray(wall_vertices_mm, float), np.asarray(wall_faces, np.int64)))
        self.catheter, self.frame_interval_s = catheter, frame_interval_s
        self.frames: list[tuple[float, float, list[np.ndarray]]] = []  # time, deployed length, coils

    @staticmethod
    def for_model(path: Path, model, catheter, frame_interval_s: float) -> "AnimationFrames":
        """Every coil of a one-world model, its wall, and the catheter as placed (a CatheterSpec)."""
        wall = model.wall
        return AnimationFrames(path, [model.node_slice(c) for c in range(model.coil_count)],
                               [c.d for c in model.coils], wall.vertices_mm if wall is not None else None,
                               wall.faces_np if wall is not None else None,
                               (catheter.tip_mm, catheter.direction, catheter.centerline_mm), frame_interval_s)

    def __call__(self, frame, state) -> None:
        x, free = state.x.numpy(), state.free.numpy()
        coils = [np.where(free[s, None] == 1, x[s], np.nan).astype(np.float32) for s in self.coil_nodes]
        self.frames.append((frame.time_s, frame.deployed_length_mm, coils))

    def _view_box(self) -> tuple[np.ndarray, np.ndarray]:
        if self.wall is not None:
            points = self.wall[0]
        else:
            points = np.vstack([c for _, _, coils in self.frames for c in coils])
            points = points[np.isfinite(points).all(axis=1)]
            if not len(points):
                points = np.array([self.catheter[0]], float)
        low, high = points.min(axis=0), points.max(axis=0)
        pad = 0.1 * max(float((high - low).max()), 1.0)
        return low - pad, high + pad

    def close(self) -> None:
        """Write the GIF (atomically); nothing if no frame was recorded."""
        if not self.frames:
            return
        picks = np.unique(np.linspace(0, len(self.frames) - 1, min(MAX_FRAMES, len(self.frames))).round().astype(int))
        low, high = self._view_box()
        fig = Figure(figsize=FIGSIZE_IN, dpi=DPI)
        FigureCanvasAgg(fig)
        ax = fig.add_subplot(projection="3d")
        ax.computed_zorder = False
        if self.wall is not None:
            ax.add_collection3d(wall_collection(*self.wall, low, high, MAX_WALL_FACES))
        widths = [line_width_pt(d, high - low, FIGSIZE_IN[0] * 0.8) for d in self.widths_mm]
        lines = [ax.plot([], [], [], color=f"C{k % 10}", lw=w, zorder=3 + k)[0] for k, w in enumerate(widths)]
        draw_catheter(ax, catheter_polyline_mm(*self.catheter, high - low), max(widths) * 1.6)
        ax.set(xlim=(low[0], high[0]), ylim=(low[1], high[1]), zlim=(low[2], high[2]),
               xlabel="x (mm)", ylabel="y (mm)", zlabel="z (mm)")
        ax.set_box_aspect(high - low)
        ax.view_init(elev=VIEW_DEG[0], azim=VIEW_DEG[1])
        ax.tick_params(labelsize=6)
        speed = (self.frame_interval_s * (len(self.frames) - 1) / max(len(picks) - 1, 1)) * GIF_FPS
        label = fig.text(0.02, 0.95, "", fontsize=9)
        fig.text(0.02, 0.02, f"{speed:.2g}× real time", fontsize=8, color="0.4")
        with atomic_path(self.path) as tmp_path:
            writer = PillowWriter(fps=GIF_FPS)
            with writer.saving(fig, str(tmp_path), DPI):
                for k in picks:
                    time_s, deployed_mm, coils = self.frames[k]
                    for line, coil in zip(lines, coils):
                        line.set_data_3d(coil[:, 0], coil[:, 1], coil[:, 2])
                    label.set_text(f"t = {time_s:.2f} s, {deployed_mm:.1f} mm deployed")
                    writer.grab_frame()
        self.frames = []
