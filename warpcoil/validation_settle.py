"""Validation of the settling step set by the fastest node (``warpcoil validate settle``):
after the push, a deployment's steps grow from the finest settling step (≤ 2 ms) while
its fastest free node moves at most c0 per step (implicit.settle_level). The reference
is the same deployment settled at the finest step throughout; the measure of "the
same" is the deployment's chaotic spread, the node-wise distance between the reference
and the reference with the catheter turned by 0.01°.

The case: the small seed deployment of ``bench accuracy --quick`` (20 mm of a 2 mm
framing coil into a 2.5 mm sphere, implicit default step). Units mm, s, nJ.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from .implicit import settle_finest_level
from .validation import CaseResult


def small_seed(turn_deg: float = 0.0):
    """The seed scene at a third of its size (bench accuracy --quick), the catheter turned by ``turn_deg``."""
    from .bench.accuracy import SEED_SCENE
    from .scene import load_scene

    base = load_scene(SEED_SCENE)
    a = math.radians(turn_deg)
    return replace(base, coils=(replace(base.coils[0], length_mm=20.0, loop_diameter_mm=2.0),),
                   wall=replace(base.wall, sphere_diameter_mm=2.5),
                   catheter=replace(base.catheter, tip_mm=(0.0, 0.0, -0.95), direction=(math.sin(a), 0.0, math.cos(a))),
                   output=replace(base.output, usd=False, png=False, tube_mesh=False))


def settled(scene, finest: bool):
    """(result, deployment) of ``scene``, settled at the finest step throughout or by the rule."""
    from .deploy import Deployment

    deployment = Deployment(scene)
    if finest:
        deployment.settle_rule = lambda _speed, _c0, frame_s, scale: settle_finest_level(frame_s, scale)
    return deployment.run(), deployment


STIFF_COIL_SCENE = """
[wall]
sphere_diameter_mm = 4.0
[catheter]
tip = [0.0, 0.0, -1.7]
direction = [0.0, 0.0, 1.0]
roll_deg = 90
[[coil]]
shape = "spherical"
wire_diameter_mm = 0.2921
bending_stiffness_uN_mm2 = 30000.0
loop_diameter_mm = 3.0
length_mm = 50.0
[simulation]
push_speed_mm_s = 50.0
[output]
usd = false
"""  # 10 × the derived stiffness (docs/FORMULATION.md "Implicit step: the settling step of stiff coils")


def stiff_coil_released() -> tuple[str, float, float]:
    """STIFF_COIL_SCENE on the implicit step: (status, the largest rise of kinetic + elastic energy from one
    frame to the next after the release (nJ; nothing drives the coil then), the largest wall force then (µN))."""
    import tempfile
    from pathlib import Path

    from .deploy import Deployment
    from .scene import load_scene

    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "stiff_coil.toml"
        path.write_text(STIFF_COIL_SCENE)
        scene = load_scene(path)
    deployment = Deployment(scene)
    result = deployment.run()
    frames = deployment.members[0].frames
    out = [f for f in frames if f.deployed_length_mm >= frames[-1].deployed_length_mm - 1e-9]
    energy = [f.kinetic_nJ + f.bend_nJ + f.twist_nJ + f.stretch_nJ for f in out]
    return result.status, float(max(np.diff(energy))), max(f.max_wall_force_uN for f in out)


def stiff_coil_cases() -> list[CaseResult]:
    """The stiff coil's settling: no energy gained after the release, and no wall force beyond its bends'
    scale EI / R² (R the loop radius; unscaled: 183 mN against 13 mN)."""
    status, rise, force_uN = stiff_coil_released()
    if status != "completed":
        raise RuntimeError(f"stiff-coil settling deployment ended {status}")
    scale_uN = 3e4 / 1.5**2  # EI / R² of STIFF_COIL_SCENE (µN)
    return [
        CaseResult("settling step of a coil at 10 × its derived stiffness: largest energy rise (nJ) from one frame "
                   "to the next after the release (nothing drives it), error in nJ", 0.0, rise, max(rise, 0.0), 1.0),
        CaseResult("settling step of a coil at 10 × its derived stiffness: largest wall force (µN) after the release "
                   "against its bending force scale EI/R², error: how far above, relative", scale_uN, force_uN,
                   max(0.0, force_uN / scale_uN - 1.0), 0.0),
    ]


def settle_cases() -> list[CaseResult]:
    (reference, _), (turned, _) = settled(small_seed(), True), settled(small_seed(0.01), True)
    result, deployment = settled(small_seed(), False)
    push_end = deployment.push_time_s
    settling_gap = lambda r: min(f.min_wall_gap_mm for f in r.frames if f.time_s > push_end)  # noqa: E731
    for r in (reference, turned, result):
        if r.status != "completed":
            raise RuntimeError(f"settling validation deployment ended {r.status}: {r.reason}")
    distance = lambda a, b: float(np.sqrt(((np.concatenate(a.positions_mm) - np.concatenate(b.positions_mm)) ** 2  # noqa: E731
                                           ).sum(axis=1).mean()))
    spread, moved = distance(turned, reference), distance(result, reference)
    c0 = deployment.model.contact.c0_mm
    rest = deployment.members[0].rest_kinetic_energy_nJ
    steps = f"{result.steps} steps against {reference.steps}"
    return [
        CaseResult(f"settling step by the fastest node ({steps}): RMS node distance (mm) to the finest-step "
                   f"settle, error in units of the chaotic spread {spread:.3g} mm (0.01° turn)", 0.0, moved,
                   moved / spread, 0.5),
        CaseResult("settling step by the fastest node: smallest wall gap (mm) after the push against the finest-step "
                   "run's smallest, error: how much deeper, in c0", reference.min_wall_gap_mm, settling_gap(result),
                   max(0.0, reference.min_wall_gap_mm - settling_gap(result)) / c0, 0.0),
        CaseResult("settling step by the fastest node: final kinetic energy (nJ) against the rest threshold, "
                   "error: how far above", rest, result.final_kinetic_nJ,
                   max(0.0, result.final_kinetic_nJ / rest - 1.0), 0.0),
    ] + stiff_coil_cases()
