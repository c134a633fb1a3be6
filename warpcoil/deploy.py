"""Deployment: push the scene's coils out of the catheter into the wall, frame by frame.

The orchestrator owns no physics: it builds the Model from a Scene, then
advances the Solver in captured chunks of one frame each, and between frames
measures, records and decides (detach, next coil, jam, rest, timeout,
unstable). Units mm, g, s, µN, nJ.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field, replace
from typing import Callable

import numpy as np

from .kernels.contact import FAR_MM
from .model import Model, ModelBuilder
from .settings import CatheterSpec, Scene
from .solver import Control, SimulationUnstable, Solver, Stepper
from .state import State, new_state_like, packed_state

COMPLETED, JAMMED, TIMEOUT, FAILED = "completed", "jammed", "timeout", "failed"
COIL_GAP_MM = 1.0  # the coils sit this far apart in the catheter
MAX_STEP_HALVINGS = 3  # an unstable frame is redone with half the step, at most this often
REST_SPEED_MM_S = 0.25  # rms node speed below which the coils count as at rest (default tolerance)


@dataclass
class Frame:
    """What a run reports per recorded frame."""

    time_s: float
    deployed_length_mm: float
    push_force_uN: float  # mean over the frame's steps
    push_force_max_uN: float  # largest single step
    kinetic_nJ: float
    bend_nJ: float
    twist_nJ: float
    stretch_nJ: float
    wall_contacts: int  # free nodes with wall gap < c0
    coil_contacts: int  # edge pairs with gap < c0
    max_wall_force_uN: float
    min_wall_gap_mm: float
    min_coil_gap_mm: float
    length_outside_sac_mm: float


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
    length_outside_sac_mm: float
    min_wall_gap_mm: float
    min_coil_gap_mm: float
    max_wall_force_uN: float
    max_push_force_uN: float  # largest frame-mean push force (single steps ring: see the frames)
    stored_energy_nJ: float
    final_kinetic_nJ: float
    final_bend_nJ: float
    final_twist_nJ: float
    final_stretch_nJ: float
    coils: list[dict] = field(default_factory=list)  # per coil: name, status, lengths, packing densities
    regions: dict | None = None  # regional densities and neck coverage (with a neck; docs/REGIONS.md)
    step_reductions: list[str] = field(default_factory=list)  # when and why the step was halved
    frames: list[Frame] = field(default_factory=list, repr=False)
    positions_mm: list[np.ndarray] = field(default_factory=list, repr=False)  # final, per coil

    def summary(self) -> dict:
        """The JSON-ready scalars (no frames or positions)."""
        d = asdict(self)
        d.pop("frames")
        d.pop("positions_mm")
        return d


@dataclass
class Anatomy:
    """The wall and, with a [neck], the sac it closes off; the catheter as placed."""

    wall: object | None  # warpcoil.wall.WallMesh
    sac: object | None  # warpcoil.sac.Sac
    catheter: CatheterSpec

    @property
    def sac_volume_mm3(self) -> float | None:
        if self.sac is not None:
            return self.sac.volume_mm3
        return self.wall.volume_mm3 if self.wall is not None else None


def resolve_anatomy(scene: Scene) -> Anatomy:
    """Read the wall, cut the sac at the neck, and place the catheter (MODEL.md, Deployment)."""
    from . import sac as sacs
    from .wall import load_wall

    wall = load_wall(scene.wall) if scene.wall is not None else None
    sac = None
    if scene.neck is not None:
        hint = None if scene.neck.sac_point_mm is None else np.asarray(scene.neck.sac_point_mm)
        if scene.neck.contour is not None:
            neck = sacs.neck_from_contour(scene.neck.contour, wall, sac_side_point_mm=hint)
        else:
            neck = sacs.neck_from_plane(np.asarray(scene.neck.plane_point_mm), np.asarray(scene.neck.plane_normal),
                                        wall, sac_side_point_mm=hint)
        sac = sacs.sac_from_neck(wall, neck)
    catheter = scene.catheter
    if catheter.placement == "neck":
        tip, direction = sacs.catheter_from_neck(sac, catheter.depth_mm, catheter.angle_deg, catheter.azimuth_deg)
        catheter = replace(catheter, tip_mm=tuple(map(float, tip)), direction=tuple(map(float, direction)))
    return Anatomy(wall=wall, sac=sac, catheter=catheter)


def build_model(scene: Scene, device=None, anatomy: Anatomy | None = None) -> Model:
    """Model from a scene: coils (pre-shapes), catheter, contact and the wall mesh."""
    anatomy = anatomy or resolve_anatomy(scene)
    builder = ModelBuilder(catheter=anatomy.catheter, settings=scene.simulation, contact=scene.contact,
                           wall=anatomy.wall)
    for coil in scene.coils:
        builder.add_coil(coil)
    return builder.finalize(device)


class Deployment:
    """One deployment of a scene. ``run()`` returns the RunResult; ``on_frame``
    (if given) is called after every recorded frame with (frame, state)."""

    def __init__(self, scene: Scene, device=None):
        self.scene = scene
        sim = scene.simulation
        self.anatomy = resolve_anatomy(scene)
        self.model = build_model(scene, device, self.anatomy)
        self.solver = Solver(self.model, dt_s=sim.dt_s, dt_safety=sim.dt_safety,
                             allow_unstable_dt=sim.allow_unstable_dt)
        steps = max(2, 2 * round(sim.frame_interval_s / self.solver.dt_s / 2))
        self.control = Control.create(self.model, active_coil=0, push_speed_mm_s=sim.push_speed_mm_s)
        self.stepper = Stepper(self.solver, packed_state(self.model, gap_mm=COIL_GAP_MM), self.control, chunk=steps)
        self.coil_status: list[str] = []
        self.coil_lengths_mm = np.array([self.model.arc_s.numpy()[last] for last in self.model.coil_last])
        packed = self.solver.energies(self.stepper.state)
        self.stored_energy_nJ = packed["bend_nJ"] + packed["twist_nJ"] + packed["stretch_nJ"]
        self._pusher_work_nJ, self._last_advance_mm = 0.0, 0.0
        push_time = float(self.coil_lengths_mm.sum() + self.model.coil_count) / sim.push_speed_mm_s
        self.max_time_s = sim.max_time_s if sim.max_time_s is not None else push_time + 2.0
        total_mass_g = float((1.0 / self.model.inv_mass.numpy()).sum())
        self.rest_kinetic_energy_nJ = (sim.rest_kinetic_energy_nJ if sim.rest_kinetic_energy_nJ is not None
                                       else 0.5 * total_mass_g * REST_SPEED_MM_S**2)
        self._radius = self.model.node_radius.numpy()
        self._segment = np.repeat([self.model.rest_length.numpy()[f] for f in self.model.coil_first],
                                  self.model.coil_last - self.model.coil_first + 1)

    def _energy_budget_nJ(self, state: State, push_force_uN: float) -> float:
        """Energy put into the coils so far (nJ): stored by packing, work of the pusher
        (|mean push force| × advance, per frame), and the push-speed kinetic energy
        each released node brings out."""
        advance = float(np.clip(state.advance.numpy(), 0.0, self.coil_lengths_mm).sum())
        self._pusher_work_nJ += abs(push_force_uN) * max(advance - self._last_advance_mm, 0.0)
        self._last_advance_mm = advance
        released = float((state.free.numpy() == 1) @ (1.0 / self.model.inv_mass.numpy()))
        speed = self.scene.simulation.push_speed_mm_s
        return self.stored_energy_nJ + self._pusher_work_nJ + 0.5 * released * speed**2 + 1.0

    def _in_sac(self, points_mm: np.ndarray) -> np.ndarray:
        from .sac import inside_sac

        return inside_sac(self.anatomy.sac, points_mm)

    # --- measurement ---------------------------------------------------------
    def measure(self, state: State, push: tuple[float, float]) -> Frame:
        """Frame quantities at ``state`` (contacts recomputed at this state)."""
        s, m = self.solver, self.model
        energies = s.check_health(state, self._energy_budget_nJ(state, push[0]))
        s.compute_contacts(state, wall_search_mm=float(FAR_MM))  # exact distances for the report
        free = state.free.numpy() == 1
        advance = state.advance.numpy()
        deployed = float(np.clip(advance, 0.0, self.coil_lengths_mm).sum())
        c0 = m.contact.c0_mm
        wall_gap = np.inf
        wall_contacts, max_wall_force, outside = 0, 0.0, 0.0
        if m.wall is not None and free.any():
            centre = s.wall_distance.numpy()[free]
            gaps = centre - self._radius[free]
            wall_gap = float(gaps.min())
            wall_contacts = int((gaps < c0).sum())
            max_wall_force = float(np.linalg.norm(s.wall_force.numpy()[free], axis=1).max())
            outside = float(self._segment[free][centre < 0.0].sum())
        if self.anatomy.sac is not None and free.any():
            outside = float(self._segment[free][~self._in_sac(state.x.numpy()[free])].sum())
        in_pass = free | np.concatenate([free[1:], [False]])  # edges with a free node
        coil_gap = float(s.coil_gap.numpy()[in_pass].min()) if (s.coil_contact and free.any()) else np.inf
        return Frame(
            time_s=state.time_s, deployed_length_mm=deployed, push_force_uN=push[0], push_force_max_uN=push[1],
            kinetic_nJ=energies["kinetic_nJ"], bend_nJ=energies["bend_nJ"], twist_nJ=energies["twist_nJ"],
            stretch_nJ=energies["stretch_nJ"], wall_contacts=wall_contacts,
            coil_contacts=int(s.coil_contacts.numpy().sum()) // 2 if s.coil_contact else 0,
            max_wall_force_uN=max_wall_force, min_wall_gap_mm=wall_gap, min_coil_gap_mm=coil_gap,
            length_outside_sac_mm=outside)

    # --- coil sequence -------------------------------------------------------------
    def _activate(self, coil: int) -> int:
        """Hand the pusher to ``coil`` (it was pushed along behind the previous one);
        −1 when none is left."""
        if coil >= self.model.coil_count:
            self.control.set_active_coil(-1)
            return -1
        self.control.set_active_coil(coil)
        self.coil_status[coil] = "pushing"
        return coil

    def _retract(self, coil: int) -> None:
        """A jammed coil: its part still in the catheter is withdrawn (cut off at the
        tip and parked, out of every pass); the deployed part stays and is detached."""
        m = self.model
        sl = m.node_slice(coil)
        inside = np.flatnonzero(self.stepper.state.free.numpy()[sl] == 0) + sl.start
        if inside.size == 0:
            return
        has_next, fixed = m.has_next.numpy(), m.fixed.numpy()
        has_next[inside.min() - 1 if inside.min() > sl.start else sl.start:sl.stop] = 0
        fixed[inside] = 1
        m.has_next.assign(has_next)
        m.fixed.assign(fixed)

    def _halve_step(self, snapshot: State, why: str) -> Stepper:
        """Go back to the frame's start with half the step (and a new captured graph).
        The step bound is linear; dense contact (several deep overlaps on one node)
        can be stiffer, and then the frame is redone rather than lost. Not done for
        a run that asked for ``allow_unstable_dt``: it gets the step it asked for."""
        self._steps_done += self.stepper.steps - self.stepper.chunk  # the failed chunk is dropped
        solver = Solver(self.model, dt_s=0.5 * self.solver.dt_s, allow_unstable_dt=True)
        self.step_reductions.append(f"t = {snapshot.time_s:.5f} s: {why.split(' at t =')[0]}; "
                                    f"step halved to {solver.dt_s:.3e} s")
        start = new_state_like(self.model)
        start.copy_from(snapshot)
        self.solver = solver
        self.stepper = Stepper(solver, start, self.control, chunk=2 * self.stepper.chunk)
        return self.stepper

    # --- the run ---------------------------------------------------------------
    def run(self, on_frame: Callable[[Frame, State], None] | None = None) -> RunResult:
        sim = self.scene.simulation
        stepper = self.stepper
        frames: list[Frame] = []
        self.coil_status = ["waiting"] * self.model.coil_count
        self.jam_reasons: list[str] = []
        self.step_reductions: list[str] = []
        self._steps_done = 0
        active = self._activate(0)
        status, reason = TIMEOUT, f"simulated time reached max_time_s = {self.max_time_s:g} s"
        started = time.perf_counter()
        first = self.measure(stepper.state, (0.0, 0.0))
        frames.append(first)
        if on_frame:
            on_frame(first, stepper.state)
        snapshot = new_state_like(self.model)
        while stepper.state.time_s < self.max_time_s:
            snapshot.copy_from(stepper.state)
            try:
                stepper.run_chunk()
                frame = self.measure(stepper.state, self.solver.take_push_force(stepper.chunk))
            except SimulationUnstable as error:
                if not sim.allow_unstable_dt and len(self.step_reductions) < MAX_STEP_HALVINGS:
                    stepper = self._halve_step(snapshot, error.reason)
                    continue
                status, reason = FAILED, error.reason
                break
            frames.append(frame)
            if on_frame:
                on_frame(frame, stepper.state)
            if active >= 0 and frame.push_force_uN > sim.jam_force_uN:
                self.coil_status[active] = JAMMED
                deployed = float(np.clip(stepper.state.advance.numpy()[active], 0.0, self.coil_lengths_mm[active]))
                self.jam_reasons.append(
                    f"coil {active} ({self.scene.coils[active].name}) jammed: push force {frame.push_force_uN:.4g} µN"
                    f" > jam_force_uN = {sim.jam_force_uN:g} µN with {deployed:.2f} of "
                    f"{self.coil_lengths_mm[active]:.2f} mm deployed; the rest was withdrawn")
                self._retract(active)
                active = self._activate(active + 1)
            elif active >= 0 and stepper.state.advance.numpy()[active] >= self.coil_lengths_mm[active]:
                self.coil_status[active] = "detached"
                active = self._activate(active + 1)
            if active < 0 and frame.kinetic_nJ < self.rest_kinetic_energy_nJ:
                if self.jam_reasons:
                    status, reason = JAMMED, "; ".join(self.jam_reasons) + "; then at rest"
                else:
                    status, reason = COMPLETED, "all coils detached and at rest"
                break
        if status in (TIMEOUT, FAILED) and self.jam_reasons:
            reason = reason + "; earlier: " + "; ".join(self.jam_reasons)
        return self._result(status, reason, frames, time.perf_counter() - started)

    def _result(self, status: str, reason: str, frames: list[Frame], wall_time_s: float) -> RunResult:
        m, state = self.model, self.stepper.state
        last = frames[-1]
        deployed = last.deployed_length_mm
        sac_volume = self.anatomy.sac_volume_mm3
        deployed_each = np.clip(state.advance.numpy(), 0.0, self.coil_lengths_mm)
        volumes = np.array([math.pi * (c.d / 2.0) ** 2 for c in m.coils]) * deployed_each
        coil_volume = float(volumes.sum())
        density = (lambda v: float(v) / sac_volume if sac_volume else None)  # noqa: E731
        x = state.x.numpy()
        free = state.free.numpy() == 1
        outside = np.zeros(m.node_count, bool)
        if self.anatomy.sac is not None:
            outside[free] = ~self._in_sac(x[free])
        elif m.wall is not None:
            outside[free] = self.solver.wall_distance.numpy()[free] < 0.0
        coils = [dict(name=c.name, status=self.coil_status[k], wire_diameter_mm=c.d,
                      length_outside_sac_mm=float(self._segment[m.node_slice(k)][outside[m.node_slice(k)]].sum()),
                      loop_diameter_mm=c.loop_diameter_mm, shape=c.shape, length_mm=float(self.coil_lengths_mm[k]),
                      deployed_length_mm=float(deployed_each[k]), packing_density=density(volumes[k]),
                      cumulative_packing_density=density(volumes[: k + 1].sum()))
                 for k, c in enumerate(m.coils)]
        finite = lambda values: float(min(values)) if values else math.inf  # noqa: E731
        return RunResult(
            status=status, reason=reason, steps=self._steps_done + self.stepper.steps, dt_s=self.solver.dt_s,
            step_bound_s=self.solver.bound.dt_s, mass_scale=m.mass_scale, wall_time_s=wall_time_s,
            simulated_time_s=state.time_s, coil_length_mm=float(self.coil_lengths_mm.sum()),
            deployed_length_mm=deployed, sac_volume_mm3=sac_volume,
            packing_density=coil_volume / sac_volume if sac_volume else None,
            length_outside_sac_mm=last.length_outside_sac_mm,
            min_wall_gap_mm=finite([f.min_wall_gap_mm for f in frames]),
            min_coil_gap_mm=finite([f.min_coil_gap_mm for f in frames]),
            max_wall_force_uN=max(f.max_wall_force_uN for f in frames),
            max_push_force_uN=max(f.push_force_uN for f in frames),
            stored_energy_nJ=self.stored_energy_nJ, final_kinetic_nJ=last.kinetic_nJ, final_bend_nJ=last.bend_nJ,
            final_twist_nJ=last.twist_nJ, final_stretch_nJ=last.stretch_nJ, coils=coils, regions=self._regions(x),
            step_reductions=list(self.step_reductions),
            frames=frames,
            positions_mm=[x[m.node_slice(c)] for c in range(m.coil_count)])


    def _regions(self, x: np.ndarray) -> dict | None:
        """Regional densities of the final coils (only where a neck defines the sac)."""
        if self.anatomy.sac is None:
            return None
        from .sac import regional_density

        m, r = self.model, self.scene.regions
        coils = [x[m.node_slice(c)][self.stepper.state.free.numpy()[m.node_slice(c)] == 1]
                 for c in range(m.coil_count)]
        kept = [(pts, coil.d) for pts, coil in zip(coils, m.coils) if len(pts) >= 2]
        density = regional_density(self.anatomy.sac, [p for p, _ in kept], [d for _, d in kept], r.voxel_mm,
                                   r.neck_band_mm, r.boundary_mm)
        return {k: float(v) for k, v in asdict(density).items()}


def deploy(scene: Scene, device=None, on_frame=None) -> RunResult:
    """Run one deployment of ``scene`` (see :class:`Deployment`)."""
    return Deployment(scene, device).run(on_frame)


__all__ = ["COMPLETED", "Deployment", "FAILED", "Frame", "JAMMED", "RunResult", "TIMEOUT", "build_model", "deploy"]
