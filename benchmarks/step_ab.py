"""The implicit step of two versions of warpcoil compared in one process: a git revision's
package (extracted and imported as ``warpcoil_<rev>``) against the checkout's, each stepping
from the same saved seed states in turn, so the shared machine's drift falls on both.

    python -m benchmarks.step_ab REV [--reps 30]

At the seed case's three moments (benchmarks.implicit_cost.seed_states: 15 mm out, 15 mm
left, settling, saved from this checkout's run) each version loads the state and replays a
chunk of 32 graph-replayed steps, alternately, ``--reps`` times; prints the least process
time per step (µs) of each and their ratio (this checkout over REV). Whole runs of one
version after the other differ by ±25 % on this machine; the ratio of two such alternated
minima repeats within a few % late in the push (docs/FORMULATION.md, "each chord pair once").
"""

from __future__ import annotations

import argparse
import importlib
import math
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.implicit_cost import STATE_ARRAYS, seed_states

ROOT = Path(__file__).resolve().parents[1]
CHUNK = 32


def import_revision(rev: str, into: Path):
    """``rev``'s warpcoil package (and its scenes) extracted under ``into`` and imported
    as ``warpcoil_<rev>`` (absolute self-imports renamed; Warp then keeps its kernels apart)."""
    name = "warpcoil_" + re.sub(r"\W", "_", rev)
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", rev, "warpcoil", "scenes"], check=True,
                             capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(into)], input=archive, check=True)
    (into / "warpcoil").rename(into / name)
    for source in (into / name).rglob("*.py"):
        text = source.read_text()
        renamed = re.sub(r"\b(from|import) warpcoil\b", rf"\1 {name}", text)
        if renamed != text:
            source.write_text(renamed)
    sys.path.insert(0, str(into))
    return importlib.import_module(name)


def main(rev: str, reps: int) -> None:
    import warpcoil

    with tempfile.TemporaryDirectory() as folder:
        other = import_revision(rev, Path(folder))
        importlib.import_module(other.__name__ + ".bench.steps")
        states = seed_states()
        versions = {rev: other, "checkout": warpcoil}
        deployments = {label: pkg.deploy.Deployment(pkg.bench.steps.seed_scene()) for label, pkg in versions.items()}
        for moment, host in states.items():
            runners, best = {}, {}
            for label, pkg in versions.items():
                d = deployments[label]
                state = pkg.state.new_state_like(d.model)
                d.control.set_active_coil(-1 if moment == "settling" else 0)
                d.solver.dt_s = host["dt_s"]

                def load(state=state):
                    for key in STATE_ARRAYS:
                        getattr(state, key).assign(host[key])
                    state.time_s = host["time_s"]

                load()
                stepper = pkg.solver.Stepper(d.solver, state, d.control, chunk=CHUNK)
                stepper.run_chunk()  # capture, lists
                runners[label], best[label] = (stepper, load), math.inf
            for _ in range(reps):
                for label, (stepper, load) in runners.items():
                    load()
                    start = time.process_time()
                    stepper.run_chunk()
                    best[label] = min(best[label], time.process_time() - start)
            a, b = (best[label] / CHUNK * 1e6 for label in versions)
            print(f"{moment:11s} {rev}: {a:7.1f}  checkout: {b:7.1f} µs/step  ratio {b / a:.3f}", flush=True)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("rev", help="git revision to compare the checkout with")
    parser.add_argument("--reps", type=int, default=30, help="alternated chunks per version and moment")
    args = parser.parse_args()
    main(args.rev, args.reps)
