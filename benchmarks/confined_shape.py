"""Where a coil comes to rest in an ordinary confined deployment, by step: the derived 18-system coil
(d 0.381 mm, primary wire 0.0762 mm, 3 mm spherical pre-shape, 50 mm) pushed at 50 mm/s into a 4 mm
sphere, at the implicit default push step, at a half and a quarter of it (``dt_s``), and on the symplectic
reference. Its pre-shape fits the sphere: the reference comes to rest in it (bend + twist ~0 nJ); the
implicit default rests stressed (docs/FORMULATION.md "In ordinary sacs too").

    python -m benchmarks.confined_shape              # default, half, quarter (~10 s)
    python -m benchmarks.confined_shape --reference  # and the reference (~1 min more)

Prints a line per run; ``--out FILE`` writes them as JSON.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

from warpcoil.deploy import Deployment
from warpcoil.scene import load_scene

SCENE = """
[wall]
sphere_diameter_mm = 4.0
[catheter]
tip = [0.0, 0.0, -1.7]
direction = [0.0, 0.0, 1.0]
[[coil]]
shape = "spherical"
wire_diameter_mm = 0.381
primary_wire_diameter_mm = 0.0762
loop_diameter_mm = 3.0
length_mm = 50.0
[simulation]
push_speed_mm_s = 50.0
[output]
usd = false
png = false
tube_mesh = false
"""
STEP_FRACTIONS = (1.0, 0.5, 0.25)  # of the implicit default push step


def run(path: Path, overrides: dict) -> dict:
    """One deployment of the scene at ``path``: status, steps, push step (s), resting bend + twist (nJ)."""
    result = Deployment(load_scene(path, overrides)).run()
    return {"status": result.status, "steps": result.steps, "dt_s": result.dt_s,
            "rest_bend_twist_nJ": result.final_bend_nJ + result.final_twist_nJ,
            "min_coil_gap_mm": result.frames[-1].min_coil_gap_mm}


def main(reference: bool = False) -> list[dict]:
    """The runs: the implicit step at each of STEP_FRACTIONS of its push step, then (``reference``) the
    symplectic reference."""
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "confined_shape.toml"
        path.write_text(SCENE)
        push_dt_s = None
        for fraction in STEP_FRACTIONS:
            keys = {} if fraction == 1.0 else {"simulation.dt_s": fraction * push_dt_s}
            rows.append({"run": f"implicit, {fraction:g} × the push step", **run(path, keys)})
            push_dt_s = push_dt_s or rows[0]["dt_s"]
        if reference:
            rows.append({"run": "reference (symplectic)", **run(path, {"simulation.integrator": "symplectic"})})
    for row in rows:
        print(f"{row['run']}: {row['status']}, {row['steps']} steps of {row['dt_s']:.3g} s, resting bend + twist "
              f"{row['rest_bend_twist_nJ']:.1f} nJ, smallest coil gap {row['min_coil_gap_mm']:.4f} mm", flush=True)
    return rows


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--reference", action="store_true", help="also run the symplectic reference")
    parser.add_argument("--out", help="write the runs as JSON to this file")
    args = parser.parse_args()
    found = main(args.reference)
    if args.out:
        Path(args.out).write_text(json.dumps(found, indent=1))
