"""What a run's frames cost beside its steps: process time per frame of the contact
measurement (Solver.measure_contacts), the health check (Solver.world_health) and the
rest of the frame loop, next to the steps' and the run's, and wall_time_s; median
over runs after a warm-up run, all in one process.

    PYTHONPATH=$PWD python -m benchmarks.frame_cost scenes/seed_sphere.toml --runs 3
    PYTHONPATH=$PWD python -m benchmarks.frame_cost scenes/seed_sphere.toml --set contact.wall_query=sdf

Process time (not wall time) so a loaded machine inflates it less; still noisy there.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from warpcoil.deploy import Deployment
from warpcoil.scene import load_scene
from warpcoil.solver import Solver, Stepper

PARTS = ("steps", "measure_contacts", "world_health")


class Timers:
    """Process time spent in the solver's steps, measurement and health check (outermost calls only)."""

    def __init__(self):
        self.seconds = dict.fromkeys(PARTS, 0.0)
        self._depth = 0
        self._saved = {}

    def _wrap(self, owner, name: str, part: str):
        inner = getattr(owner, name)
        self._saved[(owner, name)] = inner

        def timed(*args, **kwargs):
            self._depth += 1
            start = time.process_time()
            try:
                return inner(*args, **kwargs)
            finally:
                self._depth -= 1
                if self._depth == 0:
                    self.seconds[part] += time.process_time() - start

        setattr(owner, name, timed)

    def __enter__(self) -> "Timers":
        self._wrap(Stepper, "run_chunk", "steps")
        self._wrap(Solver, "measure_contacts", "measure_contacts")
        self._wrap(Solver, "world_health", "world_health")
        return self

    def __exit__(self, *exc) -> None:
        for (owner, name), inner in self._saved.items():
            setattr(owner, name, inner)


def measure(scene, runs: int) -> dict:
    """Median over ``runs`` (after a warm-up) of: run and step process time (s), per-frame µs
    of each part and of the rest of the frame loop, wall_time_s, steps and frames."""
    Deployment(scene).run()  # warm-up: modules loaded, graphs captured in this process
    rows = []
    for _ in range(runs):
        run = Deployment(scene)
        with Timers() as timers:
            start = time.process_time()
            result = run.run()
            total = time.process_time() - start
        frames = len(result.frames)
        seconds = timers.seconds
        rest = total - sum(seconds.values())
        rows.append([total, seconds["steps"], 1e6 * seconds["measure_contacts"] / frames,
                     1e6 * seconds["world_health"] / frames, 1e6 * rest / frames, result.wall_time_s,
                     result.steps, frames])
    median = np.median(np.array(rows), axis=0)
    keys = ("run_cpu_s", "steps_cpu_s", "measure_us_per_frame", "health_us_per_frame", "rest_us_per_frame",
            "wall_time_s", "steps", "frames")
    return dict(zip(keys, median.tolist()))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene")
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="scene override, e.g. contact.wall_query=sdf (repeatable)")
    args = parser.parse_args(argv)
    overrides = {"output.usd": False, "output.png": False}
    for item in args.set:
        key, _, value = item.partition("=")
        overrides[key] = value
    m = measure(load_scene(args.scene, overrides), args.runs)
    print(f"{args.scene} {' '.join(args.set)}: {int(m['steps'])} steps, {int(m['frames'])} frames; run "
          f"{m['run_cpu_s']:.3f} s CPU (steps {m['steps_cpu_s']:.3f} s), wall_time_s {m['wall_time_s']:.3f}; per frame: "
          f"measurement {m['measure_us_per_frame']:.0f} µs, health {m['health_us_per_frame']:.0f} µs, "
          f"rest of the loop {m['rest_us_per_frame']:.0f} µs (median of {args.runs})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
