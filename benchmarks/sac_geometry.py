"""Sac geometry on the shipped patient walls: sac volumes, regional densities,
herniated length and the porous field (porous.vti) of a made-up coil, and the
time these calls take.

The coil is not a deployment: nested spherical spirals (loxodromes) about the
sac's centroid at 0.3–0.9 of its equivalent radius, ~20 % packing, plus a
straight 3 mm tail from just below the neck centroid into the parent vessel (herniated).
It exercises the same calls a finished run makes (``regional_density``,
``inside_sac``, ``herniated_length_mm``, ``porous_field`` and the VTI writer) on
real walls in seconds. ``porous_solid`` (the sac-weighted mean of 1 − porosity,
sampled at d/8) is checked against ``total_voxel`` (voxel centres at d/4): two
samplings of the coil volume fraction of the sac.

    PYTHONPATH=$PWD python -m benchmarks.sac_geometry [CASE ...] [--repeats N]
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from warpcoil.porous import porous_field
from warpcoil.recorder.porous import POROUS_VTI, write_porous_vti
from warpcoil.sac import Sac, herniated_length_mm, inside_sac, regional_density
from warpcoil.scene import load_scene

SCENES = Path(__file__).resolve().parents[1] / "scenes"
CASES = ("C0001", "C0003", "C0020", "C0031", "C0091")
D_MM = 0.381
SPACING_MM = 0.2


def made_up_coil(sac: Sac, packing: float = 0.2) -> np.ndarray:
    """(N, 3) nodes ~SPACING_MM apart: spherical spirals in the sac, then a tail out of the neck."""
    centre = np.asarray(sac.closed_surface.center_mass)
    radius = (3.0 * sac.volume_mm3 / (4.0 * math.pi)) ** (1.0 / 3.0)
    length = packing * sac.volume_mm3 / (math.pi * (D_MM / 2) ** 2)
    shells = np.array([0.3, 0.5, 0.7, 0.9]) * radius
    pieces = []
    for k, r in enumerate(shells):
        share = length * r / shells.sum()
        turns = share / (2.0 * math.pi * r * 0.63)  # a turn averages 2πr·<sin θ> ≈ 2πr·0.63 over θ in [0.05π, 0.95π]
        count = max(int(share / SPACING_MM), 10)
        t = np.linspace(0.0, 1.0, count)
        polar = math.pi * (0.05 + 0.9 * t)
        azimuth = 2.0 * math.pi * turns * t + k
        pieces.append(centre + r * np.column_stack((np.sin(polar) * np.cos(azimuth), np.sin(polar) * np.sin(azimuth),
                                                    np.cos(polar))))
    neck = sac.neck
    tail = neck.centroid_mm - np.linspace(0.05, 3.05, int(3.0 / SPACING_MM) + 1)[:, None] * neck.normal  # off the fan
    return np.vstack(pieces + [tail[::-1]])


def measure(case: str, repeats: int) -> dict:
    from warpcoil.anatomy import resolve_anatomy

    anatomy = resolve_anatomy(load_scene(SCENES / f"aneurisk_{case}.toml"))
    sac, wall = anatomy.sac, anatomy.wall
    nodes = made_up_coil(sac)
    step = np.linalg.norm(np.diff(nodes, axis=0), axis=1)
    lengths = 0.5 * (np.r_[0.0, step] + np.r_[step, 0.0])  # each node's share of the polyline
    timings: dict[str, list[float]] = {"regional_density_s": [], "herniation_s": [], "porous_s": []}
    surface = sac.closed_surface
    for _ in range(repeats):
        start = time.perf_counter()
        density = regional_density(sac, [nodes], [D_MM])
        timings["regional_density_s"].append(time.perf_counter() - start)
        start = time.perf_counter()
        herniated = herniated_length_mm(sac, wall, nodes, lengths)
        inside = int(inside_sac(sac, nodes).sum())
        timings["herniation_s"].append(time.perf_counter() - start)
        start = time.perf_counter()
        field = porous_field(np.asarray(surface.vertices), np.asarray(surface.faces), [nodes], [D_MM])
        with tempfile.TemporaryDirectory() as folder:
            write_porous_vti(Path(folder) / POROUS_VTI, field)
            vti_bytes = (Path(folder) / POROUS_VTI).stat().st_size
        timings["porous_s"].append(time.perf_counter() - start)
    porous_solid = float((field.sac_fraction * (1.0 - field.porosity)).sum() / field.sac_fraction.sum())
    return dict(case=case, nodes=len(nodes), sac_volume_mm3=sac.volume_mm3, inside_nodes=inside,
                herniated_mm=herniated, **{k: float(v) for k, v in asdict(density).items()},
                porous_voxels=int(np.prod(field.shape)), porous_vti_bytes=vti_bytes, porous_solid=porous_solid,
                porous_vs_total_voxel=porous_solid / density.total_voxel - 1.0,
                **{k: float(np.median(v)) for k, v in timings.items()})


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("cases", nargs="*", default=list(CASES))
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    for case in args.cases:
        print(json.dumps(measure(case, args.repeats)), flush=True)


if __name__ == "__main__":
    main()
