"""Validation of the detachment step (``warpcoil validate detach``): the push frames in which
a coil's tail leaves the catheter, and the whip after it (DETACH_WHIP_S), run at the push
step / k (implicit.detach_level). The reference is the same deployment with k = 16, 32 and 64
in those frames: the whip is chaotic, and under gated_chord the deepest overlap of those fine
runs spreads by 0.25–0.3 c0 (4 mm helix −0.89 / −0.86 / −0.64 c0), so a result is compared with
the range they span (its distance from it; 0 inside). The measure is the deepest wall overlap
the recorded frames see while the tail whips, in units of the contact range c0.

The cases: a 3 mm (8 mm long) and a 4 mm (10 mm long) helix pushed at 100 mm/s into a
3.5 mm sphere from a catheter tip 1.1 mm off the axis, 1 ms frames (so the frame-end
gaps sample the whip densely), implicit default step. Units mm, s.
"""

from __future__ import annotations

from .implicit import DETACH_WHIP_S
from .validation import CaseResult

FINEST_LEVELS = (16, 32, 64)  # the reference runs' steps per push step in the detachment frames
WHIP_CASES = {"3 mm helix": dict(loop_diameter_mm=3.0, length_mm=8.0),
              "4 mm helix": dict(loop_diameter_mm=4.0, length_mm=10.0)}


def whip_scene(loop_diameter_mm: float = 3.0, length_mm: float = 8.0):
    """A helix whose tail whips against the wall of a 3.5 mm sphere as it leaves the catheter."""
    import warpcoil as wc

    return wc.Scene(
        coils=(wc.CoilSpec(shape="helix", length_mm=length_mm, loop_diameter_mm=loop_diameter_mm, pitch_mm=0.6,
                           name="whip"),),
        catheter=wc.CatheterSpec(tip_mm=(0.0, 1.1, -0.9), direction=(0.0, 0.0, 1.0)),
        wall=wc.WallSpec(sphere_diameter_mm=3.5),
        simulation=wc.SimulationSettings(push_speed_mm_s=100.0, frame_interval_s=0.001, integrator="implicit"))


def whip_overlap(scene, level: int | None = None):
    """(deepest frame-end wall gap (mm) from 2 ms before the tail's release to DETACH_WHIP_S
    after it, result, deployment) of ``scene`` with ``level`` steps per push step in the
    detachment frames (None: the rule's; 1: the push step throughout)."""
    from .deploy import Deployment

    deployment = Deployment(scene)
    if level is not None:
        deployment.detach_rule = lambda _speed, _dt, _c0: level
    gaps: list[tuple[float, float]] = []
    result = deployment.run(lambda frame, _state: gaps.append((frame.time_s, frame.min_wall_gap_mm)))
    if result.status != "completed":
        raise RuntimeError(f"detachment validation deployment ended {result.status}: {result.reason}")
    release_s = float(deployment.coil_lengths_mm[0]) / scene.simulation.push_speed_mm_s
    deepest = min(g for t, g in gaps if release_s - 0.002 <= t <= release_s + DETACH_WHIP_S)
    return deepest, result, deployment


def detach_cases() -> list[CaseResult]:
    rows = []
    for name, shape in WHIP_CASES.items():
        scene = whip_scene(**shape)
        fine = [whip_overlap(scene, level)[0] for level in FINEST_LEVELS]
        low, high = min(fine), max(fine)
        reference = 0.5 * (low + high)
        rule, result, deployment = whip_overlap(scene)
        c0 = deployment.model.contact.c0_mm
        k = deployment.detach_rule(scene.simulation.push_speed_mm_s, result.dt_s, c0)
        finer_k = 2 * k if 2 * k not in FINEST_LEVELS else 3 * k  # never one of the reference runs
        finer, _, _ = whip_overlap(scene, finer_k)

        def outside(gap: float) -> float:
            """Distance (in c0) of a deepest gap from the fine runs' range (0 inside it)."""
            return max(low - gap, gap - high, 0.0) / c0

        span = "/".join(str(level) for level in FINEST_LEVELS)
        rows += [
            CaseResult(f"detachment step, {name}: deepest wall gap (mm) while the tail whips, rule (k = {k}, "
                       f"+{result.detach_steps} steps) against k = {span} ({low:.4f} … {high:.4f} mm; reference: "
                       f"its middle), error: distance from that range in c0", reference, rule, outside(rule), 0.5),
            CaseResult(f"detachment step, {name}: the same at k = {finer_k} (convergence), error: distance from the "
                       f"range in c0", reference, finer, outside(finer), 0.5),
            CaseResult(f"detachment step, {name}: the rule's deepest overlap within c0, error: how much deeper "
                       f"than -c0, in c0", -c0, rule, max(0.0, -rule / c0 - 1.0), 0.0),
        ]
    return rows
