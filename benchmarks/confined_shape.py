"""Where a coil comes to rest in an ordinary confined deployment, by step and by integrator, in two cases:

* ``sphere18``: the derived 18-system coil (d 0.381 mm, primary wire 0.0762 mm, 3 mm spherical pre-shape,
  50 mm) pushed at 50 mm/s into a 4 mm sphere;
* ``seed``: the shipped seed case (scenes/seed_sphere.toml: 60 mm, d 0.2921 mm, into a 3.5 mm sphere).

Each at the implicit default push step, at a half and a quarter of it (``dt_s``), and on the symplectic
reference; with ``--tilts N``, each integrator again from N perturbed catheters (:func:`perturbed`),
counting the runs that rest in the pre-shape (bend + twist < PRESHAPE_NJ). Both pre-shapes fit their
spheres, yet where a coil comes to rest is chaotic in both integrators: over 8 perturbed catheters the
seed case rests in its pre-shape 6 times on the implicit step and once on the reference, the 18-system
coil 3 times on the implicit step and 7 times on the reference (docs/FORMULATION.md "In ordinary sacs too").

    python -m benchmarks.confined_shape              # default, half, quarter (~15 s)
    python -m benchmarks.confined_shape --reference  # and the reference (~1.5 min more)
    python -m benchmarks.confined_shape --tilts 8 --reference  # the counts (~5 min)

Prints a line per run; ``--out FILE`` writes them as JSON.
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
from pathlib import Path

from warpcoil.deploy import Deployment
from warpcoil.scene import load_scene

SPHERE18_SCENE = """
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
SEED_SCENE = Path(__file__).resolve().parents[1] / "scenes" / "seed_sphere.toml"
CASES = ("sphere18", "seed")
STEP_FRACTIONS = (1.0, 0.5, 0.25)  # of the implicit default push step
TILT_STEP_DEG = 1.0  # catheter k of --tilts is tilted k times this
TIP_OFFSET_MM = 0.1  # and its tip moved this far across
PRESHAPE_NJ = 5.0  # bend + twist at rest below this (nJ): in the pre-shape


def run(path: Path, overrides: dict) -> dict:
    """One deployment of the scene at ``path``: status, steps, push step (s), resting bend + twist (nJ)."""
    result = Deployment(load_scene(path, overrides)).run()
    return {"status": result.status, "steps": result.steps, "dt_s": result.dt_s,
            "rest_bend_twist_nJ": result.final_bend_nJ + result.final_twist_nJ,
            "min_coil_gap_mm": result.frames[-1].min_coil_gap_mm}


def case_rows(case: str, path: Path, reference: bool) -> list[dict]:
    """The runs of one case: the implicit step at each of STEP_FRACTIONS of its push step, then
    (``reference``) the symplectic reference."""
    rows, push_dt_s = [], None
    for fraction in STEP_FRACTIONS:
        keys = {"simulation.integrator": "implicit"}
        if fraction != 1.0:
            keys["simulation.dt_s"] = fraction * push_dt_s
        rows.append({"case": case, "run": f"implicit, {fraction:g} × the push step", **run(path, keys)})
        push_dt_s = push_dt_s or rows[0]["dt_s"]
    if reference:
        rows.append({"case": case, "run": "reference (symplectic)",
                     **run(path, {"simulation.integrator": "symplectic"})})
    return rows


def perturbed(path: Path, k: int, tilts: int) -> dict:
    """Catheter k of ``tilts`` (k = 1 … tilts): the scene's (along z) tilted k · TILT_STEP_DEG at azimuth
    2πk/tilts, its tip moved TIP_OFFSET_MM across at azimuth 6πk/tilts: distinct deployments, where turns
    about the sphere's axis alone would repeat one up to the mesh's facets."""
    a, tilt = 2.0 * math.pi * k / tilts, math.radians(TILT_STEP_DEG * k)
    x, y, z = load_scene(path).catheter.tip_mm
    return {"catheter.direction": [math.sin(tilt) * math.cos(a), math.sin(tilt) * math.sin(a), math.cos(tilt)],
            "catheter.tip": [x + TIP_OFFSET_MM * math.cos(3 * a), y + TIP_OFFSET_MM * math.sin(3 * a), z]}


def tilted_rows(case: str, path: Path, tilts: int, reference: bool) -> list[dict]:
    """The implicit default (and, ``reference``, the reference) from ``tilts`` perturbed catheters."""
    rows = []
    for integrator in ("implicit", "symplectic") if reference else ("implicit",):
        for k in range(1, tilts + 1):
            keys = perturbed(path, k, tilts)
            rows.append({"case": case, "run": f"{integrator}, catheter {k} (tilted {TILT_STEP_DEG * k:g}°)",
                         **run(path, {"simulation.integrator": integrator, **keys})})
    return rows


def main(reference: bool = False, cases: tuple[str, ...] = CASES, tilts: int = 0) -> list[dict]:
    """The runs of each case in ``cases`` (CASES), one line each; ``tilts`` > 0: from tilted catheters instead
    of at the three steps, with a count of the runs in the pre-shape per integrator."""
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        sphere18 = Path(folder) / "confined_shape.toml"
        sphere18.write_text(SPHERE18_SCENE)
        for case in cases:
            path = sphere18 if case == "sphere18" else SEED_SCENE
            rows += tilted_rows(case, path, tilts, reference) if tilts else case_rows(case, path, reference)
    for row in rows:
        print(f"{row['case']}, {row['run']}: {row['status']}, {row['steps']} steps of {row['dt_s']:.3g} s, resting "
              f"bend + twist {row['rest_bend_twist_nJ']:.1f} nJ, smallest coil gap {row['min_coil_gap_mm']:.4f} mm",
              flush=True)
    if tilts:
        for case in cases:
            for integrator in ("implicit", "symplectic"):
                mine = [r for r in rows if r["case"] == case and r["run"].startswith(integrator)]
                if mine:
                    print(f"{case}, {integrator}: {sum(r['rest_bend_twist_nJ'] < PRESHAPE_NJ for r in mine)} of "
                          f"{len(mine)} runs rest in the pre-shape (bend + twist < {PRESHAPE_NJ:g} nJ)", flush=True)
    return rows


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--reference", action="store_true", help="also run the symplectic reference")
    parser.add_argument("--case", choices=CASES, action="append", help="only this case (repeatable; default both)")
    parser.add_argument("--tilts", type=int, default=0, metavar="N",
                        help="instead of the steps: N perturbed catheters (tilted 1°, 2°, …, tips moved 0.1 mm)")
    parser.add_argument("--out", help="write the runs as JSON to this file")
    args = parser.parse_args()
    found = main(args.reference, tuple(args.case) if args.case else CASES, args.tilts)
    if args.out:
        Path(args.out).write_text(json.dumps(found, indent=1))
