"""Warp set-up shared by the package: one kernel cache for every process.

The cache folder is ``$WARPCOIL_KERNEL_CACHE`` if set, else Warp's default
(per user); compiled kernels are reused across runs and test sessions.
"""

import os

import warp as wp

_cache = os.environ.get("WARPCOIL_KERNEL_CACHE")
if _cache:
    wp.config.kernel_cache_dir = _cache
wp.config.log_level = wp.LOG_WARNING  # no banner or per-module load lines
wp.init()
