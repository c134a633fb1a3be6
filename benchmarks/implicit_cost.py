"""Cost of the implicit step: the seed case and the faceted sac, run by run and launch by launch.

    python -m benchmarks.implicit_cost [--repeats 3] [--out docs/bench/implicit_cost.md]
        [--solver-options '{"theta": 0.7, "near_theta": 1.0, "contact_stiffness": "chord"}']

1. ``scenes/seed_sphere.toml`` and a 60 mm coil (d 0.2921 mm) into the irregular
   faceted sac of 20 mm³ (warpcoil.faceted_sac, as ``warpcoil validate dense-pack``
   builds it, on the implicit step; with the BVH, the default, and with the wall field
   as the seed scene sets it) deployed to the end ``--repeats`` times: steps,
   the run's CPU time split into the steps (graph replays) and the frames (the
   host's measurements between them), µs per step; the fastest repeat.
2. The seed case's step at three saved moments (15 mm out, 15 mm left, settling):
   graph-replayed steps from there (the fastest of the repeats), and each launch of
   one step replayed alone from a captured graph (neighbour-grid builds weighted by
   how often a step builds there). Launches with state (the wall pass's anchors and
   certificates, the neighbour lists, the touching record) cost less replayed on a
   state that does not move, and a launch replayed on the same data again and again
   runs its data-dependent branches (BVH traversal, closest-point regions) predicted:
   their sum is a floor. So each launch is also timed *in sequence*: every launch of
   two steps captured as its own graph, the graphs replayed in the step's order for
   64 steps on from the graph-replayed ones (each timed alone, less an empty graph's
   replay; the conditional grid build is one graph): what each launch costs in a run.
3. The wall pass's signed BVH queries per step over each run (the frames' exact
   measurement pass included).

Times are this process's CPU time (``time.process_time``: Warp runs CPU kernels in
the calling thread; time the shared machine gives others is left out, cache
contention is not). Units µs, s.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time
from collections import defaultdict
from pathlib import Path
from unittest import mock

import numpy as np
import warp as wp

from warpcoil.bench.ensemble import STATE_ARRAYS
from warpcoil.bench.report import machine, markdown_table
from warpcoil.bench.steps import launch_costs, seed_scene
from warpcoil.deploy import Deployment, Ensemble
from warpcoil.field_cache import FIELD_CACHE_ENV
from warpcoil.solver import Stepper
from warpcoil.state import new_state_like
from warpcoil.validation import dense_pack_ensemble

WINDOW_MM = 15.0
MOMENTS = ("15 mm out", "15 mm left", "settling")


def faceted_sac_run(wall_query: str = "bvh") -> Ensemble:
    """The dense-pack case of ``warpcoil validate`` (20 mm³ at 20 %) on the implicit step, the
    wall queried by ``wall_query`` (the default BVH, or "sdf": the narrow-band field, as the seed
    scene sets it; its build, once per wall and cached, is made here and reported apart)."""
    return dense_pack_ensemble(0.20, 4.0, "implicit", wall_query=wall_query)


def without_field_cache(make):
    """``make()`` with the on-disk field cache off (field_cache.py), so a wall field is built."""
    with mock.patch.dict(os.environ, {FIELD_CACHE_ENV: "off"}):
        return make()


def timed_run(ensemble: Ensemble) -> dict:
    """Run to the end; steps, CPU time (s) of the run, of its steps and of its frames."""
    in_steps = [0.0]
    run_chunk = Stepper.run_chunk

    def timed_chunk(stepper, between=None):
        start = time.process_time()
        state = run_chunk(stepper, between)
        in_steps[0] += time.process_time() - start
        return state

    Stepper.run_chunk = timed_chunk
    try:
        start = time.process_time()
        result = Ensemble.run(ensemble)[0]  # (a Deployment's run returns its one result)
        total = time.process_time() - start
    finally:
        Stepper.run_chunk = run_chunk
    searches = getattr(ensemble.solver, "wall_searches", None)
    field = result.wall_field or {}
    return dict(status=result.status, steps=result.steps, cpu_s=total, steps_s=in_steps[0], frames_s=total - in_steps[0],
                field_build_s=field.get("build_s", 0.0) if not field.get("from_cache", True) else 0.0,
                us_per_step=in_steps[0] / result.steps * 1e6,
                searches_per_step=float(searches.numpy().sum()) / result.steps if searches is not None else math.nan)


def seed_states(options: dict | None = None) -> dict:
    """Host copies of the seed run's state at the three moments (with the step there);
    ``options``: the solver's (Deployment's solver_options)."""
    deployment = Deployment(seed_scene(), solver_options=options)
    total = float(deployment.coil_lengths_mm.sum())
    states: dict = {}

    def on_frame(frame, state):
        reached = {"15 mm out": frame.deployed_length_mm >= WINDOW_MM,
                   "15 mm left": frame.deployed_length_mm >= total - WINDOW_MM,
                   "settling": deployment.solver.dt_s > deployment.settle_dt_s * 0.99 > 0.0}
        for moment, now in reached.items():
            if now and moment not in states:
                states[moment] = {k: getattr(state, k).numpy().copy() for k in STATE_ARRAYS}
                states[moment]["time_s"], states[moment]["dt_s"] = state.time_s, deployment.solver.dt_s

    deployment.run(on_frame)
    return states


def replay_us(kind: str, target, args, kwargs, device, launches: int = 20, repeats: int = 15) -> float:
    """µs per call of one recorded launch, the fastest of ``repeats`` replays of a
    graph of ``launches`` of it (a HashGrid build, not capturable here, called directly)."""
    best = math.inf
    if kind == "build":
        for _ in range(repeats):
            start = time.process_time()
            target.build(*args, **kwargs)
            best = min(best, time.process_time() - start)
        return best * 1e6
    with wp.ScopedCapture(device=device) as capture:
        for _ in range(launches):
            wp.launch(target, *args, **kwargs)
    wp.capture_launch(capture.graph)
    for _ in range(repeats):
        start = time.process_time()
        wp.capture_launch(capture.graph)
        best = min(best, time.process_time() - start)
    return best / launches * 1e6


def profile(states: dict, repeats: int, steps: int = 64, options: dict | None = None) -> tuple[dict, dict, dict]:
    """Per moment: the graph-replayed step (µs, fastest of ``repeats`` chunks), µs per
    launch of one step replayed alone, and µs per step of each launch in sequence
    (``options``: the solver's, as seed_states had them)."""
    deployment = Deployment(seed_scene(), solver_options=options)
    solver, control, device = deployment.solver, deployment.control, deployment.model.device
    whole, launches, sequence = {}, {}, {}
    for moment, host in states.items():
        state = new_state_like(deployment.model)
        for k in STATE_ARRAYS:
            getattr(state, k).assign(host[k])
        state.time_s = host["time_s"]
        control.set_active_coil(-1 if moment == "settling" else 0)
        solver.dt_s = host["dt_s"]
        stepper = Stepper(solver, state, control, chunk=steps)
        stepper.run_chunk()  # capture, anchors, lists
        best = math.inf
        for _ in range(repeats):
            start = time.process_time()
            stepper.run_chunk()
            best = min(best, time.process_time() - start)
        whole[moment] = best / steps * 1e6
        sequence[moment] = in_sequence_us(stepper, device, steps)  # on from there (anchors, lists as the run left them)
        launches[moment] = launch_costs(solver, stepper.state, control, steps, time_launch=replay_us)[0]
    return whole, launches, sequence


def step_ops(solver, state_a, state_b, control) -> list:
    """Two steps (a → b → a) as (name, launch thunk), not run: each wp.launch, and the
    conditional neighbour-grid build as one."""
    ops = []
    launch, capture_if = wp.launch, wp.capture_if
    wp.launch = lambda kernel, *a, **kw: ops.append((kernel.key, lambda: launch(kernel, *a, **kw)))
    wp.capture_if = lambda condition, on_true: ops.append(
        ("grid build (conditional)", lambda: capture_if(condition, on_true=on_true)))
    try:
        solver.step(state_a, state_b, control)
        solver.step(state_b, state_a, control)
    finally:
        wp.launch, wp.capture_if = launch, capture_if
    return ops


def in_sequence_us(stepper: Stepper, device, steps: int = 64) -> dict:
    """µs per step of each launch replayed in the step's order from ``stepper``'s state
    (each launch its own captured graph, timed alone, less an empty graph's replay;
    the mean over ``steps`` steps)."""
    solver = stepper.solver
    solver.allocate_neighbour_grid(stepper.state)
    graphs = []
    for name, thunk in step_ops(solver, stepper.state, stepper._b, stepper.control):
        with wp.ScopedCapture(device=device) as capture:
            thunk()
        graphs.append((name, capture.graph))
    with wp.ScopedCapture(device=device) as capture:
        pass
    empty = capture.graph
    overhead = math.inf
    for _ in range(200):
        start = time.process_time_ns()
        wp.capture_launch(empty)
        overhead = min(overhead, time.process_time_ns() - start)
    times: dict[str, float] = defaultdict(float)
    for _ in range(steps // 2):
        for name, graph in graphs:
            start = time.process_time_ns()
            wp.capture_launch(graph)
            times[name] += (time.process_time_ns() - start - overhead) * 1e-3 / steps
    return dict(times)


def moment_table(how: str, per_moment: dict, total: str, whole: dict) -> str:
    """µs per step of each launch at each moment (slowest late in the push first), their
    sum and the graph-replayed step."""
    names = sorted({k for v in per_moment.values() for k in v}, key=lambda k: -per_moment["15 mm left"].get(k, 0.0))
    return markdown_table(
        [f"launch: µs per step, {how}"] + list(MOMENTS),
        [[k] + [per_moment[m].get(k, 0.0) for m in MOMENTS] for k in names]
        + [[total] + [sum(per_moment[m].values()) for m in MOMENTS],
           ["the step, graph-replayed"] + [whole[m] for m in MOMENTS]])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", type=Path, default=None, help="also write the report (markdown) here")
    parser.add_argument("--solver-options", type=json.loads, default=None,
                        help="the seed case's solver options (JSON), e.g. the gated θ with the chord stiffness")
    args = parser.parse_args()
    options = args.solver_options
    runs = {}
    for name, make in (("seed case", lambda: Deployment(seed_scene(), solver_options=options)),
                       ("faceted sac 20 mm³", faceted_sac_run),
                       ("faceted sac 20 mm³, wall field (sdf)", lambda: faceted_sac_run("sdf"))):
        rows = [timed_run(make() if k else without_field_cache(make)) for k in range(args.repeats)]
        runs[name] = min(rows, key=lambda r: r["cpu_s"])
        runs[name]["field_build_s"] = rows[0]["field_build_s"]  # the first: built, not loaded
        print(name, runs[name], flush=True)
    whole, launches, sequence = profile(seed_states(options), args.repeats, options=options)
    run_table = markdown_table(
        ["case", "status", "steps", "CPU s (fastest)", "of which steps", "of which frames", "µs per step",
         "signed BVH queries per step", "field build s (the first repeat's, cache off; then cached)"],
        [[n, r["status"], r["steps"], r["cpu_s"], r["steps_s"], r["frames_s"], r["us_per_step"],
          r["searches_per_step"], r["field_build_s"]] for n, r in runs.items()])
    launch_table = moment_table("replayed alone", launches, "sum of the launches", whole)
    sequence_table = moment_table("in sequence", sequence, "sum in sequence", whole)
    text = "\n\n".join([
        "# Cost of the implicit step", f"`python -m benchmarks.implicit_cost --repeats {args.repeats}"
        + (f" --solver-options '{json.dumps(options)}'`" if options else "`"),
        f"Machine: {machine()}. Times: this process's CPU time (the machine is shared).",
        run_table, launch_table, sequence_table]) + "\n"
    print(text)
    if args.out:
        args.out.write_text(text)


if __name__ == "__main__":
    main()
