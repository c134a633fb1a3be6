"""Coil description as a catalogue gives it, with physical defaults.

Units: mm, g, s; forces in µN (g·mm/s²), stiffness EI in µN·mm², axial
stiffness EA in µN.

Defaults for a platinum–tungsten (Pt–8W) coil wound close from a primary wire
of diameter ``d_w`` at pitch ``p = d_w`` on a mean winding diameter
``D_m = d - d_w``:

* bending stiffness of a close-wound helical spring (Wahl, *Mechanical
  Springs*, 2nd ed., 1963, ch. 4; Timoshenko & Gere, *Theory of Elastic
  Stability*, §2.17)::

      EI = E d_w⁴ p / (32 D_m (2 + ν))

  with E = 170 GPa, ν = 0.39: about 2.9e3 µN·mm² for d = 0.2921 mm,
  d_w = 0.05 mm, some 15× softer than the straight wire (MODEL.md).
* torsional stiffness of the coil about its own axis (same source; the wire
  is bent, not twisted)::

      GJ = E d_w⁴ p / (64 D_m) = EI (2 + ν) / 2
* linear density: wire of density 21.4 g/cm³ (Pt–8W), π D_m / p mm of wire
  per mm of coil: about 6.4e-4 g/mm.
* axial stiffness EA: a stretch-resistant coil is held by its polypropylene
  SR filament (E ≈ 1.5 GPa, Ø ≈ 0.02 mm → EA ≈ 4.7e5 µN); a plain coil by
  its spring rate in tension, ``EA = G d_w⁴ p / (8 D_m³)`` with G = 61 GPa
  (≈ 1.7e5 µN for the coil above).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path

YOUNG_MODULUS_PTW_UN_MM2 = 170e9  # 170 GPa in µN/mm² (1 Pa = 1 µN/mm²)
SHEAR_MODULUS_PTW_UN_MM2 = 61e9  # 61 GPa in µN/mm²
POISSON_PTW = 0.39
DENSITY_PTW_G_MM3 = 21.4e-3  # 21.4 g/cm³
SR_FILAMENT_EA_UN = 1.5e9 * math.pi / 4 * 0.02**2  # polypropylene, 1.5 GPa, Ø 0.02 mm

SHAPES = ("helix", "spherical", "file")


@dataclass(frozen=True)
class CoilSpec:
    """One coil: catalogue geometry, material and pre-shape.

    Only ``wire_diameter_mm`` (secondary diameter d), ``length_mm`` and
    ``loop_diameter_mm`` are needed; every other field has a physical default
    (see the module docstring). ``None`` means "use the default".
    """

    wire_diameter_mm: float = 0.2921
    length_mm: float = 60.0
    loop_diameter_mm: float = 3.0
    shape: str = "helix"
    pitch_mm: float | None = None  # helix rise per turn; default 2·d
    shrink: float = 0.6  # spherical: final over initial sphere radius
    preshape_file: Path | None = None  # shape = "file": x y z per line, mm
    segment_length_mm: float | None = None  # l0; default d
    primary_wire_diameter_mm: float = 0.05
    bending_stiffness_uN_mm2: float | None = None
    twist_stiffness_uN_mm2: float | None = None
    linear_density_g_mm: float | None = None
    axial_stiffness_uN: float | None = None
    stretch_resistant: bool = True
    name: str = field(default="coil", compare=False)
    notes: tuple[str, ...] = field(default=(), compare=False)  # catalogue notes, reported as warnings
    product: str | None = field(default=None, compare=False)  # the catalogue family it came from (result.json)
    size: str | None = field(default=None, compare=False)  # ... and its size, as the scene gave it ("6 x 20")

    def __post_init__(self) -> None:
        if self.shape not in SHAPES:
            raise ValueError(f"coil shape {self.shape!r} is not one of {SHAPES}")
        for key in ("wire_diameter_mm", "length_mm", "loop_diameter_mm", "primary_wire_diameter_mm"):
            value = getattr(self, key)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"coil {key} must be a positive number, got {value}")
        if self.primary_wire_diameter_mm >= self.wire_diameter_mm:
            raise ValueError("coil primary_wire_diameter_mm must be smaller than wire_diameter_mm")
        if self.shape == "file" and self.preshape_file is None:
            raise ValueError("coil shape 'file' needs preshape_file")

    # --- derived catalogue quantities -------------------------------------
    @property
    def d(self) -> float:
        """Secondary (outer) diameter d, mm."""
        return self.wire_diameter_mm

    @property
    def l0(self) -> float:
        """Nominal segment length, mm (default d)."""
        return self.segment_length_mm if self.segment_length_mm is not None else self.wire_diameter_mm

    @property
    def helix_pitch_mm(self) -> float:
        return self.pitch_mm if self.pitch_mm is not None else 2.0 * self.wire_diameter_mm

    @property
    def _mean_winding_diameter_mm(self) -> float:
        return self.wire_diameter_mm - self.primary_wire_diameter_mm

    @property
    def EI(self) -> float:
        """Bending stiffness, µN·mm²."""
        if self.bending_stiffness_uN_mm2 is not None:
            return self.bending_stiffness_uN_mm2
        dw, dm = self.primary_wire_diameter_mm, self._mean_winding_diameter_mm
        return YOUNG_MODULUS_PTW_UN_MM2 * dw**4 * dw / (32.0 * dm * (2.0 + POISSON_PTW))

    @property
    def GJ(self) -> float:
        """Torsional stiffness about the coil axis, µN·mm²."""
        if self.twist_stiffness_uN_mm2 is not None:
            return self.twist_stiffness_uN_mm2
        return self.EI * (2.0 + POISSON_PTW) / 2.0

    @property
    def rho(self) -> float:
        """Linear density, g/mm."""
        if self.linear_density_g_mm is not None:
            return self.linear_density_g_mm
        dw, dm = self.primary_wire_diameter_mm, self._mean_winding_diameter_mm
        return DENSITY_PTW_G_MM3 * math.pi * dw**2 / 4.0 * math.pi * dm / dw

    @property
    def EA(self) -> float:
        """Axial stiffness, µN (force per unit strain)."""
        if self.axial_stiffness_uN is not None:
            return self.axial_stiffness_uN
        dw, dm = self.primary_wire_diameter_mm, self._mean_winding_diameter_mm
        spring = SHEAR_MODULUS_PTW_UN_MM2 * dw**4 * dw / (8.0 * dm**3)
        return max(spring, SR_FILAMENT_EA_UN) if self.stretch_resistant else spring

    def with_(self, **changes) -> "CoilSpec":
        """A copy with some fields changed."""
        return replace(self, **changes)
