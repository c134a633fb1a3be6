"""Signals a stall rule could read, per frame of one deployment (docs/FORMULATION.md, "Stall").

    python -m benchmarks.stall_signals SCENE [table.key=value ...] [--csv FILE]

Runs the scene (overrides named as ``warpcoil sweep --vary`` names them, e.g.
``coil.length_mm=300 coil.shape=helix``) without outputs, and prints, against
the coils' self-deployment force F0 (µN = nJ/mm, deploy.Member):

* the push force: the largest frame mean and 0.1 s mean (× F0), and the packing
  density in the sac at which the 0.1 s mean first passes 2, 3, 5 and 10 F0;
* the deepest coil–coil overlap (the smallest ``min_coil_gap_mm``, ÷ d) and the
  largest stretch energy (nJ: the coil compressed along its axis);
* per tenth of the pushed length: the packing at its end, the elastic energy
  released per mm pushed (÷ F0: 1 when each mm that leaves the catheter relaxes
  fully, less when the sac holds it deformed) and the mean push force (÷ F0).

``--csv`` also writes the per-frame values. Units mm, s, µN, nJ.
"""

from __future__ import annotations

import argparse
import csv
import math
from dataclasses import replace

import numpy as np

from warpcoil.deploy import Deployment
from warpcoil.scene import load_scene

WINDOW_S = 0.1  # the stall window's default length
RATIOS = (2.0, 3.0, 5.0, 10.0)


def _value(text: str):
    try:
        return float(text)
    except ValueError:
        return text


def record(scene_path: str, overrides: dict) -> tuple[Deployment, object, list[dict]]:
    """Run the scene; (deployment, RunResult, one dict per frame)."""
    scene = load_scene(scene_path, overrides)
    scene = replace(scene, output=replace(scene.output, usd=False, png=False, animation=False))
    deployment = Deployment(scene)
    member = deployment.members[0]
    areas = np.array([math.pi * (c.wire_diameter_mm / 2.0) ** 2 for c in scene.coils])
    sac = deployment.anatomy.sac_volume_mm3 or math.nan
    rows: list[dict] = []

    def on_frame(frame, state):
        pushed = np.clip(state.advance.numpy()[member.coils.start:member.coils.stop], 0.0, member.coil_lengths_mm)
        in_sac = float(areas @ pushed) - areas[max(member.active, 0)] * (frame.length_outside_sac_mm or 0.0)
        rows.append(dict(time_s=frame.time_s, pushed_mm=frame.deployed_length_mm, packing=in_sac / sac,
                         push_mean_uN=frame.push_force_mean_uN, push_peak_uN=frame.push_force_peak_uN,
                         elastic_nJ=frame.bend_nJ + frame.twist_nJ + frame.stretch_nJ, stretch_nJ=frame.stretch_nJ,
                         min_coil_gap_mm=frame.min_coil_gap_mm, coil_contacts=frame.coil_contacts))

    return deployment, deployment.run(on_frame), rows


def summary(rows: list[dict], f0_uN: float, wire_mm: float) -> list[str]:
    """The printed lines (see the module docstring)."""
    col = {k: np.array([r[k] for r in rows]) for k in rows[0]}
    frame_s = col["time_s"][1] - col["time_s"][0]
    n = max(1, round(WINDOW_S / frame_s))
    pushing = np.diff(col["pushed_mm"], prepend=0.0) > 0.0
    window = np.convolve(col["push_mean_uN"], np.ones(n) / n)[:len(rows)]  # trailing mean
    lines = [f"F0 {f0_uN:.0f} µN; largest frame mean {col['push_mean_uN'].max() / f0_uN:.2f} F0, "
             f"largest {WINDOW_S:g} s mean {window[pushing].max() / f0_uN:.2f} F0"]
    for ratio in RATIOS:
        hit = np.flatnonzero(pushing & (window > ratio * f0_uN))
        lines.append(f"  {WINDOW_S:g} s mean > {ratio:g} F0: " + (
            f"first at {col['pushed_mm'][hit[0]]:.1f} mm, packing {100 * col['packing'][hit[0]]:.1f} %"
            if hit.size else "never"))
    lines.append(f"  deepest overlap {-col['min_coil_gap_mm'].min() / wire_mm:.3f} d; "
                 f"largest stretch energy {col['stretch_nJ'].max():.0f} nJ")
    tenths = []
    edges = np.linspace(0.0, col["pushed_mm"].max(), 11)
    for a, b in zip(edges[:-1], edges[1:]):
        i, j = np.searchsorted(col["pushed_mm"], a), min(np.searchsorted(col["pushed_mm"], b), len(rows) - 1)
        if col["pushed_mm"][j] > col["pushed_mm"][i]:
            released = -(col["elastic_nJ"][j] - col["elastic_nJ"][i]) / (col["pushed_mm"][j] - col["pushed_mm"][i])
            tenths.append(f"{100 * col['packing'][j]:.0f}%:{released / f0_uN:.2f}/"
                          f"{col['push_mean_uN'][i:j + 1].mean() / f0_uN:.1f}")
    lines.append("  packing:released/push per tenth of the pushed length (÷ F0): " + " ".join(tenths))
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("scene")
    parser.add_argument("overrides", nargs="*", help="table.key=value")
    parser.add_argument("--csv", help="also write the per-frame values here")
    args = parser.parse_args()
    overrides = {k: _value(v) for k, v in (o.split("=", 1) for o in args.overrides)}
    deployment, result, rows = record(args.scene, overrides)
    print(f"{result.status}: {result.reason}")
    print(f"{result.steps} steps, {result.wall_time_s:.1f} s wall, pushed {result.deployed_length_mm:.1f} mm")
    for line in summary(rows, deployment.members[0].self_deployment_force_uN,
                        min(c.wire_diameter_mm for c in deployment.scene.coils)):
        print(line)
    if args.csv:
        with open(args.csv, "w", newline="") as file:
            writer = csv.DictWriter(file, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)


if __name__ == "__main__":
    main()
