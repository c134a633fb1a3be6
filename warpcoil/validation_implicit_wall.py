"""Validation of the implicit step's wall stiffness (``warpcoil validate implicit-wall``):
the matrix carries the Jacobian of the wall's feature sum — on a flat face the law's
k n nᵀ, in a groove every pushing face's k n nᵀ — checked against central differences
of the force; and a coil pressed into a groove comes to rest at the longest settling step
where each face carries its share of the load (the net force's direction alone leaves
the second face's stiffness out, and the node then cycles at that step). Units mm, g,
s, µN.
"""

from __future__ import annotations

import math

import numpy as np
import trimesh

from .coil import CoilSpec
from .implicit import IMPLICIT_SETTLE_DT_MAX_S, ImplicitSolver
from .model import ModelBuilder
from .settings import SimulationSettings
from .solver import Control, SimulationUnstable, Stepper
from .state import new_state_like, state_from_positions
from .validation import REFERENCE_D_MM, CaseResult, _row
from .validation_friction import _overlap_for
from .wall import WallMesh

HALF_BOX_MM = 1.0
GROOVE_LOAD_UN = 300.0  # per interior node, along the groove's bisector: u ≈ 1.3 on each face
GROOVE_NODES = 5  # 1.2 mm: its ends clear of the box's other faces
REST_TIME_S = 0.1


def box_wall(half_mm: float = HALF_BOX_MM) -> WallMesh:
    """A closed cube of side 2 × ``half_mm`` centred at the origin (12 triangles)."""
    box = trimesh.creation.box(extents=(2.0 * half_mm,) * 3)
    return WallMesh(np.asarray(box.vertices, np.float64), np.asarray(box.faces, np.int32), float(box.volume), (),
                    None)


def stiffness_probe(centre_mm: np.ndarray, eps_mm: float = 1e-7) -> tuple[np.ndarray, np.ndarray]:
    """At the middle node of a 3-node coil along y centred at ``centre_mm`` in the box:
    the implicit matrix's wall stiffness and −∂F_wall/∂x by central differences
    (symmetric part; µN/mm), the wall queried through the BVH (float64)."""
    spec = CoilSpec(wire_diameter_mm=REFERENCE_D_MM, length_mm=2 * REFERENCE_D_MM)
    builder = ModelBuilder(wall=box_wall())
    builder.add_coil(spec, np.asarray(centre_mm) + np.array([[0.0, -spec.l0, 0.0], [0.0, 0.0, 0.0],
                                                               [0.0, spec.l0, 0.0]]))
    model = builder.finalize()
    state = state_from_positions(model, model.rest_positions)
    solver = ImplicitSolver(model, dt_s=1e-4, coil_contact=False, wall_query="bvh")
    solver.step(state, new_state_like(model), Control.create(model))
    matrix = solver.wall_stiffness.numpy()[1].copy()
    x0 = state.x.numpy().copy()  # (a CPU array's numpy() is a view)
    jacobian = np.zeros((3, 3))
    for a in range(3):
        forces = []
        for sign in (1.0, -1.0):
            x = x0.copy()
            x[1, a] += sign * eps_mm
            state.x.assign(x)
            solver.compute_contacts(state)
            forces.append(solver.wall_force.numpy()[1].copy())
        jacobian[:, a] = -(forces[0] - forces[1]) / (2.0 * eps_mm)
    return matrix, 0.5 * (jacobian + jacobian.T)


def groove_centre(clearance_mm: float) -> np.ndarray:
    """A point ``clearance_mm`` + d/2 from the faces x = +HALF and z = +HALF of the box."""
    inset = HALF_BOX_MM - 0.5 * REFERENCE_D_MM - clearance_mm
    return np.array([inset, 0.0, inset])


def stiffness_cases() -> list[CaseResult]:
    """The matrix against the force's Jacobian, on a face and in a groove (its second stiff direction)."""
    c0 = 0.1 * REFERENCE_D_MM
    face, face_fd = stiffness_probe(np.array([0.3, 0.1, HALF_BOX_MM - 0.5 * REFERENCE_D_MM + 0.5 * c0]))
    groove, groove_fd = stiffness_probe(groove_centre(-0.5 * c0))
    second = lambda k: float(np.sort(np.linalg.eigvalsh(k))[1])  # noqa: E731
    return [_row("implicit wall stiffness on a face: k (µN/mm) vs −∂F/∂x", float(face_fd[2, 2]), float(face[2, 2]),
                 1e-6),
            _row("implicit wall stiffness in a groove: 2nd stiff direction (µN/mm)", second(groove_fd),
                 second(groove), 1e-6)]


def groove_rest() -> list[CaseResult]:
    """A straight coil along a groove of the box, pressed into it along the bisector by
    a body load of GROOVE_LOAD_UN per interior node, at the longest settling step (2.5 ms) for
    REST_TIME_S, from ±0.2 c0 off its rest clearances (across the net force): it comes
    to rest (rms node speed), its middle node at the clearance where the law carries
    the load's share on each face (L/√2 each)."""
    spec = CoilSpec(wire_diameter_mm=REFERENCE_D_MM, length_mm=(GROOVE_NODES - 1) * REFERENCE_D_MM)
    builder = ModelBuilder(settings=SimulationSettings(damping_uN_per_mm=10.0), wall=box_wall())
    c0 = 0.1 * REFERENCE_D_MM
    s = (np.arange(GROOVE_NODES) - 0.5 * (GROOVE_NODES - 1)) * spec.l0
    expected = _overlap_for(GROOVE_LOAD_UN / math.sqrt(2.0), c0)
    # from the rest clearance, off by ±0.2 c0 (inside the contact range: the step starts with the stiffness)
    middle = groove_centre(expected) + 0.2 * c0 * np.array([1.0, 0.0, -1.0])
    start = middle[None, :] + np.outer(s, [0.0, 1.0, 0.0])
    builder.add_coil(spec, start)
    mass = spec.rho * spec.l0
    builder.body_acceleration(GROOVE_LOAD_UN / mass * np.array([1.0, 0.0, 1.0]) / math.sqrt(2.0))
    model = builder.finalize()
    solver = ImplicitSolver(model, dt_s=IMPLICIT_SETTLE_DT_MAX_S)
    stepper = Stepper(solver, state_from_positions(model, start), Control.create(model), chunk=10)
    try:
        stepper.run_steps(int(round(REST_TIME_S / solver.dt_s)))
    except SimulationUnstable:  # (the net force's direction alone: the node cycles, then runs away)
        return [CaseResult(f"implicit at the {IMPLICIT_SETTLE_DT_MAX_S * 1e3:g} ms settling step in a groove: unstable",
                           0.0, math.inf, math.inf, 1e-3)]
    state = stepper.state
    v = state.v.numpy()
    middle = state.x.numpy()[GROOVE_NODES // 2]
    gaps = HALF_BOX_MM - middle[[0, 2]] - 0.5 * REFERENCE_D_MM
    return [_row(f"implicit at the {IMPLICIT_SETTLE_DT_MAX_S * 1e3:g} ms settling step in a groove: rms node speed "
                 "(mm/s)", 0.0, float(np.sqrt((v**2).sum(axis=1).mean())), 1e-3),
            _row(f"... middle node clearance to each face (mm), load {GROOVE_LOAD_UN:g} µN on the bisector", expected,
                 float(gaps.mean()), 1e-3),
            _row("... the two faces' clearances agree (mm)", 0.0, float(gaps[0] - gaps[1]), 1e-6)]


def implicit_wall_cases() -> list[CaseResult]:
    return stiffness_cases() + groove_rest()
