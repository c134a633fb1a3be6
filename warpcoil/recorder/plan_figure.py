"""plan.png: the top options of a treatment plan side by side, one row per option, one
panel per catheter-tip perturbation: the final coils (at their wire thickness) in the
wall, with the catheter and the assist device, all panels on one scale and view.
Headless (a bare Figure on the Agg canvas). Units mm.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from ..scene import load_scene
from ..wall import load_wall
from .atomic import atomic_path
from .figures import VIEWS_DEG, _draw_3d, _view_box_mm, _wall_triangles_mm, catheter_polyline_mm, line_width_pt
from .outputs import CENTERLINE_CSV, _device_lines

PANEL_IN = 3.4  # panel width and height
DPI = 100
MAX_PANEL_FACES = 4000  # wall triangles drawn per panel (drawing speed)
TITLE_IN = 0.9  # room for the figure's title above the panels' own


def read_centerline(path: Path) -> list[np.ndarray]:
    """centerline.csv (coil, node, x_mm, y_mm, z_mm) -> one (N, 3) array per coil."""
    if not path.is_file():
        return []
    table = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    if not len(table):
        return []
    coils = table[:, 0].astype(int)
    return [table[coils == k, 2:5] for k in range(coils.max() + 1)]


def write_plan_png(path: Path, scene_path: Path, result) -> None:
    """The top ``result.plan.top`` ranked options (``result``: warpcoil.plan.PlanResult) as rows,
    their perturbations as columns, written atomically to ``path``."""
    out = Path(path).parent
    top = [r for r in result.ranked if r.rank][: result.plan.top]
    columns = result.plan.perturbations
    rows = []  # (ranked, option scene, [(member, coils)])
    for r in top:
        scene = load_scene(scene_path, result.plan.options[r.index].keys)
        members = [m for m, o in zip(result.members, result.owner) if o == r.index]
        rows.append((r, scene, [(m, read_centerline(out / m.name / CENTERLINE_CSV)) for m in members]))
    wall = load_wall(rows[0][1].wall) if rows and rows[0][1].wall is not None else None
    coils = [c for _, _, drawn in rows for _, cs in drawn for c in cs]
    vertices = wall.vertices_mm if wall is not None else np.zeros((0, 3))
    faces = wall.faces if wall is not None else np.zeros((0, 3), int)
    low, high = _view_box_mm(coils, vertices)
    triangles = _wall_triangles_mm(vertices, faces, low, high, MAX_PANEL_FACES)

    fig = Figure(figsize=(PANEL_IN * columns, PANEL_IN * max(len(rows), 1) + TITLE_IN), dpi=DPI)
    FigureCanvasAgg(fig)
    fig.suptitle(f"{Path(scene_path).name}: the top {len(rows)} options (rows, best first),\n"
                 "each catheter-tip perturbation (columns); coils drawn at wire thickness", fontsize=9,
                 y=1.0 - 0.08 / fig.get_figheight(), va="top")
    for i, (r, scene, drawn) in enumerate(rows):
        devices = _device_lines(scene, wall) if wall is not None else []
        name = result.plan.options[r.index].name
        rank = f"={r.rank}" if r.tied_with else str(r.rank)
        for j, (member, member_coils) in enumerate(drawn):
            ax = fig.add_subplot(len(rows), columns, i * columns + j + 1, projection="3d")
            widths = [line_width_pt(c.d, high - low, PANEL_IN) for c in scene.coils][: len(member_coils)]
            res = member.result
            catheter = catheter_polyline_mm(res.get("catheter_tip_mm"), res.get("catheter_direction"),
                                            scene.catheter.centerline_mm, high - low)
            _draw_3d(ax, triangles, member_coils, widths, low, high, VIEWS_DEG[0], catheter)
            for points, width_mm, color, _ in devices:
                ax.plot(*np.asarray(points).T, color=color, zorder=1.5,
                        linewidth=line_width_pt(width_mm, high - low, PANEL_IN))
            herniated = res.get("length_outside_sac_mm")
            packing = res.get("packing_density_in_sac", res.get("packing_density"))
            facts = [res["status"]]
            if herniated is not None:
                facts.append(f"herniated {herniated:.1f} mm")
            if packing is not None:
                facts.append(f"packing {100 * packing:.1f} %")
            ax.set_title(f"rank {rank}: {name}\ntip {j + 1}: " + ", ".join(facts), fontsize=7)
            ax.set(xlabel="", ylabel="", zlabel="")
            ax.tick_params(labelsize=5)
    fig.subplots_adjust(left=0.02, right=0.98, bottom=0.02, top=1.0 - TITLE_IN / fig.get_figheight(), wspace=0.05,
                        hspace=0.15)
    with atomic_path(Path(path)) as tmp_path:
        fig.savefig(tmp_path, format="png")
