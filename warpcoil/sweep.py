"""`warpcoil sweep`: one scene, some keys varied, every member deployed in
ensembles (one set of launches per group of compatible members).

``--vary catheter.angle_deg=0:30:5`` (start:stop:step, stop included) or
``--vary simulation.push_speed_mm_s=50,100``; several ``--vary`` make the
Cartesian product. Each member gets its folder ``member_NNN`` (result.json,
centerline.csv, timeseries.csv, the pictures / tube meshes the scene asks for,
and with ``--usd`` its deployment.usdc), and the sweep writes summary.csv and
summary.md, all atomically.
"""

from __future__ import annotations

import csv
import io
import itertools
import math
import time
from dataclasses import dataclass
from pathlib import Path

from .deploy import Ensemble, RunResult, ensemble_groups, resolve_anatomies
from .preflight import check_catheter
from .recorder.atomic import write_text_atomic
from .scene import load_scene


class SweepError(ValueError):
    """A --vary that cannot be read."""


def parse_vary(text: str) -> tuple[str, list]:
    """``key=start:stop:step`` or ``key=a,b,c`` → (key, values)."""
    key, sep, values = text.partition("=")
    fix = "write --vary key=start:stop:step or key=a,b,c, e.g. catheter.angle_deg=0:30:5"
    if not sep or not key or not values:
        raise SweepError(f"--vary {text!r}: {fix}")
    try:
        if ":" in values:
            start, stop, step = (float(v) for v in values.split(":"))
            if not step > 0.0 or stop < start:
                raise SweepError(f"--vary {text!r}: needs step > 0 and stop ≥ start; {fix}")
            count = int(math.floor((stop - start) / step + 1e-9)) + 1
            return key, [round(start + k * step, 12) for k in range(count)]
        return key, [_scalar(v) for v in values.split(",")]
    except ValueError as error:
        if isinstance(error, SweepError):
            raise
        raise SweepError(f"--vary {text!r}: {error}; {fix}") from error


def _scalar(text: str):
    text = text.strip()
    if text.lower() in ("true", "false"):
        return text.lower() == "true"
    try:
        return float(text)
    except ValueError:
        return text


@dataclass
class Member:
    index: int
    values: dict  # the varied keys and their values
    result: RunResult | None = None


def members(varies: list[tuple[str, list]]) -> list[Member]:
    keys = [k for k, _ in varies]
    return [Member(i, dict(zip(keys, combo))) for i, combo in enumerate(itertools.product(*(v for _, v in varies)))]


def _summary_row(member: Member) -> dict:
    r = member.result
    regions = r.regions or {}
    row = {"member": f"member_{member.index:03d}", **member.values, "status": r.status,
           "packing_density": r.packing_density, "length_outside_sac_mm": r.length_outside_sac_mm,
           "neck_coverage": regions.get("neck_coverage"), "min_coil_gap_mm": r.min_coil_gap_mm,
           "min_wall_gap_mm": r.min_wall_gap_mm, "push_force_peak_uN": r.push_force_peak_uN, "steps": r.steps,
           "wall_time_s": r.wall_time_s}
    return {k: ("" if v is None or (isinstance(v, float) and not math.isfinite(v)) else
                (f"{v:.6g}" if isinstance(v, float) else v)) for k, v in row.items()}


def write_summary(out: Path, all_members: list[Member], header: str) -> None:
    rows = [_summary_row(m) for m in all_members]
    columns = list(rows[0])
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=columns, lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    write_text_atomic(out / "summary.csv", buffer.getvalue())
    lines = [header, "", "| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(str(row[c]) for c in columns) + " |" for row in rows]
    write_text_atomic(out / "summary.md", "\n".join(lines) + "\n")


def _member_folder(out: Path, k: int) -> Path:
    return out / f"member_{k:03d}"


def _run_batch(scene_path: Path, overrides: list[dict], device, usd_folders: list[Path] | None = None,
               anatomies: list | None = None) -> list[tuple[RunResult, object]]:
    """Deploy one ensemble of members (a worker process's share); (result, wall mesh)
    each. With ``usd_folders`` (one per member) each member's frames go to its
    deployment.usdc. ``anatomies``: already resolved (same process), else resolved here."""
    from .recorder.outputs import DEPLOYMENT_USD, UsdFrames

    scenes = [load_scene(scene_path, values) for values in overrides]
    ensemble = Ensemble(scenes, device, anatomies)
    recorders: dict[int, UsdFrames] = {}
    last_time_s: dict[int, float] = {}

    def record(member, frame, state):
        k = member.index
        usd = recorders.get(k)
        if usd is None or frame.time_s < last_time_s[k]:  # a member rerun alone starts again
            folder = usd_folders[k]
            folder.mkdir(parents=True, exist_ok=True)
            wall = member.anatomy.wall
            usd = recorders[k] = UsdFrames(
                folder / DEPLOYMENT_USD, member.coil_nodes, [c.d for c in member.scene.coils],
                wall.vertices_mm if wall is not None else None, wall.faces if wall is not None else None,
                member.scene.simulation.frame_interval_s)
        last_time_s[k] = frame.time_s
        usd(frame, state)

    results = ensemble.run(record if usd_folders else None)
    for usd in recorders.values():
        usd.close()
    return list(zip(results, (a.wall for a in ensemble.anatomies)))


def run_sweep(scene_path: Path, varies: list[tuple[str, list]], out: Path, device=None,
              progress=None, jobs: int = 1, usd: bool = False) -> list[Member]:
    """Deploy every member; write their folders, then the summary (its presence
    means the sweep is complete). ``progress(done, total)``.

    ``jobs`` > 1 splits each ensemble over that many worker processes: on the
    CPU a launch runs on one core, so this is what uses the others (results are
    the same: each member equals its single run)."""
    from concurrent.futures import ProcessPoolExecutor
    from multiprocessing import get_context

    from .recorder.outputs import write_run

    todo = members(varies)
    scenes = [load_scene(scene_path, m.values) for m in todo]  # every member checked before anything is written
    out.mkdir(parents=True, exist_ok=True)
    for stale in (out / "summary.csv", out / "summary.md"):  # a summary is only ever of this sweep
        stale.unlink(missing_ok=True)
    started = time.perf_counter()
    anatomies = resolve_anatomies(scenes)  # walls read and necks cut once, for grouping and (one job) the runs
    for scene, anatomy in zip(scenes, anatomies):  # a catheter outside the lumen: SetupError before any step
        check_catheter(scene, anatomy, device)
    groups = ensemble_groups(scenes, device, anatomies)
    batches = [part for group in groups for part in (group[i::jobs] for i in range(jobs)) if part]

    def finish(batch: list[int], outcome: list) -> None:
        for k, (result, wall) in zip(batch, outcome):
            todo[k].result = result
            folder = _member_folder(out, k)
            folder.mkdir(parents=True, exist_ok=True)
            write_run(folder, scenes[k], wall, result, {"scene": str(scene_path), "varied": todo[k].values})
        if progress:
            progress(sum(m.result is not None for m in todo), len(todo))

    overrides = lambda batch: [todo[k].values for k in batch]  # noqa: E731
    folders = lambda batch: [_member_folder(out, k) for k in batch] if usd else None  # noqa: E731
    if jobs <= 1:
        for batch in batches:
            finish(batch, _run_batch(scene_path, overrides(batch), device, folders(batch),
                                     [anatomies[k] for k in batch]))
    else:
        with ProcessPoolExecutor(min(jobs, len(batches)), mp_context=get_context("spawn")) as pool:
            futures = {pool.submit(_run_batch, scene_path, overrides(b), device, folders(b)): b for b in batches}
            for future, batch in futures.items():
                finish(batch, future.result())
    elapsed = time.perf_counter() - started
    statuses = [m.result.status for m in todo]
    write_summary(out, todo, f"# Sweep of {scene_path.name}\n\n{len(todo)} members in {len(batches)} "
                  f"ensemble(s), {jobs} job(s), {elapsed:.1f} s wall time ({60.0 * len(todo) / elapsed:.3g} "
                  "deployments/min); " + ", ".join(f"{statuses.count(s)} {s}" for s in dict.fromkeys(statuses)) + ".")
    return todo


__all__ = ["SweepError", "parse_vary", "run_sweep"]
