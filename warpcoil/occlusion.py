"""In-silico Raymond–Roy occlusion class from the regional packing densities of the
sac (neck, boundary, core: :func:`warpcoil.sac.regional_density`, docs/REGIONS.md).

A region counts as occluded when its coil volume fraction reaches the threshold; a
region below it is where contrast would still fill the aneurysm:

- class 3 (residual aneurysm): the boundary or the core is below the threshold;
  modified subclass IIIb when the boundary (along the wall) is, else IIIa (within
  the coil interstices, i.e. the core);
- class 2 (residual neck): the dome is occluded, the neck region is below it;
- class 1 (complete occlusion): every region reaches it.

An empty region (NaN density, e.g. no core in a small sac) is not judged.
"""

from __future__ import annotations

import math

THRESHOLD = 0.31
THRESHOLD_SOURCE = (
    "threshold 31 %: Mascitelli JR, Oermann EK, Mocco J, Fifi J, Patel AB, 'The relationship between packing "
    "density and incomplete aneurysm occlusion following coil embolization of intracranial aneurysms', "
    "Congress of Neurological Surgeons 2015 Annual Meeting abstract (packing-density cut-off for modified "
    "Raymond-Roy class IIIa/IIIb, 405 aneurysms), applied here to each region"
)
CLASSES_SOURCE = (
    "classes: Roy D, Milot G, Raymond J, Stroke 2001;32:1998-2004; subclasses IIIa/IIIb: Mascitelli JR et al., "
    "J NeuroIntervent Surg 2015;7:496-502; regions after Holzberger F, Muhr M, Wohlmuth B, Biomech Model "
    "Mechanobiol 2024, doi:10.1007/s10237-024-01882-y (docs/REGIONS.md)"
)
SCENE_THRESHOLD_SOURCE = "threshold from the scene's [regions] occlusion_threshold"


def _below(density: float, threshold: float) -> bool:
    """True when the region has voxels and its density is under the threshold."""
    return math.isfinite(density) and density < threshold


def occlusion_grade(neck: float, boundary: float, core: float, threshold: float = THRESHOLD,
                    threshold_source: str = THRESHOLD_SOURCE) -> dict | None:
    """result.json's ``occlusion`` from the regional densities (fractions; NaN: empty region).

    None when every region is empty (no sac voxels)."""
    if not 0.0 < threshold <= 1.0:
        raise ValueError(f"occlusion threshold must be in (0, 1], got {threshold!r}")
    densities = (neck, boundary, core)
    if not any(math.isfinite(d) for d in densities):
        return None
    if _below(boundary, threshold):
        klass, modified = 3, "IIIb"
    elif _below(core, threshold):
        klass, modified = 3, "IIIa"
    elif _below(neck, threshold):
        klass, modified = 2, "II"
    else:
        klass, modified = 1, "I"
    percent = f"{100.0 * threshold:g} %"
    return {
        "raymond_roy_class": klass,
        "modified_raymond_roy_class": modified,
        "rule": (f"3 if the boundary (IIIb) or core (IIIa) density < {percent}, else 2 if the neck density "
                 f"< {percent}, else 1; an empty region is not judged"),
        "neck_density": neck if math.isfinite(neck) else None,
        "boundary_density": boundary if math.isfinite(boundary) else None,
        "core_density": core if math.isfinite(core) else None,
        "threshold": threshold,
        "source": f"{threshold_source}; {CLASSES_SOURCE}",
    }


def occlusion_of_regions(regions: dict | None, threshold: float | None = None) -> dict | None:
    """``occlusion_grade`` of a run's ``regions`` (None without a sac); ``threshold``:
    the scene's [regions] occlusion_threshold, None for :data:`THRESHOLD`."""
    if regions is None:
        return None
    if threshold is None:
        return occlusion_grade(regions["neck"], regions["boundary"], regions["core"])
    return occlusion_grade(regions["neck"], regions["boundary"], regions["core"], threshold,
                           SCENE_THRESHOLD_SOURCE)
