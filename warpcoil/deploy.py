"""Deployment: push the scene's coils out of the catheter into the wall, frame by frame.

The orchestrator owns no physics: it builds the Model from a Scene, then
advances the Solver in captured chunks of one frame each, and between frames
measures, records and decides (detach, next coil, jam, rest, timeout,
unstable). Units mm, g, s, µN, nJ.
"""

from __future__ import annotations

import math
import signal
import threading
import time
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import replace
from typing import Callable, Sequence

import numpy as np
import warp as wp

from .anatomy import Anatomy, resolve_anatomies, resolve_anatomy
from .devices import deflation
from .measure import Frame, RunResult, Snapshot, measure_frame, note_samples, run_result, take_snapshot
from .model import EnsembleError, Model, ModelBuilder, finalize_ensemble
from .implicit import (DETACH_LEAD_SEGMENTS, DETACH_WHIP_S, IMPLICIT_SETTLE_THETA, detach_level, implicit_step_s,
                       make_solver, scheme_options, SETTLE_REFINE_MAX, SETTLE_RISE_REFINE_MAX, SETTLE_STALL_DROP,
                       SETTLE_STALL_S, settle_energy_rose,
                       settle_finest_level, settle_level, settle_stalled,
                       settle_step_s, settle_step_scale)
from .preflight import SetupError, check_wall_field, preflight
from .preshape import PreshapeError
from .scene import check_built_scene
from .settings import Scene, SimulationSettings, resolve_integrator
from .solver import Control, Stepper, wall_field_extent
from .catheter_roll import packed_rolls
from .state import State, new_state_like, packed_state

COMPLETED, JAMMED, TIMEOUT, FAILED, INTERRUPTED = "completed", "jammed", "timeout", "failed", "interrupted"
COIL_GAP_MM = 1.0  # the coils sit this far apart in the catheter
DEFAULT_SETTLE_TIME_S = 2.0  # the default time limit: the push time (every coil out) and this
STALL_DRAG_FACTOR = 2.0  # the stall force is at least this × the pushed coil's damping drag at the push speed
MAX_STEP_HALVINGS = 3  # an unstable frame is redone with half the step, at most this often
REST_SPEED_MM_S = 0.25  # rms node speed below which the coils count as at rest (default tolerance)


def push_time_s(sim: SimulationSettings, coil_lengths_mm: Sequence[float]) -> float:
    """Time (s) to push out coils of these lengths (mm), each with COIL_GAP_MM, at the push speed."""
    return float(sum(length + COIL_GAP_MM for length in coil_lengths_mm)) / sim.push_speed_mm_s


def time_limit_s(sim: SimulationSettings, coil_lengths_mm: Sequence[float]) -> float:
    """The run's simulated time limit (s): ``max_time_s``, or the push time + DEFAULT_SETTLE_TIME_S."""
    return sim.max_time_s if sim.max_time_s is not None else push_time_s(sim, coil_lengths_mm) + DEFAULT_SETTLE_TIME_S


def sac_bend_forces_uN(coils: Sequence, sac_volume_mm3: float | None) -> np.ndarray:
    """Per coil (CoilSpec), EI / (2 R²) (µN = nJ/mm): the elastic energy per mm of the coil bent to the
    curvature of a sphere of the sac's volume, R = (3 V / 4π)^(1/3) — the least push force per mm with
    which any coil fills that sac, whatever its pre-shape; 0 without a sac."""
    if not sac_volume_mm3:
        return np.zeros(len(coils))
    radius_mm = (3.0 * sac_volume_mm3 / (4.0 * math.pi)) ** (1.0 / 3.0)
    return np.array([c.EI / (2.0 * radius_mm**2) for c in coils])


def model_builder(scene: Scene, anatomy: Anatomy) -> ModelBuilder:
    """The builder of a scene's world: coils (pre-shapes), catheter, contact and wall."""
    builder = ModelBuilder(catheter=anatomy.catheter, settings=scene.simulation, contact=scene.contact,
                           wall=anatomy.wall)
    builder.balloon = anatomy.balloon
    builder.stent = anatomy.stent
    for k, coil in enumerate(scene.coils):
        try:
            builder.add_coil(coil)
        except PreshapeError as error:  # which scene and coil: a pre-shape's own message names neither
            raise PreshapeError(f"{scene.where}: coil[{k}] ({coil.name}): {error}") from None
    return builder


def build_model(scene: Scene, device=None, anatomy: Anatomy | None = None) -> Model:
    """Model from a scene: coils (pre-shapes), catheter, contact and the wall mesh."""
    return model_builder(scene, anatomy or resolve_anatomy(scene)).finalize(device)


class Member:
    """One deployment's bookkeeping inside an ensemble (world ``world`` of the
    model): its coil sequence, energy budget, frames and, once it ends, its result.
    ``index`` is its place in the scenes the ensemble was given (kept when it is
    rerun alone); ``coil_nodes`` its coils' node slices in the state that
    ``on_frame`` receives with it."""

    def __init__(self, world: int, scene: Scene, anatomy: Anatomy, model: Model, host: dict[str, np.ndarray],
                 stored_energy_nJ: float, step_bound_s: float):
        """``host``: the model's arc_s, inv_mass and node_radius, read once for all members."""
        sim = scene.simulation
        self.world = self.index = world
        self.scene, self.anatomy, self.step_bound_s = scene, anatomy, step_bound_s
        self.nodes = model.world_nodes(world)
        self.coils = model.world_coils(world)
        self.coil_nodes = [model.node_slice(c) for c in self.coils]
        self.coil_lengths_mm = np.array([host["arc_s"][model.coil_last[c]] for c in self.coils])
        # each coil's last DETACH_LEAD_SEGMENTS edges (mm): a θ < 1 push opens its detachment frames that much earlier
        self.lead_mm = np.array([host["arc_s"][model.coil_last[c]]
                                 - host["arc_s"][max(model.coil_last[c] - DETACH_LEAD_SEGMENTS, model.coil_first[c])]
                                 for c in self.coils])
        self.wire_areas_mm2 = np.array([math.pi * (c.wire_diameter_mm / 2.0) ** 2 for c in scene.coils])
        self.stored_energy_nJ = stored_energy_nJ
        self.pusher_work_nJ, self.last_advance_mm = 0.0, 0.0
        self.max_time_s = time_limit_s(sim, self.coil_lengths_mm)
        self.mass_g = 1.0 / host["inv_mass"][self.nodes]
        self.rest_kinetic_energy_nJ = (sim.rest_kinetic_energy_nJ if sim.rest_kinetic_energy_nJ is not None
                                       else 0.5 * float(self.mass_g.sum()) * REST_SPEED_MM_S**2)
        self.radius = host["node_radius"][self.nodes]
        self.coil_status = ["waiting"] * len(self.coils)
        self.withdrawn_from: list[int | None] = [None] * len(self.coils)  # a jammed coil's first withdrawn node
        self.jam_reasons: list[str] = []
        # the force with which the coils draw themselves out of the catheter (µN = nJ/mm)
        self.self_deployment_force_uN = stored_energy_nJ / float(self.coil_lengths_mm.sum())
        # (at least STALL_DRAG_FACTOR × the damping drag of the pushed coil moving at the push speed, per coil: a
        # coil with little or no pre-shape draws itself out with ~0 µN, and the drag of its free part alone stalled it)
        drag_uN = (sim.damping_uN_per_mm * self.coil_lengths_mm
                   * (1.0 - math.exp(-sim.push_speed_mm_s / sim.damping_speed_mm_s)))
        # (and at least the force that bends each coil to the sac's own curvature: a straight or oversized coil
        # draws itself out with ~0 µN, but no coil fills a sac without that bend)
        self.sac_bend_forces_uN = sac_bend_forces_uN(scene.coils, anatomy.sac_volume_mm3)
        self.stall_forces_uN = (np.full(len(self.coil_lengths_mm), sim.stall_force_uN) if sim.stall_force_uN is not None
                                else np.maximum(sim.stall_force_ratio * np.maximum(self.self_deployment_force_uN,
                                                                                  self.sac_bend_forces_uN),
                                                STALL_DRAG_FACTOR * drag_uN))  # per coil, while it is pushed
        self.resisted_since_s: float | None = None  # start of the frames with mean push force > stall force
        self.frames: list[Frame] = []
        self.active = -1  # local index of the pushed coil
        self.balloon = scene.balloon
        self.deflate_from_s = None if self.balloon is None else self.balloon.deflate_at_s
        self.inflation = None if self.balloon is None else 1.0  # 1 inflated .. 0 deflated
        self.steps = 0
        self.settle_steps = 0  # steps taken at the settling steps (Ensemble._settle_chunk)
        self.settle_level = 0  # its settling step: frame / (2 settle_level) (0: not settling)
        self.settle_scale = settle_step_scale(scene.coils, scene.simulation)  # on its settling bounds (fine, stiff)
        self.sample_centre_mm = math.inf  # its contact samples' smallest wall centre distance (measure.note_samples)
        self.settle_refine = 0  # how often its kinetic energy stalled or rose: 1 the finest step from then on, each more half
        self.settle_stall_from = 0  # its settling frame from which a stall is looked for (the last refinement's)
        self.settle_kinetic_nJ: list[float] = []  # its kinetic energy at each settling frame
        self.exact_wall_from = -1  # its frame count when its wall field gave way to the BVH (Ensemble._stalled_settle)
        self.detach_level = 1  # this push frame's steps per push step (Ensemble._push_chunk; 1: the push step)
        self.detach_until_s = -math.inf  # frames starting before this run at the detachment step
        self.detach_steps = 0  # steps the detachment step added (included in steps)
        self.result: RunResult | None = None

    def energy_budget_nJ(self, advance: np.ndarray, free: np.ndarray, push_force_uN: float) -> float:
        """Energy put into the coils so far (nJ): stored by packing, work of the pusher
        (|mean push force| × advance, per frame), and the push-speed kinetic energy
        each released node brings out."""
        deployed = float(np.clip(advance, 0.0, self.coil_lengths_mm).sum())
        self.pusher_work_nJ += abs(push_force_uN) * max(deployed - self.last_advance_mm, 0.0)
        self.last_advance_mm = deployed
        released = float((free == 1) @ self.mass_g)
        speed = self.scene.simulation.push_speed_mm_s
        return self.stored_energy_nJ + self.pusher_work_nJ + 0.5 * released * speed**2 + 1.0


class SceneWarning(UserWarning):
    """What `warpcoil run` warns about before a run (preflight), for a Scene built in Python."""


class IntegratorChoice(SceneWarning):
    """The reference runs a scene built in Python that names no integrator (settings.resolve_integrator):
    the scene reader's rule, said as `warpcoil run` says it before a run."""


class Ensemble:
    """Deployments of several scenes advanced by one set of launches (one world
    each), frame by frame; ``run()`` returns one RunResult per scene, each equal
    to what a single run of that scene gives. ``on_frame(member, frame, state)``
    (if given) is called after every recorded frame of every member.

    The scenes must give the same step (dt, and the contact law's linear onset)
    and frame length; :func:`ensemble_groups` splits a sweep into such groups.
    A member that goes unstable is stopped and, after the others, run alone
    (where its step can be halved, as a single run's would be); ``on_frame``
    then sees that member's frames again from its start."""

    def __init__(self, scenes: Sequence[Scene], device=None, anatomies: Sequence[Anatomy] | None = None,
                 solver_options: dict | None = None, checked: bool = False):
        """``checked``: the scenes were checked already (a member rerun alone): scenes built in Python
        are otherwise checked as a scene file would be, with the run's preflight."""
        self.scenes = [resolve_integrator(s) for s in scenes]  # a scene built in Python: its preflight says why
        if not self.scenes:
            raise ValueError("an ensemble needs at least one scene")
        built = [] if checked else [k for k, s in enumerate(self.scenes) if s.source is None]  # as a file would be
        for k in built:
            check_built_scene(self.scenes[k])
        self.device = device
        self.anatomies = list(anatomies) if anatomies is not None else resolve_anatomies(self.scenes)
        self.model = finalize_ensemble([model_builder(s, a) for s, a in zip(self.scenes, self.anatomies)], device)
        sims = [s.simulation for s in self.scenes]
        bounds = world_bounds(self.model)
        steps = world_steps(self.model, self.scenes, bounds)
        for k in built:  # what `warpcoil run` checks before a run: errors raise SetupError, warnings are said
            for note in preflight(self.scenes[k], self.anatomies[k], device, bounds[k].dt_s):
                chose = any(note.endswith(reason) for reason in self.scenes[k].notes)  # resolve_integrator's
                warnings.warn(note, IntegratorChoice if chose else SceneWarning,
                              stacklevel=3 if type(self) is Deployment else 2)  # the caller's line
        if len(set(steps)) > 1:
            raise EnsembleError("ensemble members need the same step and frame length, got (dt_s, contact onset, "
                                f"steps per frame, integrator, settling step, push time, implicit scheme) = {steps}; split them with warpcoil.deploy.ensemble_groups")
        self.integrator = steps[0][3]
        self.settle_dt_s, self.push_time_s = steps[0][4], steps[0][5]  # (implicit) step after the push, its start
        self._push_dt_s: float | None = None  # the push's step, once the settling step took over
        self._settling = False  # every member steps at its own settling step (_settle_chunk)
        self._push_over = False  # every coil is out: the solver settles at θ IMPLICIT_SETTLE_THETA (_settle_scheme)
        self._levels: dict[int, Stepper] = {}  # settling: steps per half frame → its stepper
        self.settle_rule = settle_level  # (fastest speed mm/s, c0 mm, frame s, scale) → steps per half frame
        self._fine: dict[int, Stepper] = {}  # detachment frames: steps per push step → its stepper
        self.detach_rule = detach_level  # (push speed mm/s, push step s, c0 mm) → steps per push step
        for scene, anatomy, extent in zip(self.scenes, self.anatomies, wall_field_extent(self.model)):
            check_wall_field(scene, anatomy, extent)  # (the solver builds the field)
        contact = self.scenes[0].contact
        scheme = scheme_options(steps[0][6]) if self.integrator == "implicit" else {}  # simulation.implicit_scheme
        self._solver_options = {"wall_query": contact.wall_query, "wall_voxel_mm": contact.wall_voxel_mm,
                                **scheme, **(solver_options or {})}  # benchmarks: other skins, ...
        self.solver = make_solver(self.model, self.integrator, steps[0][0], dt_safety=sims[0].dt_safety,
                                  allow_unstable_dt=sims[0].allow_unstable_dt, **self._solver_options)
        self.scheme = dict(self.solver.scheme)  # the push's (result.json: settling and step halving change θ)
        self.control = Control.create(self.model, active_coil=0, push_speed_mm_s=[s.push_speed_mm_s for s in sims])
        rolls = packed_rolls(self.model, self.solver, self.anatomies, COIL_GAP_MM)  # (the wall's, or a bend's least)
        self.stepper = Stepper(self.solver, packed_state(self.model, gap_mm=COIL_GAP_MM, roll_references=rolls),
                               self.control, chunk=steps[0][2])
        for module in self.solver.kernel_modules:  # hashed and loaded (from the kernel cache) with the solver,
            wp.load_module(module, device=self.model.device)  # not at the first step inside the run's clock
        packed, _ = self.solver.world_energies(self.stepper.state)
        stored = packed["bend_nJ"] + packed["twist_nJ"] + packed["stretch_nJ"]
        host = {name: self.model.host(name) for name in ("arc_s", "inv_mass", "node_radius")}
        self.members = [Member(w, s, a, self.model, host, float(stored[w]), bounds[w].dt_s)
                        for w, (s, a) in enumerate(zip(self.scenes, self.anatomies))]
        self.step_reductions: list[str] = []
        self._ran = False  # run() once
        self._steps_before = 0  # steps of chunks dropped by a step halving
        self._work_before = (0.0, 0.0)  # a single run's pusher work and advance at the last frame

    # --- coil sequence -------------------------------------------------------------
    def _activate(self, member: Member, coil: int) -> None:
        """Hand the member's pusher to its coil ``coil`` (pushed along behind the
        previous one); none when no coil is left."""
        member.active = coil if coil < len(member.coils) else -1
        self.control.set_active_coil(member.active, world=member.world)
        self.solver.forget_push_reading(member.world)
        if member.active >= 0:
            member.coil_status[coil] = "pushing"

    def _retract(self, member: Member, coil: int) -> None:
        """A jammed coil: its part still in the catheter is withdrawn (cut off at the
        tip and parked, out of every pass); the deployed part stays and is detached."""
        m = self.model
        sl = m.node_slice(member.coils.start + coil)
        inside = np.flatnonzero(self.stepper.state.free.numpy()[sl] == 0) + sl.start
        if inside.size == 0:
            return
        member.withdrawn_from[coil] = int(inside.min() - sl.start)
        has_next, fixed = m.has_next.numpy(), m.fixed.numpy()
        has_next[inside.min() - 1 if inside.min() > sl.start else sl.start:sl.stop] = 0
        fixed[inside] = 1
        m.has_next.assign(has_next)
        m.fixed.assign(fixed)
        m.forget_host("has_next", "fixed")

    def _halve_step(self, snapshot: State, why: str) -> None:
        """Go back to the frame's start with half the step (and a new captured graph).
        The step bound is linear; dense contact (several deep overlaps on one node)
        can be stiffer, and then the frame is redone rather than lost. Not done for
        a run that asked for ``allow_unstable_dt``: it gets the step it asked for."""
        done, failed = ((self.members[0].settle_steps, 2 * self.members[0].settle_level) if self._settling
                        else (self.stepper.steps, self.stepper.chunk))
        self._steps_before += done - failed  # the failed frame's steps are dropped
        self._settling = False  # (a single run) on at the halved step to its end
        options = dict(self._solver_options)
        if self._push_over:  # halved after the push: on with the settling θ, the push's gate and contact stiffness
            scheme = self.solver.scheme
            options.update(method="theta", theta=IMPLICIT_SETTLE_THETA, near_theta=scheme["near_theta"],
                           contact_stiffness=scheme["contact_stiffness"])
            if scheme["chord_end"] is not None:
                options["chord_end"] = scheme["chord_end"]
        solver = make_solver(self.model, self.integrator, 0.5 * self.solver.dt_s,
                             dt_safety=self.members[0].scene.simulation.dt_safety, allow_unstable_dt=True,
                             **options)
        for m in self.members:  # (a world that went over to the exact wall stays there: Solver.use_exact_wall)
            if m.exact_wall_from >= 0:
                solver.use_exact_wall(m.world)
        self.step_reductions.append(f"t = {snapshot.time_s:.5f} s: {why.split(' at t =')[0]}; "
                                    f"step halved to {solver.dt_s:.3e} s")
        start = new_state_like(self.model)
        start.copy_from(snapshot)
        self.solver = solver
        self.stepper = Stepper(solver, start, self.control, chunk=2 * self.stepper.chunk)
        self._fine = {}  # (their solver and state were the old ones)

    def _settle_step(self) -> None:
        """Every coil is out (at the push's scheduled end, the same for every member): from
        the next frame on each member steps at its own settling step (:meth:`_settle_chunk`)."""
        self._steps_before += self.stepper.steps
        self._push_dt_s = self.solver.dt_s
        self._settle_scheme()
        self._settling = True

    def _settle_scheme(self) -> None:
        """Every coil is out: the implicit solver goes on at θ IMPLICIT_SETTLE_THETA, at the
        settling step or (a run that gave ``dt_s`` or halved its step) at its own."""
        self._push_over = True
        changed = False
        if getattr(self.solver, "theta", 1.0) != IMPLICIT_SETTLE_THETA:  # the θ-method does not bring a coil to rest
            self.solver.theta = IMPLICIT_SETTLE_THETA  # (FORMULATION.md "Implicit step: push force"): Euler settles it
            changed = True
        if getattr(self.solver, "method", "theta") == "bdf2":  # BDF2's history would restart at every change of
            self.solver.method = "theta"  # a member's settling step: Euler settles it (FORMULATION "BDF2")
            changed = True
        if changed:
            self.stepper.forget_graph()  # its graph holds the push's θ and method (the settling steppers capture anew)
            self._fine = {}  # (so do the detachment frames' steppers)

    def _settle_chunk(self, live: list[Member]) -> None:
        """One frame of settling: each live member at the step its fastest free node sets
        (implicit.settle_level: frame / (2 k), k whole, so every member's frame has the same
        length); the members of each step advance together, the others held (a member's
        steps do not depend on the others': it equals its single run)."""
        frame_s = self.members[0].scene.simulation.frame_interval_s
        state = self.stepper.state
        v, free = self.solver.host(state.v), self.solver.host(state.free) == 1  # (read before the steps)
        c0 = self.model.contact.c0_mm
        for m in live:
            moving = free[m.nodes]
            speed = float(np.sqrt((v[m.nodes][moving] ** 2).sum(axis=1).max())) if moving.any() else 0.0
            if ((m.settle_refine < SETTLE_REFINE_MAX or self.solver.field_in_use(m.world))
                    and settle_stalled(m.settle_kinetic_nJ[m.settle_stall_from:], frame_s)):
                m.settle_refine += 0 if self._stalled_settle(m) else 1  # (the exact wall first, then a finer step)
                m.settle_stall_from = len(m.settle_kinetic_nJ)
            m.settle_level = (settle_finest_level(frame_s, m.settle_scale) * 2 ** (m.settle_refine - 1)
                              if m.settle_refine else self.settle_rule(speed, c0, frame_s, m.settle_scale))
        start = state.time_s

        def run_level(k: int) -> None:
            if k not in self._levels:
                self._levels[k] = Stepper(self.solver, state, self.control, chunk=2 * k, graph_steps_max=2)
            self.solver.dt_s = frame_s / (2 * k)
            self.stepper = self._levels[k]
            self.stepper.run_chunk(self._deflating(live))
            for m in live:
                m.settle_steps += 2 * k if m.settle_level == k else 0

        self._by_level(live, lambda m: m.settle_level, run_level)
        state.time_s = start + frame_s  # the same clock whichever steps a frame took

    def _energy_rise_nJ(self, member: Member, energies: dict[str, np.ndarray]) -> float | None:
        """The rise of the member's kinetic + elastic energy (nJ) over the frame just run, where it is
        past implicit.settle_energy_rose's tolerance and nothing drives the coil (every coil out, no
        deflating balloon); else None. A frame that started with no node, contact sample (its smallest wall
        gap ≥ the contact range c0), coil or device in contact has the tolerance of one free of contact."""
        if member.active >= 0 or (member.inflation or 0.0) > 0.0 or len(member.frames) == member.exact_wall_from:
            return None
        last = member.frames[-1]
        before = last.kinetic_nJ + last.bend_nJ + last.twist_nJ + last.stretch_nJ
        after = float(sum(e[member.world] for e in energies.values()))
        contact_free = (last.wall_contacts == 0 and last.coil_contacts == 0  # (no contact energy to give back)
                        and last.min_wall_gap_mm >= self.model.contact.c0_mm
                        and member.anatomy.balloon is None and member.anatomy.stent is None)
        return after - before if settle_energy_rose(before, after, contact_free) else None

    def _energy_rose(self, member: Member, energies: dict[str, np.ndarray]) -> bool:
        """Whether a settling frame raised the member's energy (:meth:`_energy_rise_nJ`) while a finer
        settling step is left to redo it at (SETTLE_RISE_REFINE_MAX)."""
        return (member.settle_refine < SETTLE_RISE_REFINE_MAX
                and self._energy_rise_nJ(member, energies) is not None)

    def _rises_as_problems(self, running: list[Member], energies: dict[str, np.ndarray],
                           problems: list[str | None]) -> None:
        """Outside the settling step (a member's last coil out before it starts, or a run that settles
        at its own step: it gave ``dt_s`` or halved it): a frame in which a member's energy rose
        (:meth:`_energy_rise_nJ`) is a problem, redone at half the step like an unstable one, while
        halvings are left (MAX_STEP_HALVINGS); so is, in a run settling at its own step, a kinetic energy
        that has stalled (implicit.settle_stalled, as the settling step refines on it: a packed coil
        whose step sustains a cycle instead of coming to rest), where its wall field has not first given
        way to the exact wall (:meth:`_stalled_settle`, halvings or not). A member that asked for
        ``allow_unstable_dt`` gets no halving, so neither is a problem for it."""
        frame_s = self.members[0].scene.simulation.frame_interval_s
        for m in running:
            if problems[m.world] is not None:
                continue
            halvings_left = (len(self.step_reductions) < MAX_STEP_HALVINGS
                             and not m.scene.simulation.allow_unstable_dt)
            rise = self._energy_rise_nJ(m, energies) if halvings_left else None
            if rise is not None:
                problems[m.world] = self.solver.unstable_reason(
                    f"kinetic + elastic energy rose {rise:.3g} nJ in a frame with nothing driving the coil",
                    self.stepper.state.time_s)
            elif (self._push_over and m.active < 0 and not (m.inflation or 0.0) > 0.0
                  and (halvings_left or self.solver.field_in_use(m.world))
                  and settle_stalled(m.settle_kinetic_nJ[m.settle_stall_from:], frame_s)):
                m.settle_stall_from = len(m.settle_kinetic_nJ)
                if self._stalled_settle(m, before_frame=False) or not halvings_left:
                    continue
                problems[m.world] = self.solver.unstable_reason(
                    f"kinetic energy stalled at {m.settle_kinetic_nJ[-1]:.3g} nJ (less than "
                    f"{100 * SETTLE_STALL_DROP:g} % lost over {SETTLE_STALL_S:g} s) with nothing driving the coil",
                    self.stepper.state.time_s)

    def _stalled_settle(self, member: Member, before_frame: bool = True) -> bool:
        """A settling member whose kinetic energy stalled: where its wall distances still come from a wall
        field, from now on all from the exact BVH (True; Solver.use_exact_wall: at the edge of the field's
        trusted region a wall contact's force switched between two distances and kept packed coils jittering,
        kinetic 0.005–0.06 nJ for 2 s, where the BVH lets them rest); else False (refine the step).
        ``before_frame``: called before the member's next frame runs (else after one not yet recorded)."""
        if not self.solver.field_in_use(member.world):
            return False
        self.solver.use_exact_wall(member.world)
        # (the first frame on the BVH: its energy is measured on another distance, its start is the switch's time)
        member.exact_wall_from = len(member.frames) + (0 if before_frame else 1)
        return True

    def _settle_again(self, risen: list[Member], running: list[Member], snapshot: State) -> None:
        """Redo the settling frame of each member in ``risen`` from its start (``snapshot``) at half
        its step (one more settle_refine), the others held at the frame's end; the failed
        frame's steps are dropped, as :meth:`_halve_step` drops them."""
        frame_s = self.members[0].scene.simulation.frame_interval_s
        for m in risen:
            m.settle_steps -= 2 * m.settle_level
            finest = settle_finest_level(frame_s, m.settle_scale)
            m.settle_refine += 1
            while finest * 2 ** (m.settle_refine - 1) <= m.settle_level and m.settle_refine < SETTLE_RISE_REFINE_MAX:
                m.settle_refine += 1  # (a level at least twice the failed frame's)
            m.settle_stall_from = len(m.settle_kinetic_nJ)
            self._restore(m, snapshot)
        self._run_only(risen)
        self.stepper.state.time_s = snapshot.time_s
        self._settle_chunk(risen)
        self._run_only(running)

    def _deflating(self, live: list[Member]) -> Callable[[float], None] | None:
        """For Stepper.run_chunk: while a member's balloon deflates, its inflation set before
        every graph replay (≤ GRAPH_STEPS_MAX steps) to the schedule at that replay's middle,
        so the deflation follows the clock, not the frames (a frame's value held over it made
        it a staircase of frames, and a 0.1 s deflation one step at --frame-interval 0.1);
        None when none deflates."""
        deflating = [m for m in live if m.balloon is not None and m.deflate_from_s is not None
                     and m.inflation is not None and m.inflation > 0.0]
        if not deflating:
            return None

        def follow(time_s: float) -> None:
            for m in deflating:
                self.model.set_inflation(m.world, deflation(m.balloon, time_s, m.deflate_from_s))

        return follow

    def _detaching(self, member: Member, advance: np.ndarray, start_s: float, frame_s: float) -> bool:
        """Whether the member's frame about to run (from ``start_s``, ``frame_s`` long) is a
        detachment frame: its active coil's last node is released in it (the advance reaches
        the coil's length, kernels/integrate.hold_node; then member.detach_until_s is set to
        that moment + DETACH_WHIP_S), or it starts before member.detach_until_s. On a θ < 1
        push (gated_chord) also the frames in which the coil's last DETACH_LEAD_SEGMENTS edges
        leave (implicit.DETACH_LEAD_SEGMENTS)."""
        if member.active >= 0:
            speed = member.scene.simulation.push_speed_mm_s
            left_mm = member.coil_lengths_mm[member.active] - advance[member.coils.start + member.active]
            lead_mm = (member.lead_mm[member.active]
                       if getattr(self.solver, "theta", 1.0) < 1.0 else 0.0)  # θ < 1: the last nodes' releases too
            if left_mm <= speed * frame_s * (1.0 + 1e-9) + lead_mm:
                member.detach_until_s = start_s + left_mm / speed + DETACH_WHIP_S
                return True
        return start_s < member.detach_until_s

    def _push_chunk(self, live: list[Member]) -> None:
        """One push frame. The implicit step is sized for the pusher; a coil's tail leaving
        the catheter whips toward its pre-shape several times faster: a member in a
        detachment frame (:meth:`_detaching`) takes it at push step / k (``detach_rule``,
        k whole: the frame's length and the pusher's advance per frame unchanged); the
        members of each k advance together, the others held (as :meth:`_settle_chunk`:
        each equals its single run)."""
        state, frame_steps, dt = self.stepper.state, self.stepper.chunk, self.solver.dt_s
        if self.integrator == "implicit" and getattr(self.solver, "method", "theta") != "bdf2":
            # (BDF2's history flag is one per state, shared by the members: a member held while another
            # steps finer would resume it wrongly, so a BDF2 run keeps the push step through detachment)
            advance = self.solver.host(state.advance)  # (read before the steps)
            c0 = self.model.contact.c0_mm
            for m in live:
                m.detach_level = (self.detach_rule(m.scene.simulation.push_speed_mm_s, dt, c0)
                                  if self._detaching(m, advance, state.time_s, frame_steps * dt) else 1)
        start = state.time_s

        def run_level(k: int) -> None:
            if k == 1:
                self.stepper.run_chunk(self._deflating(live))
                return
            if k not in self._fine:
                self._fine[k] = Stepper(self.solver, state, self.control, chunk=k * frame_steps, graph_steps_max=2)
            self.solver.dt_s = dt / k
            try:
                self._fine[k].run_chunk(self._deflating(live))
            finally:
                self.solver.dt_s = dt

        if 1 not in self._by_level(live, lambda m: m.detach_level, run_level):
            self.stepper.steps += frame_steps  # (the push's step count; each member adds its own extra steps)
        state.time_s = start + frame_steps * dt

    def _by_level(self, live: list[Member], level_of: Callable[[Member], int],
                  run_level: Callable[[int], None]) -> list[int]:
        """Steps the members of each level (``level_of``) together by ``run_level(level)``,
        from the frame's start clock, the others held (Control.running): a member's steps do
        not depend on the others', so it equals its single run. Returns the levels."""
        state = self.stepper.state
        levels = sorted({level_of(m) for m in live}) or [1]
        start = state.time_s
        for k in levels:
            if len(levels) > 1:
                self._run_only([m for m in live if level_of(m) == k])
            state.time_s = start
            run_level(k)
        if len(levels) > 1:
            self._run_only(live)
        return levels

    def _run_only(self, members: list[Member]) -> None:
        """Only ``members``' worlds step (Control.running); the others are held."""
        mask = np.zeros(self.model.world_count, dtype=np.int32)
        mask[[m.world for m in members]] = 1
        self.control.running.assign(mask)

    def _restore(self, member: Member, snapshot: State) -> None:
        """Put a stopped member's nodes back to the frame's start (finite values)."""
        state, sl, coils = self.stepper.state, member.nodes, slice(member.coils.start, member.coils.stop)
        for name in ("x", "v", "m1", "omega", "free", "x_prev", "v_prev"):
            now, then = getattr(state, name).numpy(), getattr(snapshot, name).numpy()
            now[sl] = then[sl]
            getattr(state, name).assign(now)
        advance = state.advance.numpy()
        advance[coils] = snapshot.advance.numpy()[coils]
        state.advance.assign(advance)

    # --- the run ---------------------------------------------------------------
    def _finish(self, member: Member, status: str, reason: str, started: float, snap: Snapshot) -> None:
        if status != COMPLETED and member.jam_reasons and member.jam_reasons[0] not in reason:
            reason = reason + "; earlier: " + "; ".join(member.jam_reasons)
        member.steps = (self._steps_before + (member.settle_steps if self._settling else self.stepper.steps)
                        + member.detach_steps)
        member.result = run_result(self.model, self.solver, member, status, reason, time.perf_counter() - started,
                                   snap, self.step_reductions, self.scheme)
        if self._push_dt_s is not None:  # settled at longer steps: dt_s stays the push's, settle_dt_s the last
            frame_s = member.scene.simulation.frame_interval_s
            settle_dt = (self.solver.dt_s if not self._settling else  # (None: ended before its first settling frame)
                         frame_s / (2 * member.settle_level) if member.settle_level else None)
            member.result = replace(member.result, dt_s=self._push_dt_s, settle_dt_s=settle_dt)
        member.result = replace(member.result, detach_steps=member.detach_steps)
        self.control.stop(member.world)

    def _stalled(self, member: Member, frame: Frame, frame_s: float, advance: np.ndarray) -> str | None:
        """Why the member's deployment has stalled (None while it has not): the coil in
        the sac fills more than stall_packing of it (coils cannot pack that densely, so
        more coil can only pass through coil), or the frame-mean push force has stayed
        above the stall force (stall_force_ratio × the self-deployment force, or
        stall_force_uN) in every frame of the stall window.
        ``advance``: the member's coils' pusher advance (mm)."""
        sim, k = member.scene.simulation, member.active
        if k < 0:
            member.resisted_since_s = None
            return None
        areas = member.wire_areas_mm2
        deployed = np.clip(advance, 0.0, member.coil_lengths_mm)
        outside_mm = frame.length_outside_sac_mm or 0.0  # (None in free space)
        in_sac = float(areas @ deployed) - areas[k] * outside_mm  # (outside: at the active's d)
        sac = member.anatomy.sac_volume_mm3
        packing = in_sac / sac if sac else 0.0

        def where() -> str:  # built only when the run stalls (every frame checks)
            return (f"coil {k} ({member.scene.coils[k].name}) with {frame.deployed_length_mm:.2f} of "
                    f"{member.coil_lengths_mm.sum():.2f} mm deployed"
                    + (f", packing density {100 * packing:.1f} %" if sac else ""))

        fix = "deploy less coil (coil.length_mm) or a loop that fits the sac (coil.loop_diameter_mm)"
        if sac and packing > sim.stall_packing:
            return (f"stalled: {where()}: the coil in the sac fills more than stall_packing = {sim.stall_packing:g} of "
                    f"it, denser than coils can pack, so more coil could only pass through coil; {fix}")
        stall_force_uN = float(member.stall_forces_uN[k])
        if frame.push_force_mean_uN <= stall_force_uN:
            member.resisted_since_s = None
            return None
        if member.resisted_since_s is None:
            member.resisted_since_s = frame.time_s - frame_s
        if frame.time_s - member.resisted_since_s < sim.stall_window_s * (1.0 - 1e-9):
            return None
        sac_bend = (f" (or the force that bends it to the sac's curvature, {member.sac_bend_forces_uN[k]:.4g} µN, "
                    "where larger)" if member.sac_bend_forces_uN[k] > member.self_deployment_force_uN else "")
        limit = (f"stall_force_uN = {sim.stall_force_uN:g} µN" if sim.stall_force_uN is not None else
                 f"stall_force_ratio = {sim.stall_force_ratio:g} × the coils' self-deployment force "
                 f"{member.self_deployment_force_uN:.4g} µN{sac_bend}, at least {STALL_DRAG_FACTOR:g} × the pushed "
                 f"coil's damping drag at the push speed, = {stall_force_uN:.4g} µN")
        return (f"stalled: {where()}: the mean push force stayed above {limit} "
                f"in every frame for stall_window_s = {sim.stall_window_s:g} s (last {frame.push_force_mean_uN:.4g} "
                f"µN), a resistance that does not let up; {fix}")

    def _advance_member(self, member: Member, frame: Frame, started: float, snap: Snapshot) -> None:
        """After a frame: stall, jam, detach and next coil, rest, timeout."""
        sim = member.scene.simulation
        active = member.active
        coil = member.coils.start + active
        stalled = self._stalled(member, frame, self.stepper.chunk * self.solver.dt_s,
                                snap.advance[member.coils.start:member.coils.stop])
        if stalled is not None:
            member.coil_status[active] = JAMMED
            self._finish(member, JAMMED, stalled, started, snap)
            return
        if active >= 0 and frame.push_force_mean_uN > sim.jam_force_uN:
            member.coil_status[active] = JAMMED
            deployed = float(np.clip(snap.advance[coil], 0.0, member.coil_lengths_mm[active]))
            member.jam_reasons.append(
                f"coil {active} ({member.scene.coils[active].name}) jammed: mean push force "
                f"{frame.push_force_mean_uN:.4g} µN"
                f" over a frame > jam_force_uN = {sim.jam_force_uN:g} µN with {deployed:.2f} of "
                f"{member.coil_lengths_mm[active]:.2f} mm deployed; the rest was withdrawn")
            self._retract(member, active)
            self._activate(member, active + 1)
        elif active >= 0 and snap.advance[coil] >= member.coil_lengths_mm[active]:
            member.coil_status[active] = "detached"
            self._activate(member, active + 1)
        if member.balloon is not None:
            if member.active < 0 and member.deflate_from_s is None:
                member.deflate_from_s = snap.time_s  # the last coil detached: deflate now
            member.inflation = deflation(member.balloon, snap.time_s, member.deflate_from_s)
            self.model.set_inflation(member.world, member.inflation)
        deflated = member.inflation is None or member.inflation == 0.0
        if member.active < 0 and deflated and frame.kinetic_nJ < member.rest_kinetic_energy_nJ:
            if member.jam_reasons:
                self._finish(member, JAMMED, "; ".join(member.jam_reasons) + "; then at rest", started, snap)
            else:
                self._finish(member, COMPLETED, "all coils detached and at rest", started, snap)
        elif snap.time_s >= member.max_time_s:
            self._finish(member, TIMEOUT, f"simulated time reached max_time_s = {member.max_time_s:g} s", started,
                         snap)

    def _record(self, member: Member, frame: Frame, on_frame) -> None:
        member.frames.append(frame)
        if self._settling or self._push_over:  # (the latter: a run settling at its own step)
            member.settle_kinetic_nJ.append(frame.kinetic_nJ)
        if on_frame:
            on_frame(member, frame, self.stepper.state)

    def run(self, on_frame: Callable[[Member, Frame, State], None] | None = None) -> list[RunResult]:
        """Deploy every member; Ctrl-C (SIGINT) or SIGTERM, in the main thread, ends the run after
        the current frame, each unfinished member with status ``interrupted``. Runs once: its
        state and results are those of that run (build another for another run)."""
        if self._ran:
            raise RuntimeError("this deployment has run: its state is at the end of that run, and its results "
                               "are kept; build a new Deployment (or Ensemble) of the scene to run it again")
        self._ran = True
        with stop_between_frames() as interrupted:
            return self._run(on_frame, interrupted)

    def _interrupt(self, members: list[Member], started: float) -> None:
        snap = take_snapshot(self.solver, self.stepper.state, self.control.running)
        for member in members:
            deployed = float(np.clip(snap.advance[member.coils.start:member.coils.stop], 0.0,
                                     member.coil_lengths_mm).sum())
            self._finish(member, INTERRUPTED, f"stopped by Ctrl-C or SIGTERM at t = {snap.time_s:.4f} s with {deployed:.2f} "
                         f"of {member.coil_lengths_mm.sum():.2f} mm deployed; results are those of that moment",
                         started, snap)

    def _run(self, on_frame, interrupted: list[bool]) -> list[RunResult]:
        started = time.perf_counter()
        single = len(self.members) == 1
        for member in self.members:
            self._activate(member, 0)
        state = self.stepper.state
        energies, _ = self.solver.world_health(state)
        snap = take_snapshot(self.solver, state, self.control.running)
        for member in self.members:
            note_samples(member, snap)
            self._record(member, measure_frame(self.model, self.solver, member, snap, energies, (0.0, 0.0, 0.0)), on_frame)
            if state.time_s >= member.max_time_s:
                self._finish(member, TIMEOUT, f"simulated time reached max_time_s = {member.max_time_s:g} s",
                             started, snap)
        rerun: list[Member] = []
        snapshot = new_state_like(self.model)
        while any(m.result is None and m not in rerun for m in self.members):
            if interrupted[0]:
                self._interrupt([m for m in self.members if m.result is None and m not in rerun], started)
                break
            self.solver.copy_state(snapshot, self.stepper.state)
            settling = self._settling
            if settling:
                self._settle_chunk([m for m in self.members if m.result is None and m not in rerun])
            else:
                self._push_chunk([m for m in self.members if m.result is None and m not in rerun])
            state = self.stepper.state
            push = self.solver.take_push_force()
            running = [m for m in self.members if m.result is None and m not in rerun]
            snap = take_snapshot(self.solver, state, self.control.running)
            budgets = np.zeros(self.model.world_count)
            for m in running:
                budgets[m.world] = m.energy_budget_nJ(snap.advance[m.coils.start:m.coils.stop], snap.free[m.nodes],
                                                      push.mean_uN[m.world])
            energies, problems = self.solver.world_health(state, budgets, snap.wall_distance)
            while settling:  # a frame that gained energy is redone at half the step (implicit.SETTLE_RISE_NJ)
                risen = [m for m in running if problems[m.world] is None and self._energy_rose(m, energies)]
                if not risen:
                    break
                self._settle_again(risen, running, snapshot)
                state = self.stepper.state
                push = self.solver.take_push_force()
                snap = take_snapshot(self.solver, state, self.control.running)
                energies, problems = self.solver.world_health(state, budgets, snap.wall_distance)
            if not settling and self.integrator == "implicit":  # (a coil out before the settling step, or none)
                self._rises_as_problems(running, energies, problems)
            unstable = [m for m in running if problems[m.world] is not None]
            if unstable and single:
                member = unstable[0]
                if not member.scene.simulation.allow_unstable_dt and len(self.step_reductions) < MAX_STEP_HALVINGS:
                    member.pusher_work_nJ, member.last_advance_mm = self._work_before
                    self._halve_step(snapshot, problems[member.world])
                    continue
                # the last healthy state (the frame's start): no non-finite geometry in the results
                self._finish(member, FAILED, problems[member.world], started, take_snapshot(self.solver, snapshot, self.control.running))
                break
            for member in unstable:  # run alone afterwards, where its step can be halved
                self.control.stop(member.world)
                self._restore(member, snapshot)
                rerun.append(member)
            for member in running:
                if member in unstable:
                    continue
                if not settling:  # the frame's steps beyond the push step's (kept only for a healthy frame)
                    member.detach_steps += (member.detach_level - 1) * self.stepper.chunk
                member.detach_level = 1
                note_samples(member, snap)
                if member.balloon is not None and member.deflate_from_s is not None:  # (the frame's own time's value)
                    member.inflation = deflation(member.balloon, snap.time_s, member.deflate_from_s)
                frame = measure_frame(self.model, self.solver, member, snap, energies, tuple(p[member.world] for p in push))
                self._record(member, frame, on_frame)
                self._advance_member(member, frame, started, snap)
            if single:
                self._work_before = (self.members[0].pusher_work_nJ, self.members[0].last_advance_mm)
            pushing = [m for m in self.members if m.result is None and m not in rerun and m.active >= 0]
            if (self.integrator == "implicit" and not self._push_over and not pushing
                    and self.stepper.state.time_s >= self.push_time_s):
                if self.settle_dt_s and not self.step_reductions:
                    self._settle_step()
                else:
                    self._settle_scheme()
        if interrupted[0] and rerun:
            self._interrupt(rerun, started)  # (restored to their last healthy frame)
            rerun = []
        for member in rerun:
            alone = Ensemble([member.scene], self.device, [member.anatomy], solver_options=self._solver_options,
                             checked=True)
            alone.members[0].index = member.index
            result = alone.run(on_frame)[0]
            member.frames, member.result = alone.members[0].frames, result
        return [m.result for m in self.members]

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)  # Ctrl-C, and a batch scheduler's stop (before its kill)


@contextmanager
def _stop_handler(handler: Callable) -> Iterator[None]:
    """``handler`` for each of STOP_SIGNALS within it, the previous handlers after."""
    previous = {number: signal.signal(number, handler) for number in STOP_SIGNALS}
    try:
        yield
    finally:
        for number, action in previous.items():
            signal.signal(number, action)


def _raise_at_once(_number, _frame) -> None:
    raise KeyboardInterrupt


@contextmanager
def interrupt_on_stop() -> Iterator[None]:
    """Within it, SIGTERM (a batch scheduler's stop) interrupts as Ctrl-C does (KeyboardInterrupt): for
    `sweep` and `plan`, which then end with exit 130 and release their folder (Python's default SIGTERM
    killed them with 143, no word and the folder's lock left)."""
    with _stop_handler(_raise_at_once):
        yield


@contextmanager
def stop_at_once() -> Iterator[None]:
    """Within it, Ctrl-C or SIGTERM stop at once (KeyboardInterrupt) instead of ending the current run
    cleanly with status interrupted, and SceneWarnings are not shown: for the commands of many runs of
    the project's own scenes (`validate`, `bench`), where ending one run let the next begin. Everything
    is as before after it."""
    with interrupt_on_stop(), warnings.catch_warnings():
        warnings.simplefilter("ignore", SceneWarning)  # their scenes are set up as they are on purpose
        yield


@contextmanager
def stop_between_frames() -> Iterator[list[bool]]:
    """While a run steps, the first Ctrl-C (SIGINT) or SIGTERM only sets the yielded
    flag, which the run checks between frames (its outputs are then written, status
    interrupted); a second one interrupts at once. (`run` holds it too while it writes the
    outputs of a run that has ended.) Outside the main thread (where no
    handler can be set), and within stop_at_once, nothing changes."""
    flag = [False]
    if threading.current_thread() is not threading.main_thread() or signal.getsignal(signal.SIGINT) is _raise_at_once:
        yield flag
        return

    def handler(_signum, _frame):
        if flag[0]:
            raise KeyboardInterrupt
        flag[0] = True

    with _stop_handler(handler):
        yield flag


def world_bounds(model: Model) -> list:
    """Per world: its explicit step bound (StepBound), as a single run computes it."""
    from .solver import CONTACTS_PER_NODE, stable_step_bound

    contact_k = CONTACTS_PER_NODE * model.contact.stiffness_uN_mm()
    return [stable_step_bound(model, contact_k, model.world_nodes(w)) for w in range(model.world_count)]


def _rounded_up(value: float, digits: int = 2) -> float:
    """``value`` (> 0) rounded up to ``digits`` significant digits: a bound a user can type and meet."""
    unit = 10.0 ** (math.floor(math.log10(value)) - digits + 1)
    return math.ceil(value / unit - 1e-9) * unit


def world_steps(model: Model, scenes: Sequence[Scene], bounds: list | None = None
                ) -> list[tuple[float, float, int, str, float, float, str]]:
    """Per world: (dt_s, contact linear onset, steps per frame, integrator, settling
    step, push time, implicit scheme or "") as a single run of its scene would take them (the onset is the
    explicit step's for either integrator: both integrate the same law). The implicit
    step at its default goes on at the settling step (s) from the push time (s: when
    every coil is out, Σ (length + COIL_GAP_MM) / push speed, and the last coil's
    whip, DETACH_WHIP_S after its release, is over) once every coil is detached; a
    scene that gives ``dt_s`` keeps it (settling step 0) but settles at θ
    IMPLICIT_SETTLE_THETA from the push time too. The symplectic step: both 0."""
    from .solver import contact_linear_onset

    bounds = bounds or world_bounds(model)
    arc = model.host("arc_s")
    steps = []
    for w, scene in enumerate(scenes):
        sim = resolve_integrator(scene).simulation
        explicit_dt = sim.dt_safety * bounds[w].dt_s
        lengths_mm = [arc[model.coil_last[c]] for c in model.world_coils(w)]
        settle_dt, push_time = 0.0, 0.0
        if sim.integrator == "implicit":
            dt = sim.dt_s if sim.dt_s is not None else implicit_step_s(model, sim.push_speed_mm_s)
            onset_dt = explicit_dt
            if sim.dt_s is None:
                settle_dt = settle_step_s(dt, sim.frame_interval_s, settle_step_scale(scene.coils, sim))
            push_time = push_time_s(sim, lengths_mm)
            # the last coil's release is COIL_GAP_MM / speed before that: its whip (the detachment frames)
            # ends first
            push_time += max(0.0, DETACH_WHIP_S - COIL_GAP_MM / sim.push_speed_mm_s)
        else:
            dt = sim.dt_s if sim.dt_s is not None else explicit_dt
            onset_dt = dt
        if sim.frame_interval_s < 2.0 * dt * (1.0 - 1e-9):  # a frame is two steps or more; settling splits frames
            raise SetupError(f"{scene.where}: simulation.frame_interval_s = "
                             f"{sim.frame_interval_s:g} s is shorter than two of the run's steps ({dt:.3g} s each): a "
                             "frame is a whole, even number of steps, and the implicit step's settling splits frames "
                             f"(it would not end); fix: frame_interval_s = {_rounded_up(2.0 * dt):g} or more")
        limit_s = time_limit_s(sim, lengths_mm)
        if sim.frame_interval_s > limit_s:  # (the limit is checked at frame ends: a frame runs whole past it)
            limit = (f"max_time_s = {limit_s:g} s" if sim.max_time_s is not None
                     else f"its default time limit, the push time + {DEFAULT_SETTLE_TIME_S:g} s = {limit_s:.3g} s")
            shortest = _rounded_up(2.0 * dt)  # (the shortest frame, two steps)
            fits = (f"frame_interval_s = {max(limit_s / 10.0, shortest):.3g} or less" if shortest <= limit_s
                    else f"max_time_s = {shortest:g} or more")
            raise SetupError(f"{scene.where}: simulation.frame_interval_s = {sim.frame_interval_s:g} s is longer than "
                             f"{limit}: the limit is checked at frame ends, so the run would go past it; fix: {fits}")
        steps.append((dt, contact_linear_onset(model, onset_dt, model.world_nodes(w)),
                      max(2, 2 * round(sim.frame_interval_s / dt / 2)), sim.integrator, settle_dt, push_time,
                      sim.implicit_scheme if sim.integrator == "implicit" else ""))
    return steps


def host_models(scenes: Sequence[Scene], anatomies: Sequence[Anatomy], device=None) -> list[Model]:
    """Each scene's single-run model without its wall: what its step, contact law and explicit
    step bound (world_bounds: Member.step_bound_s) are read from on the host."""
    return [finalize_ensemble([model_builder(scene, replace(anatomy, wall=None))], device)
            for scene, anatomy in zip(scenes, anatomies)]


def ensemble_groups(scenes: Sequence[Scene], device=None, anatomies: Sequence[Anatomy] | None = None,
                    models: Sequence[Model] | None = None) -> list[list[int]]:
    """Indices of ``scenes`` grouped so each group can run as one Ensemble (same
    step, contact onset, frame length, contact law, friction and wall query, damping speed, mass
    scale and stent strut radius).
    ``anatomies``: the scenes' resolved anatomies, and ``models`` their :func:`host_models`, if the
    caller has them."""
    anatomies = anatomies if anatomies is not None else resolve_anatomies(scenes)
    models = models if models is not None else host_models(scenes, anatomies, device)
    groups: dict[tuple, list[int]] = {}
    for k, (scene, model) in enumerate(zip(scenes, models)):
        c = model.contact
        key = (world_steps(model, [scene])[0], scene.simulation.allow_unstable_dt, c.p0_uN, c.c0_mm,
               c.exclusion_edges, c.fold_span, model.damping_k, model.mass_scale, scene.contact.wall_query,
               scene.contact.wall_voxel_mm, c.friction_wall, c.friction_coil, c.friction_catheter,
               c.friction_speed_mm_s, scene.stent.strut_diameter_mm if scene.stent else 0.0)  # one per ensemble
        groups.setdefault(key, []).append(k)
    return list(groups.values())


class Deployment(Ensemble):
    """One deployment of a scene. ``run()`` returns the RunResult; ``on_frame``
    (if given) is called after every recorded frame with (frame, state)."""

    def __init__(self, scene: Scene, device=None, solver_options: dict | None = None):
        super().__init__([scene], device, solver_options=solver_options)
        self.scene = self.scenes[0]

    @property
    def anatomy(self) -> Anatomy:
        return self.anatomies[0]

    @property
    def coil_lengths_mm(self) -> np.ndarray:
        return self.members[0].coil_lengths_mm

    @property
    def stored_energy_nJ(self) -> float:
        return self.members[0].stored_energy_nJ

    def run(self, on_frame: Callable[[Frame, State], None] | None = None) -> RunResult:
        return super().run((lambda _member, frame, state: on_frame(frame, state)) if on_frame else None)[0]


def deploy(scene: Scene, device=None, on_frame=None) -> RunResult:
    """Run one deployment of ``scene`` (see :class:`Deployment`)."""
    return Deployment(scene, device).run(on_frame)


__all__ = ["COMPLETED", "Deployment", "Ensemble", "FAILED", "Frame", "IntegratorChoice", "JAMMED", "RunResult",
           "SceneWarning", "TIMEOUT", "build_model", "deploy", "ensemble_groups"]
