"""Validation of regularised Coulomb friction (``warpcoil validate friction``):
a coil piece on an inclined flat wall (stick below tan θ = μ, slide above with
g (sin θ − μ cos θ)), the capstan law (slip at T2/T1 = e^{μφ}) and an undamped
frictional system whose total energy never rises, on the reference step and on the
implicit one; and a frictional deployment on the implicit step that comes to rest.
Units mm, g, s, µN.
"""

from __future__ import annotations

import math

import numpy as np
import trimesh

from .coil import CoilSpec
from .model import ModelBuilder
from .settings import (DEFAULT_DT_SAFETY, CatheterSpec, ContactSettings, OutputSettings, Scene, SimulationSettings,
                       WallSpec)
from .solver import Control, Solver, Stepper
from .state import state_from_positions
from .validation import REFERENCE_D_MM, CaseResult, _row
from .wall import WallMesh

P0_UN = 1.0e3
# the implicit step's capstan (wall friction linearised inside the step's system; docs/FORMULATION.md "Wall and
# device friction inside the step's system"): +0.33 / +0.49 % at its default step (the reference +0.26 / +0.30 %)
IMPLICIT_CAPSTAN_TOLERANCE = 2e-2
# |T2/T1 at a quarter of the default step − at the default step| / e^{μφ}: measured 0 / 0 (the ramp moves ~0.2 %
# between the slip checks; as a per-node change after the solve: 0.10 / 0.06)
IMPLICIT_CAPSTAN_CONVERGENCE = 1e-2
E_MINUS_1 = math.e - 1.0
INCLINE_S = 0.2  # simulated time of the incline rows at segments of 2 d and 3 d (s; a slide of ~10 mm at 2μ)


def _law_uN(h_mm: np.ndarray, c0_mm: float) -> np.ndarray:
    """MODEL.md's contact law below u = 7 (validation loads stay there)."""
    u = np.maximum(1.0 - np.asarray(h_mm) / c0_mm, 0.0)
    return P0_UN / E_MINUS_1 * u * (np.exp(u) - 1.0)


def _law_energy_nJ(h_mm: np.ndarray, c0_mm: float) -> np.ndarray:
    """∫_h^{c0} |F| dh' = c0 P0/(e−1) ((u−1) e^u − u²/2 + 1)."""
    u = np.maximum(1.0 - np.asarray(h_mm) / c0_mm, 0.0)
    return c0_mm * P0_UN / E_MINUS_1 * ((u - 1.0) * np.exp(u) - 0.5 * u * u + 1.0)


def _overlap_for(load_uN: float, c0_mm: float) -> float:
    """Clearance h (mm) at which the law pushes with ``load_uN`` (bisection)."""
    low, high = -6.0 * c0_mm, c0_mm
    for _ in range(200):
        mid = 0.5 * (low + high)
        low, high = (mid, high) if _law_uN(mid, c0_mm) > load_uN else (low, mid)
    return 0.5 * (low + high)


def _wall(mesh: trimesh.Trimesh) -> WallMesh:
    return WallMesh(np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int32), float(mesh.volume), (),
                    None)


def _floor() -> WallMesh:
    """A box whose floor is the plane z = 0 (inward normal +z)."""
    box = trimesh.creation.box(extents=(40.0, 40.0, 10.0))
    box.apply_translation((0.0, 0.0, 5.0))
    return _wall(box)


def _straight(nodes: int, d: float, axis=(1.0, 0.0, 0.0), centre=(0.0, 0.0, 0.0)) -> np.ndarray:
    s = (np.arange(nodes) - 0.5 * (nodes - 1)) * d
    return np.asarray(centre) + s[:, None] * np.asarray(axis)


def straight_coils(positions: list[np.ndarray], segment_mm: float = REFERENCE_D_MM, mu_coil: float = 0.0,
                   damping: float | None = None):
    """A Model of coils of wire diameter REFERENCE_D_MM and segment length ``segment_mm`` through
    ``positions`` (node positions each, mm), contact P0_UN, coil friction ``mu_coil``, the default
    damping unless ``damping`` (µN/mm)."""
    spec = CoilSpec(wire_diameter_mm=REFERENCE_D_MM, length_mm=(len(positions[0]) - 1) * segment_mm,
                    segment_length_mm=segment_mm)
    settings = SimulationSettings() if damping is None else SimulationSettings(damping_uN_per_mm=damping)
    builder = ModelBuilder(settings=settings, contact=ContactSettings(P0_uN=P0_UN, friction_coil=mu_coil))
    for x in positions:
        builder.add_coil(spec, x)
    return builder.finalize()


# --- inclined plane ---------------------------------------------------------------
def rod_on_floor(mu: float, g_mm_s2: np.ndarray, nodes: int = 11,
                 v_reg_mm_s: float = ContactSettings.friction_speed_mm_s, segment_d: float = 1.0):
    """A straight, undamped coil piece along x on the floor (friction μ) under the body
    acceleration ``g_mm_s2`` (mm/s²), segments of ``segment_d`` · d (above 1.5 d the wall acts at
    contact samples between the nodes too): the model and its level positions at contact
    equilibrium (every node at the gap where the law carries an interior node's weight;
    an end node has half the mass and half the contact share; at samples the law per length is kept)."""
    d = REFERENCE_D_MM
    rest = _straight(nodes, segment_d * d)
    builder = ModelBuilder(settings=SimulationSettings(damping_uN_per_mm=0.0),
                           contact=ContactSettings(P0_uN=P0_UN, friction_wall=mu, friction_speed_mm_s=v_reg_mm_s),
                           wall=_floor())
    builder.add_coil(CoilSpec(wire_diameter_mm=d, length_mm=(nodes - 1) * segment_d * d,
                              segment_length_mm=segment_d * d), rest)
    builder.body_acceleration(g_mm_s2)
    model = builder.finalize()
    interior_mass = float(1.0 / model.inv_mass.numpy()[nodes // 2])
    x = rest.copy()
    x[:, 2] = 0.5 * d + _overlap_for(interior_mass * -float(g_mm_s2[2]), model.contact.c0_mm)
    return model, x


def _solver(model, implicit: bool, coil_contact: bool = True, scheme: str = "gated_chord",
            step_scale: float = 1.0) -> Solver:
    """The reference (symplectic) solver, or the implicit one at ``step_scale`` × its default
    step (the push step of the default push speed) in ``scheme`` (IMPLICIT_SCHEMES)."""
    if not implicit:
        return Solver(model, coil_contact=coil_contact)
    from .implicit import ImplicitSolver, implicit_step_s, scheme_options
    return ImplicitSolver(model, dt_s=step_scale * implicit_step_s(model, SimulationSettings().push_speed_mm_s),
                          coil_contact=coil_contact, **scheme_options(scheme))


def _label(implicit: bool) -> str:
    """A case's prefix: which step it runs on."""
    return "implicit step, friction" if implicit else "friction"


def _chunk(solver: Solver, explicit_steps: int) -> int:
    """Steps per chunk: ``explicit_steps`` of the reference's step, in the solver's."""
    return max(1, round(explicit_steps * DEFAULT_DT_SAFETY * solver.bound.dt_s / solver.dt_s))


def incline_motion(mu: float, tan_ratio: float, g_mm_s2: float = 2000.0, steps: int = 20_000,
                   nodes: int = 11, v_reg_mm_s: float = ContactSettings.friction_speed_mm_s,
                   implicit: bool = False, scheme: str = "gated_chord", segment_d: float = 1.0,
                   duration_s: float | None = None) -> tuple[float, float, float]:
    """A straight coil piece on the floor under a body acceleration g tilted by θ
    (tan θ = tan_ratio · μ), segments of ``segment_d`` · d (:func:`rod_on_floor`), starting at rest
    at its contact equilibrium, for ``steps`` of the reference's step, or (``duration_s``) that simulated
    time in chunks of 200 of them (``implicit``: the implicit step in ``scheme``, :func:`_solver`). Returns
    (fitted acceleration over the second half, mm/s²; analytic g (sin θ − μ cos θ) or 0 when it sticks;
    mean speed over the second half, mm/s; largest mean speed, mm/s)."""
    theta = math.atan(tan_ratio * mu)
    model, x = rod_on_floor(mu, g_mm_s2 * np.array([math.sin(theta), 0.0, -math.cos(theta)]), nodes, v_reg_mm_s,
                            segment_d)
    solver = _solver(model, implicit, coil_contact=False, scheme=scheme)
    chunk = _chunk(solver, 200)
    stepper = Stepper(solver, state_from_positions(model, x), Control.create(model), chunk=chunk)
    chunks = steps // 200 if duration_s is None else math.ceil(duration_s / (chunk * solver.dt_s))
    times, speeds = [], []
    for _ in range(chunks):
        state = stepper.run_chunk()
        times.append(state.time_s)
        speeds.append(float(state.v.numpy()[:, 0].mean()))
    half = len(times) // 2
    acceleration = float(np.polyfit(times[half:], speeds[half:], 1)[0])
    reference = max(g_mm_s2 * (math.sin(theta) - mu * math.cos(theta)), 0.0)
    return acceleration, reference, float(np.mean(speeds[half:])), float(np.max(np.abs(speeds)))


def incline_cases(mu: float = 0.3, implicit: bool = False) -> list[CaseResult]:
    """Stick (creep) and slide on the incline at segments of d, then at 2 d and 3 d, where the wall acts
    at contact samples between the nodes (a node's own law weighs 1/K: friction taken from the node's
    own load alone would slide at g (sin θ − μ cos θ / K))."""
    rows = []
    v_reg = ContactSettings().friction_speed_mm_s
    label = _label(implicit)
    for ratio in (0.8, 0.99):  # stuck: creeps at v_reg F_t/(μN) = v_reg tanθ/μ < v_reg
        _, _, creep, _ = incline_motion(mu, ratio, implicit=implicit)
        rows.append(_row(f"{label} incline tanθ = {ratio}μ: sticks, creep (mm/s)", ratio * v_reg, creep, 1e-2))
    for ratio in (1.2, 2.0):
        acceleration, reference, _, _ = incline_motion(mu, ratio, implicit=implicit)
        rows.append(_row(f"{label} incline tanθ = {ratio}μ: slide accel. (mm/s²)", reference, acceleration, 1e-2))
    for segment_d in (2.0, 3.0):  # (0.2 s: the d rows' time; the reference's step is contact-bound, ~1.5–1.9 × d's)
        _, _, creep, _ = incline_motion(mu, 0.8, implicit=implicit, segment_d=segment_d, duration_s=INCLINE_S)
        rows.append(_row(f"{label} incline tanθ = 0.8μ, segments {segment_d:g} d (wall at contact samples): "
                         "sticks, creep (mm/s)", 0.8 * v_reg, creep, 1e-2))
        acceleration, reference, _, _ = incline_motion(mu, 2.0, implicit=implicit, segment_d=segment_d,
                                                       duration_s=INCLINE_S)
        rows.append(_row(f"{label} incline tanθ = 2μ, segments {segment_d:g} d (wall at contact samples): "
                         "slide accel. (mm/s²)", reference, acceleration, 1e-2))
    return rows


# --- capstan ----------------------------------------------------------------------
def capstan_slip_ratio(mu: float, wrap_rad: float, radius_mm: float = 5.0, t1_uN: float = 500.0,
                       ramp_s: float = 0.2, tail_mm: float = 3.0, implicit: bool = False,
                       step_scale: float = 1.0) -> tuple[float, float]:
    """A soft coil (EI = 1 µN·mm²: bending adds ~EI/(R² T) ≈ 1e-4 to the ratio)
    wrapped by ``wrap_rad`` over a cylinder of ``radius_mm`` (the inner wall of an
    annular lumen), straight tails leaving it tangentially; tension T1 at one end,
    T2 at the other ramped from T1 up to 1.5 e^{μφ} T1 over ``ramp_s``. Returns
    (T2/T1 when the held (T1) end of the wrap first slides faster than 5 v_reg,
    e^{μφ}). ``implicit``: on the implicit step, ``step_scale`` × its default step."""
    d = REFERENCE_D_MM
    annulus = trimesh.creation.annulus(r_min=radius_mm, r_max=radius_mm + 15.0, height=6.0, sections=720)
    contact = ContactSettings(P0_uN=P0_UN, friction_wall=mu)
    c0 = 0.1 * d
    rho = radius_mm + 0.5 * d + _overlap_for(t1_uN * d / (radius_mm + 0.5 * d), c0)
    segments = int(round(wrap_rad * rho / d))
    angles = -0.5 * wrap_rad + wrap_rad / segments * np.arange(segments + 1)
    arc = np.stack([rho * np.cos(angles), rho * np.sin(angles), np.zeros_like(angles)], 1)
    chord = 2.0 * rho * math.sin(0.5 * wrap_rad / segments)
    tangent = lambda a: np.array([-math.sin(a), math.cos(a), 0.0])  # noqa: E731  direction of increasing angle
    tail = int(round(tail_mm / chord))
    head = arc[0] - tangent(angles[0]) * chord * np.arange(tail, 0, -1)[:, None]
    end = arc[-1] + tangent(angles[-1]) * chord * np.arange(1, tail + 1)[:, None]
    x = np.concatenate([head, arc, end])
    spec = CoilSpec(wire_diameter_mm=d, length_mm=(len(x) - 1) * chord, bending_stiffness_uN_mm2=1.0,
                    twist_stiffness_uN_mm2=1.0)
    builder = ModelBuilder(settings=SimulationSettings(damping_uN_per_mm=10.0), contact=contact,
                           wall=_wall(annulus))
    builder.add_coil(spec, x)
    model = builder.finalize()
    external = np.zeros((model.node_count, 3))

    def pull(t2_uN: float) -> None:
        external[0] = -t1_uN * tangent(angles[0])
        external[-1] = t2_uN * tangent(angles[-1])
        model.external.assign(external)

    pull(t1_uN)
    solver = _solver(model, implicit, coil_contact=False, step_scale=step_scale)
    stepper = Stepper(solver, state_from_positions(model, x), Control.create(model), chunk=_chunk(solver, 100))
    stepper.run_steps(int(0.02 / solver.dt_s))  # settle under T1 at both ends
    reference = math.exp(mu * wrap_rad)
    start = stepper.state.time_s
    while stepper.state.time_s - start < ramp_s:
        ratio = 1.0 + (1.5 * reference - 1.0) * (stepper.state.time_s - start) / ramp_s
        pull(ratio * t1_uN)
        state = stepper.run_chunk()
        if float(np.dot(state.v.numpy()[tail], tangent(angles[0]))) > 5.0 * contact.friction_speed_mm_s:
            return ratio, reference
    return math.inf, reference


def capstan_cases(implicit: bool = False) -> list[CaseResult]:
    """Slip at e^{μφ} (the implicit step at its default step, and how far a quarter of that step
    moves it: IMPLICIT_CAPSTAN_CONVERGENCE)."""
    rows = []
    label = _label(implicit)
    for mu, wrap in ((0.2, math.pi), (0.3, 0.5 * math.pi)):
        ratio, reference = capstan_slip_ratio(mu, wrap, implicit=implicit)
        case = f"{label} capstan μ={mu}, φ={wrap:.3f}"
        rows.append(_row(f"{case}: slip T2/T1", reference, ratio, IMPLICIT_CAPSTAN_TOLERANCE if implicit else 2e-2))
        if implicit:
            quarter, _ = capstan_slip_ratio(mu, wrap, implicit=True, step_scale=0.25)
            moved = abs(quarter - ratio) / reference
            rows.append(CaseResult(f"{case}: |T2/T1 at ¼ step − at the default step| / e^(μφ)", 0.0, moved,
                                   moved, IMPLICIT_CAPSTAN_CONVERGENCE))
    return rows


# --- energy -----------------------------------------------------------------------
def frictional_energy(mu: float = 0.3, steps: int = 5000, g_mm_s2: float = 2.0e4, speed_mm_s: float = 30.0,
                      implicit: bool = False) -> tuple[float, float, float]:
    """Undamped: a straight coil on the floor, sliding at 30 mm/s, and a second one
    across it and above the floor, sliding the other way, both pressed down by a
    body acceleration and started at their contact equilibrium (wall, coil–coil friction). Total energy = kinetic + elastic
    + contact (∫ of the law over each wall gap and coil pair gap) + body-force
    potential. Returns (largest rise of the total energy between any two frames,
    the same system's energy range without friction (the integrator's own
    fluctuation), energy dissipated), nJ."""
    d = REFERENCE_D_MM
    nodes = 15
    c0 = 0.1 * d
    mass = CoilSpec(wire_diameter_mm=d, length_mm=(nodes - 1) * d).rho * d  # per interior node
    node_mass = np.full(nodes, mass)
    node_mass[[0, -1]] *= 0.5  # end nodes carry half a segment
    lower_z = 0.5 * d + _overlap_for(node_mass.mean() * g_mm_s2, c0)  # each coil starts level, near equilibrium
    lower = _straight(nodes, d, centre=(0.0, 0.0, lower_z))
    upper = _straight(nodes, d, axis=(0.0, 1.0, 0.0),
                      centre=(0.0, 0.0, lower_z + d + _overlap_for(node_mass.sum() * g_mm_s2, c0)))
    totals = []
    for friction in (0.0, mu):
        contact = ContactSettings(P0_uN=P0_UN, friction_wall=friction, friction_coil=friction)
        builder = ModelBuilder(settings=SimulationSettings(damping_uN_per_mm=0.0), contact=contact, wall=_floor())
        for rest in (lower, upper):
            builder.add_coil(CoilSpec(wire_diameter_mm=d, length_mm=(nodes - 1) * d), rest)
        g = np.array([0.0, 0.0, -g_mm_s2])
        builder.body_acceleration(g)
        model = builder.finalize()
        solver = _solver(model, implicit)
        state = state_from_positions(model, np.concatenate([lower, upper]))
        v = np.zeros((model.node_count, 3))
        v[:nodes, 0], v[nodes:, 0] = speed_mm_s, -speed_mm_s
        state.v.assign(v)
        stepper = Stepper(solver, state, Control.create(model), chunk=_chunk(solver, 100))
        masses = 1.0 / model.inv_mass.numpy()
        share = model.contact_share.numpy()
        energy = []
        for _ in range(steps // 100):
            state = stepper.run_chunk()
            x = state.x.numpy()
            contact_nJ = (share * _law_energy_nJ(x[:, 2] - 0.5 * d, c0)).sum() + _pair_energy_nJ(x, nodes, d, c0)
            energy.append(sum(solver.energies(state).values()) + contact_nJ - float(np.sum(masses * (x @ g))))
        energy = np.array(energy)
        totals.append(energy)
    rise = [float(np.max(e - np.minimum.accumulate(e))) for e in totals]  # largest rise after any frame
    frictionless, frictional = totals
    return rise[1], max(rise[0], float(np.ptp(frictionless))), float(frictional[0] - frictional[-1])


def _pair_energy_nJ(x: np.ndarray, nodes: int, d: float, c0: float) -> float:
    """Coil–coil contact energy of the two straight coils, the potential of
    contact.py's coil–coil force (docs/FORMULATION.md): ½ s_j × the law between every
    node j and every capsule of the other coil, both ways (s_j the node's contact
    share: ½ at an end, else 1), minus the joint corrections
    w_jk = ½ (s_j [k interior] + s_k [j interior]) of the law between node spheres j
    and k (a straight coil never touches itself)."""
    a, b = x[:nodes], x[nodes:]

    def node_capsule(points: np.ndarray, chain: np.ndarray) -> np.ndarray:
        p0, e = chain[:-1][None], (chain[1:] - chain[:-1])[None]
        t = np.clip(np.sum((points[:, None] - p0) * e, axis=2) / np.sum(e * e, axis=2), 0.0, 1.0)
        return np.linalg.norm(points[:, None] - p0 - t[..., None] * e, axis=2)

    interior = np.ones(nodes)
    interior[[0, -1]] = 0.0
    share = 0.5 + 0.5 * interior  # uniform segments: ½ at an end
    weight = 0.5 * (share[:, None] * interior[None, :] + interior[:, None] * share[None, :])
    node_node = np.linalg.norm(a[:, None] - b[None], axis=2)
    return float(0.5 * (share[:, None] * _law_energy_nJ(node_capsule(a, b) - d, c0)).sum()
                 + 0.5 * (share[:, None] * _law_energy_nJ(node_capsule(b, a) - d, c0)).sum()
                 - (weight * _law_energy_nJ(node_node - d, c0)).sum())


def energy_cases(implicit: bool = False) -> list[CaseResult]:
    """Friction never raises the total energy beyond the integrator's own fluctuation, and
    (the reference, which conserves energy) dissipates ≫ that. (The implicit step loses energy
    itself, comparable to what friction dissipates here: only the first holds for it.)"""
    rise, fluctuation, dissipated = frictional_energy(implicit=implicit)
    label = _label(implicit)
    rows = [CaseResult(f"{label} energy: largest rise (nJ) ≤ frictionless fluctuation", 0.0, rise, rise, fluctuation)]
    if not implicit:
        rows.append(CaseResult(f"{label} energy: frictionless fluctuation / dissipated", 0.0, fluctuation / dissipated,
                               fluctuation / dissipated, 0.2))
    return rows


# --- a frictional deployment on the implicit step ----------------------------------
def frictional_deployment(friction: bool = True) -> Scene:
    """A 40 mm helical coil (d 0.254 mm, loop 3 mm) pushed at 30 mm/s into a 3.5 mm sphere,
    wall / coil / catheter friction μ 0.1 / 0.2 / 0.3 (``friction``: else none), on the
    implicit step at its default scheme."""
    contact = (ContactSettings(friction_wall=0.1, friction_coil=0.2, friction_catheter=0.3) if friction
               else ContactSettings())
    return Scene(coils=(CoilSpec(shape="helix", wire_diameter_mm=0.254, loop_diameter_mm=3.0, length_mm=40.0),),
                 catheter=CatheterSpec(tip_mm=(0.0, 0.0, -1.45), direction=(0.0, 0.0, 1.0)),
                 wall=WallSpec(sphere_diameter_mm=3.5), contact=contact,
                 simulation=SimulationSettings(push_speed_mm_s=30.0, integrator="implicit"), output=OutputSettings(usd=False))


def frictional_rest_cases() -> list[CaseResult]:
    """The frictional deployment comes to rest within its time limit (push + 2 s: kinetic
    energy under the rest tolerance), its smallest coil and wall gaps no deeper than the
    frictionless run's by more than c0/2."""
    from .deploy import Deployment
    runs = {}
    for friction in (True, False):
        deployment = Deployment(frictional_deployment(friction))
        runs[friction] = (deployment.run(), deployment.members[0].rest_kinetic_energy_nJ)
    (result, rest), (frictionless, _) = runs[True], runs[False]
    half_c0 = 0.5 * deployment.model.contact.c0_mm
    label = "implicit step, friction μ 0.1/0.2/0.3, 40 mm helix into a 3.5 mm sphere"
    ratio = result.final_kinetic_nJ / rest  # (completed: under 1; any other status fails the row)
    rows = [CaseResult(f"{label}: {result.status} at {result.simulated_time_s:.2f} s, final kinetic / rest tolerance",
                       1.0, ratio, max(ratio - 1.0, 0.0) + float(result.status != "completed"), 0.0)]
    for name, gap, reference in (("coil", result.min_coil_gap_mm, frictionless.min_coil_gap_mm),
                                 ("wall", result.min_wall_gap_mm, frictionless.min_wall_gap_mm)):
        rows.append(CaseResult(f"{label}: smallest {name} gap (mm) ≥ frictionless − c0/2", reference, gap,
                               max(reference - gap, 0.0), half_c0))
    return rows


def friction_cases() -> list[CaseResult]:
    """The reference (symplectic) step's cases, then the implicit step's: incline, capstan (with its
    step convergence), energy, a deployment at rest; coil–coil friction (validation_coil_friction.py)."""
    from .validation_coil_friction import coil_friction_cases

    return (incline_cases() + capstan_cases() + energy_cases() + incline_cases(implicit=True)
            + capstan_cases(implicit=True) + energy_cases(implicit=True) + frictional_rest_cases()
            + coil_friction_cases())
