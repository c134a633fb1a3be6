"""What a deployment measures: per frame (:class:`Frame`, from a :class:`Snapshot` of
the solver arrays) and at its end (:class:`RunResult`, with the regional densities).

Functions of the model, the solver and a member's bookkeeping (:class:`Measured`,
which :class:`warpcoil.deploy.Member` provides); nothing here steers the run.
Units mm, g, s, µN, nJ.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Protocol

import numpy as np
import warp as wp

from .anatomy import Anatomy
from .devices import device_report
from .geometry import lengths_outside, surface_bvh
from .model import Model
from .occlusion import occlusion_of_regions
from .sac import regional_density, sac_surface
from .settings import Scene
from .solver import Solver
from .state import State


class Measured(Protocol):
    """A member's bookkeeping that its measurements read (warpcoil.deploy.Member)."""

    world: int
    nodes: slice  # its nodes in the ensemble's state
    coils: range  # its coils in the model
    scene: Scene
    anatomy: Anatomy
    coil_lengths_mm: np.ndarray
    radius: np.ndarray  # per node (mm)
    coil_status: list[str]
    steps: int
    step_bound_s: float
    stored_energy_nJ: float
    mass_g: np.ndarray  # per node (g)
    frames: list
    inflation: float | None  # the balloon's, None without one
    deflate_from_s: float | None  # when the balloon started to deflate
    sample_centre_mm: float  # the smallest signed centre distance of its contact samples so far (note_samples)
    withdrawn_from: list  # per coil: a jammed coil's first withdrawn node (local index), else None
    exact_wall_from: int  # its frame count when its wall field gave way to the exact BVH, −1 never


@dataclass
class Frame:
    """What a run reports per recorded frame."""

    time_s: float
    deployed_length_mm: float
    push_force_mean_uN: float  # signed mean over the frame's steps (compressive > 0)
    push_force_peak_uN: float  # largest compressive single-step value in the frame (≥ 0)
    push_force_rms_uN: float  # root mean square over the frame's steps
    kinetic_nJ: float
    bend_nJ: float
    twist_nJ: float
    stretch_nJ: float
    wall_contacts: int  # free nodes with wall gap < c0
    coil_contacts: int  # edge pairs with gap < c0 (same-coil pairs: counted from their rest clearance)
    max_wall_force_uN: float
    min_wall_gap_mm: float
    min_coil_gap_mm: float  # (same-coil pairs: gap + the rest offset, so c0 at rest)
    length_outside_sac_mm: float | None  # None in free space (no wall: no sac to be outside of)
    balloon_inflation: float | None = None  # 1 inflated, 0 deflated; None without a balloon


@dataclass
class RunResult:
    """End-of-run report (MODEL.md, "What a run reports"); keys carry their units."""

    status: str
    reason: str
    steps: int
    dt_s: float
    step_bound_s: float
    mass_scale: float
    wall_time_s: float
    simulated_time_s: float
    coil_length_mm: float
    deployed_length_mm: float
    sac_volume_mm3: float | None
    packing_density: float | None
    length_outside_sac_mm: float | None
    min_wall_gap_mm: float
    min_coil_gap_mm: float
    max_wall_force_uN: float  # largest over the frames: a ringing contact's snapshot, not converged in dt
    final_max_wall_force_uN: float  # largest on one node at the end (at rest: the coils' load on the wall)
    push_force_peak_uN: float  # largest compressive single-step push force of the run
    push_force_mean_max_uN: float  # largest frame mean (signed mean over a frame's steps)
    push_force_rms_uN: float  # root mean square over every step while a coil was pushed
    push_kinetic_elastic_mean: float  # kinetic / elastic energy over the frames that pushed: mean (quasi-static ≪ 1)
    push_kinetic_elastic_max: float  # ... and largest (the snap of a packed coil reads 0.2 in the seed case)
    stored_energy_nJ: float
    final_kinetic_nJ: float
    final_bend_nJ: float
    final_twist_nJ: float
    final_stretch_nJ: float
    coils: list[dict] = field(default_factory=list)  # per coil: name, status, lengths, packing densities
    regions: dict | None = None  # regional densities and neck coverage (with a neck; docs/REGIONS.md)
    occlusion: dict | None = None  # in-silico Raymond–Roy class from the regions (warpcoil.occlusion)
    step_reductions: list[str] = field(default_factory=list)  # when and why the step was halved
    settle_dt_s: float | None = None  # implicit default: the last settling step (each frame's set by its fastest node)
    detach_steps: int = 0  # implicit: steps the detachment frames added (in steps; docs/FORMULATION.md)
    wall_repairs: list[str] = field(default_factory=list)  # what wall intake changed (merged, removed, flipped)
    catheter_tip_mm: tuple | None = None  # the catheter as placed (placement "neck": computed)
    catheter_direction: tuple | None = None
    frames: list[Frame] = field(default_factory=list, repr=False)
    positions_mm: list[np.ndarray] = field(default_factory=list, repr=False)  # final, per coil
    packing_density_in_sac: float | None = None  # π(d/2)² (deployed − herniated length) / sac volume
    device: dict | None = None  # assist device: kind, geometry, state over time (warpcoil.devices.device_report)
    wall_field: dict | None = None  # wall_query "sdf": voxel_mm, voxels, build_s (s) and from_cache (field_cache.py)
    # the integrator as the push ran it: integrator; implicit: method, theta, near_theta, contact_stiffness, chord_end
    scheme: dict | None = None

    def summary(self) -> dict:
        """The JSON-ready scalars (no frames or positions)."""
        d = asdict(self)
        d.pop("frames")
        d.pop("positions_mm")
        return d


@dataclass
class Snapshot:
    """Host copies of the solver arrays a frame's measurement reads (all worlds).
    ``wall_distance``: each node's signed centre distance (mm, > 0 in the lumen), exact
    where the node is within its contact range or past the wall and for each world's
    smallest gap; elsewhere a certified lower bound above the contact range
    (Solver.measure_contacts). ``sample_wall_gap``: per edge with contact samples (segments
    longer than 1.5 d), the smallest wall gap of its points between the nodes (mm; FAR_MM where
    none is measured: wall_measure.sample_wall_gaps)."""

    time_s: float
    x: np.ndarray
    free: np.ndarray
    advance: np.ndarray
    wall_distance: np.ndarray
    wall_force: np.ndarray
    coil_gap: np.ndarray
    coil_contacts: np.ndarray
    sample_wall_gap: np.ndarray


def take_snapshot(solver: Solver, state: State, running: wp.array) -> Snapshot:
    """Host copies of what a frame's measurement reads (all worlds)."""
    s = solver
    s.measure_contacts(state, running)
    arrays = (state.x, state.free, state.advance, s.wall_distance, s.wall_force, s.coil_gap, s.coil_contacts,
              s.sample_wall_gap)
    return Snapshot(state.time_s, *(s.host(a).copy() for a in arrays))

def measure_frame(model: Model, solver: Solver, member: Measured, snap: Snapshot, energies: dict,
                  push: tuple[float, float, float]) -> Frame:
    """Frame quantities of one member at the snapshot; ``push``: the frame's
    push force mean, peak and RMS (µN)."""
    w, sl, m = member.world, member.nodes, model
    free = snap.free[sl] == 1
    any_free = bool(free.any())
    advance = snap.advance[member.coils.start:member.coils.stop]
    deployed = float(np.clip(advance, 0.0, member.coil_lengths_mm).sum())
    c0 = m.contact.c0_mm
    wall_gap = np.inf
    wall_contacts, max_wall_force = 0, 0.0
    if m.world_walls[w] is not None and any_free:
        gaps = snap.wall_distance[sl][free] - member.radius[free]
        wall_gap = min(float(gaps.min()), float(snap.sample_wall_gap[sl].min()))  # and along coarse segments
        wall_contacts = int(np.count_nonzero(gaps < c0))
        max_wall_force = float(np.linalg.norm(snap.wall_force[sl][free], axis=1).max())
    outside = lengths_outside_mm(m, member, snap.x[sl], free, advance)
    coil_gap = np.inf
    if solver.coil_contact and any_free:
        in_pass = free.copy()  # edges with a free node: the node or the next one free
        in_pass[:-1] |= free[1:]
        coil_gap = float(snap.coil_gap[sl][in_pass].min())
    return Frame(
        time_s=snap.time_s, deployed_length_mm=deployed, push_force_mean_uN=float(push[0]),
        push_force_peak_uN=float(push[1]), push_force_rms_uN=float(push[2]),
        kinetic_nJ=float(energies["kinetic_nJ"][w]),
        bend_nJ=float(energies["bend_nJ"][w]), twist_nJ=float(energies["twist_nJ"][w]),
        stretch_nJ=float(energies["stretch_nJ"][w]), wall_contacts=wall_contacts,
        coil_contacts=int(snap.coil_contacts[sl].sum()) // 2 if solver.coil_contact else 0,
        max_wall_force_uN=max_wall_force, min_wall_gap_mm=wall_gap, min_coil_gap_mm=coil_gap,
        length_outside_sac_mm=None if outside is None else float(outside.sum()), balloon_inflation=member.inflation)


def lengths_outside_mm(model: Model, member: Measured, x: np.ndarray, free: np.ndarray, advance: np.ndarray
                       ) -> np.ndarray | None:
    """Per coil of the member: the length (mm) of its deployed centre line outside the sac (with no [neck]:
    outside the wall); None in free space. ``x``: the member's nodes (mm), ``free``: bool per node,
    ``advance``: per coil, its pusher advance (mm). The line runs along the edges between free nodes and on
    into the catheter as far as the coil is pushed out (by arc length); an edge that crosses the surface
    counts its part outside up to the crossing (geometry.lengths_outside), not its nodes' shares."""
    anatomy = member.anatomy
    if model.world_walls[member.world] is None:
        return None
    wall = anatomy.wall
    surface = sac_surface(anatomy.sac) if anatomy.sac is not None else surface_bvh(wall, wall.vertices_mm, wall.faces)
    sl = member.nodes
    s = model.host("arc_s")[sl]
    coil = model.host("coil_of")[sl][:-1] - member.coils.start
    edge = free[:-1] & (model.host("has_next")[sl][:-1] == 1)  # the deployed edges: from a free node
    part = edge & ~free[1:]  # ... into the catheter: out as far as the advance
    out = np.clip((advance[coil[part]] - s[:-1][part]) / (s[1:][part] - s[:-1][part]), 0.0, 1.0)
    tips = x[:-1][part] + out[:, None] * (x[1:][part] - x[:-1][part])
    index = np.cumsum(free) - 1  # a free node's place among the free nodes
    ends = index[1:].copy()
    ends[part] = int(free.sum()) + np.arange(len(tips))
    lengths = lengths_outside(surface, np.concatenate((x[free], tips)), index[:-1][edge], ends[edge])
    return np.bincount(coil[edge], weights=lengths, minlength=len(member.coils))


def run_result(model: Model, solver: Solver, member: Measured, status: str, reason: str, wall_time_s: float,
               snap: Snapshot, step_reductions: list[str], scheme: dict | None = None) -> RunResult:
    """The member's RunResult from its frames and the frame's snapshot; ``scheme``: the
    integrator's settings while pushing (default: the solver's)."""
    m, sl = model, member.nodes
    frames = member.frames
    last = frames[-1]
    sac_volume = member.anatomy.sac_volume_mm3
    advance = snap.advance[member.coils.start:member.coils.stop]
    deployed_each = np.clip(advance, 0.0, member.coil_lengths_mm)
    coil_specs = [m.coils[c] for c in member.coils]
    volumes = np.array([math.pi * (c.d / 2.0) ** 2 for c in coil_specs]) * deployed_each
    coil_volume = float(volumes.sum())
    density = (lambda v: float(v) / sac_volume if sac_volume else None)  # noqa: E731
    x = snap.x[sl]
    free = snap.free[sl] == 1
    outside = lengths_outside_mm(m, member, x, free, advance)
    local = [slice(int(m.coil_first[c]) - sl.start, int(m.coil_last[c]) + 1 - sl.start) for c in member.coils]
    coils = [dict(name=c.name, status=member.coil_status[k], wire_diameter_mm=c.d,
                  length_outside_sac_mm=None if outside is None else float(outside[k]),
                  loop_diameter_mm=c.loop_diameter_mm, shape=c.shape, product=c.product, size=c.size,
                  length_mm=float(member.coil_lengths_mm[k]),
                  deployed_length_mm=float(deployed_each[k]), packing_density=density(volumes[k]),
                  cumulative_packing_density=density(volumes[: k + 1].sum()))
             for k, c in enumerate(coil_specs)]
    finite = lambda values: float(min(values)) if values else math.inf  # noqa: E731
    regions = regional_densities(model, member, x, free)
    coil_gap = finite([f.min_coil_gap_mm for f in frames])
    pushing = push_summary(frames, 0.5 * float(member.mass_g.sum()) / float(member.coil_lengths_mm.sum())
                           * member.scene.simulation.push_speed_mm_s ** 2)
    return RunResult(
        status=status, reason=reason + crossing_note(coil_gap, min(c.d for c in coil_specs))
        + wall_crossing_note(member.sample_centre_mm, coil_specs)
        + quasi_static_note(pushing["push_kinetic_elastic_mean"], (scheme or solver.scheme)["integrator"]),
        steps=member.steps,
        dt_s=solver.dt_s, step_bound_s=member.step_bound_s, mass_scale=m.mass_scale, wall_time_s=wall_time_s,
        simulated_time_s=snap.time_s, coil_length_mm=float(member.coil_lengths_mm.sum()),
        deployed_length_mm=last.deployed_length_mm, sac_volume_mm3=sac_volume,
        packing_density=coil_volume / sac_volume if sac_volume else None,
        length_outside_sac_mm=last.length_outside_sac_mm,
        min_wall_gap_mm=finite([f.min_wall_gap_mm for f in frames]),
        min_coil_gap_mm=coil_gap,
        max_wall_force_uN=max(f.max_wall_force_uN for f in frames), final_max_wall_force_uN=last.max_wall_force_uN,
        **pushing,
        stored_energy_nJ=member.stored_energy_nJ, final_kinetic_nJ=last.kinetic_nJ, final_bend_nJ=last.bend_nJ,
        final_twist_nJ=last.twist_nJ, final_stretch_nJ=last.stretch_nJ, coils=coils,
        regions=regions, occlusion=occlusion_of_regions(regions, member.scene.regions.occlusion_threshold),
        step_reductions=list(step_reductions),
        wall_repairs=list(member.anatomy.wall.notes) if member.anatomy.wall is not None else [],
        catheter_tip_mm=member.anatomy.catheter.tip_mm, catheter_direction=member.anatomy.catheter.direction,
        frames=frames,
        positions_mm=[x[s][:cut] for s, cut in zip(local, member.withdrawn_from)],  # (a jammed coil: what stays)
        packing_density_in_sac=(sum(math.pi * (c["wire_diameter_mm"] / 2.0) ** 2 * max(
            c["deployed_length_mm"] - c["length_outside_sac_mm"], 0.0) for c in coils) / sac_volume
            if sac_volume else None),
        device=device_report(member.scene, member.anatomy, frames, member.deflate_from_s),
        wall_field=_field_report(solver.wall_fields[member.world], member), scheme=dict(scheme or solver.scheme))


CROSSED_GAP_RATIO = 0.5  # a coil gap below −d/2: two wires' centre lines closer than half a diameter


def crossing_note(min_coil_gap_mm: float, d_mm: float) -> str:
    """What a run's reason adds where its smallest coil gap (mm) went below −CROSSED_GAP_RATIO × d
    (the thinnest wire's, mm): segments that deep in each other may have passed through (the contact
    law keeps overlaps to a small part of c0 where it holds); empty otherwise."""
    if not min_coil_gap_mm < -CROSSED_GAP_RATIO * d_mm:
        return ""
    return (f"; but coil segments came within half a wire diameter of each other's centre lines (smallest coil gap "
            f"{min_coil_gap_mm:.3g} mm, thinnest wire d = {d_mm:g} mm): coils may have passed through each other, and "
            "the geometry is not to be trusted there")


def note_samples(member: Measured, snap: Snapshot) -> None:
    """Keep in ``member.sample_centre_mm`` the smallest signed centre distance (mm, > 0 in the lumen) of its
    contact samples (the points between the nodes of segments longer than 1.5 d) up to ``snap``."""
    centre = snap.sample_wall_gap[member.nodes] + member.radius  # (FAR_MM where none is measured)
    member.sample_centre_mm = min(member.sample_centre_mm, float(centre.min()))


def wall_crossing_note(sample_centre_mm: float, coils) -> str:
    """What a run's reason adds where a contact sample's centre went past the wall (``sample_centre_mm`` < 0,
    :func:`note_samples`): the wall acts at the nodes and at the samples between them of segments longer than
    1.5 d (CoilSpecs ``coils``), so only a push harder than the law holds can carry one through; empty otherwise."""
    if not sample_centre_mm < 0.0:
        return ""
    coarse = max(c.l0 / c.d for c in coils)
    return (f"; but a coil segment's centre line crossed the wall between its nodes ({-sample_centre_mm:.3g} mm past "
            f"it, segments of up to {coarse:.2g} d): the geometry is not to be trusted there; fix: "
            "segment_length_mm ≤ 1.5 d")


def _field_report(field, member: Measured) -> dict | None:
    """result.json's ``wall_field``: the field's voxel (mm), size, build or load time (s), origin, and the
    time (s) from which the exact BVH gave every wall distance instead (a stalled settling; None: never)."""
    if field is None:
        return None
    exact_from_s = member.frames[member.exact_wall_from - 1].time_s if member.exact_wall_from > 0 else None
    return {"voxel_mm": field.voxel_mm, "voxels": field.voxels, "build_s": field.build_s, "from_cache": field.from_cache,
            "exact_wall_from_s": exact_from_s}

def regional_densities(model: Model, member: Measured, x: np.ndarray, free: np.ndarray) -> dict | None:
    """Regional densities of the final coils (only where a neck defines the sac)."""
    if member.anatomy.sac is None:
        return None
    m, r, sl = model, member.scene.regions, member.nodes
    coils = [(x[int(m.coil_first[c]) - sl.start:int(m.coil_last[c]) + 1 - sl.start],
              free[int(m.coil_first[c]) - sl.start:int(m.coil_last[c]) + 1 - sl.start], m.coils[c].d)
             for c in member.coils]
    kept = [(pts[f], d) for pts, f, d in coils if f.sum() >= 2]
    density = regional_density(member.anatomy.sac, [p for p, _ in kept], [d for _, d in kept], r.voxel_mm,
                               r.neck_band_mm, r.boundary_mm)
    return {k: float(v) for k, v in asdict(density).items()}


def pushed_frames(frames: list[Frame]) -> list[Frame]:
    """The frames in which the pusher pushed (the deployed length grew): the others (the
    first record, settling, a member held) read no push force, a 0 that is no reading."""
    return [f for f, before in zip(frames[1:], frames) if f.deployed_length_mm > before.deployed_length_mm]


QUASI_STATIC_KE_RATIO = 0.1  # kinetic / elastic energy while pushing above which a push is not quasi-static
# the implicit step's numerical damping reads the kinetic energy while pushing low: its mean kinetic / elastic
# was 2.2–17× below the reference's on the same case (8 cases of a physicist's audit, 0.0174–0.086 where the
# reference read 0.11–0.31): on it the note fires above QUASI_STATIC_KE_RATIO / IMPLICIT_KE_UNDERREAD
IMPLICIT_KE_UNDERREAD = 8.0


def push_summary(frames: list[Frame], push_nJ_per_mm: float = 0.0) -> dict[str, float]:
    """The run's push force (µN) over the frames in which the pusher pushed: the largest compressive
    single-step value (≥ 0), the largest frame mean (signed: a coil that draws itself out reads below 0
    throughout) and the RMS (each frame spans the same simulated time, so over that time); and the mean and
    largest kinetic / elastic energy of those frames (MODEL.md: report it), over the frames whose elastic
    energy is above the kinetic energy of the deployed length carried at the push speed (``push_nJ_per_mm``
    of it: ½ mass per mm × speed², nJ/mm: a straight coil carried along stores next to nothing, and its
    ratio says nothing); 0 where none pushed."""
    pushed = pushed_frames(frames)
    ratios = [f.kinetic_nJ / elastic for f in pushed
              if (elastic := f.bend_nJ + f.twist_nJ + f.stretch_nJ) > push_nJ_per_mm * f.deployed_length_mm]
    if not pushed:
        return {"push_force_peak_uN": 0.0, "push_force_mean_max_uN": 0.0, "push_force_rms_uN": 0.0,
                "push_kinetic_elastic_mean": 0.0, "push_kinetic_elastic_max": 0.0}
    return {"push_force_peak_uN": max(f.push_force_peak_uN for f in pushed),
            "push_force_mean_max_uN": max(f.push_force_mean_uN for f in pushed),
            "push_force_rms_uN": float(np.sqrt(np.mean(np.square([f.push_force_rms_uN for f in pushed])))),
            "push_kinetic_elastic_mean": float(np.mean(ratios)) if ratios else 0.0,
            "push_kinetic_elastic_max": max(ratios, default=0.0)}


def quasi_static_note(kinetic_elastic_mean: float, integrator: str = "symplectic") -> str:
    """What a run's reason adds where the frames that pushed had kinetic / elastic energy above
    QUASI_STATIC_KE_RATIO on average (MODEL.md: a simulation may push faster than a clinician while it
    stays quasi-static), on the implicit step above QUASI_STATIC_KE_RATIO / IMPLICIT_KE_UNDERREAD (its
    numerical damping reads the kinetic energy low); empty otherwise."""
    implicit = integrator == "implicit"
    limit = QUASI_STATIC_KE_RATIO / IMPLICIT_KE_UNDERREAD if implicit else QUASI_STATIC_KE_RATIO
    if not kinetic_elastic_mean > limit:
        return ""
    if implicit:
        return (f"; but the push was likely not quasi-static (kinetic / elastic energy {kinetic_elastic_mean:.2g} on "
                f"average while pushing, above {limit:g}: the implicit step's damping reads it 2–17× below the "
                f"reference's, which then reads above {QUASI_STATIC_KE_RATIO:g}): the coil's inertia shapes the "
                "result, which the implicit step does not resolve (its push force is that of a slower push); push "
                "slower (simulation.push_speed_mm_s) to model a clinical deployment, or rerun on the reference "
                "(simulation.integrator = \"symplectic\")")
    return (f"; but the push was not quasi-static (kinetic / elastic energy {kinetic_elastic_mean:.2g} on average "
            f"while pushing, above {QUASI_STATIC_KE_RATIO:g}): the coil's inertia shapes the result; push slower "
            "(simulation.push_speed_mm_s) to model a clinical deployment")
