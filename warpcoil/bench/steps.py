"""`warpcoil bench steps`: per-step cost of the seed case, change by change, and
where the time of a step goes.

1. The seed case (scenes/seed_sphere.toml) run to the end once per setting, in
   one process, the cheap-step changes added one by one: neighbour skin
   0.05 → 0.2 mm, the signed wall query skipped for nodes in contact that cannot
   have left the lumen, wall query BVH → narrow-band field. Steps, wall time and µs
   per step (the run's wall time over its steps: frames and checks included;
   the field's build time reported apart, it is part of the run's time); and,
   less noisy, the graph-replayed step cost of each setting from the same
   three saved states (below), interleaved, the fastest of ``--repeats``.
2. The damping solve (stopped at its fixed point) against the six-iteration
   solve: the integration kernel timed alone on the half-deployed state.
3. A profile at three states of the run — the first 15 mm out, the last 15 mm
   out, after detachment: the graph-replayed step cost there, and each launch
   of one step replayed alone from a captured graph (neighbour-grid builds
   weighted by how often a step builds); the launch floor (the same launches
   on a 3-node coil).
"""

from __future__ import annotations

import json
import math
import time
from collections import defaultdict
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import warp as wp

from ..deploy import Deployment
from ..kernels import integrate
from ..recorder.atomic import write_text_atomic
from ..scene import load_scene
from ..solver import Stepper
from ..state import new_state_like
from .ensemble import SEED_SCENE, STATE_ARRAYS
from .report import markdown_table, write_report

SETTINGS = (  # cumulative: each row adds one change to the one before
    ("before: skin 0.05 mm, wall BVH", dict(neighbour_skin_mm=0.05, wall_query="bvh", wall_sided_skip=False)),
    ("+ neighbour skin 0.2 mm", dict(neighbour_skin_mm=0.2, wall_query="bvh", wall_sided_skip=False)),
    ("+ signed wall query skipped in the lumen", dict(neighbour_skin_mm=0.2, wall_query="bvh")),
    ("+ wall field (the seed scene's setting)", dict(neighbour_skin_mm=0.2, wall_query="sdf")),
)
WINDOW_MM = 15.0  # the profile's first and last stretch of the push


def clock(device) -> float:
    """Seconds of this process's CPU time on a CPU device (Warp runs CPU kernels in
    the calling thread, so time the shared machine gives to others is left out);
    wall time on a GPU."""
    return time.process_time() if wp.get_device(device).is_cpu else time.perf_counter()


def chunk_time_s(stepper: Stepper) -> float:
    """Time (:func:`clock`) of one chunk after two warm-up chunks (capture, wall
    sides and anchors, neighbour lists)."""
    device = stepper.solver.model.device
    stepper.run_chunk()
    stepper.run_chunk()
    wp.synchronize_device(device)
    start = clock(device)
    stepper.run_chunk()
    wp.synchronize_device(device)
    return clock(device) - start


def launch_floor_us(device) -> float:
    """µs per step of the same launches on a 3-node coil (no wall), graph replay."""
    from .. import CoilSpec, Control, ModelBuilder, Solver, state_from_positions

    builder = ModelBuilder()
    d = 0.2921
    builder.add_coil(CoilSpec(length_mm=2 * d, wire_diameter_mm=d), np.array([[0.0, 0.0, 0.0], [0.0, 0.0, d],
                                                                             [0.0, 0.0, 2 * d]]))
    model = builder.finalize(device)
    state = state_from_positions(model, model.rest_positions + np.array([0.0, 0.0, 1.0]))
    return chunk_time_s(Stepper(Solver(model), state, Control.create(model), chunk=1000)) / 1000 * 1e6


@dataclass
class RunRow:
    setting: str
    steps: int
    run_time_s: float  # set-up + run (clock())
    us_per_step: float  # the run alone over its steps
    set_up_s: float  # model and solver, the wall field's build included
    status: str


@dataclass
class Profile:
    state: str
    graph_us_per_step: float
    kernel_us_per_step: dict = field(default_factory=dict)  # launch → µs per step, each replayed alone


def seed_scene():
    return load_scene(SEED_SCENE, {"output.usd": False, "output.png": False})


def run_setting(name: str, options: dict, keep_states: bool) -> tuple[RunRow, dict]:
    """The seed case to the end with ``options``; with ``keep_states`` also its
    states (host copies) at the profile's three moments."""
    before = clock(None)
    deployment = Deployment(seed_scene(), solver_options=options)
    set_up = clock(None) - before  # model, solver and (with the field) its build
    total = float(deployment.coil_lengths_mm.sum())
    states: dict = {}

    def on_frame(frame, state):
        if not keep_states:
            return
        moments = {"first 15 mm": frame.deployed_length_mm >= WINDOW_MM,
                   "last 15 mm": frame.deployed_length_mm >= total - WINDOW_MM,
                   "after detachment": frame.deployed_length_mm >= total}
        for moment, reached in moments.items():
            if reached and moment not in states:
                states[moment] = {k: getattr(state, k).numpy().copy() for k in STATE_ARRAYS}
                states[moment]["time_s"] = state.time_s

    device = deployment.model.device
    start = clock(device)
    result = deployment.run(on_frame)
    elapsed = clock(device) - start
    return RunRow(name, result.steps, elapsed + set_up, elapsed / result.steps * 1e6, set_up,
                  result.status), states


class LaunchRecorder:
    """Records every wp.launch (and HashGrid.build) of the code run while active,
    passing them through."""

    def __init__(self):
        self.launches: list[tuple] = []

    def __enter__(self):
        self._launch, self._build = wp.launch, wp.HashGrid.build
        recorder = self

        def launch(kernel, *args, **kwargs):
            recorder.launches.append(("launch", kernel, args, kwargs))
            return recorder._launch(kernel, *args, **kwargs)

        def build(grid, *args, **kwargs):
            recorder.launches.append(("build", grid, args, kwargs))
            return recorder._build(grid, *args, **kwargs)

        wp.launch, wp.HashGrid.build = launch, build
        return self

    def __exit__(self, *exc):
        wp.launch, wp.HashGrid.build = self._launch, self._build


def launch_us(kind: str, target, args: tuple, kwargs: dict, device, repeats: int = 50) -> float:
    """µs per call of one recorded launch, replayed ``repeats`` times from a
    captured graph (the compute and ~0.4 µs of replay; no Python launch
    overhead); a HashGrid build (not capturable here) is timed directly."""
    def call():
        if kind == "launch":
            wp.launch(target, *args, **kwargs)
        else:
            wp.HashGrid.build(target, *args, **kwargs)

    if kind == "build":
        call()
        wp.synchronize_device(device)
        start = clock(device)
        for _ in range(repeats):
            call()
        wp.synchronize_device(device)
        return (clock(device) - start) / repeats * 1e6
    with wp.ScopedCapture(device=device) as capture:
        for _ in range(repeats):
            call()
    wp.capture_launch(capture.graph)
    wp.synchronize_device(device)
    start = clock(device)
    for _ in range(4):
        wp.capture_launch(capture.graph)
    wp.synchronize_device(device)
    return (clock(device) - start) / (4 * repeats) * 1e6


def _start(deployment: Deployment, moment: str, host: dict):
    """A fresh state of ``deployment`` set to a saved moment of the seed run."""
    state = new_state_like(deployment.model)
    for name in STATE_ARRAYS:
        getattr(state, name).assign(host[name])
    state.time_s = host["time_s"]
    deployment.control.set_active_coil(-1 if moment == "after detachment" else 0)
    return state


def window_us(deployment: Deployment, moment: str, host: dict, steps: int) -> float:
    """µs per step of ``steps`` graph-replayed steps from a saved moment (after
    two warm-up chunks: capture, wall sides and anchors, neighbour lists)."""
    stepper = Stepper(deployment.solver, _start(deployment, moment, host), deployment.control, chunk=steps)
    return chunk_time_s(stepper) / steps * 1e6


def launch_costs(solver, state, control, steps: int, time_launch=launch_us) -> tuple[dict[str, float], float]:
    """µs per step of each launch of one step from ``state``, each replayed alone
    (``time_launch(kind, target, args, kwargs, device)``, µs per call), and the
    neighbour-grid builds per step there (counted over ``steps`` steps run without
    graphs from ``state``), by which the build's launches are weighted. The
    touching and chord-candidate records a launch reads are put back as the step left
    them before each one."""
    device = solver.model.device
    stepper = Stepper(solver, state, control, chunk=steps, use_graph=False)
    builds_before = solver.grid_builds
    stepper.run_chunk()
    build_share = (solver.grid_builds - builds_before) / steps
    solver._rebuild.fill_(1)
    conditional, solver._conditional_rebuild = solver._conditional_rebuild, False  # record a build too
    with LaunchRecorder() as recorder:
        solver.step(stepper.state, stepper._b, control)
    solver._conditional_rebuild = conditional
    # the implicit step's coil-contact records (touching partners, chord candidates)
    records = [getattr(solver, k) for k in ("_touch_count", "_chord_count") if getattr(solver, k, None) is not None]
    noted = [r.numpy().copy() for r in records]
    times: dict[str, float] = defaultdict(float)
    for kind, target, args, kwargs in recorder.launches:
        name = target.key if kind == "launch" else "HashGrid.build"
        for record, left in zip(records, noted):  # the contact pass's replays add to them: as the step left them
            record.assign(left)
        times[name] += time_launch(kind, target, args, kwargs, device)
    for name in ("mark_built", "HashGrid.build", "build_neighbours", "coil_midpoint_steps", "walk_neighbours"):
        if name in times:
            times[name] *= build_share
    return dict(times), build_share


def profile_state(deployment: Deployment, moment: str, host: dict, steps: int) -> Profile:
    """Each launch of a step at a saved moment replayed alone from a captured graph
    (:func:`launch_costs`)."""
    times, build_share = launch_costs(deployment.solver, _start(deployment, moment, host), deployment.control, steps)
    times["(grid builds per step)"] = build_share
    return Profile(moment, 0.0, dict(sorted(times.items(), key=lambda kv: -kv[1])))


@wp.func
def damped_speed_six(speed: wp.float64, a: wp.float64, k: wp.float64) -> wp.float64:
    """The damping solve before: always six Newton iterations (the bench and its test compare against it)."""
    if a <= wp.float64(0.0) or speed <= wp.float64(0.0):
        return speed
    s = speed / (wp.float64(1.0) + a / k)
    for _ in range(6):
        e = wp.exp(-s / k)
        s = s - (s + a * (wp.float64(1.0) - e) - speed) / (wp.float64(1.0) + a / k * e)
    return wp.max(s, wp.float64(0.0))


@wp.kernel
def damping_solves(v: wp.array(dtype=wp.vec3d), a: wp.array(dtype=wp.float64), k: wp.float64, six: int,
                   out: wp.array(dtype=wp.float64)):
    i = wp.tid()
    speed = wp.length(v[i])
    if six != 0:
        out[i] = damped_speed_six(speed, a[i], k)
    else:
        out[i] = integrate.damped_speed(speed, a[i], k)


def damping_us(host: dict, repeats: int = 2000) -> dict:
    """µs per launch (graph replay) of the damping solve over the nodes'
    velocities of a state (with the force step added, as in the integration
    kernel), six iterations against stopped at the fixed point."""
    deployment = Deployment(seed_scene())
    m, dt = deployment.model, deployment.solver.dt_s
    deployment.solver.compute_forces(_start(deployment, "last 15 mm", host))
    v = host["v"] + dt * m.inv_mass.numpy()[:, None] * deployment.solver.force.numpy()
    a = dt * m.damping_c.numpy() * m.inv_mass.numpy()
    va, aa = wp.array(v, dtype=wp.vec3d), wp.array(a, dtype=wp.float64)
    out = wp.zeros(len(v), dtype=wp.float64)
    timings = {}
    for label, six in (("six iterations", 1), ("stopped at the fixed point", 0)):
        wp.launch(damping_solves, len(v), inputs=[va, aa, m.damping_k, six, out])
        with wp.ScopedCapture() as capture:
            for _ in range(repeats):
                wp.launch(damping_solves, len(v), inputs=[va, aa, m.damping_k, six, out])
        start = clock(None)
        wp.capture_launch(capture.graph)
        wp.synchronize()
        timings[label] = (clock(None) - start) / repeats * 1e6
    return timings


def main(out: Path, quick: bool, repeats: int) -> int:
    device = wp.get_device()
    rows, states = [], {}
    for name, options in SETTINGS:
        row, saved = run_setting(name, options, keep_states=not states)
        states = states or saved
        rows.append(row)
        print(f"{name}: {row.steps} steps, {row.run_time_s:.2f} s ({row.us_per_step:.1f} µs/step, set-up "
              f"{row.set_up_s:.2f} s, {row.status})", flush=True)
    steps = 200 if quick else 1000
    deployments = {name: Deployment(seed_scene(), solver_options=options) for name, options in SETTINGS}
    windows = {(name, moment): math.inf for name in deployments for moment in states}
    for _ in range(repeats):  # interleaved, fastest of the repeats (the machine is shared)
        for (name, moment) in windows:
            windows[name, moment] = min(windows[name, moment],
                                        window_us(deployments[name], moment, states[moment], steps))
    default = deployments[SETTINGS[-1][0]]  # the profile with every change on
    profiles = [profile_state(default, moment, host, steps) for moment, host in states.items()]
    for p in profiles:
        p.graph_us_per_step = windows[SETTINGS[-1][0], p.state]
    damping = damping_us(states["last 15 mm"])
    floor = launch_floor_us(device)
    run_table = markdown_table(["setting", "steps", "time (s)", "µs per step", "of which set-up, field build "
                                                                            "included (s)", "status"],
                               [[r.setting, r.steps, r.run_time_s, r.us_per_step, r.set_up_s, r.status]
                                for r in rows])
    window_table = markdown_table(
        ["setting: µs per step (graph replay, fastest of the repeats)"] + list(states),
        [[name] + [windows[name, moment] for moment in states] for name, _ in SETTINGS])
    kernels = list(dict.fromkeys(k for p in profiles for k in p.kernel_us_per_step))
    profile_table = markdown_table(
        ["launch (every change on): µs per step, each replayed alone"] + [p.state for p in profiles],
        [[k] + [p.kernel_us_per_step.get(k, 0.0) for p in profiles] for k in kernels]
        + [["sum of the launches"] + [sum(v for k, v in p.kernel_us_per_step.items() if not k.startswith("("))
                                      for p in profiles],
           ["whole step (graph replay)"] + [p.graph_us_per_step for p in profiles]])
    notes = [
        f"Damping solve over the {len(states['last 15 mm']['v'])} nodes (last 15 mm state, one launch): "
        + ", ".join(f"{k} {v:.2f} µs" for k, v in damping.items()) + ".",
        f"Launch floor (the same launches on a 3-node coil, graph replay): {floor:.3g} µs per step. "
        "Compute floor at a state: its graph-replay cost minus the launch floor. "
        + ("Times are this process's CPU time (the machine is shared; time given to other processes is left out)."
           if device.is_cpu else "Times are wall times."),
    ]
    write_report(out / "steps.md", "Seed-case step cost, change by change, and where a step's time goes",
                 "warpcoil bench steps" + (" --quick" if quick else "") + f" --repeats {repeats}",
                 [f"Device: {device.alias} ({device.name}).", run_table, window_table, profile_table] + notes)
    write_text_atomic(out / "steps.json", json.dumps({
        "runs": [asdict(r) for r in rows], "windows_us": {f"{k[0]} | {k[1]}": v for k, v in windows.items()},
        "profiles": [asdict(p) for p in profiles], "damping_us": damping, "launch_floor_us": floor}, indent=1))
    return 0
