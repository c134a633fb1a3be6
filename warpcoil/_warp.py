"""Warp set-up shared by the package: one kernel cache for every process.

The cache folder is ``$WARPCOIL_KERNEL_CACHE`` if set, else Warp's default
(per user); compiled kernels are reused across runs and test sessions.

Warp's native start-up prints "Could not find or load the NVIDIA CUDA driver"
on every machine without a GPU; that line is dropped here (CPU runs do not
need CUDA), and the command line says so in its own words only when a CUDA
device is asked for (``--device cuda:0``). Anything else Warp prints at
start-up is passed on.
"""

import os
import sys
import tempfile

import warp as wp

CUDA_DRIVER_MISSING_LINE = "Could not find or load the NVIDIA CUDA driver"

_cache = os.environ.get("WARPCOIL_KERNEL_CACHE")
if _cache:
    wp.config.kernel_cache_dir = _cache
wp.config.log_level = wp.LOG_WARNING  # no banner or per-module load lines


def _init_without_driver_notice() -> None:
    """wp.init() with its native stderr (fd 2) captured, the CUDA-driver notice removed."""
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError):  # no usable fd 2 (embedded interpreters): init as is
        wp.init()
        return
    with tempfile.TemporaryFile(mode="w+b") as captured:
        os.dup2(captured.fileno(), 2)
        try:
            wp.init()
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        captured.seek(0)
        text = captured.read().decode(errors="replace")
    kept = [line for line in text.splitlines(keepends=True) if CUDA_DRIVER_MISSING_LINE not in line]
    if kept:
        sys.stderr.write("".join(kept))


_init_without_driver_notice()
