"""On-disk cache of built wall fields (NanoVDB files), like Warp's kernel cache.

A wall field depends only on the wall (vertices, faces, origin), its band, voxel,
crease threshold and region, and on how it is built (the source of wall_field.py and
its kernels, hashed, and :data:`FIELD_FORMAT_VERSION` for what the source does not show). Its file
is named by a SHA-256 of all of them (and the Warp version and device kind, since a
float32 voxel built on CUDA may round differently from one built on the CPU), so a
changed input never finds a stale file.

Folder: ``$WARPCOIL_FIELD_CACHE`` if set, else ``fields/`` inside the kernel cache
folder (``$WARPCOIL_KERNEL_CACHE`` or Warp's default; Warp's cache clearing only
removes its own ``wp_*`` folders). ``WARPCOIL_FIELD_CACHE=off`` disables it.

Each file is the volume's ``.nvdb`` bytes followed by :data:`TRAILER` and their
SHA-256 (Warp's reader ignores bytes past the grid), written to a temporary file and
renamed into place, so parallel jobs (``warpcoil sweep --jobs N``) never read a
half-written file (a temporary left by a killed writer is removed an hour later). A
file that is short, corrupt or unreadable is rebuilt and replaced.
"""

from __future__ import annotations

import functools
import hashlib
import os
import struct
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
import warp as wp

FIELD_FORMAT_VERSION = 1  # bump when build_wall_field writes different voxels for the same inputs
TEMPORARY_PREFIX = ".warpcoil-field-"  # a writer's temporary file, renamed when complete
FIELD_CACHE_ENV = "WARPCOIL_FIELD_CACHE"
DISABLED_VALUES = ("off", "0", "false", "no", "none")
TRAILER = b"WARPCOIL-SHA256:"
STALE_TEMPORARY_S = 3600.0  # a temporary file this old was left by a killed writer: removed at the next write


def field_cache_dir() -> Path | None:
    """The folder of cached fields, or None when ``WARPCOIL_FIELD_CACHE`` disables it."""
    setting = os.environ.get(FIELD_CACHE_ENV, "").strip()
    if setting.lower() in DISABLED_VALUES:
        return None
    if setting:
        return Path(setting)
    return Path(wp.config.kernel_cache_dir or tempfile.gettempdir()) / "fields"


def field_key(wall, band_mm: float, voxel_mm: float, crease_mm: float, region: tuple | None) -> str:
    """SHA-256 (hex) of everything the field of ``wall`` (a model.WallModel) depends on."""
    digest = hashlib.sha256()
    digest.update(f"warpcoil-field v{FIELD_FORMAT_VERSION} warp {wp.__version__} "
                  f"{'cuda' if wall.vertices.device.is_cuda else 'cpu'}".encode())
    digest.update(_build_code_digest())  # a change to the build's code never serves an old field
    digest.update(np.ascontiguousarray(wall.vertices_mm, dtype=np.float64).tobytes())
    digest.update(np.ascontiguousarray(wall.faces_np, dtype=np.int32).tobytes())
    digest.update(np.ascontiguousarray(wall.origin, dtype=np.float64).tobytes())
    digest.update(struct.pack("<3d", float(band_mm), float(voxel_mm), float(crease_mm)))
    if region is None:
        digest.update(b"whole wall")
    else:
        digest.update(np.ascontiguousarray(region[0], dtype=np.float64).tobytes() + struct.pack("<d", float(region[1])))
    return digest.hexdigest()


@functools.cache
def _build_code_digest() -> bytes:
    """SHA-256 of the source that builds a field (wall_field.py and its kernels)."""
    from . import wall_field
    from .kernels import wall_field as kernels

    return hashlib.sha256(b"".join(Path(m.__file__).read_bytes() for m in (wall_field, kernels))).digest()


def load_volume(path: Path, device) -> wp.Volume | None:
    """The volume stored at ``path``, or None when it is missing, short or corrupt."""
    try:
        data = path.read_bytes()
    except OSError:
        return None
    body, mark, checksum = data[:-32 - len(TRAILER)], data[-32 - len(TRAILER):-32], data[-32:]
    if mark != TRAILER or hashlib.sha256(body).digest() != checksum:
        return None
    try:
        return wp.Volume.load_from_nvdb(body, device=device)
    except Exception:  # noqa: BLE001 — a file the checksum passes but Warp rejects: rebuild it
        return None


def save_volume(volume: wp.Volume, path: Path) -> bool:
    """Write ``volume`` to ``path`` atomically (temporary file, then rename); False
    (with a warning) when the folder cannot be written — the run goes on uncached."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        remove_stale_temporaries(path.parent)
        handle, temporary = tempfile.mkstemp(prefix=TEMPORARY_PREFIX + path.stem + ".", suffix=".tmp",
                                             dir=path.parent)
        os.close(handle)
    except OSError as error:
        warnings.warn(f"wall field cache {path.parent} not writable ({error}); set {FIELD_CACHE_ENV} to a "
                      f"writable folder or to 'off'", stacklevel=3)
        return False
    try:
        volume.save_to_nvdb(temporary)
        body = Path(temporary).read_bytes()
        with open(temporary, "ab") as handle:
            handle.write(TRAILER + hashlib.sha256(body).digest())
        os.replace(temporary, path)
        return True
    except OSError as error:
        warnings.warn(f"could not write the wall field cache file {path} ({error})", stacklevel=3)
        return False
    finally:
        if os.path.exists(temporary):
            os.remove(temporary)


def remove_stale_temporaries(folder: Path) -> None:
    """Remove temporary files older than STALE_TEMPORARY_S (a writer killed before its rename)."""
    now = time.time()
    for temporary in folder.glob(TEMPORARY_PREFIX + "*.tmp"):  # ours only: the folder may be shared
        try:
            if now - temporary.stat().st_mtime > STALE_TEMPORARY_S:
                temporary.unlink()
        except OSError:  # another job removed or renamed it first
            pass


def cached_wall_field(wall, band_mm: float, voxel_mm: float, crease_mm: float, region: tuple | None):
    """The field of ``wall`` from the cache folder when a valid file holds it, else
    built by ``wall_field.build_wall_field`` and stored there (wall_field.WallField)."""
    from .wall_field import INNER_MM_VOXELS, WallField, build_wall_field

    folder = field_cache_dir()
    if folder is None:
        return build_wall_field(wall, band_mm, voxel_mm, crease_mm, region)
    start = time.perf_counter()
    path = folder / f"{field_key(wall, band_mm, voxel_mm, crease_mm, region)}.nvdb"
    volume = load_volume(path, wall.vertices.device)
    if volume is not None:
        return WallField(volume=volume, voxel_mm=float(voxel_mm), band_mm=float(band_mm),
                         inner_mm=INNER_MM_VOXELS * float(voxel_mm), voxels=int(volume.get_voxel_count()),
                         build_s=time.perf_counter() - start, from_cache=True)
    field = build_wall_field(wall, band_mm, voxel_mm, crease_mm, region)
    save_volume(field.volume, path)
    return field
