"""State: everything that changes in time, as device arrays (mm, mm/s, rad/s)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from .kernels import integrate
from .model import Model, default_director, transport
from .orientation import normal_part

ALL_OUT_MM = 1.0e9  # a pusher advance that puts every node past the tip (free space)


@dataclass
class State:
    x: wp.array  # node positions, mm
    v: wp.array  # node velocities, mm/s
    m1: wp.array  # edge material directors (unit)
    omega: wp.array  # edge twist rates, rad/s
    free: wp.array  # 1 where a node has free dynamics
    advance: wp.array  # per coil pusher advance, mm (node i is out when advance − s_i ≥ 0)
    x_prev: wp.array  # node positions one step earlier, mm (the BDF2 step's history)
    v_prev: wp.array  # node velocities one step earlier, mm/s
    time_s: float = 0.0
    history_dt_s: float = 0.0  # the step (s) that led from (x_prev, v_prev) here; 0: no history

    def copy_from(self, other: "State") -> None:
        for name in ("x", "v", "m1", "omega", "free", "advance", "x_prev", "v_prev"):
            wp.copy(getattr(self, name), getattr(other, name))
        self.time_s = other.time_s
        self.history_dt_s = other.history_dt_s


def _free_flags(model: Model, advance: np.ndarray) -> np.ndarray:
    coil_of = model.coil_of.numpy()
    sigma = advance[coil_of] - model.arc_s.numpy()
    return ((sigma >= 0.0) & (model.fixed.numpy() == 0)).astype(np.int32)


def _state(model: Model, x: np.ndarray, m1: np.ndarray, advance: np.ndarray) -> State:
    n = model.node_count
    return State(
        x=model.array(x, wp.vec3d), v=wp.zeros(n, dtype=wp.vec3d, device=model.device),
        m1=model.array(m1, wp.vec3d), omega=wp.zeros(n, dtype=wp.float64, device=model.device),
        free=model.array(_free_flags(model, advance), wp.int32), advance=model.array(advance, wp.float64),
        x_prev=model.array(x, wp.vec3d), v_prev=wp.zeros(n, dtype=wp.vec3d, device=model.device),
    )


def state_from_positions(model: Model, positions_mm: np.ndarray, first_directors: np.ndarray | None = None) -> State:
    """A state at rest with the given positions, every node free (no catheter), and
    twist-free directors carried along each coil."""
    positions_mm = np.asarray(positions_mm, dtype=np.float64)
    advance = np.full(model.coil_count, ALL_OUT_MM)
    return _state(model, positions_mm, model.directors_along(positions_mm, first_directors), advance)


def rest_state(model: Model) -> State:
    """Each coil in its pre-shape, at rest, free."""
    return state_from_positions(model, model.rest_positions)


def packed_state(model: Model, gap_mm: float = 1.0, roll_references: list[np.ndarray | None] | None = None) -> State:
    """The coils packed in the catheter, one behind the other (``gap_mm`` apart),
    the first coil's distal node at the tip (in each world, in its own
    catheter); directors carried along the catheter so each edge keeps its
    pre-shape frame orientation (MODEL.md, Step 2). ``roll_references`` (per world, a unit
    vector normal to the catheter at its tip, or None): each coil's first director is that vector
    carried back along the catheter to the coil's first edge (:func:`carried_back`), its part normal
    to that edge (the coil's roll about the catheter; catheter_roll.packed_rolls), else the model's
    default."""
    lengths = model.host("arc_s")[model.coil_last]
    advance = np.zeros(model.coil_count)
    for w in range(model.world_count):
        coils = model.world_coils(w)
        sl = slice(coils.start, coils.stop)
        advance[sl] = -np.concatenate([[0.0], np.cumsum(lengths[sl] + gap_mm)[:-1]])
    x = wp.zeros(model.node_count, dtype=wp.vec3d, device=model.device)
    wp.launch(integrate.place_on_catheter, model.node_count, device=model.device, inputs=[
        model.arc_s, model.coil_of, model.world_of, model.array(advance, wp.float64), model.catheter_path,
        model.catheter_first, model.catheter_count, x])
    positions = x.numpy()
    first = None
    if roll_references is not None and any(r is not None for r in roll_references):
        first = []
        coil_world = model.host("coil_world")
        path, path_first, path_count = (model.host(k) for k in ("catheter_path", "catheter_first", "catheter_count"))
        for c, f in enumerate(model.coil_first):
            tangent = positions[f + 1] - positions[f]
            tangent = tangent / np.linalg.norm(tangent)
            w = int(coil_world[c])
            reference = roll_references[w]
            if reference is not None:  # (a coil behind another: its depth in the catheter, −advance)
                start = int(path_first[w])
                reference = carried_back(reference, path[start:start + int(path_count[w])], -float(advance[c]))
            director = None if reference is None else normal_part(reference, tangent)
            first.append(default_director(tangent) if director is None else director)
        first = np.stack(first)
    return _state(model, positions, model.directors_along(positions, first), advance)


def carried_back(reference: np.ndarray, path_mm: np.ndarray, depth_mm: float) -> np.ndarray:
    """``reference`` (normal to the catheter at its tip) carried by parallel transport back along the catheter
    centerline ``path_mm`` (proximal → tip, as kernels/integrate.catheter_point reads it) to ``depth_mm``
    behind the tip: unchanged along a straight catheter."""
    d = np.asarray(reference, dtype=np.float64)
    k = len(path_mm) - 1
    ahead = path_mm[k] - path_mm[k - 1]
    remaining = depth_mm - float(np.linalg.norm(ahead))
    while k > 1 and remaining > 0.0:
        k -= 1
        behind = path_mm[k] - path_mm[k - 1]
        d = transport(d[None], ahead[None] / np.linalg.norm(ahead), behind[None] / np.linalg.norm(behind))[0]
        ahead = behind
        remaining -= float(np.linalg.norm(behind))
    return d


def new_state_like(model: Model) -> State:
    """An uninitialised state of the model's sizes (the output buffer of a step)."""
    n = model.node_count
    dev = model.device
    return State(
        x=wp.zeros(n, dtype=wp.vec3d, device=dev), v=wp.zeros(n, dtype=wp.vec3d, device=dev),
        m1=wp.zeros(n, dtype=wp.vec3d, device=dev), omega=wp.zeros(n, dtype=wp.float64, device=dev),
        free=wp.zeros(n, dtype=wp.int32, device=dev), advance=wp.zeros(model.coil_count, dtype=wp.float64, device=dev),
        x_prev=wp.zeros(n, dtype=wp.vec3d, device=dev), v_prev=wp.zeros(n, dtype=wp.vec3d, device=dev),
    )
