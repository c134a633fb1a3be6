"""`warpcoil bench accuracy`: run time against error for the knobs that trade one for the other.

Cases and their references:

* cantilever (P L²/EI = 5, clamped at node 0): tip deflection against the extensible elastica;
* helix recovery and free release: loop diameter and pitch against the rest helix;
* a deployment into the seed sphere (``--quick``: a 20 mm coil): its final shape
  is chaotic, so it is compared with the finest setting through well-posed
  quantities — radius of gyration, mean node distance from the sac centre,
  fraction of the sac volume within d of the coil, and the distal tip's
  trajectory over the first loop (RMS distance / loop length); the push force's
  mean over the push is compared with the finest setting's in units of the coil's
  self-deployment force F0 (a default candidate within PUSH_FORCE_TOLERANCE_F0). How chaotic is
  measured, not assumed: the finest setting rerun with the catheter turned by
  0.01° gives the spread below which errors cannot be told apart. A push is
  only a default candidate while it stays quasi-static (kinetic / elastic
  energy ≤ 0.1 while pushing, MODEL.md).

Knobs: step size (dt_safety × the stable bound), the integrator (the implicit
step at its default — gated_chord: θ 0.65, proximity- and turn-gated, chord contact stiffness — beside
the named scheme linearly implicit Euler (tangent contact stiffness) at the same push step, Euler's push
advance per step from 0.4 to 2.4 c0,
the plain θ-method at θ = 0.7, the gated θ 0.7 with either contact stiffness, linearly implicit
BDF2, and Euler with the chord contact stiffness to either predicted end), push advance per step (push
speed), segment length l0 ∈ {d/2, d, 2d} (d/2 on the validation cases, where
it is affordable), mass scaling. A free release's rest state has more than one basin: each
default release (and the implicit step at 50, 100, 150 and 200 mm/s) is rerun with the catheter
turned by 0.01°, and the detail says in how many runs it came to rest in the helix (implicit Euler
at 0.8 c0 per push step at 100 and 150 mm/s: none; at 0.4 c0: all; docs/FORMULATION.md
"the free release that comes to rest tangled"). The deployment reference is the finest
setting swept: dt 0.25 × bound, true inertia, push 50 mm/s, l0 = d, with the exact
wall (BVH) whatever the seed scene's ``wall_query``; the implicit default step also
runs with the other wall query (the scene's against the BVH or the wall field).
Float64 only (the kernels are written in float64; float32 is not offered).
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from .. import validation
from ..deploy import Deployment
from ..implicit import EULER, GATED_CHORD, IMPLICIT_ADVANCE_PER_C0, IMPLICIT_SETTLE_DT_MAX_S
from ..measure import QUASI_STATIC_KE_RATIO
from ..scene import load_scene
from ..recorder.atomic import write_text_atomic
from .report import markdown_table, timed, write_report

SEED_SCENE = Path(__file__).resolve().parents[2] / "scenes" / "seed_sphere.toml"
D = validation.REFERENCE_D_MM
L0_IS_THE_MODEL = "l0 = d defines the model (MODEL.md)"
MASS_SCALING_CHANGES_DYNAMICS = "mass scaling changes the dynamics (heavier nodes, more inertia: its error in the table)"
# a deployment setting is a default candidate only while its push force's mean over the push is within this
# many self-deployment forces F0 (stored energy per mm, docs/FORMULATION.md "Stall") of the finest setting's
PUSH_FORCE_TOLERANCE_F0 = 0.25
THETA_LOW = 0.7  # the plain θ-method's setting shown beside the default and linearly implicit Euler
# the plain θ-method (every node at θ, tangent contact stiffness) at θ
PLAIN_THETA = {"near_theta": None, "contact_stiffness": "tangent"}
# the proximity-gated θ at THETA_LOW with the tangent stiffness (FORMULATION.md "proximity-gated θ")
GATED_THETA = {"theta": THETA_LOW, "near_theta": 1.0, "contact_stiffness": "tangent"}
# the implicit default: gated_chord (θ 0.65, proximity and turn gates, chord; docs/FORMULATION.md "the turn gate",
# "Implicit step: gated_chord the default"); beside it the named scheme "euler" (linearly implicit Euler, tangent)
DEFAULT_LABEL = f"gated_chord: θ {GATED_CHORD['theta']:g} gated, chord"
EULER_LABEL = "Euler, tangent"
IMPLICIT_DEFAULT_ROW = "implicit, default step ("  # the deployment's implicit default row, also checked for the front


@dataclass
class Row:
    case: str
    setting: str
    default: bool  # the reference step's default setting (symplectic, dt 0.9 × bound)
    steps: int
    wall_time_s: float
    error: float
    detail: str = ""
    not_default: str = ""  # why the setting cannot be a default (shown, not a Pareto candidate)
    floor: float = 0.0  # errors below this are indistinguishable (a deployment's chaotic spread)
    implicit_default: bool = False  # the implicit step at its default (the scene default) in the case's set-up


# --- validation cases --------------------------------------------------------------
def cantilever_rows(quick: bool, repeats: int) -> list[Row]:
    rows = []
    for segments in (25, 50) if quick else (25, 50, 100):
        for safety in (0.5, 0.9) if quick else (0.25, 0.5, 0.9):
            (deflection, reference), t = timed(lambda: validation.cantilever_deflection(segments, 5.0, dt_safety=safety),
                                               repeats)
            error = abs(deflection - reference) / reference
            rows.append(Row("cantilever", f"{segments} segments, dt {safety} bound", segments == 50 and safety == 0.9,
                            0, t, error))
    (deflection, reference), t = timed(lambda: validation.cantilever_deflection(50, 5.0, integrator="implicit"),
                                       repeats)
    error = abs(deflection - reference) / reference
    rows.append(Row("cantilever", f"50 segments, implicit default step ({DEFAULT_LABEL}; at rest: settling θ 1)", False,
                    0, t, error, implicit_default=True))
    return rows


def _helix_error(results) -> float:
    return max(r.error for r in results)


def helix_rows(quick: bool, repeats: int) -> list[Row]:
    rows = []
    for factor in (1.0, 2.0) if quick else (0.5, 1.0, 2.0):
        for safety in (0.5, 0.9) if quick or factor != 1.0 else (0.25, 0.5, 0.9):
            res, t = timed(lambda: validation.helix_recovery(segment_length_mm=factor * D, dt_safety=safety), repeats)
            rows.append(Row("helix recovery", f"l0 {factor:g} d, dt {safety} bound", factor == 1.0 and safety == 0.9,
                            0, t, _helix_error(res), f"D {res[0].result:.4f} mm, pitch {res[1].result:.4f} mm",
                            not_default=L0_IS_THE_MODEL if factor != 1.0 else ""))
    res, t = timed(lambda: validation.helix_recovery(integrator="implicit"), repeats)
    rows.append(Row("helix recovery", f"l0 1 d, implicit default step ({DEFAULT_LABEL}; unpushed: settling θ 1)", False, 0, t,
                    _helix_error(res),
                    f"D {res[0].result:.4f} mm, pitch {res[1].result:.4f} mm", implicit_default=True))
    return rows


# a free release's rest state has more than one basin: each default setting is rerun with the catheter turned by
# this much (in free space a rigid rotation: only round-off changes) at these azimuths, and the untangled share shown
RELEASE_TILT_DEG = 0.01
RELEASE_AZIMUTHS_DEG = (0.0, 90.0, 180.0, 270.0)


def _release_detail(res, speed: float, integrator: str, perturbations: int, advance_per_c0: float | None = None,
                    solver_options: dict | None = None) -> tuple[str, str]:
    """(detail, not_default): the fitted helix and how many of the run and its
    ``perturbations`` tilted reruns came to rest in the helix (every row within
    tolerance); a setting that tangled in any of them is not a default candidate."""
    shape = f"D {res[0].result:.4f} mm, pitch {res[1].result:.4f} mm"
    if perturbations == 0:
        return shape, ""
    runs = [res] + [validation.free_release(push_speed_mm_s=speed, integrator=integrator,
                                            catheter=validation.tilted_catheter(RELEASE_TILT_DEG, azimuth),
                                            advance_per_c0=advance_per_c0, solver_options=solver_options)
                    for azimuth in RELEASE_AZIMUTHS_DEG[:perturbations]]
    helix = sum(all(r.passed for r in run) for run in runs)
    pitches = ", ".join(f"{run[1].result:.2f}" for run in runs[1:])
    detail = (f"{shape}; rest helix in {helix} of {len(runs)} runs "
              f"(catheter turned {RELEASE_TILT_DEG:g}°: pitch {pitches} mm)")
    tangled = len(runs) - helix
    return detail, (f"comes to rest tangled in {tangled} of {len(runs)} runs (catheter turned {RELEASE_TILT_DEG:g}°)"
                    if tangled else "")


def release_rows(quick: bool, repeats: int) -> list[Row]:
    rows = []
    if quick:  # mass scaling on a free release (shown once; the full sweep shows it on the seed deployment)
        res, t = timed(lambda: validation.free_release(push_speed_mm_s=200.0, mass_scale=10.0), repeats)
        rows.append(Row("free release", "push 200 mm/s, dt 0.9 bound, mass scale 10", False, 0, t, _helix_error(res),
                        f"D {res[0].result:.4f} mm, pitch {res[1].result:.4f} mm"))
    default_speed = 200.0 if quick else 100.0
    for speed in (200.0,) if quick else (50.0, 100.0, 200.0):
        for safety in (0.5, 0.9) if speed > 50.0 else (0.9,):
            res, t = timed(lambda: validation.free_release(push_speed_mm_s=speed, dt_safety=safety), repeats)
            default = speed == default_speed and safety == 0.9
            detail, tangled = _release_detail(res, speed, "symplectic", 0 if quick or not default else 4)
            rows.append(Row("free release", f"push {speed:g} mm/s, dt {safety} bound", default, 0, t,
                            _helix_error(res), detail, not_default=tangled))
    for speed in (default_speed,) if quick else (50.0, 100.0, 150.0, 200.0):
        res, t = timed(lambda: validation.free_release(push_speed_mm_s=speed, integrator="implicit"), repeats)
        detail, tangled = _release_detail(res, speed, "implicit", 2 if quick else 4)
        rows.append(Row("free release", f"push {speed:g} mm/s, implicit default step ({DEFAULT_LABEL})", False, 0, t,
                        _helix_error(res), detail, not_default=tangled, implicit_default=speed == default_speed))
    for speed in () if quick else (100.0, 150.0):  # Euler tangles at the default push step (FORMULATION.md "the
        # free release that comes to rest tangled"): Euler at it, and at half of it
        for label, advance, options in ((f"implicit {EULER_LABEL}", IMPLICIT_ADVANCE_PER_C0, EULER),
                                        (f"implicit Euler {0.5 * IMPLICIT_ADVANCE_PER_C0:g} c0 per push step",
                                         0.5 * IMPLICIT_ADVANCE_PER_C0, EULER)):
            res, t = timed(lambda: validation.free_release(push_speed_mm_s=speed, integrator="implicit",
                                                           advance_per_c0=advance, solver_options=options), repeats)
            detail, tangled = _release_detail(res, speed, "implicit", 4, advance, solver_options=options)
            rows.append(Row("free release", f"push {speed:g} mm/s, {label}", False, 0, t, _helix_error(res), detail,
                            not_default=tangled))
    return rows


# --- deployment ----------------------------------------------------------------------
@dataclass
class Shape:
    """Well-posed measures of a deployed coil (mm, and a volume fraction)."""

    gyration_mm: float
    mean_centre_distance_mm: float
    coverage: float
    tip_track: np.ndarray  # (k, 3) distal tip at fixed deployed lengths over the first loop
    push_mean_uN: float = 0.0  # push force averaged over the frames of the push (µN; not in the error)
    self_deployment_uN: float = 0.0  # F0: the coil's stored energy per mm (µN), the push force's scale
    rest_bend_twist_nJ: float = 0.0  # bend + twist energy at rest (nJ; not in the error: the resting state is chaotic)


def _coverage(x: np.ndarray, radius_mm: float, spacing_mm: float) -> float:
    """Fraction of the sphere of ``radius_mm`` (centred at 0) within d of the coil polyline."""
    g = np.arange(-radius_mm, radius_mm + spacing_mm, spacing_mm)
    pts = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    pts = pts[np.linalg.norm(pts, axis=1) < radius_mm]
    a, b = x[:-1], x[1:]
    ab = b - a
    near = np.zeros(len(pts), bool)
    for chunk in np.array_split(np.arange(len(pts)), max(1, len(pts) // 2000)):
        p = pts[chunk][:, None, :]
        s = np.clip(np.einsum("pkj,kj->pk", p - a, ab) / np.einsum("kj,kj->k", ab, ab), 0.0, 1.0)
        dist = np.linalg.norm(p - (a + s[..., None] * ab), axis=2).min(axis=1)
        near[chunk] = dist < D
    return float(near.mean())


def deploy_shape(scene, loop_length_mm: float, sac_radius_mm: float,
                 solver_options: dict | None = None) -> tuple[Shape, int, float]:
    """The deployed coil's shape measures, steps, and the largest kinetic / elastic
    energy ratio while pushing (MODEL.md's measure of quasi-static pushing)."""
    deployment = Deployment(scene, solver_options=solver_options)
    grid = np.linspace(0.5, loop_length_mm, 16)
    track_len, track_x = [], []
    ratio = [0.0]
    length = float(deployment.coil_lengths_mm.sum())
    push = []

    def on_frame(frame, state):
        if 0.0 < frame.deployed_length_mm < length:
            push.append(frame.push_force_mean_uN)
        if frame.deployed_length_mm <= loop_length_mm + 0.5:
            track_len.append(frame.deployed_length_mm)
            track_x.append(state.x.numpy()[0].copy())
        elastic = frame.bend_nJ + frame.twist_nJ + frame.stretch_nJ
        if 0.0 < frame.deployed_length_mm < length and elastic > 0.0:
            ratio[0] = max(ratio[0], frame.kinetic_nJ / elastic)

    result = deployment.run(on_frame)
    if result.status != "completed":
        raise RuntimeError(f"accuracy benchmark deployment ended {result.status}: {result.reason}")
    x = result.positions_mm[0]
    track = np.stack([np.interp(grid, track_len, np.asarray(track_x)[:, k]) for k in range(3)], axis=1)
    shape = Shape(float(np.sqrt(((x - x.mean(0)) ** 2).sum(1).mean())), float(np.linalg.norm(x, axis=1).mean()),
                  _coverage(x, sac_radius_mm, D / 2), track, float(np.mean(push)) if push else 0.0,
                  deployment.members[0].self_deployment_force_uN, result.final_bend_nJ + result.final_twist_nJ)
    return shape, result.steps, ratio[0]


def shape_error(shape: Shape, ref: Shape, loop_mm: float) -> tuple[float, str]:
    rel = {
        "Rg": abs(shape.gyration_mm - ref.gyration_mm) / ref.gyration_mm,
        "centre": abs(shape.mean_centre_distance_mm - ref.mean_centre_distance_mm) / ref.mean_centre_distance_mm,
        "coverage": abs(shape.coverage - ref.coverage) / ref.coverage,
        "track": float(np.sqrt(((shape.tip_track - ref.tip_track) ** 2).sum(1).mean())) / loop_mm,
    }
    return max(rel.values()), ", ".join(f"{k} {v:.2%}" for k, v in rel.items())


def deployment_rows(quick: bool, repeats: int) -> list[Row]:
    base = load_scene(SEED_SCENE)
    base = replace(base, output=replace(base.output, usd=False, png=False, tube_mesh=False))
    case = "seed deployment"
    if quick:  # the seed case at a third of its size: 20 mm of a 2 mm framing coil in a 2.5 mm sphere (16 %)
        base = replace(base, coils=(replace(base.coils[0], length_mm=20.0, loop_diameter_mm=2.0),),
                       wall=replace(base.wall, sphere_diameter_mm=2.5),
                       catheter=replace(base.catheter, tip_mm=(0.0, 0.0, -0.95)))
        case = "small seed deployment (20 mm in 2.5 mm)"
    coil = base.coils[0]
    loop_mm = math.pi * coil.loop_diameter_mm

    def variant(dt_safety=0.9, push=50.0, l0_factor=1.0, mass_scale=1.0, integrator="symplectic", dt_s=None):
        sim = replace(base.simulation, dt_safety=dt_safety, push_speed_mm_s=push, mass_scale=mass_scale,
                      integrator=integrator, dt_s=dt_s)
        return replace(base, simulation=sim, coils=(replace(coil, segment_length_mm=l0_factor * D),))

    sac_radius = base.wall.sphere_diameter_mm / 2.0
    c0 = base.contact.c0_mm if base.contact.c0_mm is not None else 0.1 * coil.wire_diameter_mm  # as the model has it
    # the finest setting swept: the smallest step and slowest push, true inertia, l0 = d, the exact wall (BVH)
    finest = variant(dt_safety=0.25, mass_scale=1.0, push=50.0)
    finest = replace(finest, contact=replace(finest.contact, wall_query="bvh"))
    reference, _, _ = deploy_shape(finest, loop_mm, sac_radius)
    # the chaotic spread: the same finest setting with the catheter turned by 0.01°
    turned = replace(finest, catheter=replace(finest.catheter, direction=(math.sin(math.radians(0.01)), 0.0,
                                                                         math.cos(math.radians(0.01)))))
    (spread_shape, spread_steps, _), spread_t = timed(lambda: deploy_shape(turned, loop_mm, sac_radius), 1)
    floor, spread_detail = shape_error(spread_shape, reference, loop_mm)
    spread_detail += (f"; at rest bend + twist {spread_shape.rest_bend_twist_nJ:.1f} nJ "
                      f"(finest {reference.rest_bend_twist_nJ:.1f})")
    rows = [Row(case, "finest, catheter turned 0.01° (the chaotic spread)", False, spread_steps, spread_t, floor,
                spread_detail, not_default="the reference setting", floor=floor)]
    settings = {
        "default (dt 0.9 bound, push 50 mm/s, l0 d, true inertia)": (variant(), None),
        "dt 0.5 bound": (variant(dt_safety=0.5), None),
        "push 200 mm/s": (variant(push=200.0), None),
        "mass scale 10": (variant(mass_scale=10.0), None),
        f"implicit, default step ({DEFAULT_LABEL}, push advance {IMPLICIT_ADVANCE_PER_C0:g} c0 per step, then "
        f"the settling step, ≤ {IMPLICIT_SETTLE_DT_MAX_S * 1e3:g} ms)": (variant(integrator="implicit"), None),
    }
    settings[f"implicit {EULER_LABEL}, push advance {IMPLICIT_ADVANCE_PER_C0:g} c0"] = (
        variant(integrator="implicit"), EULER)
    settings[f"implicit, default step, gated θ {THETA_LOW:g} (θ_i 1 near an obstacle), tangent stiffness"] = (
        variant(integrator="implicit"), GATED_THETA)
    settings[f"implicit, default step, gated θ {THETA_LOW:g}, chord contact stiffness"] = (
        variant(integrator="implicit"), {**GATED_THETA, "contact_stiffness": "chord"})
    other_query = "bvh" if base.contact.wall_query == "sdf" else "sdf"  # the scene's wall query against the other
    implicit_other = variant(integrator="implicit")
    settings[f"implicit, default step, wall_query {other_query}"] = (
        replace(implicit_other, contact=replace(implicit_other.contact, wall_query=other_query)), None)
    # the push step on the front, kept after the push: the linearly implicit Euler step (θ 1) and the plain θ-method
    # with less numerical damping (θ THETA_LOW, every node, tangent; it does not settle at the settling step)
    for theta in (1.0, THETA_LOW):
        for advance in (0.8, 1.2, 1.6, 2.4) if theta != 1.0 else (0.4, 1.2, 1.6, 2.4):
            settings[f"implicit θ {theta:g}, push advance {advance:g} c0 (kept)"] = (
                variant(integrator="implicit", dt_s=advance * c0 / base.simulation.push_speed_mm_s),
                {"theta": theta, **PLAIN_THETA})
    for advance in (0.8, 1.2, 1.6, 2.4):  # linearly implicit BDF2 (L-stable), kept after the push
        settings[f"implicit BDF2, push advance {advance:g} c0 (kept)"] = (
            variant(integrator="implicit", dt_s=advance * c0 / base.simulation.push_speed_mm_s), {"method": "bdf2"})
    for end, advances in (("flight", (0.8, 1.2, 1.6)), ("solve", (1.2, 1.6))):  # Euler with the chord contact
        for advance in advances:  # stiffness to each predicted end (kernels/chord.py), kept after the push
            settings[f"implicit, chord contact stiffness ({end} end), push advance {advance:g} c0 (kept)"] = (
                variant(integrator="implicit", dt_s=advance * c0 / base.simulation.push_speed_mm_s),
                {**EULER, "contact_stiffness": "chord", "chord_end": end})
    if not quick:  # (l0 = d/2 is swept on the helix: on this deployment it took 3 min a run)
        settings.update({"push 100 mm/s": (variant(push=100.0), None), "mass scale 100": (variant(mass_scale=100.0), None),
                         "l0 2d": (variant(l0_factor=2.0), None)})
    for label, (scene, options) in settings.items():
        try:
            (shape, steps, ke_ratio), t = timed(lambda: deploy_shape(scene, loop_mm, sac_radius, options), repeats)
        except RuntimeError as failure:  # reported as a row, not a crash of the whole sweep
            rows.append(Row(case, label, label.startswith("default"), 0, math.nan, math.inf, str(failure),
                            not_default="did not complete", floor=floor,
                            implicit_default=label.startswith(IMPLICIT_DEFAULT_ROW)))
            continue
        error, detail = shape_error(shape, reference, loop_mm)
        push_error = abs(shape.push_mean_uN - reference.push_mean_uN) / reference.self_deployment_uN
        not_default = (L0_IS_THE_MODEL if label.startswith("l0") else
                       MASS_SCALING_CHANGES_DYNAMICS if label.startswith("mass") else
                       f"not quasi-static (kinetic/elastic {ke_ratio:.3g} > {QUASI_STATIC_KE_RATIO:g}; MODEL.md)"
                       if ke_ratio > QUASI_STATIC_KE_RATIO else
                       f"push force off by {push_error:.2f} F0 (> {PUSH_FORCE_TOLERANCE_F0:g} F0)"
                       if push_error > PUSH_FORCE_TOLERANCE_F0 else "")
        rows.append(Row(case, label, label.startswith("default"), steps, t, error,
                        f"{detail}; kinetic/elastic ≤ {ke_ratio:.3g}; push mean {shape.push_mean_uN:.0f} µN "
                        f"(finest {reference.push_mean_uN:.0f}; error {push_error:.2f} F0, F0 "
                        f"{reference.self_deployment_uN:.0f} µN); at rest bend + twist {shape.rest_bend_twist_nJ:.1f} nJ "
                        f"(finest {reference.rest_bend_twist_nJ:.1f})", not_default=not_default, floor=floor,
                        implicit_default=label.startswith(IMPLICIT_DEFAULT_ROW)))
    return rows


# --- report ---------------------------------------------------------------------------
def pareto_check(rows: list[Row]) -> str:
    """Is the reference's default (and, on a deployment, the implicit default, the scene default)
    on (or within 10 % of) the Pareto front of its case? Rows with
    a ``not_default`` reason are not candidates; errors below a case's floor (a
    deployment's chaotic spread) count as equal."""
    lines = []
    for case in dict.fromkeys(r.case for r in rows):
        case_rows = [r for r in rows if r.case == case]
        defaults = [("reference default", next(r for r in case_rows if r.default))]
        defaults += [("default (implicit)", r) for r in case_rows if r.setting.startswith(IMPLICIT_DEFAULT_ROW)]
        for name, default in defaults:
            level = lambda r: max(r.error, r.floor)  # noqa: E731
            better = [r for r in case_rows if not r.not_default and level(r) <= level(default)
                      and r.wall_time_s < default.wall_time_s / 1.1]
            verdict = "on the front (within 10 %)" if not better else "dominated by " + ", ".join(
                f"{r.setting} ({r.wall_time_s:.3g} s, error {r.error:.2e})" for r in better)
            floor = f" (errors below the chaotic spread {default.floor:.2e} count as equal)" if default.floor else ""
            excluded = sorted({f"{r.setting}: {r.not_default}" for r in case_rows
                               if r.not_default and r.wall_time_s < default.wall_time_s and level(r) <= level(default)})
            lines.append(f"- {case}: {name} {default.wall_time_s:.3g} s, error {default.error:.2e}{floor} — {verdict}"
                         + (f"; faster but not default candidates: {'; '.join(excluded)}" if excluded else ""))
    return "\n".join(lines)


def plot(rows: list[Row], path: Path) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from ..recorder.atomic import atomic_path

    fig = Figure(figsize=(8, 5.5), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    for case in dict.fromkeys(r.case for r in rows):
        pts = [r for r in rows if r.case == case]
        line, = ax.loglog([r.wall_time_s for r in pts], [max(r.error, 1e-7) for r in pts], "o", label=case)
        for d in (r for r in pts if r.default or r.implicit_default):
            ax.loglog([d.wall_time_s], [max(d.error, 1e-7)], "*", ms=16, color=line.get_color(), mec="k")
    ax.set_xlabel("wall time (s, median)")
    ax.set_ylabel("relative error")
    ax.set_title("warpcoil: error against run time (stars: the implicit and the reference default)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")


def main(out: Path, quick: bool, repeats: int) -> int:
    rows: list[Row] = []
    for part in (cantilever_rows, helix_rows, release_rows, deployment_rows):
        new = part(quick, repeats)
        rows.extend(new)
        for r in new:
            print(f"{r.case:28s} {r.setting:46s} {r.wall_time_s:8.2f} s  error {r.error:.2e}  {r.detail}", flush=True)
    write_outputs(out, rows, quick, repeats)
    return 0


def write_outputs(out: Path, rows: list[Row], quick: bool, repeats: int) -> None:
    """accuracy.md (table and Pareto check), accuracy.png and accuracy.json in ``out``
    (also from a sweep's accuracy.json: ``[Row(**r) for r in json.load(...)]``)."""
    table = markdown_table(["case", "setting", "default", "steps", "wall time (s)", "error", "detail"],
                           [[r.case, r.setting,
                             "reference" if r.default else "implicit" if r.implicit_default else "",
                             r.steps or "", r.wall_time_s, r.error,
                             r.detail] for r in rows])
    plot(rows, out / "accuracy.png")
    command = f"warpcoil bench accuracy{' --quick' if quick else ''} --repeats {repeats}"
    write_report(out / "accuracy.md", "Run time against error", command,
                 [f"Median wall time of {repeats} run(s) per setting; errors are deterministic.", table,
                  "## Defaults and the Pareto front\n\n" + pareto_check(rows), "![error against run time](accuracy.png)"])
    write_text_atomic(out / "accuracy.json", json.dumps([asdict(r) for r in rows], indent=1))
