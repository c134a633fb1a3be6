"""The stall force's scale: the self-deployment force F0 of a coil (its elastic energy
per mm straightened in the catheter, nJ/mm = µN) is EI κ²/2 + GJ τ²/2 of its helix
pre-shape, κ = R/(R² + c²), τ = c/(R² + c²), c = pitch/2π (MODEL.md bending energy)."""

from __future__ import annotations

import math

import pytest

from warpcoil.coil import CoilSpec
from warpcoil.deploy import Ensemble
from warpcoil.settings import CatheterSpec, Scene, SimulationSettings, WallSpec


@pytest.mark.parametrize("loop_diameter_mm, pitch_mm", [(2.5, 0.6), (4.0, 0.9), (35.0, 0.6)])
def test_self_deployment_force_is_the_straightened_helix_energy_per_length(loop_diameter_mm, pitch_mm):
    coil = CoilSpec(name="h", shape="helix", wire_diameter_mm=0.2921, loop_diameter_mm=loop_diameter_mm,
                    pitch_mm=pitch_mm, length_mm=20.0)
    scene = Scene(coils=(coil,), catheter=CatheterSpec(tip_mm=(0.0, 0.0, -1.45), direction=(0.0, 0.0, 1.0)),
                  wall=WallSpec(sphere_diameter_mm=3.5), simulation=SimulationSettings(push_speed_mm_s=100.0))
    ensemble = Ensemble([scene])
    member, model = ensemble.members[0], ensemble.model.coils[0]
    radius, rise = loop_diameter_mm / 2.0, pitch_mm / (2.0 * math.pi)
    curvature, torsion = radius / (radius**2 + rise**2), rise / (radius**2 + rise**2)
    expected = model.EI * curvature**2 / 2.0 + model.GJ * torsion**2 / 2.0
    assert member.self_deployment_force_uN == pytest.approx(expected, rel=0.03)  # ends and discretisation
    sac_bend = model.EI / (2.0 * 1.75**2)  # bent to the 3.5 mm sphere's curvature (its mesh: within 1 %)
    assert member.sac_bend_forces_uN[0] == pytest.approx(sac_bend, rel=0.01)
    assert member.stall_forces_uN[0] == pytest.approx(
        scene.simulation.stall_force_ratio * max(member.self_deployment_force_uN, member.sac_bend_forces_uN[0]))
    assert (member.stall_forces_uN[0] > 50.0 * sac_bend) if loop_diameter_mm > 3.5 else (
        member.stall_forces_uN[0] == pytest.approx(100.0 * expected, rel=0.03))


def test_the_stall_floor_is_the_pushed_coils_own_drag():
    """Two coils, 30 mm straight-ish then 2 mm, in free space (no sac to bend them to): each is held to twice its
    own damping drag at the push speed (the first version held the 2 mm finishing coil to the whole set's, ~590 µN
    against ~37 µN)."""
    coils = tuple(CoilSpec(name=f"h{k}", shape="helix", wire_diameter_mm=0.2921, loop_diameter_mm=200.0, pitch_mm=0.6,
                           length_mm=length) for k, length in enumerate((30.0, 2.0)))
    scene = Scene(coils=coils, catheter=CatheterSpec(tip_mm=(0.0, 0.0, -1.45), direction=(0.0, 0.0, 1.0)),
                  simulation=SimulationSettings(push_speed_mm_s=50.0))
    member = Ensemble([scene]).members[0]
    assert not member.sac_bend_forces_uN.any()
    per_mm = 2.0 * 10.0 * (1.0 - math.exp(-50.0 / 20.0))  # STALL_DRAG_FACTOR × c (1 − e^(−v/k)), µN/mm
    assert member.stall_forces_uN[0] == pytest.approx(per_mm * member.coil_lengths_mm[0])
    assert member.stall_forces_uN[1] == pytest.approx(per_mm * member.coil_lengths_mm[1])
    assert member.stall_forces_uN[1] > 100.0 * member.self_deployment_force_uN  # (the floor is what sets it)


def test_stall_signals_summary_reads_the_window_mean_and_the_released_energy():
    """benchmarks.stall_signals: pushed at 50 mm/s with frames of 0.01 s, a push force
    rising as F0 × (pushed / 10 mm) passes 2 F0 on its trailing 0.1 s mean (10 frames:
    mean pushed = pushed − 2.25 mm) first at 22.5 mm; an elastic energy falling by F0
    per mm pushed releases 1.00 F0 per mm in every tenth."""
    import numpy as np

    from benchmarks.stall_signals import summary

    f0, wire = 500.0, 0.3
    rows = [dict(time_s=t, pushed_mm=50.0 * t, packing=0.5 * t, push_mean_uN=f0 * 5.0 * t, push_peak_uN=0.0,
                 elastic_nJ=1e5 - f0 * 50.0 * t, stretch_nJ=0.0, min_coil_gap_mm=-0.03, coil_contacts=0)
            for t in np.arange(101) * 0.01]
    lines = summary(rows, f0, wire)
    assert "  0.1 s mean > 2 F0: first at 22.5 mm, packing 22.5 %" in lines
    assert "  0.1 s mean > 5 F0: never" in lines  # (the 0.1 s mean ends at 4.78 F0)
    assert "deepest overlap 0.100 d" in lines[-2]
    assert lines[-1].count(":1.00/") == 10
