"""Narrow-band signed distance field of the wall (a NanoVDB ``wp.Volume``):
the kernels that build it from the wall's BVH and the sampler the contact
pass uses.

The field holds, at every voxel of the tiles (8³ voxels) that touch the band
``−inner_mm ≤ d ≤ band_mm`` (d: signed distance, mm, > 0 in the lumen), the
exact signed distance of the voxel centre (float32, from :func:`contact.wall_query`),
in the wall's local frame (relative to its origin), except where the centre lies
more than a stencil's diagonal beyond the band outside the lumen (:func:`fill_distances`).
Every other voxel is NaN,
so a trilinear sample that touches one is NaN: a sample is either built from
eight exact corner values or visibly untrusted. The sampler is
:func:`contact.field_sample`.
"""

import warp as wp

from .contact import field_sample, wall_query, wall_query_sided

FIELD_NAN = wp.constant(wp.float32(wp.nan))
TILE_VOXELS = wp.constant(8)  # NanoVDB leaf: 8³ voxels


@wp.func
def face_tile_range(vertices: wp.array(dtype=wp.vec3d), faces: wp.array(dtype=wp.int32), f: int,
                    tile_mm: wp.float64, reach_mm: wp.float64):
    """Lowest tile and tile counts of the box around face f grown by ``reach_mm``."""
    v0 = vertices[faces[3 * f]]
    v1 = vertices[faces[3 * f + 1]]
    v2 = vertices[faces[3 * f + 2]]
    lo = wp.min(wp.min(v0, v1), v2)
    hi = wp.max(wp.max(v0, v1), v2)
    first = wp.vec3i(0, 0, 0)
    count = wp.vec3i(0, 0, 0)
    for k in range(3):
        a = int(wp.floor((lo[k] - reach_mm) / tile_mm))
        b = int(wp.floor((hi[k] + reach_mm) / tile_mm))
        first[k] = a
        count[k] = b - a + 1
    return first, count


@wp.func
def near_region(vertices: wp.array(dtype=wp.vec3d), faces: wp.array(dtype=wp.int32), f: int,
                centre: wp.vec3d, radius: wp.float64) -> bool:
    """Face f's box comes within ``radius`` of ``centre``."""
    v0 = vertices[faces[3 * f]]
    v1 = vertices[faces[3 * f + 1]]
    v2 = vertices[faces[3 * f + 2]]
    lo = wp.min(wp.min(v0, v1), v2)
    hi = wp.max(wp.max(v0, v1), v2)
    return wp.length(wp.max(wp.min(centre, hi), lo) - centre) <= radius


@wp.kernel
def count_face_tiles(vertices: wp.array(dtype=wp.vec3d), faces: wp.array(dtype=wp.int32), tile_mm: wp.float64,
                     reach_mm: wp.float64, region_centre: wp.vec3d, region_mm: wp.float64,
                     counts: wp.array(dtype=wp.int32)):
    """Tiles in each face's box grown by ``reach_mm`` (the candidates it proposes);
    none for a face farther than the region's radius + reach from its centre."""
    f = wp.tid()
    first, count = face_tile_range(vertices, faces, f, tile_mm, reach_mm)
    counts[f] = 0
    if near_region(vertices, faces, f, region_centre, region_mm + reach_mm):
        counts[f] = count[0] * count[1] * count[2]


@wp.kernel
def propose_face_tiles(vertices: wp.array(dtype=wp.vec3d), faces: wp.array(dtype=wp.int32), tile_mm: wp.float64,
                       reach_mm: wp.float64, region_centre: wp.vec3d, region_mm: wp.float64,
                       offsets: wp.array(dtype=wp.int32), tiles: wp.array(dtype=wp.vec3i),
                       keep: wp.array(dtype=wp.int32)):
    """Each face proposes the tiles of its grown box (as the index of their first
    voxel) and keeps those whose centre lies within ``reach_mm`` of the face's
    plane (a superset of the tiles within reach of the face) and of the region."""
    f = wp.tid()
    if not near_region(vertices, faces, f, region_centre, region_mm + reach_mm):
        return
    first, count = face_tile_range(vertices, faces, f, tile_mm, reach_mm)
    v0 = vertices[faces[3 * f]]
    normal = wp.cross(vertices[faces[3 * f + 1]] - v0, vertices[faces[3 * f + 2]] - v0)
    area2 = wp.length(normal)
    half = wp.float64(0.5) * tile_mm
    k = offsets[f]
    for i in range(count[0]):
        for j in range(count[1]):
            for l in range(count[2]):
                t = wp.vec3i(first[0] + i, first[1] + j, first[2] + l)
                centre = wp.vec3d(wp.float64(t[0]) * tile_mm + half, wp.float64(t[1]) * tile_mm + half,
                                  wp.float64(t[2]) * tile_mm + half)
                near = area2 == wp.float64(0.0) or wp.abs(wp.dot(centre - v0, normal)) <= reach_mm * area2
                near = near and wp.length(centre - region_centre) <= region_mm + reach_mm
                tiles[k] = t * TILE_VOXELS
                keep[k] = wp.where(near, 1, 0)
                k += 1


@wp.kernel
def keep_band_tiles(mesh: wp.uint64, vertices: wp.array(dtype=wp.vec3d), faces: wp.array(dtype=wp.int32),
                    voxel_mm: wp.float64, tiles: wp.array(dtype=wp.vec3i), inner_mm: wp.float64,
                    band_mm: wp.float64, keep: wp.array(dtype=wp.int32)):
    """Keep the tiles that meet the band −inner ≤ d ≤ band: the signed distance of
    the tile's centre within the band grown by the tile's half diagonal."""
    i = wp.tid()
    half = wp.float64(0.5) * wp.float64(TILE_VOXELS) * voxel_mm  # tile of voxel centres 0..7: centre at 3.5 voxels
    t = tiles[i]
    centre = wp.vec3d(wp.float64(t[0]) * voxel_mm + half - wp.float64(0.5) * voxel_mm,
                      wp.float64(t[1]) * voxel_mm + half - wp.float64(0.5) * voxel_mm,
                      wp.float64(t[2]) * voxel_mm + half - wp.float64(0.5) * voxel_mm)
    grow = wp.sqrt(wp.float64(3.0)) * (half - wp.float64(0.5) * voxel_mm)
    zero = wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(0.0))
    face, d, inward = wall_query(mesh, vertices, faces, 0, zero, centre, band_mm + inner_mm + grow)
    keep[i] = wp.where(face >= 0 and d >= -(inner_mm + grow) and d <= band_mm + grow, 1, 0)


@wp.kernel
def fill_distances(volume: wp.uint64, mesh: wp.uint64, vertices: wp.array(dtype=wp.vec3d),
                   faces: wp.array(dtype=wp.int32), voxels: wp.array(dtype=wp.vec3i), voxel_mm: wp.float64,
                   reach_mm: wp.float64, outside_mm: wp.float64):
    """Each active voxel gets the exact signed distance (mm) of its centre; NaN if no
    face is within ``reach_mm`` (which a kept tile cannot have) or if the centre lies
    more than ``outside_mm`` outside the lumen (beyond the band by a stencil's
    diagonal: in no trusted sample of the band). That far out the pseudo-normal's
    side is not confirmed by the winding number (half a tile's voxels lie outside,
    and each confirmation costs ~4× the query): an inside voxel it misjudges is NaN
    too, which leaves its samples to the BVH."""
    i = wp.tid()
    c = voxels[i]
    p = wp.vec3d(wp.float64(c[0]) * voxel_mm, wp.float64(c[1]) * voxel_mm, wp.float64(c[2]) * voxel_mm)
    zero = wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(0.0))
    face, d, inward = wall_query_sided(mesh, vertices, faces, 0, zero, p, reach_mm, outside_mm)
    value = FIELD_NAN
    if face >= 0 and d >= -outside_mm:
        value = wp.float32(d)
    wp.volume_store(volume, c[0], c[1], c[2], value)


@wp.kernel
def find_creases(volume: wp.uint64, voxels: wp.array(dtype=wp.vec3i), crease_mm: wp.float64,
                 crease: wp.array(dtype=wp.int32)):
    """Flag a voxel whose distance has a second difference above ``crease_mm``
    along an axis: the wall's normal turns within a voxel of it (a crease,
    where a trilinear sample would be off by up to a quarter of that). A smooth
    wall of curvature κ gives h²κ, far below."""
    i = wp.tid()
    c = voxels[i]
    d = wp.volume_lookup_f(volume, c[0], c[1], c[2])
    flagged = int(0)
    for axis in range(3):
        e = wp.vec3i(0, 0, 0)
        e[axis] = 1
        up = wp.volume_lookup_f(volume, c[0] + e[0], c[1] + e[1], c[2] + e[2])
        down = wp.volume_lookup_f(volume, c[0] - e[0], c[1] - e[1], c[2] - e[2])
        second = wp.float64(up) + wp.float64(down) - wp.float64(2.0) * wp.float64(d)
        if wp.abs(second) > crease_mm:  # false where a neighbour is outside the band (NaN)
            flagged = 1
    crease[i] = flagged


@wp.kernel
def clear_creases(volume: wp.uint64, voxels: wp.array(dtype=wp.vec3i), crease: wp.array(dtype=wp.int32)):
    """Flagged voxels become NaN: a sample whose stencil touches one goes to the BVH."""
    i = wp.tid()
    if crease[i] != 0:
        c = voxels[i]
        wp.volume_store(volume, c[0], c[1], c[2], FIELD_NAN)


@wp.kernel
def sample_field(volume: wp.uint64, points: wp.array(dtype=wp.vec3d), grad_tolerance: wp.float64,
                 trusted: wp.array(dtype=wp.int32), distance: wp.array(dtype=wp.float64),
                 normal: wp.array(dtype=wp.vec3d)):
    """The field at points (wall frame): for measurements and tests."""
    i = wp.tid()
    ok, d, n = field_sample(volume, points[i], grad_tolerance)
    trusted[i] = wp.where(ok, 1, 0)
    distance[i] = d
    normal[i] = n


@wp.kernel
def exact_distances(mesh: wp.uint64, vertices: wp.array(dtype=wp.vec3d), faces: wp.array(dtype=wp.int32),
                    points: wp.array(dtype=wp.vec3d), distance: wp.array(dtype=wp.float64),
                    normal: wp.array(dtype=wp.vec3d)):
    """The BVH's exact signed distance and inward normal at points (wall frame)."""
    i = wp.tid()
    zero = wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(0.0))
    face, d, n = wall_query(mesh, vertices, faces, 0, zero, points[i], wp.float64(1.0e6))
    distance[i] = d
    normal[i] = n
