"""What one deployment spends outside its steps: wall time less the time inside the step
graphs' replays (``Stepper.run_chunk`` less the graph captures made in it).

    python -m benchmarks.outside_steps [scene]   # default scenes/seed_sphere.toml

Prints one JSON line: wall_s (the run's ``wall_time_s``), steps_s, outside_s (s). Run it in
alternated fresh processes (before/after a change) and compare medians: the machine's
run-to-run spread is ±20 % under load (docs/FORMULATION.md, "what a run spends outside
the steps").
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace

import warp as wp

from warpcoil import solver as solver_module
from warpcoil.deploy import Deployment
from warpcoil.scene import load_scene


def main(scene_path: str = "scenes/seed_sphere.toml") -> dict:
    spent = {"chunks_s": 0.0, "captures_s": 0.0}
    in_chunk = [False]
    capture_class, run_chunk = wp.ScopedCapture, solver_module.Stepper.run_chunk

    class TimedCapture(capture_class):
        def __enter__(self):
            self._started = time.perf_counter()
            return super().__enter__()

        def __exit__(self, *exc):
            done = super().__exit__(*exc)
            if in_chunk[0]:
                spent["captures_s"] += time.perf_counter() - self._started
            return done

    def timed_chunk(stepper, between=None):
        in_chunk[0], started = True, time.perf_counter()
        try:
            return run_chunk(stepper, between)
        finally:
            spent["chunks_s"] += time.perf_counter() - started
            in_chunk[0] = False

    scene = load_scene(scene_path)
    scene = replace(scene, output=replace(scene.output, usd=False, png=False, tube_mesh=False))
    deployment = Deployment(scene)
    wp.ScopedCapture, solver_module.Stepper.run_chunk = TimedCapture, timed_chunk
    try:
        result = deployment.run()
    finally:
        wp.ScopedCapture, solver_module.Stepper.run_chunk = capture_class, run_chunk
    steps_s = spent["chunks_s"] - spent["captures_s"]
    return {"steps": result.steps, "wall_s": round(result.wall_time_s, 3), "steps_s": round(steps_s, 3),
            "outside_s": round(result.wall_time_s - steps_s, 3)}


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scene", nargs="?", default="scenes/seed_sphere.toml", help="scene file (TOML)")
    print(json.dumps(main(parser.parse_args().scene)), flush=True)
