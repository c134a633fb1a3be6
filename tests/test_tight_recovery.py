"""A close-wound helix (turns 10 µm apart, inside the contact onset c0) released with
coil contact on (validate tight-pitch; docs/FORMULATION.md, "Tight pitch from straight")."""

import numpy as np

import warpcoil as wc
from warpcoil import preshape
from warpcoil.metrics import fit_helix
from warpcoil.settings import DEFAULT_DT_SAFETY, SimulationSettings
from warpcoil.validation import TIGHT_HELIX, TIGHT_STRETCH, _recovered

D = 0.2921
SHORT = dict(TIGHT_HELIX, length_mm=10.0)  # three turns


def distances(x: np.ndarray) -> np.ndarray:
    return np.linalg.norm(x[:, None] - x[None], axis=2)


def test_a_stretched_tight_helix_closes_onto_its_pre_shape():
    """Released from twice its pitch, the turns close in order and stop at their rest
    clearance: the rest shape itself (every node-to-node distance within 1 µm of the
    pre-shape's, a rigid-motion-free comparison), pitch and loop within 1 %."""
    damping = SimulationSettings().damping_uN_per_mm
    x = _recovered(None, DEFAULT_DT_SAFETY, SHORT, True, damping, stretch=TIGHT_STRETCH)
    spec = wc.CoilSpec(wire_diameter_mm=D, shape="helix", **SHORT)
    rest = preshape.helix(spec.loop_diameter_mm, spec.helix_pitch_mm, spec.length_mm, spec.l0)
    assert np.abs(distances(x) - distances(rest)).max() < 1e-3
    fit = fit_helix(x)
    assert abs(fit.pitch_mm / SHORT["pitch_mm"] - 1.0) < 1e-2
    assert abs(fit.loop_diameter_mm / SHORT["loop_diameter_mm"] - 1.0) < 1e-2


def segment_distances(x: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """Closest distance between segments (x_i, x_i+1) and (x_j, x_j+1), mm (Ericson §5.1.9)."""
    p1, d1, p2, d2 = x[i], x[i + 1] - x[i], x[j], x[j + 1] - x[j]
    r = p1 - p2
    a, e = (d1 * d1).sum(1), (d2 * d2).sum(1)
    b, c, f = (d1 * d2).sum(1), (d1 * r).sum(1), (d2 * r).sum(1)
    denom = a * e - b * b
    s = np.where(denom > 1e-14 * a * e, np.clip((b * f - c * e) / np.where(denom > 0, denom, 1.0), 0, 1), 0.0)
    t = (b * s + f) / e
    s = np.where(t < 0, np.clip(-c / a, 0, 1), np.where(t > 1, np.clip((b - c) / a, 0, 1), s))
    t = np.clip(t, 0, 1)
    return np.linalg.norm(p1 + s[:, None] * d1 - p2 - t[:, None] * d2, axis=1)


def test_a_straight_start_whips_its_turns_together_without_crossing():
    """Started straight, the short tight helix forms its turns in a whip (speeds of
    up to ~4 m/s). Every pair of segments that are not bonded neighbours stays
    apart by more than d/2 between their centrelines, sampled every second step, and
    no pair changes the sign of its crossing orientation (the volume spanned by the
    two segments) while close: no segment tunnels through another."""
    spec = wc.CoilSpec(wire_diameter_mm=D, shape="helix", **SHORT)
    builder = wc.ModelBuilder()
    builder.add_coil(spec)
    model = builder.finalize()
    start = np.zeros((model.node_count, 3))
    start[:, 0] = model.arc_s.numpy()
    solver = wc.Solver(model)
    stepper = wc.Stepper(solver, wc.state_from_positions(model, start), wc.Control.create(model), chunk=2)
    i, j = np.triu_indices(model.node_count - 1, k=model.contact.exclusion_edges + 1)
    closest, fastest, orientation = np.inf, 0.0, None
    while stepper.state.time_s < 0.02:
        state = stepper.run_chunk()
        x = state.x.numpy()
        gap = segment_distances(x, i, j)
        closest = min(closest, gap.min())
        fastest = max(fastest, np.linalg.norm(state.v.numpy(), axis=1).max())
        volume = np.einsum("ij,ij->i", np.cross(x[i + 1] - x[i], x[j + 1] - x[j]), x[j] - x[i])
        if orientation is not None:
            assert not np.any((np.sign(volume) != orientation) & (gap < 0.5 * D))
        orientation = np.sign(volume)
    assert fastest > 1000.0  # a real whip
    assert closest > 0.5 * D
