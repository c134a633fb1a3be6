"""Where a coil comes to rest in a tight sac, by scheme and frame interval: a 30 mm
spherical coil of 2.5 mm loops (d 0.2921 mm, segments of d) pushed at 100 mm/s into a
3.2 mm sphere, whose pre-shape fits it without touching itself, from catheters tilted
3° at ``runs`` azimuths (tip offset 0.05 mm). A run "in the pre-shape" completes and rests with bend +
twist energy below 10 nJ; the others rest tangled (155–201 nJ, 18–19 coil contacts) (docs/FORMULATION.md, "the free release
that comes to rest tangled": in a sac too).

    python -m benchmarks.tight_sac --scheme gated_chord --frame-interval 0.01
    python -m benchmarks.tight_sac --scheme euler
    python -m benchmarks.tight_sac --scheme reference   # the symplectic step (~6 s a run)

Prints a line per run and the count; ``--out FILE`` writes them as JSON.
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
from pathlib import Path

from warpcoil.deploy import Deployment
from warpcoil.scene import load_scene

SCENE = """
[wall]
sphere_diameter_mm = 3.2
[catheter]
tip = [0.0, 0.0, -1.3]
direction = [0.0, 0.0, 1.0]
[[coil]]
name = "framing"
shape = "spherical"
wire_diameter_mm = 0.2921
loop_diameter_mm = 2.5
length_mm = 30.0
segment_length_mm = 0.2921
[simulation]
push_speed_mm_s = 100.0
[output]
usd = false
png = false
tube_mesh = false
"""
PRESHAPE_NJ = 10.0  # bend + twist at rest below this (nJ): in its pre-shape (0 nJ; BDF2 rests at 0.5–1.3, tangled ≥ 155)
TILT_DEG = 3.0
TIP_OFFSET_MM = 0.05
SCHEMES = ("gated_chord", "euler", "bdf2", "reference")


def perturbed(k: int, runs: int) -> dict:
    """Run k's catheter: tilted TILT_DEG at azimuth 2πk/runs, its tip moved TIP_OFFSET_MM (mm)."""
    a, tilt = 2.0 * math.pi * k / runs, math.radians(TILT_DEG)
    return {"catheter.direction": [math.sin(tilt) * math.cos(a), math.sin(tilt) * math.sin(a), math.cos(tilt)],
            "catheter.tip": [TIP_OFFSET_MM * math.cos(3 * a), TIP_OFFSET_MM * math.sin(3 * a), -1.3]}


def main(scheme: str = "gated_chord", frame_interval_s: float = 0.01, runs: int = 12) -> dict:
    """Each run's status, steps and resting bend + twist energy (nJ), and how many rest in the pre-shape."""
    scheme_keys = ({"simulation.integrator": "symplectic"} if scheme == "reference"
                   else {"simulation.integrator": "implicit", "simulation.implicit_scheme": scheme})
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "tight_sac.toml"
        path.write_text(SCENE)
        for k in range(runs):
            scene = load_scene(path, {**scheme_keys, **perturbed(k, runs), "simulation.frame_interval_s": frame_interval_s})
            result = Deployment(scene).run()
            last = result.frames[-1]
            rows.append({"run": k, "status": result.status, "steps": result.steps,
                         "rest_bend_twist_nJ": last.bend_nJ + last.twist_nJ, "coil_contacts": last.coil_contacts})
            print(f"run {k}: {result.status}, {result.steps} steps, bend + twist {rows[-1]['rest_bend_twist_nJ']:.1f} nJ, "
                  f"{last.coil_contacts} coil contacts", flush=True)
    in_preshape = sum(row["status"] == "completed" and row["rest_bend_twist_nJ"] < PRESHAPE_NJ for row in rows)
    print(f"{scheme}, frames of {frame_interval_s} s: {in_preshape} of {runs} at rest in the pre-shape")
    return {"scheme": scheme, "frame_interval_s": frame_interval_s, "in_preshape": in_preshape, "runs": rows}


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scheme", choices=SCHEMES, default="gated_chord",
                        help="the implicit step's scheme, or the symplectic reference")
    parser.add_argument("--frame-interval", type=float, default=0.01, help="frame interval (s)")
    parser.add_argument("--runs", type=int, default=12, help="perturbed catheters")
    parser.add_argument("--out", help="write the runs as JSON to this file")
    args = parser.parse_args()
    if args.runs < 1 or args.frame_interval <= 0.0:
        parser.error("--runs must be ≥ 1 and --frame-interval > 0")
    found = main(args.scheme, args.frame_interval, args.runs)
    if args.out:
        Path(args.out).write_text(json.dumps(found, indent=1))
