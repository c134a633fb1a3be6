"""Compile every warpcoil kernel module for a CUDA architecture without a GPU.

Warp ships NVRTC, so the CUDA code generation of each module (the same source
the CPU path runs) can be checked ahead of time on a machine with no driver:
a kernel that only fails to build for CUDA (a type Warp cannot lower there,
a missing overload) shows up here, not on a user's workstation.

    python -m benchmarks.cuda_compile            # sm_90 (H100/H200)
    python -m benchmarks.cuda_compile --arch 80  # A100

Cold compile on the 2-core development CPU: a few minutes (the contact and
friction modules take most of it). Exits 1 if any module fails.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import tempfile
import time

import warp as wp

KERNEL_MODULES = (
    "warpcoil.kernels.chord", "warpcoil.kernels.contact", "warpcoil.kernels.devices", "warpcoil.kernels.elastic",
    "warpcoil.kernels.friction", "warpcoil.kernels.friction_damping", "warpcoil.kernels.implicit",
    "warpcoil.kernels.integrate", "warpcoil.kernels.node_theta",
    "warpcoil.kernels.wall_field", "warpcoil.kernels.wall_measure", "warpcoil.geometry", "warpcoil.porous", "warpcoil.preflight",
    "warpcoil.bench.steps",
)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--arch", type=int, default=90, help="CUDA compute capability ×10 (default 90: sm_90)")
    args = parser.parse_args(argv)
    wp.config.quiet = True
    wp.init()
    failed = 0
    with tempfile.TemporaryDirectory() as out:
        for name in KERNEL_MODULES:
            start = time.perf_counter()
            try:
                artefacts = wp.compile_aot_module(importlib.import_module(name), arch=args.arch, module_dir=out)
                print(f"{name}: ok in {time.perf_counter() - start:.1f} s ({', '.join(p.name for p in artefacts)})")
            except Exception as error:  # noqa: BLE001 — report every module, then fail
                failed += 1
                print(f"{name}: FAILED after {time.perf_counter() - start:.1f} s: {error}")
    print(f"{len(KERNEL_MODULES) - failed} of {len(KERNEL_MODULES)} kernel modules compile for sm_{args.arch}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
