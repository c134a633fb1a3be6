"""Validation cases with analytic references (``warpcoil validate``; the tests run
the same functions).

Each case returns :class:`CaseResult` rows: reference, result, relative error
and tolerance. Units mm, g, s, µN.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import warp as wp

from . import preshape
from .coil import CoilSpec
from .kernels import contact, integrate
from .metrics import fit_helix
from .model import ModelBuilder
from .settings import DEFAULT_DT_SAFETY, CatheterSpec, SimulationSettings
from .solver import Control, Solver, Stepper
from .state import packed_state, state_from_positions

REFERENCE_D_MM = 0.2921  # the abstract's coil: secondary radius 0.014605 cm


@dataclass(frozen=True)
class CaseResult:
    case: str
    reference: float
    result: float
    error: float  # relative, or absolute where the reference is 0
    tolerance: float

    @property
    def passed(self) -> bool:
        return bool(self.error <= self.tolerance)


def _rel(result: float, reference: float) -> float:
    return abs(result - reference) / abs(reference) if reference != 0.0 else abs(result)


def _row(case: str, reference: float, result: float, tolerance: float) -> CaseResult:
    return CaseResult(case, float(reference), float(result), _rel(result, reference), tolerance)


# --- contact law ------------------------------------------------------------
def contact_law(p0_uN: float = 1.0e3, c0_mm: float = 0.1 * REFERENCE_D_MM) -> list[CaseResult]:
    """F(0) = P0, F(−6 c0) = 4463.43 P0, value and slope continuous at u = 7, zero for h ≥ c0."""
    eps = 1e-9 * c0_mm
    h = np.array([0.0, -6.0 * c0_mm, -6.0 * c0_mm - eps, -6.0 * c0_mm + eps, c0_mm, 2.0 * c0_mm, c0_mm - eps])
    f = wp.zeros(len(h), dtype=wp.float64)
    k = wp.zeros(len(h), dtype=wp.float64)
    wp.launch(contact.evaluate_law, len(h), inputs=[wp.array(h, dtype=wp.float64), p0_uN, c0_mm,
                                                    float(contact.U_LINEAR), f, k])
    f, k = f.numpy(), k.numpy()
    jump = abs(f[2] - f[3]) / f[1]
    kink = abs(k[2] - k[3]) / k[1]
    return [
        _row("contact: F(0)/P0", 1.0, f[0] / p0_uN, 1e-12),
        _row("contact: F(-6 c0)/P0", 4463.43, f[1] / p0_uN, 1e-6),
        CaseResult("contact: value jump at u=7 (rel.)", 0.0, jump, jump, 1e-6),
        CaseResult("contact: slope jump at u=7 (rel.)", 0.0, kink, kink, 1e-6),
        CaseResult("contact: F at h = c0, 2 c0, c0-", 0.0, f[4] + f[5] + f[6], f[4] + f[5] + f[6], 1e-9),
    ]


# --- gradient -----------------------------------------------------------------
def _rotate(v: np.ndarray, axis: np.ndarray, angle: float | np.ndarray) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    c, s = np.atleast_1d(c)[:, None], np.atleast_1d(s)[:, None]
    return v * c + np.cross(axis, v) * s + axis * np.sum(axis * v, axis=1, keepdims=True) * (1.0 - c)


def gradient_check(positions: np.ndarray, directors: np.ndarray, rest: np.ndarray, spec: CoilSpec,
                   eps: float = 1e-6) -> tuple[float, float]:
    """Relative error of forces and twisting torques against central differences of
    the energy, with directors dragged by parallel transport (as the solver does).

    All 6N + 2(N−1) perturbed copies are evaluated in one batch model."""
    n = len(positions)
    dofs = 3 * n
    builder = ModelBuilder()
    builder.add_coil(spec, rest)
    model = builder.finalize()
    state = state_from_positions(model, positions)
    state.m1.assign(directors)
    solver = Solver(model)
    solver.compute_forces(state)
    force, torque = solver.force.numpy(), solver.torque.numpy()[: n - 1]

    signs = np.array([1.0, -1.0])
    shift = np.einsum("s,kd->skd", signs * eps, np.eye(dofs)).reshape(2 * dofs, n, 3)
    moved = positions[None] + shift  # (2·3N, n, 3)
    copies = 2 * dofs + 2 * (n - 1)
    batch = ModelBuilder()
    for _ in range(copies):
        batch.add_coil(spec, rest)
    batch_model = batch.finalize()
    x_old = np.tile(positions, (copies, 1))
    x_new = np.concatenate([moved.reshape(-1, 3), np.tile(positions, (2 * (n - 1), 1))])
    m1 = wp.zeros(copies * n, dtype=wp.vec3d)
    zeros_f = wp.zeros(copies * n, dtype=wp.float64)
    wp.launch(integrate.update_frames, copies * n, inputs=[
        wp.array(x_old, dtype=wp.vec3d), wp.array(x_new, dtype=wp.vec3d), wp.array(np.tile(directors, (copies, 1)),
        dtype=wp.vec3d), zeros_f, zeros_f, wp.zeros(copies * n, dtype=wp.int32), batch_model.has_next,
        batch_model.inv_inertia, zeros_f, batch_model.world_of, wp.ones(1, dtype=wp.int32), 0.0, m1,
        wp.zeros(copies * n, dtype=wp.float64)])
    m1 = m1.numpy().reshape(copies, n, 3)
    tangents = np.diff(positions, axis=0)
    tangents /= np.linalg.norm(tangents, axis=1)[:, None]
    for sign_index, sign in enumerate(signs):  # twist perturbations, all edges at once
        rows = 2 * dofs + sign_index * (n - 1) + np.arange(n - 1)
        m1[rows, np.arange(n - 1)] = _rotate(directors[:-1], tangents, sign * eps)
    twisted = state_from_positions(batch_model, x_new)
    twisted.m1.assign(m1.reshape(-1, 3))
    batch_solver = Solver(batch_model)
    energy = batch_solver.elastic_energy_per_node(twisted).reshape(copies, n).sum(axis=1)
    grad_x = ((energy[:dofs] - energy[dofs:2 * dofs]) / (2 * eps)).reshape(n, 3)
    grad_theta = (energy[2 * dofs:2 * dofs + n - 1] - energy[2 * dofs + n - 1:]) / (2 * eps)
    force_err = np.abs(grad_x + force).max() / np.abs(force).max()
    torque_err = np.abs(grad_theta + torque).max() / max(np.abs(torque).max(), 1e-300)
    return float(force_err), float(torque_err)


def gradient_cases(seed: int = 0) -> list[CaseResult]:
    """Forces = −∇W on a random 3D configuration and on an exactly straight one."""
    rng = np.random.default_rng(seed)
    spec = CoilSpec(length_mm=4.0, loop_diameter_mm=2.0, axial_stiffness_uN=2.0e4)
    rest = preshape.helix(2.0, 0.8, 4.0, spec.l0)
    n = len(rest)
    curved = rest + 0.03 * rng.standard_normal(rest.shape)
    tangents = np.diff(curved, axis=0)
    tangents /= np.linalg.norm(tangents, axis=1)[:, None]
    model_builder = ModelBuilder()
    model_builder.add_coil(spec, rest)
    model = model_builder.finalize()
    bishop = model.directors_along(curved)
    twisted = bishop.copy()
    twisted[:-1] = _rotate(bishop[:-1], tangents, rng.uniform(-0.5, 0.5, n - 1))
    straight = np.zeros_like(rest)
    straight[:, 2] = np.arange(n) * spec.l0 * 1.001
    straight_dirs = model.directors_along(straight)
    straight_dirs[:-1] = _rotate(straight_dirs[:-1], np.array([0.0, 0.0, 1.0]), rng.uniform(-0.5, 0.5, n - 1))
    rows = []
    for label, x, m1 in (("random 3D", curved, twisted), ("straight", straight, straight_dirs)):
        f_err, t_err = gradient_check(x, m1, rest, spec)
        rows.append(CaseResult(f"gradient: force vs FD, {label}", 0.0, f_err, f_err, 1e-5))
        rows.append(CaseResult(f"gradient: torque vs FD, {label}", 0.0, t_err, t_err, 1e-5))
    return rows


# --- cantilever ---------------------------------------------------------------
ELASTICA_DEFLECTION = {5.0: 0.713792}  # δ/L under a tip dead load, P L²/EI = 5 (Euler elastica)


def cantilever_deflection(segments: int, load_parameter: float, length_mm: float = 20.0,
                          dt_safety: float = DEFAULT_DT_SAFETY) -> float:
    """Tip deflection δ/L of a clamped straight coil under a transverse dead load
    P = load_parameter · EI / L² at the free end, damped to rest.

    The clamp holds the first edge (nodes 0 and 1: position and direction), as
    in Discrete Elastic Rods; the clamped section is then the midpoint of that
    edge (the first bending vertex's Voronoi cell starts there), so the nodes
    sit at x = (k − ½) l0 with l0 = L/(n − ½) and the tip at x = L."""
    l0 = length_mm / (segments - 0.5)
    spec = CoilSpec(length_mm=length_mm, segment_length_mm=l0)
    rest = np.zeros((segments + 1, 3))
    rest[:, 0] = (np.arange(segments + 1) - 0.5) * l0
    omega1 = 3.516 * math.sqrt(spec.EI / (spec.rho * length_mm**4))  # first mode, rad/s
    speed_scale = 1.0e3  # mm/s: keep the damping in its linear range
    damping = 2.0 * spec.rho * omega1 * speed_scale  # critical for mode 1, per mm
    builder = ModelBuilder(settings=SimulationSettings(damping_uN_per_mm=damping, damping_speed_mm_s=speed_scale))
    builder.add_coil(spec, rest)
    builder.clamp(0, nodes=2)
    load = load_parameter * spec.EI / length_mm**2
    builder.apply_force(0, -1, (0.0, -load, 0.0))
    model = builder.finalize()
    stepper = Stepper(Solver(model, coil_contact=False, dt_safety=dt_safety), state_from_positions(model, rest),
                      Control.create(model), chunk=1000)  # a bending straight beam cannot touch itself
    state, rested = stepper.run_to_rest(1e-10 * load * length_mm, max_steps=2_000_000, min_steps=20_000)
    if not rested:
        raise RuntimeError("cantilever did not come to rest")
    return float(-state.x.numpy()[-1, 1] / length_mm)


def cantilever_cases(resolutions=(25, 50, 100)) -> list[CaseResult]:
    rows = []
    errors = []
    for segments in resolutions:
        row = _row(f"cantilever PL²/EI=5, {segments} segments: δ/L", ELASTICA_DEFLECTION[5.0],
                   cantilever_deflection(segments, 5.0), 5e-3 if segments >= 50 else 2e-2)
        rows.append(row)
        errors.append(row.error)
    shrinking = all(b < a for a, b in zip(errors, errors[1:]))
    rows.append(CaseResult("cantilever: error shrinks with refinement", 1.0, float(shrinking),
                           0.0 if shrinking else 1.0, 0.0))
    rows.append(_row("cantilever PL²/EI=0.05, 50 segments: δ/L vs PL²/(3EI)", 0.05 / 3.0,
                     cantilever_deflection(50, 0.05), 5e-3))
    return rows


# --- helix recovery and free release -----------------------------------------
HELIX = dict(length_mm=60.0, loop_diameter_mm=3.0, pitch_mm=0.6)


def _helix_spec(segment_length_mm: float | None = None) -> CoilSpec:
    return CoilSpec(wire_diameter_mm=REFERENCE_D_MM, shape="helix", segment_length_mm=segment_length_mm, **HELIX)


def _helix_rows(label: str, points: np.ndarray) -> list[CaseResult]:
    fit = fit_helix(points)
    return [
        _row(f"{label}: loop diameter (mm)", HELIX["loop_diameter_mm"], fit.loop_diameter_mm, 1e-2),
        _row(f"{label}: pitch (mm)", HELIX["pitch_mm"], fit.pitch_mm, 3e-2),
    ]


def _settle(stepper: Stepper, max_steps: int) -> np.ndarray:
    state, rested = stepper.run_to_rest(1e-5, max_steps=max_steps)
    if not rested:
        raise RuntimeError("the coil did not come to rest")
    return state.x.numpy()


def helix_recovery(segment_length_mm: float | None = None, dt_safety: float = DEFAULT_DT_SAFETY) -> list[CaseResult]:
    """A 60 mm helical coil started straight, free ends, damped to rest."""
    spec = _helix_spec(segment_length_mm)
    builder = ModelBuilder(settings=SimulationSettings(damping_uN_per_mm=5.0))
    builder.add_coil(spec)
    model = builder.finalize()
    n = model.node_count
    straight = np.zeros((n, 3))
    straight[:, 0] = model.arc_s.numpy()
    # elastic only: a straight start is no physical state, and its whipping release
    # would tangle the coil through self-contact (free_release has contact on)
    stepper = Stepper(Solver(model, coil_contact=False, dt_safety=dt_safety), state_from_positions(model, straight),
                      Control.create(model), chunk=1000)
    return _helix_rows("helix recovery", _settle(stepper, max_steps=4_000_000))


def free_release(push_speed_mm_s: float = 100.0, dt_safety: float = DEFAULT_DT_SAFETY,
                 segment_length_mm: float | None = None, mass_scale: float = 1.0) -> list[CaseResult]:
    """The helical coil packed in a straight catheter and pushed out into empty space."""
    spec = _helix_spec(segment_length_mm)
    settings = SimulationSettings(damping_uN_per_mm=5.0, push_speed_mm_s=push_speed_mm_s, mass_scale=mass_scale)
    builder = ModelBuilder(catheter=CatheterSpec(), settings=settings)
    builder.add_coil(spec)
    model = builder.finalize()
    control = Control.create(model, active_coil=0, push_speed_mm_s=push_speed_mm_s)
    stepper = Stepper(Solver(model, dt_safety=dt_safety), packed_state(model), control, chunk=1000)
    coil_length = float(model.arc_s.numpy()[-1])
    while stepper.state.advance.numpy()[0] < coil_length:
        stepper.run_steps(stepper.chunk)
    control.set_active_coil(-1)  # detached: the pusher stops
    return _helix_rows("free release", _settle(stepper, max_steps=stepper.steps + 4_000_000))


# --- energy ---------------------------------------------------------------------
def energy_conservation(steps: int = 100_000) -> list[CaseResult]:
    """Undamped free vibration of a straight-rest coil started bent into an arc."""
    length, segments, bend_angle = 20.0, 40, 1.0
    spec = CoilSpec(length_mm=length, segment_length_mm=length / segments)
    s = np.linspace(0.0, length, segments + 1)
    rest = np.stack([s, np.zeros_like(s), np.zeros_like(s)], axis=1)
    radius = length / bend_angle
    arc = np.stack([radius * np.sin(s / radius), radius * (1.0 - np.cos(s / radius)), np.zeros_like(s)], axis=1)
    builder = ModelBuilder(settings=SimulationSettings(damping_uN_per_mm=0.0))
    builder.add_coil(spec, rest)
    model = builder.finalize()
    solver = Solver(model, coil_contact=False)  # a gently bent rod does not touch itself
    stepper = Stepper(solver, state_from_positions(model, arc), Control.create(model), chunk=1000)
    total = lambda e: sum(e.values())  # noqa: E731
    e0 = total(solver.energies(stepper.state))
    drift = 0.0
    for _ in range(steps // stepper.chunk):
        stepper.run_steps(stepper.chunk)
        drift = max(drift, abs(total(solver.energies(stepper.state)) - e0) / e0)
    return [CaseResult(f"energy: undamped, {steps} steps, max |ΔE|/E", 0.0, drift, drift, 1e-2)]


# --- wall field -------------------------------------------------------------
def wall_field_cases(diameter_mm: float = 3.5, voxels_mm: tuple[float, float] = (0.08, 0.04),
                     c0_mm: float = 0.1 * REFERENCE_D_MM, points: int = 20000) -> list[CaseResult]:
    """The narrow-band field of the seed sphere against the exact BVH at random
    points of the contact band (0–0.25 mm inside the wall), where the field is
    trusted: largest distance error (≤ 0.05 c0 at the default voxel), its
    observed order as the voxel halves (≈ 1: the faceted wall's creases; ≥ 2
    on a smooth wall), RMS normal error (≤ 2°), share of points trusted."""
    from .model import WallModel
    from .wall import sphere_wall
    from .wall_field import band_points, build_wall_field, field_error

    mesh = sphere_wall(diameter_mm)
    wall = WallModel.create(mesh.vertices_mm, mesh.faces, mesh.volume_mm3, wp.get_device())
    pts = band_points(wall, (0.0, 0.25), points)
    coarse, fine = (field_error(wall, build_wall_field(wall, 0.3, h), pts) for h in voxels_mm)
    order = math.log(coarse.distance_max_mm / fine.distance_max_mm) / math.log(voxels_mm[0] / voxels_mm[1])
    h = voxels_mm[1]
    return [
        CaseResult(f"wall field h={h} mm: max |d − d_BVH| / c0", 0.0, fine.distance_max_mm / c0_mm,
                   fine.distance_max_mm / c0_mm, 0.05),
        _row(f"wall field: observed order of the distance error, h {voxels_mm[0]} → {h} mm", 1.0, order, 0.6),
        CaseResult(f"wall field h={h} mm: RMS normal error (deg)", 0.0, fine.normal_rms_deg, fine.normal_rms_deg, 2.0),
        CaseResult(f"wall field h={h} mm: share of band points untrusted", 0.0, 1.0 - fine.trusted / fine.points,
                   1.0 - fine.trusted / fine.points, 0.05),
    ]


# --- porous field ------------------------------------------------------------------
def porous_cases(d_mm: float = 0.3) -> list[CaseResult]:
    """Sampled coil volume of one oblique capsule against π r² L + 4/3 π r³ as the voxel shrinks
    (d/2 → d/8); an aligned array of rods: its mean solid fraction, and the tensor of one of its
    voxels along and across the rods against Happel's K∥, K⊥ at that voxel's solid fraction."""
    import trimesh

    from .porous import happel_permeabilities_mm2, porous_field

    box = trimesh.creation.box(extents=[3.0] * 3)
    vertices, faces = np.asarray(box.vertices), np.asarray(box.faces)
    r = 0.5 * d_mm
    piece = np.array([[-1.0, 0.1234, -0.0771], [1.0, -0.0567, 0.0913]])
    exact = math.pi * r**2 * float(np.linalg.norm(piece[1] - piece[0])) + 4.0 / 3.0 * math.pi * r**3
    rows = []
    for divisor, tolerance in ((2, 0.05), (4, 0.01), (8, 0.005)):
        h = d_mm / divisor
        field = porous_field(vertices, faces, [piece], [d_mm], h)
        volume = float(((1.0 - field.porosity) * field.sac_fraction).sum() * h**3)
        rows.append(_row(f"porous: capsule volume, voxel d/{divisor} (mm3)", exact, volume, tolerance))
    offsets = np.arange(-2, 3) * 0.57 + 0.137  # 5 × 5 rods along z, 0.57 mm apart (off the sample lattice), in the box
    rods = [np.array([[x, y, -2.0], [x, y, 2.0]]) for x in offsets for y in offsets]
    field = porous_field(vertices, faces, rods, [d_mm] * len(rods), 0.5 * d_mm)
    solid = float(((1.0 - field.porosity) * field.sac_fraction).sum() / field.sac_fraction.sum())
    voxel = np.unravel_index(np.argmax((field.porosity < 1.0) & (field.sac_fraction == 1.0)), field.shape)
    parallel, transverse = happel_permeabilities_mm2(np.array(1.0 - field.porosity[voxel]), np.array(r))
    tensor = field.permeability_tensor_mm2()[voxel]
    rows += [_row("porous: aligned rods, mean solid fraction", len(rods) * math.pi * r**2 / 9.0, solid, 0.01),
             _row("porous: aligned rods, K along = Happel K∥ (mm2)", float(parallel), tensor[2, 2], 1e-12),
             _row("porous: aligned rods, K across = Happel K⊥ (mm2)", float(transverse), tensor[0, 0], 1e-12)]
    return rows


CASES = {
    "contact": contact_law,
    "gradient": gradient_cases,
    "cantilever": cantilever_cases,
    "helix": helix_recovery,
    "release": free_release,
    "energy": energy_conservation,
    "wall_field": wall_field_cases,
    "porous": porous_cases,
}


def run(names: list[str] | None = None) -> list[CaseResult]:
    rows: list[CaseResult] = []
    for name in names or list(CASES):
        rows.extend(CASES[name]())
    return rows


def format_table(rows: list[CaseResult]) -> str:
    header = f"{'case':58s} {'reference':>12s} {'result':>12s} {'error':>10s} {'tolerance':>10s}  ok"
    lines = [header, "-" * len(header)]
    for r in rows:
        lines.append(f"{r.case:58s} {r.reference:12.6g} {r.result:12.6g} {r.error:10.2e} {r.tolerance:10.1e}  "
                     f"{'yes' if r.passed else 'NO'}")
    return "\n".join(lines)
