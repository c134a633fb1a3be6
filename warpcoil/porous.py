"""The coiled sac as a porous medium for CFD (docs/POROUS.md), mm.

Over the sac's bounding box, voxels of edge h; each voxel is sampled at 4×4×4
points (spacing h/4). A sample is in the sac when it lies inside the closed sac
surface, and in the coil when it lies within d/2 of a coil segment (the coil as
a chain of capsules of the wire (secondary) diameter d). Per voxel:

* ``sac_fraction``: sac samples / 64; ``sac``: 1 where ``sac_fraction`` ≥ ½.
* ``porosity`` ε = 1 − (sac samples in the coil) / (sac samples); 1 off the sac.
  Coil outside the sac (herniated into the parent vessel) is not counted.
* The local coil orientation tensor A = Σ_s n_s t_s t_sᵀ / Σ_s n_s over the coil
  segments s touching the voxel's sac samples (n_s of them, t_s the unit tangent),
  and the local fibre radius a = Σ n_s r_s / Σ n_s.
* Happel's (1959) cell-model permeabilities of a fibre array at solid fraction
  φ = 1 − ε, along (K∥) and across (K⊥) the fibres:
  K∥ = a²/(4φ) (−ln φ − 3/2 + 2φ − φ²/2),  K⊥ = a²/(8φ) (−ln φ − (1 − φ²)/(1 + φ²)).
* ``permeability_tensor_mm2`` K = K⊥ I + (K∥ − K⊥) A (each segment's transversely
  isotropic tensor rotated onto its tangent, averaged with weights n_s);
  ``permeability_mm2`` = tr K / 3 = (K∥ + 2 K⊥)/3, the value for fibres in random
  orientation. Both are +inf where there is no coil (ε = 1) and 0 where φ = 1.

One kernel thread per voxel (gather form): one ``wp.Bvh`` query for the segments
near the voxel, a 64-bit mask of the samples inside each, one
``wp.mesh_query_point_no_sign`` to decide whether the sac surface passes near
(then one ``wp.mesh_query_ray`` per sample, else one for the voxel centre).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from .geometry import SurfaceBVH, first_hit_inside

SAMPLES_PER_AXIS = wp.constant(4)  # 4³ = 64 samples per voxel: one bit each of a uint64 mask
SAMPLES = wp.constant(64)


@dataclass(frozen=True)
class PorousField:
    """Voxel fields over the sac's bounding box; arrays are (nx, ny, nz[, ...]) with x slowest."""

    origin_mm: np.ndarray  # (3,) corner of voxel (0, 0, 0)
    voxel_mm: float
    sac_fraction: np.ndarray  # volume fraction of each voxel inside the sac
    porosity: np.ndarray  # 1 − coil volume fraction of the voxel's sac part (1 off the sac)
    orientation: np.ndarray  # (..., 3, 3) coil orientation tensor, trace 1 (0 where no coil)
    fibre_radius_mm: np.ndarray  # weighted mean wire radius of the coil in the voxel (0 where none)

    @property
    def sac(self) -> np.ndarray:
        return self.sac_fraction >= 0.5

    @property
    def shape(self) -> tuple[int, int, int]:
        return tuple(self.porosity.shape)  # type: ignore[return-value]

    def permeabilities_mm2(self) -> tuple[np.ndarray, np.ndarray]:
        """(K∥, K⊥) of each voxel (mm²), Happel's fibre-array model at its solid fraction and fibre radius."""
        return happel_permeabilities_mm2(1.0 - self.porosity, self.fibre_radius_mm)

    def permeability_tensor_mm2(self) -> np.ndarray:
        """(..., 3, 3) K = K⊥ I + (K∥ − K⊥) A."""
        parallel, transverse = self.permeabilities_mm2()
        with np.errstate(invalid="ignore"):  # inf − inf where there is no coil
            tensor = transverse[..., None, None] * np.eye(3) + (parallel - transverse)[..., None, None] * self.orientation
        tensor[self.porosity >= 1.0] = np.inf
        return tensor

    def permeability_mm2(self) -> np.ndarray:
        """tr K / 3 = (K∥ + 2 K⊥) / 3: the permeability of randomly oriented fibres (mm²)."""
        parallel, transverse = self.permeabilities_mm2()
        return (parallel + 2.0 * transverse) / 3.0


def happel_permeabilities_mm2(solid_fraction: np.ndarray, fibre_radius_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Happel (1959) cell model: permeability along and across an array of fibres of radius a (mm²).

    +inf at solid fraction 0, 0 at 1 (the brackets, ≥ 0 on (0, 1], are clipped at 0 against rounding).
    """
    phi = np.asarray(solid_fraction, dtype=np.float64)
    a2 = np.asarray(fibre_radius_mm, dtype=np.float64) ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        log = -np.log(phi)
        parallel = a2 / (4.0 * phi) * np.maximum(log - 1.5 + 2.0 * phi - 0.5 * phi**2, 0.0)
        transverse = a2 / (8.0 * phi) * np.maximum(log - (1.0 - phi**2) / (1.0 + phi**2), 0.0)
    none = phi <= 0.0
    return np.where(none, np.inf, parallel), np.where(none, np.inf, transverse)


@wp.func
def _sample_point(corner: wp.vec3d, h: wp.float64, bit: int) -> wp.vec3d:
    step = h / wp.float64(4.0)
    i = bit // 16
    j = (bit // 4) % 4
    k = bit % 4
    return corner + step * wp.vec3d(wp.float64(i) + wp.float64(0.5), wp.float64(j) + wp.float64(0.5),
                                    wp.float64(k) + wp.float64(0.5))


@wp.func
def _inside(mesh: wp.uint64, p: wp.vec3d) -> wp.uint64:
    return wp.uint64(first_hit_inside(mesh, wp.vec3(float(p[0]), float(p[1]), float(p[2]))))


@wp.func
def _count_bits(mask: wp.uint64) -> int:
    count = int(0)
    for bit in range(SAMPLES):
        if (mask >> wp.uint64(bit)) & wp.uint64(1) != wp.uint64(0):
            count = count + 1
    return count


@wp.kernel
def _voxel_occupancy(origin: wp.vec3d, h: wp.float64, ny: int, nz: int, sac_mesh: wp.uint64,
                     segments: wp.uint64, a: wp.array(dtype=wp.vec3d), b: wp.array(dtype=wp.vec3d),
                     radius: wp.array(dtype=wp.float64), sac_count: wp.array(dtype=int),
                     coil_count: wp.array(dtype=int), orientation: wp.array(dtype=wp.mat33d),
                     radius_sum: wp.array(dtype=wp.float64)):
    """Per voxel (coordinates relative to the sac mesh's centre): sample counts, Σ n_s t tᵀ and Σ n_s r_s."""
    v = wp.tid()
    i = v // (ny * nz)
    j = (v // nz) % ny
    l = v % nz
    corner = origin + h * wp.vec3d(wp.float64(i), wp.float64(j), wp.float64(l))
    centre = corner + wp.float64(0.5) * h * wp.vec3d(wp.float64(1.0), wp.float64(1.0), wp.float64(1.0))

    # the sac samples: all alike unless the sac surface passes within half a diagonal of the centre
    sac = wp.uint64(0)
    near = wp.mesh_query_point_no_sign(sac_mesh, wp.vec3(float(centre[0]), float(centre[1]), float(centre[2])),
                                       float(h) * 0.8661)
    if near.result:
        for bit in range(SAMPLES):
            sac = sac | (_inside(sac_mesh, _sample_point(corner, h, bit)) << wp.uint64(bit))
    elif _inside(sac_mesh, centre) == wp.uint64(1):
        sac = ~wp.uint64(0)
    sac_count[v] = _count_bits(sac)
    if sac == wp.uint64(0):
        return

    lower = wp.vec3(float(corner[0]), float(corner[1]), float(corner[2]))
    upper = lower + wp.vec3(float(h), float(h), float(h))
    query = wp.bvh_query_aabb(segments, lower, upper)
    s = int(0)
    coil = wp.uint64(0)
    tensor = wp.mat33d()
    weighted_radius = wp.float64(0.0)
    while wp.bvh_query_next(query, s):
        step = b[s] - a[s]
        length2 = wp.dot(step, step)
        if length2 > wp.float64(0.0):  # a zero-length segment's ball lies in its neighbours' capsules
            mask = wp.uint64(0)
            for bit in range(SAMPLES):
                p = _sample_point(corner, h, bit)
                along = wp.clamp(wp.dot(p - a[s], step) / length2, wp.float64(0.0), wp.float64(1.0))
                gap = p - a[s] - along * step
                if wp.dot(gap, gap) <= radius[s] * radius[s]:
                    mask = mask | (wp.uint64(1) << wp.uint64(bit))
            mask = mask & sac
            n = _count_bits(mask)
            t = step / wp.sqrt(length2)
            tensor = tensor + wp.float64(n) * wp.outer(t, t)
            weighted_radius = weighted_radius + wp.float64(n) * radius[s]
            coil = coil | mask
    coil_count[v] = _count_bits(coil)
    orientation[v] = tensor
    radius_sum[v] = weighted_radius


MAX_POROUS_VOXELS = 20_000_000  # a field larger than this is refused before the run (~100 bytes a voxel)


def porous_grid_shape(sac_vertices_mm: np.ndarray, voxel_mm: float) -> tuple[int, int, int]:
    """Voxels per axis of the field over the sac's bounding box, one voxel of margin on each side."""
    vertices = np.asarray(sac_vertices_mm, dtype=np.float64)
    span = vertices.max(axis=0) - vertices.min(axis=0)
    return tuple(int(n) for n in np.ceil(span / voxel_mm).astype(np.int64) + 2)


def porous_voxel_mm(voxel_mm: float | None, wire_diameters_mm) -> float:
    """The field's voxel edge (mm): ``voxel_mm``, by default half the smallest wire diameter."""
    return 0.5 * float(min(wire_diameters_mm)) if voxel_mm is None else float(voxel_mm)


def porous_surface(sac, wall) -> tuple[np.ndarray, np.ndarray] | None:
    """(vertices mm, faces) the field fills: the sac cut at the neck (a Sac), else the whole wall
    (a WallMesh; None with no wall)."""
    if sac is not None:
        return np.asarray(sac.closed_surface.vertices), np.asarray(sac.closed_surface.faces)
    if wall is not None:
        return wall.vertices_mm, wall.faces
    return None


def porous_field(sac_vertices_mm: np.ndarray, sac_faces: np.ndarray, coils_mm: list[np.ndarray],
                 wire_diameters_mm: list[float], voxel_mm: float | None = None, device=None) -> PorousField:
    """The porous-medium fields of ``coils_mm`` (node polylines) in the closed sac surface.

    ``voxel_mm`` defaults to half the smallest wire diameter.
    """
    if len(coils_mm) != len(wire_diameters_mm) or not coils_mm:
        raise ValueError(f"porous_field: {len(coils_mm)} coils but {len(wire_diameters_mm)} wire diameters; "
                         "give one diameter per coil and at least one coil")
    h = porous_voxel_mm(voxel_mm, wire_diameters_mm)
    if not (np.isfinite(h) and h > 0.0):
        raise ValueError(f"porous_field: voxel_mm must be a positive number of mm, got {voxel_mm}")
    device = wp.get_device(device)
    surface = SurfaceBVH(sac_vertices_mm, sac_faces, device)
    lo = np.asarray(sac_vertices_mm, dtype=np.float64).min(axis=0)
    shape = porous_grid_shape(sac_vertices_mm, h)
    origin = lo - h  # one voxel of margin on each side

    starts, ends, radii = [], [], []
    for nodes, d in zip(coils_mm, wire_diameters_mm):
        nodes = np.asarray(nodes, dtype=np.float64).reshape(-1, 3) - surface.centre_mm
        starts.append(nodes[:-1])
        ends.append(nodes[1:])
        radii.append(np.full(max(len(nodes) - 1, 0), 0.5 * float(d)))
    a, b, r = np.concatenate(starts), np.concatenate(ends), np.concatenate(radii)
    count = int(np.prod(shape))
    sac_count = wp.zeros(count, dtype=int, device=device)
    coil_count = wp.zeros(count, dtype=int, device=device)
    orientation = wp.zeros(count, dtype=wp.mat33d, device=device)
    radius_sum = wp.zeros(count, dtype=wp.float64, device=device)
    if len(a):
        grow = r[:, None] + 1e-5 * (1.0 + np.abs(np.vstack((a, b))).max())  # float32 boxes hold every candidate
        bvh = wp.Bvh(wp.array((np.minimum(a, b) - grow).astype(np.float32), dtype=wp.vec3, device=device),
                     wp.array((np.maximum(a, b) + grow).astype(np.float32), dtype=wp.vec3, device=device))
        as_vec3d = lambda x: wp.array(x, dtype=wp.vec3d, device=device)  # noqa: E731
        wp.launch(_voxel_occupancy, count,
                  inputs=[wp.vec3d(*(origin - surface.centre_mm)), wp.float64(h), shape[1], shape[2],
                          surface.mesh.id, bvh.id, as_vec3d(a), as_vec3d(b), wp.array(r, dtype=wp.float64,
                                                                                      device=device)],
                  outputs=[sac_count, coil_count, orientation, radius_sum], device=device)
    sac_n = sac_count.numpy().reshape(shape)
    coil_n = coil_count.numpy().reshape(shape)
    tensor = orientation.numpy().reshape(shape + (3, 3))
    weight = np.trace(tensor, axis1=-2, axis2=-1)  # Σ n_s (t is a unit vector)
    with np.errstate(divide="ignore", invalid="ignore"):
        porosity = np.where(sac_n > 0, 1.0 - coil_n / sac_n, 1.0)
        orientation_tensor = np.where(weight[..., None, None] > 0, tensor / weight[..., None, None], 0.0)
        fibre_radius = np.where(weight > 0, radius_sum.numpy().reshape(shape) / weight, 0.0)
    return PorousField(origin_mm=origin, voxel_mm=h, sac_fraction=sac_n / SAMPLES, porosity=porosity,
                       orientation=orientation_tensor, fibre_radius_mm=fibre_radius)
