"""Probes of what the CPU cannot show, first in a lent GPU's run (benchmarks/device_check.sh;
``python3 -m benchmarks.cuda_probe [device]``), from a review of the CUDA path (BENCHMARKS.md section 5):

0. toolkit, driver, conditional-graph support, mempool;
1. ``HashGrid.build`` inside ``wp.capture_if`` inside a captured graph (as the Stepper's neighbour
   rebuild): capture, instantiation at the first launch, a correct result;
2. two float64 hash grids each built in its own captured graph, A replayed after B's capture: does A's
   replay pick up B's descriptor (Warp's native hashgrid keeps one static descriptor per type)?
3. ``validation_push._law_uN`` (CPU arrays beside a GPU default device)."""
import argparse

import numpy as np
import warp as wp

parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
parser.add_argument("device", nargs="?", help="Warp device, e.g. cuda:0 (default Warp's)")
dev = wp.get_device(parser.parse_args().device)
from warp._src import context as c
print("device", dev, "toolkit", c.runtime.toolkit_version, "driver", c.runtime.driver_version,
      "conditional", wp.is_conditional_graph_supported(),
      "mempool", (wp.is_mempool_enabled(dev) if dev.is_cuda else None), flush=True)

@wp.kernel
def count_near(grid: wp.uint64, pts: wp.array(dtype=wp.vec3d), r: wp.float64, out: wp.array(dtype=wp.int32)):
    i = wp.tid()
    q = wp.hash_grid_query(grid, pts[i], r)
    n = int(0)
    j = int(0)
    while wp.hash_grid_query_next(q, j):
        if wp.length(pts[i] - pts[j]) <= r:
            n += 1
    out[i] = n

def make(offset, n=64):
    rng = np.random.default_rng(int(offset))
    p = wp.array(rng.uniform(0, 1, (n, 3)) + offset, dtype=wp.vec3d, device=dev)
    g = wp.HashGrid(16, 16, 16, device=dev, dtype=wp.float64)
    g.build(p, 0.2)
    return p, g, wp.zeros(n, dtype=wp.int32, device=dev)

def expected(p, r=0.2):
    a = p.numpy(); d = np.linalg.norm(a[:, None] - a[None], axis=2)
    return (d <= r).sum(axis=1)

# 1. conditional build
p, g, out = make(0.0)
flag = wp.ones(1, dtype=wp.int32, device=dev)
try:
    with wp.ScopedCapture(device=dev) as cap:
        wp.capture_if(flag, on_true=lambda: g.build(p, 0.2))
        wp.launch(count_near, p.shape[0], inputs=[g.id, p, 0.2, out], device=dev)
    p.assign(p.numpy() + 0.5)  # moved: only a rebuild in the graph finds the new cells right
    wp.capture_launch(cap.graph)
    wp.synchronize_device(dev)
    print("1 capture_if(HashGrid.build):", "OK" if np.array_equal(out.numpy(), expected(p)) else "WRONG RESULT")
except Exception as e:  # noqa: BLE001
    print("1 capture_if(HashGrid.build): FAILED:", type(e).__name__, e)

# 2. two grids, interleaved replays
pa, ga, oa = make(0.0)
pb, gb, ob = make(10.0, n=32)
graphs = []
for p_, g_, o_ in ((pa, ga, oa), (pb, gb, ob)):
    with wp.ScopedCapture(device=dev) as cap:
        g_.build(p_, 0.2)
        wp.launch(count_near, p_.shape[0], inputs=[g_.id, p_, 0.2, o_], device=dev)
    graphs.append(cap.graph)
wp.capture_launch(graphs[0])  # A replayed after B was captured
wp.synchronize_device(dev)
print("2 grid A replayed after grid B's capture:",
      "OK" if np.array_equal(oa.numpy(), expected(pa)) else "WRONG (cross-talk)")

# 3. validation_push._law_uN as written (arrays on the default device, launch on cpu)
try:
    from warpcoil.validation_push import _law_uN
    print("3 validation_push._law_uN:", _law_uN(0.0, 1.0, 0.03, 7.0))
except Exception as e:  # noqa: BLE001
    print("3 validation_push._law_uN: FAILED:", type(e).__name__, str(e)[:160])
