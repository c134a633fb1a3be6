"""Several coils through one catheter: order, per-coil results, a jam ends one coil only."""

import math

import numpy as np
import pytest

import warpcoil as wc
from warpcoil.deploy import COMPLETED, JAMMED, Deployment
from warpcoil.occlusion import occlusion_grade

from test_length_outside import length_below

R_SAC = 1.75
D = 0.2921


def two_coil_scene(jam_force_uN=1.0e5):
    coils = (
        wc.CoilSpec(shape="helix", length_mm=8.0, loop_diameter_mm=2.5, pitch_mm=0.6, name="framing"),
        wc.CoilSpec(shape="helix", length_mm=5.0, loop_diameter_mm=2.0, pitch_mm=0.6, name="filling",
                    wire_diameter_mm=0.254, primary_wire_diameter_mm=0.04),
    )
    return wc.Scene(coils=coils, catheter=wc.CatheterSpec(tip_mm=(0.0, 0.0, -1.45), direction=(0.0, 0.0, 1.0)),
                    wall=wc.WallSpec(sphere_diameter_mm=2 * R_SAC),
                    simulation=wc.SimulationSettings(push_speed_mm_s=100.0, frame_interval_s=0.005,
                                                     jam_force_uN=jam_force_uN))


def test_coils_are_deployed_in_order_and_earlier_coils_keep_moving():
    deployment = Deployment(two_coil_scene())
    first_coil_moved_late = []
    snapshot = {}

    def on_frame(frame, state):
        x = state.x.numpy()[deployment.model.node_slice(0)].copy()
        advance = state.advance.numpy()
        if advance[1] > 0.0:  # second coil is out
            if "x" in snapshot:
                first_coil_moved_late.append(np.abs(x - snapshot["x"]).max())
            snapshot["x"] = x
        assert not (advance[1] > 0.0 and advance[0] < deployment.coil_lengths_mm[0])  # strictly in order

    result = deployment.run(on_frame)
    assert result.status == COMPLETED, result.reason
    assert [c["status"] for c in result.coils] == ["detached", "detached"]
    assert max(first_coil_moved_late) > 1e-4  # the first coil is pushed around by the second
    volume = math.pi / 6 * (2 * R_SAC) ** 3
    densities = [c["packing_density"] for c in result.coils]
    for coil, spec in zip(result.coils, two_coil_scene().coils):
        assert coil["packing_density"] == pytest.approx(math.pi * (spec.d / 2) ** 2 * coil["length_mm"] / volume,
                                                        rel=0.01)
    assert result.coils[1]["cumulative_packing_density"] == pytest.approx(sum(densities))
    assert result.packing_density == pytest.approx(sum(densities))


def test_a_jam_ends_that_coil_and_the_next_one_goes_on():
    deployment = Deployment(two_coil_scene(jam_force_uN=2.0))
    result = deployment.run()
    assert result.status == JAMMED
    assert "coil 0 (framing) jammed" in result.reason
    first, second = result.coils
    assert first["status"] == JAMMED and first["deployed_length_mm"] < first["length_mm"]
    assert second["status"] in (JAMMED, "detached") and second["deployed_length_mm"] > 0.0
    # the withdrawn part of the jammed coil is out of every pass: fixed, not free, cut off
    state = deployment.stepper.state
    sl = deployment.model.node_slice(0)
    inside = state.free.numpy()[sl] == 0
    assert inside.any() and np.all(deployment.model.fixed.numpy()[sl][inside] == 1)
    assert np.all(np.linalg.norm(state.x.numpy()[state.free.numpy() == 1], axis=1) < R_SAC)


def test_a_neck_defines_the_sac_places_the_catheter_and_gives_regional_densities():
    """A plane neck near the bottom of a spherical wall: the sac is the part above it
    (its volume the sphere minus the cap below), the catheter tip sits on the sac
    axis just inside the neck, and the run reports regional densities."""
    from warpcoil.deploy import Deployment
    from warpcoil.settings import NeckSpec

    z_neck = -1.2
    scene = wc.Scene(
        coils=(wc.CoilSpec(shape="helix", length_mm=6.0, loop_diameter_mm=2.5, pitch_mm=0.6),),
        catheter=wc.CatheterSpec(placement="neck", depth_mm=0.3),
        wall=wc.WallSpec(sphere_diameter_mm=2 * R_SAC),
        neck=NeckSpec(plane_point_mm=(0.0, 0.0, z_neck), plane_normal=(0.0, 0.0, 1.0)),
        simulation=wc.SimulationSettings(push_speed_mm_s=100.0, frame_interval_s=0.005),
    )
    deployment = Deployment(scene)
    cap_height = R_SAC + z_neck
    cap = math.pi * cap_height**2 * (3 * R_SAC - cap_height) / 3
    sphere = 4 / 3 * math.pi * R_SAC**3
    assert deployment.anatomy.sac_volume_mm3 == pytest.approx(sphere - cap, rel=0.02)
    tip = np.asarray(deployment.anatomy.catheter.tip_mm)
    assert np.allclose(tip, (0.0, 0.0, z_neck + 0.3), atol=0.02)
    assert np.allclose(deployment.anatomy.catheter.direction, (0.0, 0.0, 1.0), atol=1e-6)
    result = deployment.run()
    assert result.status == COMPLETED, result.reason
    assert result.packing_density == pytest.approx(
        math.pi * (D / 2) ** 2 * result.coil_length_mm / deployment.anatomy.sac_volume_mm3)
    regions = result.regions
    assert set(regions) >= {"neck", "boundary", "core", "total_voxel", "neck_coverage"}
    assert 0.0 <= regions["neck_coverage"] <= 1.0
    assert regions["total_voxel"] == pytest.approx(result.packing_density, rel=0.3)
    assert result.occlusion == occlusion_grade(regions["neck"], regions["boundary"], regions["core"])
    below = length_below(result.positions_mm[0], z_neck)  # the centre line clipped at the neck plane
    assert result.length_outside_sac_mm == result.coils[0]["length_outside_sac_mm"] == pytest.approx(below, abs=1e-4)


def test_a_frame_that_goes_unstable_is_redone_with_half_the_step(monkeypatch):
    """Force the first health check to fail: the run restarts that frame with half
    the step, reports it, and completes."""
    from warpcoil.solver import Solver

    real = Solver.world_health
    calls = {"n": 0}

    def flaky(self, state, energy_budget_nJ=None, wall_distance_mm=None):
        calls["n"] += 1
        energies, problems = real(self, state, energy_budget_nJ, wall_distance_mm)
        if calls["n"] == 2:  # the first frame after the start
            problems = ["forced for the test at t = 0"]
        return energies, problems

    monkeypatch.setattr(Solver, "world_health", flaky)
    deployment = Deployment(two_coil_scene())
    dt = deployment.solver.dt_s
    result = deployment.run()
    assert result.status == COMPLETED, result.reason
    assert len(result.step_reductions) == 1 and "step halved" in result.step_reductions[0]
    assert result.dt_s == pytest.approx(dt / 2)


def test_a_jammed_coils_exported_geometry_ends_at_its_cut(tmp_path):
    """The withdrawn part of a jammed coil leaves with the catheter: the final centreline (CSV, tube mesh,
    porous field: the CFD geometry) holds only what stays, every node in the sac and every edge near its rest
    length, and the USD draws no edge across the cut (the first version exported the parked part in the
    catheter, 17 nodes outside the sac, joined to the deployed part by a 0.74 mm edge of rest length 0.30)."""
    from pxr import Usd, UsdGeom

    from warpcoil.recorder.outputs import UsdFrames

    deployment = Deployment(two_coil_scene(jam_force_uN=2.0))
    usd = UsdFrames.for_model(tmp_path / "run.usdc", deployment.model, 0.005, deployment.members[0].withdrawn_from)
    result = deployment.run(usd)
    usd.close()
    first = result.coils[0]
    assert first["status"] == JAMMED
    rest = deployment.model.rest_length.numpy()
    stage = Usd.Stage.Open(str(tmp_path / "run.usdc"))
    drawn = UsdGeom.BasisCurves(stage.GetPrimAtPath("/World/Coils/Coil_0")).GetPointsAttr().Get(
        stage.GetEndTimeCode())
    for k, x in enumerate(result.positions_mm):
        sl = deployment.model.node_slice(k)
        assert np.all(np.linalg.norm(x, axis=1) < R_SAC)
        assert np.all(np.linalg.norm(np.diff(x, axis=0), axis=1) < 1.05 * rest[sl][:len(x) - 1])
    kept = result.positions_mm[0]
    assert (len(kept) - 1) * rest[0] == pytest.approx(first["deployed_length_mm"], abs=rest[0])
    edges = np.linalg.norm(np.diff(np.asarray(drawn), axis=0), axis=1)
    assert edges.max() < 1.05 * rest[0] and np.allclose(np.asarray(drawn)[len(kept):], kept[-1], atol=1e-5)
