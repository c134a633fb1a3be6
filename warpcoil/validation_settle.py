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
    ]
