"""Stress test of numerical stability: a sweep of deployments, checked in every frame.

``warpcoil bench stress [--quick]`` varies one parameter at a time from a base case
(a spherical coil, d = 0.2921 mm, into a 3.5 mm spherical sac at 100 mm/s): the
step size around the stable bound, the contact law, push speed, damping, packing
density, friction (0–0.5), a balloon deflating under the packed coil, sharp and
narrow-necked wall meshes, and a seeded random fuzz of scenes.

Every recorded frame is checked (see :class:`FrameChecks`) for non-finite
positions, tunnelling (a free node centre outside the wall), crossed coils
(segment gap < −d: the centrelines passed through each other) and an energy
blow-up (kinetic energy above ``BLOWUP_FACTOR`` × the energy put in). A run within
the stable bound must end completed, jammed or timed out with none of these; a
run past it must be refused, or stop as "failed" with a reason naming dt.
Anything else is *unexplained*, listed in the report, and makes ``main`` return 1.

Writes ``stress.md`` (the report) and ``stress.json`` (one record per run, with
the scene that reproduces it). Units mm, g, s, µN, nJ.
"""

from __future__ import annotations

import json
import math
import tempfile
import time
from collections import Counter
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
import trimesh

from ..coil import CoilSpec
from ..deploy import COMPLETED, FAILED, JAMMED, TIMEOUT, Deployment, Frame, build_model
from ..model import Model
from ..preshape import PreshapeError
from ..recorder.atomic import write_text_atomic
from ..settings import BalloonSpec, CatheterSpec, ContactSettings, Scene, SimulationSettings, WallSpec
from ..solver import Solver, UnstableStepError
from ..state import State
from ..wall import WallError
from .report import markdown_table, write_report

REFUSED = "refused"
D_MM = 0.2921  # secondary diameter of every coil in the sweep
SAC_DIAMETER_MM = 3.5
TIP_MM = (0.0, 0.0, -1.45)  # 0.3 mm inside the base sac, pointing at the dome
PUSH_SPEED_MM_S = 100.0
FRAME_INTERVAL_S = 0.005
SETTLE_S = 0.2  # simulated time allowed after the push before "timeout"
BLOWUP_FACTOR = 10.0
DT_FACTORS = (0.25, 0.5, 0.9, 1.1, 1.5, 3.0)
FORCED_DT_FACTORS = (1.5, 3.0)
FUZZ_SEED = 20240607


@dataclass(frozen=True)
class Case:
    group: str
    name: str
    scene: Scene
    params: dict  # the varied parameters, for the report


@dataclass
class Record:
    """One run of the sweep: outcome, per-frame checks and the verdict."""

    group: str
    case: str
    params: dict
    status: str  # completed, jammed, timeout, refused, failed
    reason: str
    refused_for: str | None = None  # "dt" or "input" for refused runs
    dt_ratio: float | None = None  # dt over the stable bound (None when refused for its input)
    steps: int = 0
    wall_time_s: float = 0.0
    simulated_time_s: float = 0.0
    packing_density: float | None = None
    frames: int = 0
    nan_frames: int = 0
    tunnel_frames: int = 0
    crossing_frames: int = 0
    blowup_frames: int = 0
    min_wall_centre_mm: float | None = None  # signed centre distance of free nodes to the wall (< 0: outside)
    min_coil_gap_mm: float | None = None
    max_energy_ratio: float = 0.0  # kinetic energy over the energy put in (see FrameChecks)
    push_force_peak_uN: float | None = None  # largest compressive single-step push force
    final_kinetic_nJ: float | None = None
    crashed: bool = False  # an exception other than the simulator's own refusals
    verdict: str = ""  # ok, explained, unexplained
    problems: list[str] = field(default_factory=list)
    scene: dict = field(default_factory=dict)

    @property
    def outcome(self) -> str:
        return f"{self.status} ({self.refused_for})" if self.refused_for else self.status


# --- per-frame checks -----------------------------------------------------------
class FrameChecks:
    """``on_frame`` callback that checks every recorded frame.

    * NaN: a non-finite node position (the solver itself stops such a run as failed);
    * tunnelling: a free node whose centre is outside the wall
      (``solver.wall_distance`` < 0, exact right after ``Deployment.measure``; not
      ``frame.length_outside_sac_mm``, which with a [neck] also counts the parent vessel);
    * crossing: the smallest segment–segment gap below −d;
    * blow-up: kinetic energy > BLOWUP_FACTOR × E_in, where E_in = the elastic
      energy stored by packing the coil straight + a bound on the pusher's work
      (Σ frames |largest step push force| × push speed × frame time) + the kinetic
      energy of the released mass at push speed (½ m_free v²).
    """

    def __init__(self, deployment: Deployment):
        self.deployment = deployment
        self.speed = deployment.scene.simulation.push_speed_mm_s
        self.mass = 1.0 / deployment.model.inv_mass.numpy()  # g per node
        self.d = min(c.wire_diameter_mm for c in deployment.scene.coils)
        self.work_nJ, self.released_mass_g, self.last_time_s = 0.0, 0.0, 0.0
        self.frames = self.nan = self.tunnel = self.crossing = self.blowup = 0
        self.min_centre, self.min_gap, self.max_ratio = math.inf, math.inf, 0.0

    def __call__(self, frame: Frame, state: State) -> None:
        self.frames += 1
        free = state.free.numpy() == 1
        if not np.isfinite(state.x.numpy()).all():
            self.nan += 1
        if self.deployment.model.wall is not None and free.any():
            centre = float(self.deployment.solver.wall_distance.numpy()[free].min())
            self.min_centre = min(self.min_centre, centre)
            self.tunnel += centre < 0.0
        self.min_gap = min(self.min_gap, frame.min_coil_gap_mm)
        self.crossing += frame.min_coil_gap_mm < -self.d
        self.work_nJ += abs(frame.push_force_peak_uN) * self.speed * (frame.time_s - self.last_time_s)
        self.last_time_s = frame.time_s
        self.released_mass_g = max(self.released_mass_g, float(self.mass[free].sum()))
        energy_in = self.deployment.stored_energy_nJ + self.work_nJ + 0.5 * self.released_mass_g * self.speed**2
        ratio = frame.kinetic_nJ / energy_in if energy_in > 0.0 else 0.0
        self.max_ratio = max(self.max_ratio, ratio)
        self.blowup += ratio > BLOWUP_FACTOR

    def fill(self, record: Record) -> None:
        finite = lambda v: v if math.isfinite(v) else None  # noqa: E731
        record.frames, record.nan_frames, record.tunnel_frames = self.frames, self.nan, self.tunnel
        record.crossing_frames, record.blowup_frames = self.crossing, self.blowup
        record.min_wall_centre_mm, record.min_coil_gap_mm = finite(self.min_centre), finite(self.min_gap)
        record.max_energy_ratio = self.max_ratio


# --- one run and its verdict --------------------------------------------------------
def run_case(case: Case) -> Record:
    """Deploy ``case.scene`` with the frame checks and classify the outcome."""
    scene = case.scene
    record = Record(case.group, case.name, case.params, status=FAILED, reason="",
                    scene=json.loads(json.dumps(asdict(scene), default=str)))
    started = time.perf_counter()
    try:
        deployment = Deployment(scene)
    except (PreshapeError, WallError) as error:
        record.status, record.refused_for, record.reason = REFUSED, "input", str(error)
        return classify(record)
    except UnstableStepError as error:
        record.status, record.refused_for, record.reason = REFUSED, "dt", str(error)
        record.dt_ratio = scene.simulation.dt_s / step_bound(build_model(scene))
        return classify(record)
    record.dt_ratio = deployment.solver.dt_s / deployment.solver.bound.dt_s
    checks = FrameChecks(deployment)
    try:
        result = deployment.run(checks)
        record.status, record.reason, record.steps = result.status, result.reason, result.steps
        record.simulated_time_s, record.packing_density = result.simulated_time_s, result.packing_density
        record.push_force_peak_uN, record.final_kinetic_nJ = result.push_force_peak_uN, result.final_kinetic_nJ
    except Exception as error:  # a crash is recorded (and unexplained), the sweep goes on
        record.crashed, record.reason = True, f"crashed: {type(error).__name__}: {error}"
        record.steps, record.simulated_time_s = deployment.stepper.steps, deployment.stepper.state.time_s
    record.wall_time_s = time.perf_counter() - started
    checks.fill(record)
    return classify(record)


def classify(record: Record) -> Record:
    """Set ``problems`` and ``verdict`` (ok / explained / unexplained) from the outcome and checks."""
    problems = []
    if record.nan_frames:
        problems.append(f"non-finite positions in {record.nan_frames} frame(s)")
    if record.tunnel_frames:
        problems.append(f"tunnelling in {record.tunnel_frames} frame(s), "
                        f"a node centre {-(record.min_wall_centre_mm or 0.0):.3g} mm outside the wall")
    if record.crossing_frames:
        problems.append(f"coils crossed in {record.crossing_frames} frame(s), "
                        f"smallest gap {record.min_coil_gap_mm:.3g} mm")
    if record.blowup_frames:
        problems.append(f"energy blow-up in {record.blowup_frames} frame(s), "
                        f"kinetic / energy in up to {record.max_energy_ratio:.3g}")
    inside = record.dt_ratio is not None and record.dt_ratio <= 1.0
    why = None  # what makes the run unexplained
    if record.crashed:
        why = record.reason
    elif record.status == REFUSED:
        why = "a dt within the stable bound was refused" if record.refused_for == "dt" and inside else None
    elif record.status == FAILED:
        if inside:
            why = "failed within the stable bound"
        elif "dt" not in record.reason:
            why = "failed past the bound without naming dt"
    elif problems:  # completed, jammed or timeout with a broken state
        why = "within the stable bound" if inside else "past the bound, and the run was not stopped"
    record.problems = problems + ([why] if why else [])
    if why:
        record.verdict = "unexplained"
    else:
        record.verdict = "ok" if inside and record.status in (COMPLETED, JAMMED, TIMEOUT) else "explained"
    return record


# --- the sweep ----------------------------------------------------------------------
def scene(length_mm: float, *, shape: str = "spherical", loop_mm: float = 3.0, wall: WallSpec | None = None,
          tip_mm: tuple[float, float, float] = TIP_MM, direction: tuple[float, float, float] = (0.0, 0.0, 1.0),
          contact: ContactSettings | None = None, **simulation) -> Scene:
    """The base case with some fields changed; ``simulation`` are SimulationSettings fields
    (the integrator the reference, symplectic Euler, unless given).
    max_time_s is the push time + SETTLE_S."""
    sim = SimulationSettings(**{"push_speed_mm_s": PUSH_SPEED_MM_S, "frame_interval_s": FRAME_INTERVAL_S,
                                "integrator": "symplectic", **simulation})
    sim = replace(sim, max_time_s=(length_mm + 1.0) / sim.push_speed_mm_s + SETTLE_S)
    return Scene(coils=(CoilSpec(wire_diameter_mm=D_MM, length_mm=length_mm, loop_diameter_mm=loop_mm, shape=shape),),
                 catheter=CatheterSpec(tip_mm=tip_mm, direction=direction),
                 wall=wall or WallSpec(sphere_diameter_mm=SAC_DIAMETER_MM),
                 contact=contact or ContactSettings(), simulation=sim)


def step_bound(model: Model) -> float:
    """The stable step bound (s) the Deployment's solver checks dt against."""
    return Solver(model, allow_unstable_dt=True).bound.dt_s


def dt_cases(length_mm: float) -> list[Case]:
    bound = step_bound(build_model(scene(length_mm)))
    cases = [Case("step size", f"dt = {f:g} × bound", scene(length_mm, dt_s=f * bound), {"dt_factor": f})
             for f in DT_FACTORS]
    cases += [Case("step size", f"dt = {f:g} × bound, allow_unstable_dt",
                   scene(length_mm, dt_s=f * bound, allow_unstable_dt=True),
                   {"dt_factor": f, "allow_unstable_dt": True}) for f in FORCED_DT_FACTORS]
    return cases


def contact_cases(length_mm: float) -> list[Case]:
    cases = [Case("contact", f"P0 = {p0:g} µN", scene(length_mm, contact=ContactSettings(P0_uN=p0)), {"P0_uN": p0})
             for p0 in (1e2, 1e4)]
    cases += [Case("contact", f"c0 = {k:g} d", scene(length_mm, contact=ContactSettings(c0_mm=k * D_MM)),
                   {"c0_mm": k * D_MM}) for k in (0.05, 0.3)]
    return cases


def speed_cases(length_mm: float) -> list[Case]:
    """Slow pushes get a shorter coil (0.25 s of pushing, at least 3 mm)."""
    return [Case("push speed", f"{v:g} mm/s", scene(min(length_mm, max(3.0, 0.25 * v)), push_speed_mm_s=v),
                 {"push_speed_mm_s": v, "length_mm": min(length_mm, max(3.0, 0.25 * v))})
            for v in (10.0, 50.0, 200.0, 1000.0)]


def damping_cases(length_mm: float) -> list[Case]:
    return [Case("damping", f"{c:g} µN/mm", scene(length_mm, damping_uN_per_mm=c), {"damping_uN_per_mm": c})
            for c in (1.0, 100.0)]


def packing_cases(length_mm: float) -> list[Case]:
    """Helix coils (loop 0.85 × sac) into spheres sized for a target packing density."""
    cases = []
    for density in (0.2, 0.4, 0.6, 0.8):
        diameter = (6.0 * (D_MM / 2.0) ** 2 * length_mm / density) ** (1.0 / 3.0)  # π d²L/4 = φ π D³/6
        cases.append(Case("packing", f"{100 * density:.0f} % ({diameter:.2f} mm sac)",
                          scene(length_mm, shape="helix", loop_mm=0.85 * diameter,
                                wall=WallSpec(sphere_diameter_mm=diameter), tip_mm=(0.0, 0.0, 0.3 - diameter / 2.0)),
                          {"target_density": density, "sphere_diameter_mm": diameter}))
    return cases


FRICTIONS = (0.1, 0.3, 0.5)  # the base case is frictionless


def friction_cases(length_mm: float) -> list[Case]:
    """The base case and the 40 % packing case with wall, coil and catheter friction μ."""
    diameter = (6.0 * (D_MM / 2.0) ** 2 * length_mm / 0.4) ** (1.0 / 3.0)
    cases = []
    for mu in FRICTIONS:
        contact = ContactSettings(friction_wall=mu, friction_coil=mu, friction_catheter=mu)
        cases.append(Case("friction", f"μ = {mu:g}", scene(length_mm, contact=contact), {"friction": mu}))
        cases.append(Case("friction", f"μ = {mu:g}, 40 % packing ({diameter:.2f} mm sac)", scene(
            length_mm, shape="helix", loop_mm=0.85 * diameter, wall=WallSpec(sphere_diameter_mm=diameter),
            tip_mm=(0.0, 0.0, 0.3 - diameter / 2.0), contact=contact), {"friction": mu, "target_density": 0.4}))
    return cases


def balloon_cases(length_mm: float) -> list[Case]:
    """A balloon across the lower sac (beside the catheter) holding the packed coil,
    deflated in 20 ms when the coil detaches, frictionless and with μ = 0.3."""
    balloon = BalloonSpec(axis_mm=((-1.2, 0.7, -0.9), (1.2, 0.7, -0.9)), diameter_mm=0.8, deflation_time_s=0.02)
    cases = []
    for mu in (0.0, 0.3):
        contact = ContactSettings(friction_wall=mu, friction_coil=mu, friction_catheter=mu)
        sc = replace(scene(length_mm, contact=contact), balloon=balloon)
        cases.append(Case("balloon", f"deflating under the coil, μ = {mu:g}", sc, {"friction": mu}))
    return cases


def _necked_sphere(radius_mm: float, neck_radius_mm: float, neck_bottom_mm: float) -> trimesh.Trimesh:
    """A spherical sac on a thin cylindrical neck below it (surface of revolution about z)."""
    join = -math.sqrt(radius_mm**2 - neck_radius_mm**2)
    arc = np.linspace(math.atan2(join, neck_radius_mm), math.pi / 2.0, 40)
    profile = np.vstack([[0.0, neck_bottom_mm], [neck_radius_mm, neck_bottom_mm],
                         np.column_stack((radius_mm * np.cos(arc), radius_mm * np.sin(arc)))])
    profile[-1] = (0.0, radius_mm)
    return trimesh.creation.revolve(profile, sections=48)


def mesh_cases(length_mm: float, mesh_dir: Path) -> list[Case]:
    """Sharp edges and corners, an apex, an elongated sac, a narrow neck, a tip at the wall."""
    ellipsoid = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    ellipsoid.apply_scale((1.4, 1.4, 2.8))
    cone = trimesh.creation.cone(radius=1.8, height=4.0, sections=48)
    cone.apply_translation((0.0, 0.0, -1.75))
    meshes = {  # name: (mesh, catheter tip)
        "box 3 mm (edges, corners)": (trimesh.creation.box(extents=(3.0, 3.0, 3.0)), (0.0, 0.0, -1.2)),
        "cylinder r 1.6 × 3.6 mm (rims)": (trimesh.creation.cylinder(radius=1.6, height=3.6, sections=48),
                                           (0.0, 0.0, -1.5)),
        "cone r 1.8 × 4 mm (apex)": (cone, (0.0, 0.0, -1.45)),
        "ellipsoid 2.8 × 2.8 × 5.6 mm": (ellipsoid, (0.0, 0.0, -2.5)),
        "sphere 3.5 mm on a 0.9 mm neck": (_necked_sphere(1.75, 0.45, -3.0), (0.0, 0.0, -2.6)),
    }
    cases = []
    for k, (name, (mesh, tip)) in enumerate(meshes.items()):
        path = mesh_dir / f"wall_{k}.stl"
        mesh.export(path)
        cases.append(Case("wall mesh", name, scene(length_mm, wall=WallSpec(mesh=path), tip_mm=tip),
                          {"mesh": name, "tip_mm": tip}))
    grazing = (0.0, math.sin(math.radians(60.0)), math.cos(math.radians(60.0)))
    cases.append(Case("wall mesh", "sphere 3.5 mm, tip 0.2 mm from the wall at 60°",
                      scene(length_mm, tip_mm=(0.0, 0.0, -1.55), direction=grazing),
                      {"tip_mm": (0.0, 0.0, -1.55), "direction": grazing}))
    return cases


def fuzz_cases(count: int, seed: int = FUZZ_SEED) -> list[Case]:
    """Random valid scenes: sac 3–8 mm, coil 5–40 mm with loop 0.5–1 × sac, helix or
    spherical, push 20–300 mm/s, dt_safety 0.2–0.9, P0 3e2–3e3 µN, c0 0.05–0.2 d,
    damping 3–50 µN/mm, catheter tip 0.2–0.6 mm into the sac, tilted up to 30°."""
    rng = np.random.default_rng(seed)
    cases = []
    for k in range(count):
        sac = rng.uniform(3.0, 8.0)
        p = dict(sphere_diameter_mm=sac, length_mm=rng.uniform(5.0, 40.0), loop_mm=rng.uniform(0.5, 1.0) * sac,
                 shape=str(rng.choice(["helix", "spherical"])), push_speed_mm_s=rng.uniform(20.0, 300.0),
                 dt_safety=rng.uniform(0.2, 0.9), P0_uN=rng.uniform(3e2, 3e3), c0_mm=rng.uniform(0.05, 0.2) * D_MM,
                 damping_uN_per_mm=rng.uniform(3.0, 50.0), tip_depth_mm=rng.uniform(0.2, 0.6),
                 tilt_deg=rng.uniform(0.0, 30.0), azimuth_deg=rng.uniform(0.0, 360.0))
        tilt, azimuth = math.radians(p["tilt_deg"]), math.radians(p["azimuth_deg"])
        direction = (math.sin(tilt) * math.cos(azimuth), math.sin(tilt) * math.sin(azimuth), math.cos(tilt))
        cases.append(Case("fuzz", f"seed {seed} #{k}", scene(
            p["length_mm"], shape=p["shape"], loop_mm=p["loop_mm"], wall=WallSpec(sphere_diameter_mm=sac),
            tip_mm=(0.0, 0.0, p["tip_depth_mm"] - sac / 2.0), direction=direction,
            contact=ContactSettings(P0_uN=p["P0_uN"], c0_mm=p["c0_mm"]), push_speed_mm_s=p["push_speed_mm_s"],
            dt_safety=p["dt_safety"], damping_uN_per_mm=p["damping_uN_per_mm"]), p))
    return cases


def cases(quick: bool, mesh_dir: Path) -> list[Case]:
    """The sweep: an 8 mm base coil and 5 fuzz scenes when quick, else 20 mm and 20."""
    length = 8.0 if quick else 20.0
    return [*dt_cases(length), *contact_cases(length), *speed_cases(length), *damping_cases(length),
            *packing_cases(length), *friction_cases(length), *balloon_cases(length), *mesh_cases(length, mesh_dir),
            *fuzz_cases(5 if quick else 20)]


# --- report ---------------------------------------------------------------------------
def _fmt(value: float | None, spec: str = ".3g") -> str:
    return "–" if value is None else format(value, spec)


def _row(r: Record) -> list:
    return [r.case, _fmt(r.dt_ratio), r.outcome, r.steps, f"{r.wall_time_s:.1f}",
            _fmt(None if r.packing_density is None else 100 * r.packing_density, ".1f"),
            _fmt(r.min_wall_centre_mm, ".4f"), _fmt(r.min_coil_gap_mm, ".4f"), _fmt(r.max_energy_ratio, ".2g"),
            _fmt(r.push_force_peak_uN, ".3g"), _fmt(r.final_kinetic_nJ, ".2g"),
            r.verdict, "; ".join(r.problems) or "–"]


def report_sections(records: list[Record], wall_time_s: float, quick: bool) -> list[str]:
    counts = Counter(r.outcome for r in records)
    verdicts = Counter(r.verdict for r in records)
    unexplained = [r for r in records if r.verdict == "unexplained"]
    summary = (f"{len(records)} runs in {wall_time_s:.0f} s wall time ({'quick' if quick else 'full'} sweep): "
               + ", ".join(f"{n} {k}" for k, n in sorted(counts.items())) + "; verdicts: "
               + ", ".join(f"{n} {k}" for k, n in sorted(verdicts.items())) + ".")
    checks = (
        "## Checks (every recorded frame)\n\n"
        "* **NaN**: a non-finite node position (the solver also stops such a run: status failed).\n"
        "* **tunnelling**: a free node centre outside the wall (`solver.wall_distance` < 0 right after "
        "`Deployment.measure`); *min wall centre* is the smallest signed "
        "centre distance (> 0 inside).\n"
        "* **crossing**: smallest segment–segment coil gap < −d (centrelines passed through each other).\n"
        f"* **energy blow-up**: kinetic energy > {BLOWUP_FACTOR:g} × E_in, E_in = elastic energy stored by "
        "packing the coil straight + Σ frames |largest step push force| × push speed × frame time + "
        "½ m_free v_push²; *KE/E_in* is its largest ratio.\n\n"
        "Verdicts: **ok** = within the stable bound (dt ≤ bound), completed / jammed / timeout with no check "
        "tripped; **explained** = refused (dt past the bound, or invalid input), or past the bound and stopped "
        "as failed with a reason naming dt (or ran clean); **unexplained** = failed, crashed or a tripped check "
        f"within the bound, or a tripped check past the bound that did not stop the run. Timeout: push time + "
        f"{SETTLE_S:g} s simulated.")
    header = ["case", "dt/bound", "status", "steps", "wall s", "packing %", "min wall centre mm",
              "min coil gap mm", "KE/E_in", "max push µN", "final KE nJ", "verdict", "problems"]
    groups = list(dict.fromkeys(r.group for r in records))
    tables = [f"## {g}\n\n" + markdown_table(header, [_row(r) for r in records if r.group == g]) for g in groups]
    reasons = "## Reasons (runs not completed)\n\n" + "\n".join(
        f"* {r.group} / {r.case}: **{r.outcome}**: {r.reason}" for r in records if r.status != COMPLETED)
    if unexplained:
        listing = "## Unexplained\n\n" + "\n".join(
            f"* {r.group} / {r.case} ({json.dumps(r.params, default=str)}): {'; '.join(r.problems)} "
            f"— scene in stress.json" for r in unexplained)
    else:
        listing = "## Unexplained\n\nNone."
    return [summary, listing, checks, *tables, reasons]


def main(out_dir: Path, quick: bool = False, repeats: int = 1) -> int:
    """Run the sweep, write ``stress.md`` and ``stress.json`` to ``out_dir``; 1 if any run is
    unexplained. ``repeats`` is not used: each run is an observation, not a timing."""
    out_dir = Path(out_dir)
    started = time.perf_counter()
    records = []
    with tempfile.TemporaryDirectory(prefix="warpcoil-stress-") as mesh_dir:
        sweep = cases(quick, Path(mesh_dir))
        for k, case in enumerate(sweep, 1):
            record = run_case(case)
            records.append(record)
            print(f"[{k}/{len(sweep)}] {case.group} / {case.name}: {record.outcome} in {record.wall_time_s:.1f} s"
                  f" ({record.verdict}) {record.reason[:120]}", flush=True)
    wall_time_s = time.perf_counter() - started
    command = "warpcoil bench stress" + (" --quick" if quick else "")
    write_report(out_dir / "stress.md", "Stress test: numerical stability", command,
                 report_sections(records, wall_time_s, quick))
    write_text_atomic(out_dir / "stress.json", json.dumps(
        {"command": command, "wall_time_s": wall_time_s, "runs": [asdict(r) for r in records]}, indent=1,
        default=str))
    unexplained = sum(r.verdict == "unexplained" for r in records)
    print(f"{len(records)} runs in {wall_time_s:.0f} s, {unexplained} unexplained -> {out_dir / 'stress.md'}")
    return 1 if unexplained else 0
