"""The balloon's and the stent's contact stiffness in the implicit step: the
matrix against finite differences of the force (exact along the contact normal;
Gauss–Newton drops the stated curvature term), energy/force consistency, and
implicit deployments that keep every node outside the balloon and inside the wall."""

import math
from pathlib import Path

import numpy as np
import pytest

from warpcoil import validation, validation_devices
from warpcoil.coil import CoilSpec
from warpcoil.deploy import Deployment
from warpcoil.implicit import EULER, ImplicitSolver
from warpcoil.model import ModelBuilder
from warpcoil.scene import load_scene
from warpcoil.settings import ContactSettings, SimulationSettings
from warpcoil.solver import Control
from warpcoil.state import new_state_like, state_from_positions

from test_implicit import blocks_dense

P0, C0, R_NODE = 1.0e3, 0.03, 0.15  # µN, mm, mm
BALLOON_R = 1.0  # mm, a straight balloon along z
DT = 1.0e-4  # s


def edge_model(balloon: bool, segments: int = 2, strut: tuple | None = None):
    """A straight coil of ``segments`` edges at rest length along z (no elastic force),
    beside a balloon or a stent strut; undamped."""
    spec = CoilSpec(wire_diameter_mm=2 * R_NODE, length_mm=0.3 * segments, segment_length_mm=0.3)
    rest = np.zeros((segments + 1, 3))
    rest[:, 2] = np.arange(segments + 1) * 0.3
    builder = ModelBuilder(settings=SimulationSettings(damping_uN_per_mm=0.0), contact=ContactSettings(P0_uN=P0, c0_mm=C0))
    builder.add_coil(spec, rest)
    if balloon:
        builder.balloon = (np.array([[0.0, 0.0, -3.0], [0.0, 0.0, 3.0]]), np.full(2, BALLOON_R))
    if strut is not None:
        builder.stent = (np.array([strut[0]]), np.array([strut[1]]), 0.035)
    return builder.finalize(), rest


def system_and_forces(model, x):
    """(M + dt² H, the force at x as a function of positions, M) of one implicit step at x
    (θ = 1: the matrix of the linearly implicit Euler step)."""
    solver = ImplicitSolver(model, dt_s=DT, **EULER)  # the tangent stiffness: the law's Hessian
    state = state_from_positions(model, x)
    solver.allocate_neighbour_grid(state)
    solver.step(state, new_state_like(model), Control.create(model))
    a = blocks_dense(solver, model.node_count)

    def force(y):
        s = state_from_positions(model, y)
        solver.compute_forces(s)
        return solver.force.numpy().copy()

    return a, force, np.kron(np.diag(1.0 / model.inv_mass.numpy()), np.eye(3))


def law(gap):
    u = 1.0 - gap / C0
    return P0 / (math.e - 1.0) * u * (math.exp(u) - 1.0), P0 / ((math.e - 1.0) * C0) * (math.exp(u) * (1 + u) - 1)


@pytest.mark.parametrize("gap", [0.02, 0.0, -0.02])
def test_balloon_stiffness_is_the_force_jacobian_less_its_curvature_term(gap):
    """Nodes pressed on a straight balloon (gap in c0 units 0.67, 0, −0.67): the
    matrix's device part (A − M)/dt² equals the central-difference Jacobian of −F
    plus the curvature term F/ρ (I − n nᵀ − t tᵀ) (ρ: distance to the axis) that
    Gauss–Newton drops, and is exact along the normal; each node's law is weighted
    by its contact share (½ at the coil's free ends, as its mass)."""
    model, rest = edge_model(balloon=True)
    x = rest + [BALLOON_R + R_NODE + gap, 0.0, 0.0]
    a, force, mass = system_and_forces(model, x)
    hessian = (a - mass) / DT**2
    eps = 1e-7
    fd = np.zeros_like(hessian)
    for k in range(x.size):
        y_plus, y_minus = x.copy(), x.copy()
        y_plus.flat[k] += eps
        y_minus.flat[k] -= eps
        fd[:, k] = -(force(y_plus) - force(y_minus)).ravel() / (2 * eps)
    magnitude, stiffness = law(gap)
    share = model.contact_share.numpy()
    assert share == pytest.approx([0.5, 1.0, 0.5])
    assert force(x)[:, 0] == pytest.approx(share * magnitude, rel=1e-12)
    rho = BALLOON_R + R_NODE + gap
    curvature = magnitude / rho * np.diag([0.0, 1.0, 0.0])  # I − n nᵀ − t tᵀ with n = x̂, t = ẑ
    expected = fd + np.kron(np.diag(share), curvature)
    assert np.abs(hessian - expected).max() <= 2e-6 * np.abs(fd).max()
    bare, _, _ = system_and_forces(edge_model(balloon=False)[0], x)
    device = (a - bare) / DT**2
    assert device == pytest.approx(np.kron(np.diag(share), stiffness * np.diag([1.0, 0, 0])), rel=1e-9,
                                   abs=1e-9 * stiffness)  # s_i k n nᵀ on each node


def test_strut_stiffness_is_exact_along_the_normal_and_couples_the_edge_nodes():
    """An edge across a strut: the matrix's device part is k w wᵀ ⊗ n nᵀ with
    w = (1 − s, s) the closest point's weights (off-diagonal block within the band);
    moving the edge rigidly along n, (A − M)/dt² u equals the central difference of −F
    (the curvature terms of the closest-point parameters vanish for that motion)."""
    s = 0.3  # the strut crosses the edge 30 % along it
    gap = 0.01
    height = R_NODE + 0.035 + gap
    strut = ((-height, -2.0, 0.09), (-height, 2.0, 0.09))
    model, rest = edge_model(balloon=False, strut=strut)
    a, force, _ = system_and_forces(model, rest)
    bare, _, _ = system_and_forces(edge_model(balloon=False)[0], rest)
    device = (a - bare) / DT**2
    _, stiffness = law(gap)
    w = np.array([1 - s, s])
    n = np.array([1.0, 0.0, 0.0])
    expected = np.zeros_like(device)
    expected[:6, :6] = stiffness * np.kron(np.outer(w, w), np.outer(n, n))  # edge 0's two nodes
    assert device == pytest.approx(expected, rel=1e-7, abs=1e-7 * stiffness)
    eps = 1e-7
    u = np.tile(n, model.node_count)
    rate = -(force(rest + eps * n) - force(rest - eps * n)).ravel() / (2 * eps)
    assert device @ u == pytest.approx(rate, rel=1e-6, abs=1e-6 * stiffness)
    assert np.linalg.eigvalsh(a).min() > 0.0  # positive definite


def test_balloon_force_is_minus_the_gradient_of_the_law_potential():
    """Energy/force consistency: the balloon force on a node equals −dΦ/dx of the
    law's potential Φ(g) = ∫_g^c0 |F| (central differences of Φ at the node), times
    the node's contact share (½ at the coil's end)."""
    model, rest = edge_model(balloon=True)
    direction = np.array([0.6, 0.8, 0.0])
    x = rest + (BALLOON_R + R_NODE + 0.01) * direction
    solver = ImplicitSolver(model, dt_s=DT)
    solver.compute_forces(state_from_positions(model, x))
    f = solver.force.numpy()[0]
    share = model.contact_share.numpy()[0]
    assert share == pytest.approx(0.5)

    def potential(p):
        g = np.linalg.norm(p[:2]) - BALLOON_R - R_NODE
        grid = np.linspace(g, C0, 4001)
        return share * np.trapezoid([law(h)[0] for h in grid], grid)

    eps = 1e-6
    grad = [(potential(x[0] + eps * e) - potential(x[0] - eps * e)) / (2 * eps) for e in np.eye(3)]
    assert f == pytest.approx(-np.asarray(grad), rel=1e-5, abs=1e-6 * np.linalg.norm(f))


ASSISTED = ('[wall]\nsphere_diameter_mm = 4.0\n[catheter]\ntip = [0.0, 0.0, -1.5]\n'
            '[[coil]]\nshape = "helix"\nwire_diameter_mm = 0.2921\nloop_diameter_mm = 2.0\nlength_mm = 5\n'
            '[simulation]\npush_speed_mm_s = 100.0\nframe_interval_s = 0.002\nintegrator = "{integrator}"\n')
BALLOON = '[balloon]\naxis = [[-1.2, 0.8, -0.3], [1.2, 0.8, -0.3]]\ndiameter_mm = 0.8\ndeflation_time_s = 0.02\n'


def balloon_gaps(model, x, radius_mm):
    """Each node's clearance to the inflated balloon (mm) from the model's stations."""
    stations, cap = model.balloon_stations.numpy(), model.balloon_cap_radius.numpy()
    count = int(model.balloon_count.numpy()[0])
    fraction = float(model.balloon_inflation.numpy()[0])
    best = np.full(len(x), np.inf)
    for k in range(count - 1):
        a, b = stations[k], stations[k + 1]
        t = np.clip((x - a) @ (b - a) / ((b - a) @ (b - a)), 0.0, 1.0)
        dist = np.linalg.norm(x - (a + t[:, None] * (b - a)), axis=1)
        best = np.minimum(best, dist - fraction * ((1 - t) * cap[k] + t * cap[k + 1]))
    return best - radius_mm


def balloon_run(path: Path, integrator: str):
    """(result, deepest balloon overlap mm, node-frames touching it) of the assisted
    scene on ``integrator``, checked at every frame while the balloon is inflated."""
    path.write_text(ASSISTED.format(integrator=integrator) + BALLOON)
    deployment = Deployment(load_scene(path))
    model = deployment.model
    worst = {"balloon": np.inf, "touching": 0}

    def check(frame, state):
        free = state.free.numpy() == 1
        if frame.balloon_inflation == 1.0 and free.any():
            gaps = balloon_gaps(model, state.x.numpy()[free], model.node_radius.numpy()[free])
            worst["balloon"] = min(worst["balloon"], gaps.min())
            worst["touching"] += int((gaps < model.contact.c0_mm).sum())

    return deployment, deployment.run(check), worst["balloon"], worst["touching"]


def test_implicit_balloon_deployment_keeps_the_coil_outside_the_balloon_and_inside_the_wall(tmp_path: Path):
    """A 5 mm helix pushed past an inflated balloon across a 4 mm sphere, deflated
    after detachment: at every frame every free node's centre is outside the balloon
    and inside the wall, the coil pressing no deeper into either than on the reference
    step (which reaches 1.7 c0 into the balloon), at a step 8× the reference's."""
    implicit, result, overlap, touching = balloon_run(tmp_path / "i.toml", "implicit")
    reference, expected, overlap_ref, _ = balloon_run(tmp_path / "s.toml", "symplectic")
    c0 = implicit.model.contact.c0_mm
    assert isinstance(implicit.solver, ImplicitSolver)
    assert result.status == expected.status == "completed"
    assert touching > 0  # the coil did press on the balloon
    radius = 0.5 * implicit.model.coils[0].d
    assert -radius < overlap and -radius < result.min_wall_gap_mm  # every node centre outside the balloon, inside the wall
    assert overlap >= overlap_ref - 0.1 * c0 and result.min_wall_gap_mm >= expected.min_wall_gap_mm - 0.1 * c0
    assert implicit.solver.dt_s > 5 * reference.solver.dt_s


STENT = '[stent]\naxis = [[-0.02, 0.013, -1.5], [0.02, 0.013, 1.5]]\ndiameter_mm = 4.5\ncell_size_mm = 1.5\n'


def strut_gaps(x, has_next, radius, starts, ends, strut_radius):
    """Each coil edge's smallest clearance to the struts (mm; closest points by dense sampling)."""
    edges = np.flatnonzero(has_next)
    s = np.linspace(0.0, 1.0, 21)
    points = x[edges, None, :] + s[None, :, None] * (x[edges + 1] - x[edges])[:, None, :]  # (E, 21, 3)
    d = ends - starts
    rel = points[:, :, None, :] - starts[None, None]  # (E, 21, S, 3)
    t = np.clip((rel * d).sum(-1) / (d * d).sum(-1), 0.0, 1.0)
    dist = np.linalg.norm(rel - t[..., None] * d, axis=-1).min(axis=(1, 2))
    return dist - radius[edges] - strut_radius


def test_implicit_stent_deployment_keeps_the_coil_off_the_struts(tmp_path: Path):
    """The helix deployed inside a stent apposed to the sphere: at every frame every
    free edge stays less than c0 into every strut (it touches them, it does not pass)
    and every node inside the wall."""
    path = tmp_path / "s.toml"
    path.write_text(ASSISTED.format(integrator="implicit") + STENT)
    deployment = Deployment(load_scene(path))
    model = deployment.model
    starts, ends, _ = model.strut_host
    has_next, radius = model.has_next.numpy(), model.node_radius.numpy()
    c0 = model.contact.c0_mm
    worst = {"gap": np.inf, "touching": 0}

    def check(frame, state):
        free = state.free.numpy() == 1
        gaps = strut_gaps(state.x.numpy(), has_next * free * np.roll(free, -1), radius, starts, ends,
                          model.strut_radius_mm)
        if gaps.size:
            worst["gap"] = min(worst["gap"], gaps.min())
            worst["touching"] += int((gaps < c0).sum())

    result = deployment.run(check)
    assert result.status == "completed"
    assert worst["touching"] > 0
    assert worst["gap"] > -c0 and result.min_wall_gap_mm > -c0


def test_validate_implicit_devices_rest_cases():
    """`warpcoil validate implicit-devices`, its static part: the balloon and two struts
    carry a uniform load at the law's clearance, at the implicit default step."""
    rows = validation_devices.balloon_rest() + validation_devices.stent_rest()
    failed = [r for r in rows if not r.passed]
    assert not failed, validation.format_table(failed)


def test_validate_implicit_devices_converges_to_the_reference():
    """Shortened (two step sizes, 1 ms): the helix closing onto the balloon converges to
    the reference as dt halves, the balloon pressed at the end."""
    rows = validation_devices.balloon_convergence(time_s=1.0e-3, factors=(0.2, 0.1))
    failed = [r for r in rows if not r.passed]
    assert not failed, validation.format_table(failed)
    assert rows[0].result > rows[1].result
