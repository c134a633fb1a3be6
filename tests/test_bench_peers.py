"""`warpcoil bench peers`: the checks its numbers rest on, on short windows.

* The NumPy twin and the Warp solver agree (same model, same settings) on the
  free helix released from straight and on a window of the seed deployment
  with the wall in contact: the agreement check the benchmark reports.
* The PyElastica rod of benchmarks/pyelastica_helix.py (when PyElastica is
  installed) is at rest in its helix, and a damped run from straight loses energy.
"""

import math

import numpy as np
import pytest

from warpcoil.bench import peers
from warpcoil.metrics import fit_helix

numpy_twin, ph = peers.import_benchmarks()


def assert_agrees(row, tolerance):
    a = row.agreement
    assert a["free_equal"] and a["time_equal"]
    assert a["position_rel"] <= tolerance
    assert a["director_abs"] <= peers.DIRECTOR_FACTOR * tolerance
    assert a["energy_rel"] <= tolerance
    assert row.agrees


def test_twin_agrees_with_warp_on_the_free_helix():
    row = peers.compare_twin(numpy_twin, peers.helix_window(), steps=400, repeats=1,
                             tolerance=peers.HELIX_TOLERANCE, chunk=100, warp_repeats=1)
    assert row.max_displacement_mm > 1e-3  # the coil is whipping out of straight: a real check
    assert_agrees(row, peers.HELIX_TOLERANCE)


def test_twin_agrees_with_warp_in_the_seed_deployment():
    window = peers.seed_window(prepush_steps=12_000)  # ≈ 3 mm out, the loop reaching the wall
    row = peers.compare_twin(numpy_twin, window, steps=20, repeats=1, tolerance=peers.SEED_TOLERANCE, chunk=10,
                             warp_repeats=1)
    assert row.twin_max_wall_contacts >= 1  # the wall pass exerts a force in this window
    assert row.max_displacement_mm > 1e-4
    assert_agrees(row, peers.SEED_TOLERANCE)


def _needs_pyelastica():
    pytest.importorskip("elastica", reason="PyElastica is not installed (pip install -e '.[bench]')")
    reason = ph.unavailable_reason()
    if reason:
        pytest.skip(reason)


def test_pyelastica_rod_is_at_rest_in_its_helix():
    _needs_pyelastica()
    p = ph.coil_parameters()
    rod = ph.build_rod(60, p)
    fit = fit_helix(rod.position_collection.T)
    assert fit.loop_diameter_mm == pytest.approx(3.0, rel=1e-9)
    assert fit.pitch_mm == pytest.approx(0.6, rel=1e-9)
    assert max(ph.rest_residual(rod, p)) < 1e-10
    assert ph.elastic_energy_nJ(rod) < 1e-12
    assert np.abs(rod.rest_kappa[2]).max() < 1e-12  # Bishop frame: no rest twist
    ph.rigidly_move(rod)  # the rest state is the shape, not the placement
    assert max(ph.rest_residual(rod, p)) < 1e-9
    assert ph.elastic_energy_nJ(rod) < 1e-12
    ph.set_straight(rod)  # and the residual measures something
    force, torque = ph.rest_residual(rod, p)
    assert torque > 0.1
    assert ph.elastic_energy_nJ(rod) > 1e3


def test_pyelastica_damped_run_from_straight_loses_energy():
    _needs_pyelastica()
    sim, rod, stepper, dt, bound = ph.make_simulator(40, 0.5)
    assert dt == pytest.approx(0.5 * bound)
    e0 = ph.elastic_energy_nJ(rod) + ph.kinetic_energy_nJ(rod)
    ph.run_steps(sim, stepper, dt, 3000)
    e1 = ph.elastic_energy_nJ(rod) + ph.kinetic_energy_nJ(rod)
    assert np.isfinite(rod.position_collection).all()
    assert math.isfinite(e1) and e1 < 0.9 * e0
    assert ph.kinetic_energy_nJ(rod) > 0.0  # it moved
