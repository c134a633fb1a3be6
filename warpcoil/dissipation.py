"""The integrator's numerical dissipation, measured by the energy balance of each step
(issue 11, dissipation; docs/FORMULATION.md "Implicit step: numerical dissipation").

Per step n → n+1 of one world (energies nJ, forces µN, positions mm):

    numerical = pusher work − ΔE − physical damping work

    ΔE        = Δ(kinetic: free nodes + edge spins) + Δ(stretch + bend + twist, exact)
                + Δ(contact energy: −½ Σ (f_c,n + f_c,n+1)·Δx, trapezoid over every node)
    pusher    = −½ Σ_held (f_n + f_n+1)·Δx  (the catheter's constraint force on the nodes it
                carries, f the conservative force: elastic + contact)
    physical  = dt Σ_free c (1 − exp(−|v'|/k)) |v'| + dt Σ_edges b ω'²  (the model's damping law
                at the new velocities, MODEL.md)

For linearly implicit Euler on a linear system M Δv = dt (−K x' − C v') the balance is
exactly numerical = ½ Δvᵀ M Δv + ½ Δxᵀ K Δx ≥ 0 (validation_dissipation.chain_rows):
per unit time ≈ ½ dt ω² × (a mode's energy), first order in dt once dt ω ≪ 1, and all
of a mode's energy when dt ω ≳ 1. Under the θ-method (the default gated_chord, θ 0.65) the
damping acts at (1 − θ) v + θ v', not at v': the difference between the two damping works is
booked as numerical (first order in dt like the rest). The trapezoid terms are second order. Not booked: the
fold force (a coil's contact with its own near neighbours, elastic.fold_force): its work
on the free nodes counts as numerical dissipation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .solver import Control, Solver
from .state import State, new_state_like


@dataclass
class DissipationTotals:
    """Energy ledger of a run (nJ)."""

    pusher_work_nJ: float = 0.0
    physical_nJ: float = 0.0
    numerical_nJ: float = 0.0
    steps: int = 0

    @property
    def ratio(self) -> float:
        """Numerical / physical dissipation (nan before any physical dissipation)."""
        return self.numerical_nJ / self.physical_nJ if self.physical_nJ > 0.0 else math.nan


@dataclass(frozen=True)
class StepLedger:
    """One step's energy balance (nJ): changes of kinetic, elastic and contact energy,
    the pusher's work and the model's damping work."""

    pusher_nJ: float
    kinetic_nJ: float
    elastic_nJ: float
    contact_nJ: float
    physical_nJ: float

    @property
    def numerical_nJ(self) -> float:
        """What the step removed beyond the model's damping: work − ΔE − physical."""
        return self.pusher_nJ - self.kinetic_nJ - self.elastic_nJ - self.contact_nJ - self.physical_nJ


class DissipationMeter:
    """Steps ``solver`` one step at a time (no graph) on world 0 of a one-world model and
    books each step's energy balance (module docstring) into ``totals``."""

    def __init__(self, solver: Solver, state: State, control: Control):
        if solver.model.world_count != 1:
            raise ValueError("DissipationMeter measures a one-world model")
        self.solver, self.control = solver, control
        m = solver.model
        self._a, self._b = state, new_state_like(m)
        self._b.copy_from(state)
        self._damping_c = m.damping_c.numpy()
        self._damping_k = float(m.damping_k)
        self._twist_damping = m.twist_damping.numpy()
        self._fixed = m.fixed.numpy() != 0
        self.totals = DissipationTotals()

    @property
    def state(self) -> State:
        return self._a

    def _energy(self, state: State) -> tuple[float, float]:
        """(kinetic, elastic) energy of ``state`` (nJ)."""
        energies, _ = self.solver.world_energies(state)
        elastic = float(energies["stretch_nJ"][0] + energies["bend_nJ"][0] + energies["twist_nJ"][0])
        return float(energies["kinetic_nJ"][0]), elastic

    def step(self, dt: float | None = None) -> StepLedger:
        """One step of ``dt`` (s; default the solver's), booked into ``totals``; returns its ledger."""
        s = self.solver
        dt = s.dt_s if dt is None else dt
        a, b = self._a, self._b
        kin0, el0 = self._energy(a)
        x0 = a.x.numpy().copy()
        s.step(a, b, self.control, dt)
        f0, fc0 = s.force.numpy().copy(), s.contact_force.numpy().copy()  # the step's forces at its start
        s.compute_forces(b, self.control.running)
        f1, fc1 = s.force.numpy(), s.contact_force.numpy()
        kin1, el1 = self._energy(b)
        dx = b.x.numpy() - x0
        free = (b.free.numpy() != 0) & ~self._fixed
        held = ~free & ~self._fixed
        speed = np.linalg.norm(b.v.numpy()[free], axis=1)
        physical = dt * (float(np.sum(self._damping_c[free] * (1.0 - np.exp(-speed / self._damping_k)) * speed))
                         + float(np.sum(self._twist_damping * b.omega.numpy() ** 2)))
        one = StepLedger(pusher_nJ=-0.5 * float(np.sum((f0[held] + f1[held]) * dx[held])),
                         kinetic_nJ=kin1 - kin0, elastic_nJ=el1 - el0,
                         contact_nJ=-0.5 * float(np.sum((fc0 + fc1) * dx)), physical_nJ=physical)
        self._a, self._b = b, a
        t = self.totals
        self.totals = DissipationTotals(t.pusher_work_nJ + one.pusher_nJ, t.physical_nJ + physical,
                                        t.numerical_nJ + one.numerical_nJ, t.steps + 1)
        return one

