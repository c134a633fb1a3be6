"""One Warp kernel cache for the whole test run (compile once per run, not per test); the checkout's
root on the import path, for the tests of benchmarks/ (not part of the installed package)."""

import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
os.environ.setdefault("WARPCOIL_KERNEL_CACHE", str(ROOT / ".warp_cache"))
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))
