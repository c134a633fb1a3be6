"""The neighbour lists walked per world (contact.walk_neighbours, no hash grid) are the
grid's lists, as sets, edge by edge (overflowed lists too), and a run built on them is
the grid-built run bit for bit (the contact pass's sums do not depend on list order)."""

from dataclasses import replace

import numpy as np
import pytest

import warpcoil as wc
from warpcoil.deploy import Ensemble, build_model
from warpcoil.implicit import ImplicitSolver
from warpcoil.solver import NEIGHBOUR_WALK_MAX_NODES
from test_deploy import two_coil_scene

from benchmarks.neighbour_build import lists


def built_lists(model, x: np.ndarray, how: str, **options) -> tuple[list, wc.Solver]:
    solver = wc.Solver(model, dt_s=1.0e-6, allow_unstable_dt=True, neighbour_build=how, **options)
    state = wc.packed_state(model, gap_mm=1.0)
    state.x.assign(x)
    solver.allocate_neighbour_grid(state)
    return lists(solver), solver


def shapes(model) -> dict[str, np.ndarray]:
    """Node positions to build at: the coils strung along the catheter, the coils at their
    pre-shapes (dense: every loop within the loop diameter), the pre-shape with the
    second coil's edges stretched to 3× (the walk's skip bound is the coil's longest step),
    the pre-shape with every node moved at random (uneven steps, one edge 2 mm long), and a
    world gone unstable: one node NaN, the first coil's start 50 mm away (no skip bound)."""
    rest = model.rest_x.numpy()
    stretched = rest.copy()
    second = model.node_slice(1)
    stretched[second] = rest[second][0] + 3.0 * (rest[second] - rest[second][0])
    shaken = rest + np.random.default_rng(7).normal(scale=0.2, size=rest.shape)
    shaken[second.start + 5:second.stop] += [2.0, 0.0, 0.0]
    unstable = rest.copy()
    first = model.node_slice(0)
    unstable[first.start:first.start + 10] += [50.0, 0.0, 0.0]
    unstable[first.start + 10] = np.nan
    return {"catheter": wc.packed_state(model, gap_mm=1.0).x.numpy(), "pre-shape": rest, "stretched": stretched,
            "shaken": shaken, "unstable": unstable}


@pytest.mark.parametrize("capacity", [64, 3], ids=["lists", "overflowing lists"])
def test_walked_lists_are_the_grids(capacity):
    model = build_model(two_coil_scene())
    for name, x in shapes(model).items():
        grid, _ = built_lists(model, x, "grid", neighbour_capacity=capacity)
        walked, solver = built_lists(model, x, "walk", neighbour_capacity=capacity)
        assert walked == grid, name
        assert any(len(row) > 0 for row in grid if row is not None), name  # there was something to find
        if capacity == 3 and name in ("pre-shape", "stretched"):
            assert None in walked and solver._list_overflow.numpy()[0] == 1  # the grid is built for those


def test_ensemble_worlds_walk_their_own_edges():
    """Two worlds at the same place: each edge lists only its own world's edges."""
    scene = two_coil_scene()
    one = build_model(scene)
    two = Ensemble([scene, scene]).model
    x = np.concatenate([one.rest_x.numpy()] * 2)
    grid, _ = built_lists(two, x, "grid")
    walked, _ = built_lists(two, x, "walk")
    assert walked == grid
    n = one.node_count
    single, _ = built_lists(one, one.rest_x.numpy(), "walk")
    assert walked[:n] == single and walked[n:] == [None if r is None else tuple(b + n for b in r) for r in single]


def run_implicit(how: str, capacity: int, steps: int = 240) -> dict[str, np.ndarray]:
    """The two-coil scene pushed on the implicit step, graph-captured (the rebuild, and in the
    walk an overflow's grid build, as conditional nodes)."""
    scene = two_coil_scene()
    model = build_model(scene)
    solver = ImplicitSolver(model, dt_s=2.0e-4, neighbour_build=how, neighbour_capacity=capacity)
    control = wc.Control.create(model, active_coil=0, push_speed_mm_s=scene.simulation.push_speed_mm_s)
    stepper = wc.Stepper(solver, wc.packed_state(model, gap_mm=1.0), control, chunk=40)
    overflowed = 0
    for _ in range(steps // stepper.chunk):
        stepper.run_chunk()
        overflowed += bool((solver._neighbour_count.numpy() == -1).any())
    state = stepper.state
    out = {name: getattr(state, name).numpy().copy() for name in ("x", "v", "m1", "omega")}
    out["overflowed"] = overflowed
    return out


@pytest.mark.parametrize("capacity, steps", [(64, 240), (1, 400)], ids=["lists", "overflowing lists"])
def test_walked_run_is_the_grid_run(capacity, steps):
    grid, walked = run_implicit("grid", capacity, steps), run_implicit("walk", capacity, steps)
    if capacity == 1:
        assert walked["overflowed"] > 0  # the grid built inside the captured steps did the work
    for name in ("x", "v", "m1", "omega"):
        assert np.array_equal(grid[name], walked[name]), name


def test_neighbour_build_is_checked_and_auto_walks_small_worlds_on_the_cpu():
    model = build_model(two_coil_scene())
    with pytest.raises(ValueError, match="neighbour_build"):
        wc.Solver(model, neighbour_build="tree")
    assert model.node_count <= NEIGHBOUR_WALK_MAX_NODES
    assert wc.Solver(model).walk_neighbours == model.device.is_cpu
    assert not wc.Solver(model, neighbour_build="grid").walk_neighbours
    assert not wc.Solver(Ensemble([two_coil_scene()] * 2).model).walk_neighbours  # ensembles: the grid (unmeasured)
    spec = wc.CoilSpec(length_mm=NEIGHBOUR_WALK_MAX_NODES * 0.3, segment_length_mm=0.3)
    rest = np.zeros((NEIGHBOUR_WALK_MAX_NODES + 1, 3))
    rest[:, 0] = np.arange(NEIGHBOUR_WALK_MAX_NODES + 1) * 0.3
    builder = wc.ModelBuilder()
    builder.add_coil(spec, rest)
    large = builder.finalize()
    assert large.node_count > NEIGHBOUR_WALK_MAX_NODES and not wc.Solver(large).walk_neighbours  # a large world: the grid
