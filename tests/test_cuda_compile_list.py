"""The CUDA ahead-of-time compile check (benchmarks/cuda_compile.py) covers every
module of the package that defines a Warp kernel, so no kernel reaches a GPU
without having been through NVRTC on a machine without one."""

from pathlib import Path

from benchmarks.cuda_compile import KERNEL_MODULES

PACKAGE = Path(__file__).resolve().parents[1] / "warpcoil"


def test_every_kernel_module_is_compiled_for_cuda():
    defining = {".".join(path.relative_to(PACKAGE.parent).with_suffix("").parts)
                for path in PACKAGE.rglob("*.py") if "@wp.kernel" in path.read_text()}
    assert defining == set(KERNEL_MODULES)
