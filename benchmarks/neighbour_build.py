"""Cost of one coil–coil neighbour-list build: the hash grid against the per-world walk.

    python -m benchmarks.neighbour_build [--repeats 5]

1. One world packed dense: the seed coil (d 0.2921 mm, spherical pre-shape) at its
   pre-shape, lengthened with its loop diameter ∝ √length, so every edge is near
   many others — the walk's worst case (O(N²) against the grid's O(N) plus the
   constant of Warp's CPU radix sort over 65 536 buckets). Where the walk stops
   paying sets solver.NEIGHBOUR_WALK_MAX_NODES.
2. The seed case's states 15 mm out, 15 mm left and settling (most edges strung
   along the catheter while pushing).

Each build: the captured rebuild (``Solver._build_neighbour_lists``) replayed ten times, CPU
time of this process (``time.process_time``), the fastest of ``--repeats``
alternated replays per setting; the two lists are checked equal as sets. µs.
"""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import replace

import warp as wp

from warpcoil.bench.report import machine, markdown_table
from warpcoil.bench.steps import seed_scene
from warpcoil.deploy import Deployment
from warpcoil.solver import NEIGHBOUR_WALK_MAX_NODES, Solver
from warpcoil.state import State

BUILDS_PER_GRAPH = 10
LENGTHS_MM = (60.0, 90.0, 120.0, 150.0)


def captured_builds(solver: Solver):
    """A graph of BUILDS_PER_GRAPH forced rebuilds at the solver's current midpoints."""
    solver._rebuild.fill_(1)
    with wp.ScopedCapture(device=solver.model.device) as capture:
        for _ in range(BUILDS_PER_GRAPH):
            solver._build_neighbour_lists()
    wp.capture_launch(capture.graph)
    return capture.graph


def lists(solver: Solver) -> list:
    """Per edge: its neighbour list as a sorted tuple, or None when it overflowed (NO_LIST)."""
    count, table = solver._neighbour_count.numpy(), solver._neighbours.numpy()
    return [None if c < 0 else tuple(sorted(table[a, :c])) for a, c in enumerate(count)]


def build_us(model, state: State, repeats: int) -> tuple[float, float]:
    """(grid, walk) µs per build at ``state``'s positions."""
    solvers, graphs = {}, {}
    for how in ("grid", "walk"):
        solver = Solver(model, dt_s=1.0e-6, allow_unstable_dt=True, neighbour_build=how)
        solver.allocate_neighbour_grid(state)
        solver._launch_midpoints(state)
        solvers[how], graphs[how] = solver, captured_builds(solver)
    if lists(solvers["grid"]) != lists(solvers["walk"]):
        raise AssertionError("the walked lists differ from the grid's")
    best = {how: math.inf for how in graphs}
    for _ in range(repeats):
        for how, graph in graphs.items():
            start = time.process_time()
            wp.capture_launch(graph)
            best[how] = min(best[how], (time.process_time() - start) / BUILDS_PER_GRAPH * 1e6)
    return best["grid"], best["walk"]


def dense_rows(repeats: int) -> list[list]:
    base = seed_scene()
    rows = []
    for length in LENGTHS_MM:
        coil = replace(base.coils[0], length_mm=length, loop_diameter_mm=3.0 * math.sqrt(length / 60.0))
        deployment = Deployment(replace(base, coils=(coil,)))
        state = deployment.stepper.state
        state.x.assign(deployment.model.rest_x.numpy())
        grid, walk = build_us(deployment.model, state, repeats)
        rows.append([f"dense, {length:.0f} mm", deployment.model.node_count, grid, walk, walk / grid])
    return rows


def seed_rows(repeats: int) -> list[list]:
    from benchmarks.implicit_cost import seed_states
    from warpcoil.bench.ensemble import STATE_ARRAYS
    from warpcoil.state import new_state_like

    deployment = Deployment(seed_scene())
    rows = []
    for moment, host in seed_states().items():
        state = new_state_like(deployment.model)
        for name in STATE_ARRAYS:
            getattr(state, name).assign(host[name])
        grid, walk = build_us(deployment.model, state, repeats)
        rows.append([f"seed case, {moment}", deployment.model.node_count, grid, walk, walk / grid])
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    rows = dense_rows(args.repeats) + seed_rows(args.repeats)
    print("\n\n".join([
        "# Neighbour-list build: hash grid against the per-world walk",
        f"Machine: {machine()}. CPU time of this process, µs per build, fastest of {args.repeats}. "
        f"'auto' walks up to {NEIGHBOUR_WALK_MAX_NODES} nodes a world.",
        markdown_table(["state", "nodes", "grid µs", "walk µs", "walk / grid"], rows)]))


if __name__ == "__main__":
    main()
