"""warpcoil: mechanics-based virtual coiling of intracranial aneurysms in NVIDIA Warp.

Units everywhere: mm, g, s (forces µN, energies nJ, EI µN·mm²).
"""

from . import _warp  # noqa: F401  (kernel cache and Warp init before any kernel)
from . import metrics
from .coil import CoilSpec
from .model import Model, ModelBuilder
from .settings import CatheterSpec, ContactSettings, Scene, SimulationSettings, WallSpec
from .solver import Control, SimulationUnstable, Solver, Stepper, UnstableStepError, stable_step_bound
from .state import State, packed_state, rest_state, state_from_positions

__all__ = [
    "CatheterSpec", "CoilSpec", "ContactSettings", "Control", "Model", "ModelBuilder", "Scene",
    "SimulationSettings", "SimulationUnstable", "Solver", "State", "Stepper", "UnstableStepError",
    "WallSpec", "metrics", "packed_state", "rest_state", "stable_step_bound", "state_from_positions",
]
__version__ = "0.1.0"
