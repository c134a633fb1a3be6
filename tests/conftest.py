"""One Warp kernel cache for the whole test run (compile once per run, not per test)."""

import os
from pathlib import Path

os.environ.setdefault("WARPCOIL_KERNEL_CACHE", str(Path(__file__).resolve().parents[1] / ".warp_cache"))
