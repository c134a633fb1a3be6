"""Run outputs: result.json, centerline.csv, timeseries.csv, deployment.usdc and porous.vti.

Every file is written under a temporary name and renamed when complete
(:mod:`warpcoil.recorder.atomic`), so a failed run leaves no half-written file.
"""

from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import asdict, fields
from pathlib import Path

import numpy as np

from ..measure import Frame, RunResult
from ..model import Model
from ..settings import Scene
from ..state import State
from .atomic import write_text_atomic
from .porous import POROUS_VTI, write_porous_vti
from .usd import UsdRecorder

RESULT_JSON = "result.json"
CENTERLINE_CSV = "centerline.csv"
TIMESERIES_CSV = "timeseries.csv"
DEPLOYMENT_USD = "deployment.usdc"
SUMMARY_PNG = "summary.png"
TUBE_STL, TUBE_VTP = "coils.stl", "coils.vtp"
ANIMATION_GIF = "deployment.gif"
RUN_OUTPUTS = (RESULT_JSON, CENTERLINE_CSV, TIMESERIES_CSV, DEPLOYMENT_USD, SUMMARY_PNG, TUBE_STL, TUBE_VTP,
               ANIMATION_GIF, POROUS_VTI)  # every file a run may write (recorder.folder clears exactly these)
SWEEP_OUTPUTS = ("summary.csv", "summary.md")  # a sweep's (and a plan's) beside its member_NNN folders
PLAN_OUTPUTS = ("plan.md", "plan.csv", "plan.png")  # and a plan's
ALL_OUTPUTS = RUN_OUTPUTS + SWEEP_OUTPUTS + PLAN_OUTPUTS  # what --overwrite clears, whichever command wrote them
MEMBER_FOLDERS = r"member_\d+"


def _json_ready(value):
    """inf/NaN have no JSON form: report them as null (no data, e.g. no contact partner)."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _json_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_ready(v) for v in value]
    return value


def write_result_json(path: Path, result: RunResult, extra: dict | None = None) -> None:
    payload = {**result.summary(), **(extra or {})}
    write_text_atomic(path, json.dumps(_json_ready(payload), indent=2) + "\n")


def write_centerline_csv(path: Path, positions_mm: list[np.ndarray]) -> None:
    """Final centerline: one row per node, columns coil,node,x_mm,y_mm,z_mm."""
    buffer = io.StringIO()
    buffer.write("coil,node,x_mm,y_mm,z_mm\n")
    for coil, x in enumerate(positions_mm):
        rows = np.column_stack([np.full(len(x), coil), np.arange(len(x)), x])
        np.savetxt(buffer, rows, fmt=["%d", "%d", "%.9g", "%.9g", "%.9g"], delimiter=",")
    write_text_atomic(path, buffer.getvalue())


def write_timeseries_csv(path: Path, frames: list[Frame]) -> None:
    """One row per recorded frame, the Frame fields as columns (units in the names)."""
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=[f.name for f in fields(Frame)], lineterminator="\n")
    writer.writeheader()
    for frame in frames:
        writer.writerow({k: ("" if isinstance(v, float) and not math.isfinite(v) else v)
                         for k, v in asdict(frame).items()})
    write_text_atomic(path, buffer.getvalue())


class UsdFrames:
    """``on_frame`` callback that records every frame's centerlines into a USD file
    (written on :meth:`close`; nothing is written if the run raises). A frame only
    keeps a copy of the node positions; the stage takes its time samples on
    :meth:`close`, in frame order (~0.25 ms a frame, outside the run).

    ``coil_nodes``: each coil's node slice in the state; ``wall_vertices_mm`` /
    ``wall_faces``: the static wall, or None; ``withdrawn_from``: the member's list (deploy.Member, set in
    place where a jam withdraws the rest of a coil) of each coil's first withdrawn node, or None: from the
    jam on, those nodes are drawn on the coil's cut end."""

    def __init__(self, path: Path, coil_nodes: list[slice], widths_mm: list[float],
                 wall_vertices_mm: np.ndarray | None, wall_faces: np.ndarray | None, frame_interval_s: float,
                 withdrawn_from: list | None = None):
        self.coil_nodes = coil_nodes
        self.balloon = False  # the model has a balloon (its inflation is recorded per frame)
        self._withdrawn_from = withdrawn_from
        self._frames: list[tuple[float, np.ndarray, float | None]] = []  # (time s, positions mm, inflation)
        self.recorder = UsdRecorder(path, [s.stop - s.start for s in coil_nodes], widths_mm, wall_vertices_mm,
                                    wall_faces, time_codes_per_second=1.0 / frame_interval_s,
                                    frames_per_second=1.0 / frame_interval_s)  # one code per frame: real time

    @staticmethod
    def for_model(path: Path, model: Model, frame_interval_s: float,
                  withdrawn_from: list | None = None) -> "UsdFrames":
        """Every coil of a one-world model, with its wall."""
        wall = model.wall
        frames = UsdFrames(path, [model.node_slice(c) for c in range(model.coil_count)], [c.d for c in model.coils],
                           wall.vertices_mm if wall is not None else None,
                           wall.faces_np if wall is not None else None, frame_interval_s, withdrawn_from)
        balloon = stent = None
        if model.has_stent:
            starts, ends, _ = model.strut_host
            stent = (starts, ends, model.strut_radius_mm)
        if model.has_balloon:
            count = int(model.balloon_count.numpy()[0])
            balloon = (model.balloon_stations.numpy()[:count], model.balloon_cap_radius.numpy()[:count])
        frames.add_device(balloon, stent)
        return frames

    def add_device(self, balloon: tuple | None, stent: tuple | None) -> None:
        """The assist device: ``balloon`` (axis stations mm, capped radii mm; its
        inflation then follows the frames) or ``stent`` (strut starts, ends mm, strut
        radius mm), as an anatomy holds them; None for none."""
        if stent is not None and len(stent[0]) > 0:
            self.recorder.add_stent(stent[0], stent[1], 2.0 * stent[2])
        if balloon is not None and len(balloon[1]) >= 2:
            self.recorder.add_balloon(balloon[0], balloon[1])
            self.balloon = True

    def __call__(self, frame: Frame, state: State) -> None:
        nodes = slice(self.coil_nodes[0].start, self.coil_nodes[-1].stop)
        x = state.x.numpy()[nodes].copy()
        for s, cut in zip(self.coil_nodes, self._withdrawn_from or []):  # no edge across a jammed coil's cut
            if cut:
                x[s.start - nodes.start + cut:s.stop - nodes.start] = x[s.start - nodes.start + cut - 1]
        self._frames.append((frame.time_s, x, frame.balloon_inflation))

    def close(self) -> None:
        first = self.coil_nodes[0].start
        for time_s, x, inflation in self._frames:
            self.recorder.add_frame(time_s, [x[s.start - first:s.stop - first] for s in self.coil_nodes])
            if self.balloon and inflation is not None:
                self.recorder.set_balloon(time_s, inflation)
        self._frames = []
        self.recorder.close()


def write_porous(path: Path, scene: Scene, wall, sac, positions_mm: list[np.ndarray]) -> None:
    """porous.vti of the final coils in the sac (the whole wall when the scene has no [neck])."""
    from ..porous import porous_field, porous_surface

    if sac is None and scene.neck is not None:
        from ..anatomy import resolve_anatomy

        sac = resolve_anatomy(scene).sac
    surface = porous_surface(sac, wall)
    if surface is None:
        raise ValueError(f"{scene.source}: output.porous needs a [wall]; fix: add a [wall] or set porous = false")
    field = porous_field(*surface, positions_mm, [c.d for c in scene.coils], scene.output.porous_voxel_mm)
    write_porous_vti(path, field)


def _device_lines(scene: Scene, wall) -> list:
    """The scene's assist device as (points (K, 3) mm, line width in mm, colour, label) polylines
    for the summary picture: each stent strut, or the balloon's axis at its inflated diameter."""
    from ..devices import balloon_geometry, stent_struts

    if scene.stent is not None:
        starts, ends = stent_struts(scene.stent, wall)
        return [(np.stack([a, b]), scene.stent.strut_diameter_mm, "0.45", None) for a, b in zip(starts, ends)]
    if scene.balloon is not None:
        stations, radii = balloon_geometry(scene.balloon, wall)
        return [(stations, 2.0 * float(np.median(radii)), (0.3, 0.6, 0.9, 0.25), "balloon (inflated)")]
    return []


def summary_title(scene: Scene, result: RunResult) -> str:
    """summary.png's headline: the scene, the status and the packing density of the coil in the sac
    (result.json's ``packing_density_in_sac``; the deployed coil's beside it), and the Raymond–Roy class."""
    packing = ("no sac" if result.packing_density_in_sac is None else
               f"packing density in sac {100 * result.packing_density_in_sac:.1f} % "
               f"(all deployed coil {100 * result.packing_density:.1f} %)")
    grade = f", Raymond–Roy class {result.occlusion['raymond_roy_class']}" if result.occlusion else ""
    return f"{Path(str(scene.source or 'scene')).stem}: {result.status}, {packing}{grade}"


def write_run(out: Path, scene: Scene, wall, result: RunResult, extra: dict | None = None, sac=None) -> None:
    """Everything a run writes after it ends (the USD is recorded during the run):
    CSVs, then the pictures, tube meshes and porous field the scene asks for, then
    result.json last, so its presence means the folder is complete. ``wall``: the
    run's WallMesh (Anatomy.wall) or None; ``sac``: its Sac (Anatomy.sac), cut again
    from the scene when the porous field needs it and it is not given. Final
    positions with a non-finite value (they should not occur: a failed run reports
    its last healthy frame) are not written as geometry; result.json says so in
    ``not_written``."""
    from .figures import write_summary_png

    write_timeseries_csv(out / TIMESERIES_CSV, result.frames)
    extra = dict(extra or {})
    if not all(np.isfinite(x).all() for x in result.positions_mm):
        extra["not_written"] = [CENTERLINE_CSV, TUBE_STL, TUBE_VTP, SUMMARY_PNG, POROUS_VTI]
        extra["not_written_reason"] = "the final node positions hold non-finite values"
        write_result_json(out / RESULT_JSON, result, extra)
        return
    write_centerline_csv(out / CENTERLINE_CSV, result.positions_mm)
    diameters = [c.d for c in scene.coils]
    if scene.output.tube_mesh:
        from .tube import coils_tube_mesh, write_tube_stl, write_tube_vtp  # (VTK: only a tube mesh needs it)

        mesh = coils_tube_mesh(result.positions_mm, diameters)
        write_tube_stl(out / TUBE_STL, mesh)
        write_tube_vtp(out / TUBE_VTP, mesh)
    if scene.output.porous:
        write_porous(out / POROUS_VTI, scene, wall, sac, result.positions_mm)
    if scene.output.png:
        starts = np.cumsum([c["deployed_length_mm"] for c in result.coils])[:-1].tolist()
        write_summary_png(
            out / SUMMARY_PNG, wall.vertices_mm if wall is not None else np.zeros((0, 3)),
            wall.faces if wall is not None else np.zeros((0, 3), int), result.positions_mm, result.frames,
            result.sac_volume_mm3, diameters, starts, title=summary_title(scene, result),
            catheter=(result.catheter_tip_mm, result.catheter_direction, scene.catheter.centerline_mm),
            devices=_device_lines(scene, wall), occlusion=result.occlusion)
    write_result_json(out / RESULT_JSON, result, extra)
