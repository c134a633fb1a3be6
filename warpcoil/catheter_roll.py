"""The coil's roll about the catheter when it is packed (mm, nJ).

In a straight catheter every roll stores the same elastic energy, and the roll is counted from the
direction the wall defines (Anatomy.roll_reference). In a curved one it does not: a pre-curved coil
whose curvature lies against the bend stores more (a 30 mm helix of 3 mm loops through a quarter
arc of radius 3 mm: 22 421 nJ at the coordinate axes' roll, 16 607 nJ with its curvature along the
bend), and a coil in a frictionless catheter turns until it stores the least. The model's held edges
do not spin, so the packed coil starts at that roll: :func:`packed_rolls` scans it every
ROLL_SCAN_DEG, refines it every ROLL_FINE_DEG, then turns it by ``catheter.roll_deg``.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from .model import Model, default_director
from .orientation import tip_axis, turned
from .state import packed_state

ROLL_SCAN_DEG = 15.0
ROLL_FINE_DEG = 1.0
FLAT_ENERGY = 1.0e-9  # relative spread of the stored energy over the rolls below which the catheter is straight


def packed_rolls(model: Model, solver, anatomies: Sequence, gap_mm: float) -> list[np.ndarray | None]:
    """Per world, the direction normal to the catheter's tip axis that the packed coils' first director takes
    (packed_state's ``roll_references``): the wall's (Anatomy.roll_reference) in a straight catheter; in a
    curved one (a centerline along which the stored energy depends on the roll) the least-energy roll, turned
    by ``catheter.roll_deg``."""
    references = [a.roll_reference() for a in anatomies]
    curved = [w for w, a in enumerate(anatomies) if a.catheter.centerline_mm is not None]
    if not curved:
        return references
    axes = {w: tip_axis(anatomies[w].catheter) for w in curved}
    base = {w: references[w] if references[w] is not None else default_director(-axes[w]) for w in curved}

    def stored(offsets: dict[int, float]) -> dict[int, float]:
        trial = list(references)
        for w in curved:
            trial[w] = turned(base[w], axes[w], offsets[w])
        per_node = solver.elastic_energy_per_node(packed_state(model, gap_mm, trial))
        return {w: float(per_node[model.world_nodes(w)].sum()) for w in curved}

    scan = np.arange(0.0, 360.0, ROLL_SCAN_DEG)
    energies = [stored({w: a for w in curved}) for a in scan]
    best = {w: float(scan[int(np.argmin([e[w] for e in energies]))]) for w in curved}
    fine = np.arange(-ROLL_SCAN_DEG, ROLL_SCAN_DEG + 0.5 * ROLL_FINE_DEG, ROLL_FINE_DEG)
    refined = [stored({w: best[w] + f for w in curved}) for f in fine]
    for w in curved:
        values = [e[w] for e in energies]
        if max(values) - min(values) <= FLAT_ENERGY * max(abs(max(values)), 1.0):
            continue  # a straight centerline: every roll stores the same, the wall's reference stays
        least = best[w] + float(fine[int(np.argmin([e[w] for e in refined]))])
        references[w] = turned(base[w], axes[w], least + anatomies[w].catheter.roll_deg)
    return references
