"""`warpcoil bench ensemble`: seed-case deployments per minute against ensemble size B.

Two measurements:

* full: B copies of scenes/seed_sphere.toml, the catheter tilted 0–20° across
  the members (so they differ), each deployed to the end by one ensemble —
  deployments per minute as measured (the ensemble lasts as long as its
  slowest member);
* window: B identical members started from the half-deployed state of the
  single run, a window of steps timed after a warm-up — the cost per member
  and step c(B), so deployments per minute ≈ (single run's) × c(1) / c(B)
  for B too large to run to the end on a slow device (marked as such).

Also reported: the launch floor (the same launches on a 3-node model, graph
replay) against the compute per step.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import warp as wp

from ..deploy import Ensemble
from ..recorder.atomic import write_text_atomic
from ..scene import load_scene
from ..solver import Stepper
from .report import markdown_table, write_report

SEED_SCENE = Path(__file__).resolve().parents[2] / "scenes" / "seed_sphere.toml"
STATE_ARRAYS = ("x", "v", "m1", "omega", "free", "advance")


@dataclass
class Row:
    members: int
    full_wall_time_s: float | None = None  # the whole ensemble, deployed to the end
    full_steps: int | None = None  # its longest member's steps
    completed: int | None = None
    window_steps: int = 0
    us_per_member_step: float = 0.0  # window: wall time / (steps × members), half-deployed
    deployments_per_min: float = 0.0
    extrapolated: bool = False


def seed_scenes(members: int, tilt_deg: float = 20.0) -> list:
    scenes = []
    for k in range(members):
        a = math.radians(tilt_deg * k / max(members - 1, 1))
        scenes.append(load_scene(SEED_SCENE, {"catheter.direction": [math.sin(a), 0.0, math.cos(a)],
                                              "output.usd": False, "output.png": False}))
    return scenes


def run_full(members: int, device) -> tuple[Row, dict]:
    """Deploy B tilted seed members to the end; also returns member 0's state when
    half of its coil was out (numpy arrays, for the windows)."""
    ensemble = Ensemble(seed_scenes(members), device)
    half = 0.5 * float(ensemble.members[0].coil_lengths_mm.sum())
    mid: dict = {}

    def on_frame(member, frame, state):
        if member.index == 0 and not mid and frame.deployed_length_mm >= half:
            sl = member.nodes
            mid.update({name: getattr(state, name).numpy()[sl].copy() for name in STATE_ARRAYS if name != "advance"})
            mid["advance"] = state.advance.numpy()[member.coils.start:member.coils.stop].copy()

    start = time.perf_counter()
    results = ensemble.run(on_frame)
    elapsed = time.perf_counter() - start
    return Row(members, elapsed, max(r.steps for r in results), sum(r.status == "completed" for r in results),
               deployments_per_min=60.0 * members / elapsed), mid


def window_us_per_member_step(members: int, mid: dict, steps: int, device) -> float:
    """µs per member and step of B identical half-deployed members (after two warm-up chunks)."""
    ensemble = Ensemble(seed_scenes(members, tilt_deg=0.0), device)
    state = ensemble.stepper.state
    for name in STATE_ARRAYS:
        getattr(state, name).assign(np.concatenate([mid[name]] * members))
    stepper = Stepper(ensemble.solver, state, ensemble.control, chunk=steps)
    return chunk_time_s(stepper) / (steps * members) * 1e6


def chunk_time_s(stepper: Stepper) -> float:
    """Wall time of one chunk after two warm-up chunks (the capture — on the CPU
    nothing runs during it — and a first replay: wall sides, anchors, neighbour grid)."""
    device = stepper.solver.model.device
    stepper.run_chunk()
    stepper.run_chunk()
    wp.synchronize_device(device)
    start = time.perf_counter()
    stepper.run_chunk()
    wp.synchronize_device(device)
    return time.perf_counter() - start


def launch_floor_us(device) -> float:
    """µs per step of the same launch sequence on a 3-node coil (no wall): what graph
    replay costs when there is almost nothing to compute."""
    from .. import CoilSpec, Control, ModelBuilder, Solver, state_from_positions

    builder = ModelBuilder()
    d = 0.2921
    builder.add_coil(CoilSpec(length_mm=2 * d, wire_diameter_mm=d), np.array([[0.0, 0.0, 0.0], [0.0, 0.0, d],
                                                                             [0.0, 0.0, 2 * d]]))
    model = builder.finalize(device)
    state = state_from_positions(model, model.rest_positions + np.array([0.0, 0.0, 1.0]))
    return chunk_time_s(Stepper(Solver(model), state, Control.create(model), chunk=1000)) / 1000 * 1e6


def main(out: Path, quick: bool, repeats: int, device=None) -> int:
    """The full runs and windows of every size; the report is rewritten after each measurement, so a
    run stopped by a time limit (a lent GPU's) keeps what it measured."""
    device = wp.get_device(device)
    sizes = (1, 4, 16) if quick else (1, 16, 256, 4096)
    full_sizes = [b for b in sizes if b <= (1 if quick else 16)] if device.is_cpu else list(sizes)
    rows = {b: Row(b) for b in sizes}
    floor = launch_floor_us(device)
    row, mid = run_full(1, device)  # the windows start from its half-deployed state
    rows[1] = row
    print(f"B =     1 full: {row.deployments_per_min:.3g} deployments/min ({row.completed}/1 completed, "
          f"{row.full_wall_time_s:.1f} s)", flush=True)
    for b in sizes:  # the windows first: cheap at any size
        steps = 40 if b * 200 < 100_000 or device.is_cuda else 10
        rows[b].window_steps = steps
        rows[b].us_per_member_step = window_us_per_member_step(b, mid, steps, device)
        print(f"B = {b:5d} window: {rows[b].us_per_member_step:.3g} µs per member-step", flush=True)
        write_ensemble_report(out, rows, floor, quick, device)
    for b in full_sizes[1:]:
        row, _ = run_full(b, device)
        row.window_steps, row.us_per_member_step = rows[b].window_steps, rows[b].us_per_member_step
        rows[b] = row
        print(f"B = {b:5d} full: {row.deployments_per_min:.3g} deployments/min ({row.completed}/{b} completed, "
              f"{row.full_wall_time_s:.1f} s)", flush=True)
        write_ensemble_report(out, rows, floor, quick, device)
    return 0


def write_ensemble_report(out: Path, rows: dict, floor: float, quick: bool, device) -> None:
    """ensemble.md and ensemble.json from the rows measured so far (deployments per minute of a size
    without a full run extrapolated from its window; sizes not yet measured left out)."""
    one = rows[1]
    rows = {b: r for b, r in rows.items() if r.us_per_member_step or r.full_wall_time_s is not None}
    for r in rows.values():
        r.extrapolated = r.full_wall_time_s is None
        if r.extrapolated and r.us_per_member_step:
            r.deployments_per_min = one.deployments_per_min * one.us_per_member_step / r.us_per_member_step
    table = markdown_table(
        ["B (members)", "full run: wall time (s)", "completed", "µs per member-step (half deployed)",
         "deployments / min"],
        [[r.members, "" if r.full_wall_time_s is None else r.full_wall_time_s,
          "" if r.completed is None else f"{r.completed}/{r.members}", r.us_per_member_step,
          f"{r.deployments_per_min:.3g}" + (" (from the window)" if r.extrapolated else "")]
         for r in rows.values()])
    notes = (f"Launch floor (the same launches per step on a 3-node coil, graph replay): {floor:.3g} µs per step; "
             f"compute of the half-deployed seed case: {one.us_per_member_step:.3g} µs per step; the single run "
             f"averages {one.full_wall_time_s / one.full_steps * 1e6:.3g} µs per step over {one.full_steps} steps "
             f"(frames, measurements and checks included).")
    command = f"warpcoil bench ensemble{' --quick' if quick else ''}" + (f" --device {device.alias}"
                                                                         if device.is_cuda else "")
    write_report(out / "ensemble.md", "Seed-case deployments per minute against ensemble size", command,
                 [f"Device: {device.alias} ({device.name}).", table, notes])
    write_text_atomic(out / "ensemble.json", json.dumps({"rows": [asdict(r) for r in rows.values()],
                                                          "launch_floor_us_per_step": floor}, indent=1))
