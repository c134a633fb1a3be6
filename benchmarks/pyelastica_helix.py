"""PyElastica peer of warpcoil's helix recovery (``warpcoil validate helix``).

The same coil as ``warpcoil.validation.helix_recovery``: L = 60 mm, d = 0.2921 mm,
loop diameter D = 3 mm, pitch 0.6 mm, stiffness and density from
:class:`warpcoil.CoilSpec`'s defaults, as a PyElastica ``CosseratRod`` whose
rest shape is the helix, started straight at rest, free ends, damped to rest;
then loop diameter and pitch are measured with :func:`warpcoil.metrics.fit_helix`.

PyElastica (https://github.com/GazzolaLab/PyElastica, ``pip install pyelastica``)
is unit-agnostic; everything here is in warpcoil's mm, g, s (forces µN, energies
nJ). It is optional: :func:`available` says whether it can be imported.

Parameter mapping (warpcoil → PyElastica)
-----------------------------------------

PyElastica builds its stiffness matrices from a solid circular section (E, G,
radius); a coil is not a solid wire, so the matrices are set directly from
the coil's own stiffnesses after the rod is built:

=====================  =======================================================
``bend_matrix``        diag(EI, EI, GJ) (µN·mm², per Voronoi domain)
``shear_matrix``       diag(S, S, EA) with S = EA (µN): warpcoil's rod is
                       unshearable (Kirchhoff); S = EA is the same penalty
                       stiffness warpcoil puts on stretching. At rest in free
                       space the internal force is zero, so S does not change
                       the recovered shape, only the transient and the step
                       bound (the shear–rotary-inertia mode, ω² ≈ S/J₁).
``density``            ρ_lin / (π r²), so node masses are ρ_lin × length as in
                       warpcoil (ρ_lin = ``CoilSpec.rho``, g/mm); r = d/2
``mass_second_moment`` per element ρ_lin l × diag(r_w²/2, r_w²/2, r_w²): the
                       wire of the coil lies on a tube of the winding radius
                       r_w = (d − d_w)/2, whose polar moment ρ_lin r_w² is
                       warpcoil's twist inertia J = m r_w²
damping                ``AnalyticalLinearDamper(uniform_damping_constant=ν)``
                       with ν = damping_uN_per_mm / (damping_speed_mm_s · ρ_lin),
                       the low-speed decay rate of warpcoil's nonlinear damping
                       (and of its twist damping): 5 µN/mm / (20 mm/s · ρ) ≈ 391 /s
time stepping          ``PositionVerlet`` at dt = safety × 2/ω_max (Gershgorin
                       bound of stretch, shear-rotation, bending-rotation and
                       twist modes, :func:`stable_dt`). PyElastica's examples use
                       dt = 0.01 dx in SI units; that rule carries units (it is
                       a wave-speed bound for their materials), so the bound
                       is computed here instead
=====================  =======================================================

Rest shape: the helix sampled at equal arc length L/n (n = ``n_elem``), as
warpcoil samples it (chords as rest lengths), with directors d3 = the edge
tangent and d1 carried along by parallel transport (the discrete Bishop frame,
as warpcoil's rest directors). The rod is built *in* this configuration and its
own strains become the rest strains (``rest_kappa`` = κ, ``rest_sigma`` = σ), so
the discrete helix is an exact zero-force state (:func:`rest_residual` checks
it). Rest twist is then 0 (Bishop frame) and the curvature rotates in the
material frame, exactly warpcoil's rest state.

Start: straight along x (node spacing = the rest chords, so no stretch), d3 =
x, d1 = z for every element (twist-free), zero velocity. Run to rest: every
``check_every`` steps the kinetic energy (translation + rotation) is compared
with ``kinetic_tolerance_nJ`` (warpcoil's helix recovery: 1e-5 nJ, checked
every 1000 steps).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from warpcoil.coil import CoilSpec
from warpcoil.metrics import fit_helix
from warpcoil.settings import SimulationSettings
from warpcoil.validation import HELIX, REFERENCE_D_MM

DAMPING_UN_PER_MM = 5.0  # validation.helix_recovery's damping_uN_per_mm
DAMPING_SPEED_MM_S = SimulationSettings().damping_speed_mm_s  # its default k (mm/s)


def unavailable_reason() -> str | None:
    """None when a usable PyElastica is installed, else why not."""
    try:
        import inspect

        from elastica import AnalyticalLinearDamper
    except ImportError as error:
        return f"PyElastica is not installed ({error}); pip install pyelastica"
    if "uniform_damping_constant" not in inspect.getsource(AnalyticalLinearDamper):
        return ("the installed PyElastica predates AnalyticalLinearDamper(uniform_damping_constant=...) "
                "(GazzolaLab/PyElastica#437); pip install -U pyelastica")
    return None


def available() -> bool:
    """Whether a usable PyElastica can be imported."""
    return unavailable_reason() is None


def helix_spec() -> CoilSpec:
    """warpcoil's helix-recovery coil (validation._helix_spec with defaults)."""
    return CoilSpec(wire_diameter_mm=REFERENCE_D_MM, shape="helix", **HELIX)


@dataclass(frozen=True)
class CoilParameters:
    """The coil in PyElastica's terms (mm, g, s)."""

    length_mm: float
    loop_diameter_mm: float
    pitch_mm: float
    radius_mm: float  # d/2, section radius (volume, mass bookkeeping)
    winding_radius_mm: float  # r_w = (d − d_w)/2
    EI: float  # µN·mm²
    GJ: float  # µN·mm²
    EA: float  # µN
    shear_uN: float  # S, µN
    rho_g_mm: float  # linear density, g/mm
    damping_per_s: float  # ν, 1/s


def coil_parameters(spec: CoilSpec | None = None) -> CoilParameters:
    spec = spec or helix_spec()
    rho = spec.rho
    return CoilParameters(
        length_mm=spec.length_mm, loop_diameter_mm=spec.loop_diameter_mm, pitch_mm=spec.helix_pitch_mm,
        radius_mm=0.5 * spec.d, winding_radius_mm=0.5 * (spec.d - spec.primary_wire_diameter_mm),
        EI=spec.EI, GJ=spec.GJ, EA=spec.EA, shear_uN=spec.EA, rho_g_mm=rho,
        damping_per_s=DAMPING_UN_PER_MM / (DAMPING_SPEED_MM_S * rho))


# --- geometry ----------------------------------------------------------------------
def discrete_helix(p: CoilParameters, n_elem: int) -> np.ndarray:
    """(n+1, 3) nodes of the helix at equal arc length L/n (as warpcoil.preshape.helix)."""
    radius = 0.5 * p.loop_diameter_mm
    turn = math.hypot(2.0 * math.pi * radius, p.pitch_mm)
    angle = 2.0 * math.pi * np.linspace(0.0, p.length_mm, n_elem + 1) / turn
    return np.column_stack((radius * np.cos(angle), radius * np.sin(angle), p.pitch_mm * angle / (2.0 * math.pi)))


def _transport(v: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Parallel transport of v from unit tangent a to unit tangent b (smallest rotation)."""
    k = np.cross(a, b)
    return v + np.cross(k, v) + np.cross(k, np.cross(k, v)) / (1.0 + a @ b)


def bishop_directors(nodes: np.ndarray, first_d1: np.ndarray | None = None) -> np.ndarray:
    """PyElastica director collection (3, 3, n): row 0 = d1 (parallel transported
    along the polyline), row 1 = d2 = d3 × d1, row 2 = d3 = the unit edge tangent."""
    t = np.diff(nodes, axis=0)
    t /= np.linalg.norm(t, axis=1)[:, None]
    n = len(t)
    d1 = np.zeros((n, 3))
    if first_d1 is None:
        helper = np.eye(3)[int(np.argmin(np.abs(t[0])))]
        first_d1 = np.cross(t[0], helper)
    d1[0] = first_d1 - (first_d1 @ t[0]) * t[0]
    d1[0] /= np.linalg.norm(d1[0])
    for k in range(1, n):
        m = _transport(d1[k - 1], t[k - 1], t[k])
        m -= (m @ t[k]) * t[k]
        d1[k] = m / np.linalg.norm(m)
    q = np.zeros((3, 3, n))
    q[0] = d1.T
    q[1] = np.cross(t, d1).T
    q[2] = t.T
    return q


# --- the rod ---------------------------------------------------------------------
def build_rod(n_elem: int, p: CoilParameters | None = None):
    """A CosseratRod in the discrete helix, whose rest strains are its strains
    there (a zero-force state), with the coil's stiffness, mass and inertia."""
    from elastica import CosseratRod
    from elastica.rod.cosserat_rod import _compute_bending_twist_strains, _compute_shear_stretch_strains

    p = p or coil_parameters()
    nodes = discrete_helix(p, n_elem)
    directors = bishop_directors(nodes)
    area = math.pi * p.radius_mm**2
    rod = CosseratRod.straight_rod(
        n_elem, start=nodes[0].copy(), direction=directors[2, :, 0].copy(), normal=directors[0, :, 0].copy(),
        base_length=p.length_mm, base_radius=p.radius_mm, density=p.rho_g_mm / area,
        youngs_modulus=p.EI / (math.pi * p.radius_mm**4 / 4.0), shear_modulus=p.GJ / (math.pi * p.radius_mm**4 / 2.0),
        position=nodes.T.copy(), directors=directors.copy())
    # stiffness: the coil's own (see the module docstring)
    rod.bend_matrix[:] = 0.0
    rod.bend_matrix[0, 0], rod.bend_matrix[1, 1], rod.bend_matrix[2, 2] = p.EI, p.EI, p.GJ
    rod.shear_matrix[:] = 0.0
    rod.shear_matrix[0, 0], rod.shear_matrix[1, 1], rod.shear_matrix[2, 2] = p.shear_uN, p.shear_uN, p.EA
    # mass: ρ_lin per length (straight_rod lumps half an element on each node already);
    # rotational inertia of a tube of radius r_w
    mass_per_element = p.rho_g_mm * rod.rest_lengths
    rod.mass[:] = 0.0
    rod.mass[:-1] += 0.5 * mass_per_element
    rod.mass[1:] += 0.5 * mass_per_element
    inertia = np.array([0.5, 0.5, 1.0]) * p.winding_radius_mm**2
    rod.mass_second_moment_of_inertia[:] = 0.0
    rod.inv_mass_second_moment_of_inertia[:] = 0.0
    for i in range(3):
        rod.mass_second_moment_of_inertia[i, i] = inertia[i] * mass_per_element
        rod.inv_mass_second_moment_of_inertia[i, i] = 1.0 / (inertia[i] * mass_per_element)
    # rest strains = the strains of the helix
    _compute_shear_stretch_strains(rod.position_collection, rod.volume, rod.lengths, rod.tangents, rod.radius,
                                   rod.rest_lengths, rod.rest_voronoi_lengths, rod.dilatation,
                                   rod.voronoi_dilatation, rod.director_collection, rod.sigma)
    _compute_bending_twist_strains(rod.director_collection, rod.rest_voronoi_lengths, rod.kappa)
    rod.rest_sigma[:] = rod.sigma
    rod.rest_kappa[:] = rod.kappa
    return rod


def rest_residual(rod, p: CoilParameters | None = None) -> tuple[float, float]:
    """(largest |internal force| / (EI κ̄/l), largest |internal torque| / (EI κ̄))
    at the rod's current state: 0 in its rest helix, ~1e-12 after a rigid motion of
    it, O(1) straight (κ̄ = the helix's curvature, l the mean element length: the
    force and moment scales of the rest curvature)."""
    p = p or coil_parameters()
    rod.compute_internal_forces_and_torques(np.float64(0.0))
    radius = 0.5 * p.loop_diameter_mm
    c = p.pitch_mm / (2.0 * math.pi)
    kappa_bar = radius / (radius**2 + c**2)
    moment = p.EI * kappa_bar
    force = moment / float(rod.rest_lengths.mean())
    return (float(np.abs(rod.internal_forces).max()) / force,
            float(np.abs(rod.internal_torques).max()) / moment)


def rigidly_move(rod, angle_rad: float = 0.7, axis=(1.0, 2.0, 3.0), shift_mm=(0.3, -1.2, 2.5)) -> None:
    """Rotate (about ``axis`` through the origin) and translate the rod's nodes and
    directors: the strains, and so the internal forces, must not change."""
    a = np.asarray(axis, dtype=np.float64)
    a /= np.linalg.norm(a)
    k = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    r = np.eye(3) + math.sin(angle_rad) * k + (1.0 - math.cos(angle_rad)) * k @ k
    rod.position_collection[:] = r @ rod.position_collection + np.asarray(shift_mm)[:, None]
    rod.director_collection[:] = np.einsum("ijk,lj->ilk", rod.director_collection, r)


def set_straight(rod) -> None:
    """Straight along x with the rest chords as spacing (no stretch), d1 = z,
    twist-free, zero velocities."""
    x = np.concatenate([[0.0], np.cumsum(rod.rest_lengths)])
    rod.position_collection[:] = 0.0
    rod.position_collection[0] = x
    n = rod.n_elems
    q = np.zeros((3, 3, n))
    q[0, 2], q[1, 1], q[2, 0] = 1.0, -1.0, 1.0  # d1 = z, d2 = d3 × d1 = x × z = −y, d3 = x
    rod.director_collection[:] = q
    rod.velocity_collection[:] = 0.0
    rod.omega_collection[:] = 0.0


def kinetic_energy_nJ(rod) -> float:
    return float(rod.compute_translational_energy() + rod.compute_rotational_energy())


def elastic_energy_nJ(rod) -> float:
    return float(rod.compute_bending_energy() + rod.compute_shear_energy())


def stable_dt(rod, p: CoilParameters | None = None) -> float:
    """2/ω_max for position Verlet, ω_max² from Gershgorin bounds per node/element:
    stretch 2 (k_{i−1} + k_i)/m_i with k = EA/l; shear-rotation (S l + 4 EI/l̄)/J₁
    (shear couple and bending of an element's rotation about d1/d2, J₁ = its rotary
    inertia); twist 4 GJ/(l̄ J₃)."""
    p = p or coil_parameters()
    l = np.asarray(rod.rest_lengths)
    m = np.asarray(rod.mass)
    k = p.EA / l
    ks = np.zeros(len(m))
    ks[:-1] += k
    ks[1:] += k
    stretch = 2.0 * ks / m
    j1 = np.asarray(rod.mass_second_moment_of_inertia[0, 0])
    j3 = np.asarray(rod.mass_second_moment_of_inertia[2, 2])
    lbar = float(np.mean(rod.rest_voronoi_lengths))
    shear = (p.shear_uN * l + 4.0 * p.EI / lbar) / j1
    twist = 4.0 * p.GJ / lbar / j3
    omega_max = math.sqrt(max(stretch.max(), shear.max(), twist.max()))
    return 2.0 / omega_max


# --- the run ---------------------------------------------------------------------
@dataclass
class RecoveryResult:
    n_elem: int
    dt_s: float
    dt_bound_s: float
    steps: int
    wall_time_s: float  # stepping only (the check of the kinetic energy included)
    setup_time_s: float  # building and finalising the simulator
    rested: bool
    loop_diameter_mm: float
    pitch_mm: float
    diameter_error: float
    pitch_error: float
    final_kinetic_nJ: float
    final_elastic_nJ: float
    positions: np.ndarray = field(repr=False, default=None)

    @property
    def error(self) -> float:
        return max(self.diameter_error, self.pitch_error)


def make_simulator(n_elem: int, dt_safety: float, p: CoilParameters | None = None):
    """(simulator, rod, stepper, dt, dt bound): the rod started straight, damped, finalised."""
    from elastica import AnalyticalLinearDamper, BaseSystemCollection, Damping, PositionVerlet

    class HelixRecovery(BaseSystemCollection, Damping):
        pass

    p = p or coil_parameters()
    rod = build_rod(n_elem, p)
    bound = stable_dt(rod, p)
    dt = dt_safety * bound
    set_straight(rod)
    sim = HelixRecovery()
    sim.append(rod)
    sim.dampen(rod).using(AnalyticalLinearDamper, uniform_damping_constant=p.damping_per_s, time_step=dt)
    sim.finalize()
    return sim, rod, PositionVerlet(), dt, bound


def run_steps(sim, stepper, dt: float, steps: int, t: float = 0.0) -> float:
    """``steps`` position-Verlet steps; returns the time."""
    t = np.float64(t)
    dt = np.float64(dt)
    for _ in range(steps):
        t = stepper.step(sim, t, dt)
    return float(t)


def helix_recovery(n_elem: int = 205, dt_safety: float = 0.5, kinetic_tolerance_nJ: float = 1e-5,
                   check_every: int = 1000, max_steps: int = 2_000_000, p: CoilParameters | None = None,
                   min_steps: int = 0) -> RecoveryResult:
    """Start straight, damp to rest (kinetic energy < tolerance at a check), fit the helix."""
    p = p or coil_parameters()
    start = time.perf_counter()
    sim, rod, stepper, dt, bound = make_simulator(n_elem, dt_safety, p)
    setup = time.perf_counter() - start
    start = time.perf_counter()
    steps, t, rested = 0, 0.0, False
    while steps < max_steps:
        t = run_steps(sim, stepper, dt, check_every, t)
        steps += check_every
        x = rod.position_collection
        if not np.isfinite(x).all():
            break
        if steps >= min_steps and kinetic_energy_nJ(rod) < kinetic_tolerance_nJ:
            rested = True
            break
    wall = time.perf_counter() - start
    x = np.array(rod.position_collection.T)
    if np.isfinite(x).all():
        fit = fit_helix(x)
        diameter, pitch = fit.loop_diameter_mm, fit.pitch_mm
    else:
        diameter = pitch = math.nan
    return RecoveryResult(
        n_elem=n_elem, dt_s=dt, dt_bound_s=bound, steps=steps, wall_time_s=wall, setup_time_s=setup, rested=rested,
        loop_diameter_mm=diameter, pitch_mm=pitch,
        diameter_error=abs(diameter - p.loop_diameter_mm) / p.loop_diameter_mm,
        pitch_error=abs(pitch - p.pitch_mm) / p.pitch_mm, final_kinetic_nJ=kinetic_energy_nJ(rod),
        final_elastic_nJ=elastic_energy_nJ(rod), positions=x)


if __name__ == "__main__":
    import sys

    if not available():
        sys.exit(unavailable_reason())
    rod = build_rod(205)
    print("rest residual (force, torque, relative):", rest_residual(rod))
    r = helix_recovery(205)
    print(r)
