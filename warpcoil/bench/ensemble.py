"""`warpcoil bench ensemble`: seed-case deployments per minute against ensemble size B.

B copies of scenes/seed_sphere.toml, the catheter tilted 0–20° across the
members (so they differ), advanced by one set of launches. For small B every
member is deployed to the end (measured throughput); for large B on a slow
device a window of steps from the packed start is timed and the throughput
extrapolated from the largest fully measured B by the per-member step cost
(marked as such). Also reported: the launch floor (the same launches on a
3-node model, graph replay) and the compute per step.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import warp as wp

from ..deploy import Ensemble
from ..recorder.atomic import write_text_atomic
from ..scene import load_scene
from ..solver import Stepper
from .report import markdown_table, write_report

SEED_SCENE = Path(__file__).resolve().parents[2] / "scenes" / "seed_sphere.toml"
WINDOW_STEPS = 40  # steps timed per window (after a warm-up chunk that captures the graph)


@dataclass
class Row:
    members: int
    measured: str  # "full" or "window"
    wall_time_s: float  # full: the ensemble's run; window: WINDOW_STEPS steps
    steps: int  # full: the longest member's steps
    us_per_member_step: float  # window: wall time / (steps × members)
    deployments_per_min: float
    completed: int = 0


def seed_scenes(members: int) -> list:
    scenes = []
    for k in range(members):
        a = math.radians(20.0 * k / max(members - 1, 1))
        scenes.append(load_scene(SEED_SCENE, {"catheter.direction": [math.sin(a), 0.0, math.cos(a)],
                                              "output.usd": False, "output.png": False}))
    return scenes


def window_cost_s(ensemble: Ensemble) -> float:
    """Wall time of WINDOW_STEPS steps of the ensemble from its packed start, pushing."""
    for member in ensemble.members:
        ensemble.control.set_active_coil(0, world=member.world)
    stepper = Stepper(ensemble.solver, ensemble.stepper.state, ensemble.control, chunk=WINDOW_STEPS)
    stepper.run_chunk()  # capture
    wp.synchronize_device(ensemble.model.device)
    start = time.perf_counter()
    stepper.run_chunk()
    wp.synchronize_device(ensemble.model.device)
    return time.perf_counter() - start


def launch_floor_us(device) -> float:
    """µs per step of the same launch sequence on a 3-node coil (no wall): what graph
    replay costs when there is almost nothing to compute."""
    from .. import CoilSpec, Control, ModelBuilder, Solver, state_from_positions
    import numpy as np

    builder = ModelBuilder()
    builder.add_coil(CoilSpec(shape="straight", length_mm=2 * 0.2921, wire_diameter_mm=0.2921))
    model = builder.finalize(device)
    state = state_from_positions(model, model.rest_positions + np.array([0.0, 0.0, 1.0]))
    stepper = Stepper(Solver(model), state, Control.create(model), chunk=1000)
    stepper.run_chunk()
    wp.synchronize_device(model.device)
    start = time.perf_counter()
    stepper.run_chunk()
    wp.synchronize_device(model.device)
    return (time.perf_counter() - start) / 1000 * 1e6


def main(out: Path, quick: bool, repeats: int, device=None) -> int:
    device = wp.get_device(device)
    sizes = (1, 4, 16) if quick else (1, 16, 256, 4096)
    full_up_to = 64 if device.is_cuda else (4 if quick else 16)
    rows: list[Row] = []
    for members in sizes:
        scenes = seed_scenes(members)
        ensemble = Ensemble(scenes, device)
        if members <= full_up_to:
            start = time.perf_counter()
            results = ensemble.run()
            elapsed = time.perf_counter() - start
            window = window_cost_s(Ensemble(scenes, device))
            rows.append(Row(members, "full", elapsed, max(r.steps for r in results),
                            window / (WINDOW_STEPS * members) * 1e6, 60.0 * members / elapsed,
                            sum(r.status == "completed" for r in results)))
        else:
            window = window_cost_s(ensemble)
            base = max((r for r in rows if r.measured == "full"), key=lambda r: r.members)
            per_member = window / (WINDOW_STEPS * members) * 1e6
            rows.append(Row(members, "window", window, WINDOW_STEPS, per_member,
                            base.deployments_per_min * base.us_per_member_step / per_member * members / base.members))
        r = rows[-1]
        print(f"B = {members:5d} ({r.measured}): {r.deployments_per_min:9.3g} deployments/min, "
              f"{r.us_per_member_step:.3g} µs per member-step", flush=True)
    floor = launch_floor_us(device)
    table = markdown_table(
        ["B (members)", "measured", "wall time (s)", "steps", "µs per member-step", "deployments / min", "completed"],
        [[r.members, "full deployments" if r.measured == "full" else f"{WINDOW_STEPS}-step window, extrapolated",
          r.wall_time_s, r.steps, r.us_per_member_step, r.deployments_per_min,
          f"{r.completed}/{r.members}" if r.measured == "full" else ""] for r in rows])
    one = rows[0]
    notes = (f"Launch floor (the same launches per step on a 3-node coil, graph replay): {floor:.3g} µs per step. "
             f"Compute at B = 1: {one.us_per_member_step:.3g} µs per step (window from the packed start; the "
             f"full run averages {one.wall_time_s / one.steps * 1e6:.3g} µs per step over {one.steps} steps).")
    command = f"warpcoil bench ensemble{' --quick' if quick else ''}" + (f" --device {device.alias}" if device.is_cuda else "")
    write_report(out / "ensemble.md", "Seed-case deployments per minute against ensemble size", command,
                 [f"Device: {device.alias} ({device.name}).", table, notes])
    write_text_atomic(out / "ensemble.json", json.dumps({"rows": [asdict(r) for r in rows],
                                                          "launch_floor_us_per_step": floor}, indent=1))
    return 0
