"""Scene-level settings: catheter, wall, contact, integration, output.

Units: mm, g, s; forces µN; energies nJ (µN·mm). ``None`` means "derive the
default from the coil" (documented per field).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path


@dataclass(frozen=True)
class CatheterSpec:
    """Microcatheter: a tube ending at ``tip_mm`` and pointing along ``direction``.

    ``centerline_mm`` (optional) is a polyline from the proximal end to the
    tip (its last point must equal the tip); without it the catheter is
    straight along ``direction``.
    """

    tip_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    direction: tuple[float, float, float] = (0.0, 0.0, 1.0)
    centerline_mm: tuple[tuple[float, float, float], ...] | None = None


@dataclass(frozen=True)
class WallSpec:
    """Closed triangle surface of the lumen (sac + neck cap, or sac + parent vessel)."""

    mesh: Path
    units: str = "mm"  # "mm" or "m"


@dataclass(frozen=True)
class ContactSettings:
    """Exponential contact law of MODEL.md, shared by coil–wall and coil–coil.

    P0_uN: force at zero clearance (≈ 13 kPa mean local pressure × a node's
    patch d·l0 ≈ 1e3 µN). c0_mm: clearance where contact starts (default
    0.1·d, a few times the wall's RMS roughness).
    """

    P0_uN: float = 1.0e3
    c0_mm: float | None = None


@dataclass(frozen=True)
class SimulationSettings:
    """Push, damping, step size and stopping rules.

    * push_speed_mm_s: pusher speed (clinically a few mm/s; faster is fine while
      kinetic/elastic energy stays small, which the run reports).
    * damping_uN_per_mm, damping_speed_mm_s: the nonlinear damping of MODEL.md,
      force per node ``c (1 - exp(-|v|/k)) v/|v|`` with ``c = damping_uN_per_mm · l0``
      and ``k = damping_speed_mm_s``; low-speed coefficient c/k. Defaults damp
      the slow unwinding of a released 3 mm loop close to critically (the helix
      recovery settles fastest near 5–10 µN/mm).
    * dt_s: step; None → dt_safety × the stable bound. A dt above the bound is
      refused unless allow_unstable_dt.
    * mass_scale: node masses (and twist inertia) × this factor; a named
      quasi-static speed-up, reported in results.
    * jam_force_uN: push force at which the deployment is "jammed" (in-vitro
      insertion forces are of the order of 0.1 N = 1e5 µN).
    * rest_kinetic_energy_nJ: after detachment the run ends when kinetic energy
      is below this.
    * max_time_s: simulated time limit (status "timeout"); None → push time + 2 s.
    * frame_interval_s: interval between recorded frames.
    """

    push_speed_mm_s: float = 50.0
    damping_uN_per_mm: float = 10.0
    damping_speed_mm_s: float = 20.0
    dt_s: float | None = None
    dt_safety: float = 0.5
    allow_unstable_dt: bool = False
    mass_scale: float = 1.0
    jam_force_uN: float = 1.0e5
    rest_kinetic_energy_nJ: float = 1.0e-3
    max_time_s: float | None = None
    frame_interval_s: float = 0.01


@dataclass(frozen=True)
class OutputSettings:
    usd: bool = True


@dataclass(frozen=True)
class Scene:
    """A whole scene: coils deployed in order through one catheter."""

    coils: tuple  # tuple[CoilSpec, ...]
    catheter: CatheterSpec = field(default_factory=CatheterSpec)
    wall: WallSpec | None = None
    contact: ContactSettings = field(default_factory=ContactSettings)
    simulation: SimulationSettings = field(default_factory=SimulationSettings)
    output: OutputSettings = field(default_factory=OutputSettings)
    source: Path | None = None  # the TOML file it was read from
