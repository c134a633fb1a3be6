#!/usr/bin/env bash
# Issue 11's one prepared GPU run (BENCHMARKS.md section 5), for a session that is lent the
# device machine (an H200 whose image lacks warp-lang, trimesh, usd-core and dask; its 'device'
# tool carries at most 64 MiB a call, the working tree included, and gives a machine back after
# 30 s idle). Three verbs:
#
#   bash benchmarks/device_check.sh fetch     # here: the wheels (cp312, manylinux x86-64) into .whl/,
#                                             # packed and cut into .whl/part_00, part_01, … ≤ PART_MIB
#   bash benchmarks/device_check.sh receive   # there, one device `run` per part, back to back, each
#                                             # carrying the next part (carry: [".whl/part_NN"]): a warm
#                                             # machine keeps what the earlier calls carried
#   bash benchmarks/device_check.sh run       # there, as the last call (carrying the last part, timeout_s
#                                             # 600): joins and installs the wheels, compiles the kernels,
#                                             # then the seed case on cuda:0, `bench ensemble` (B = 1, 16,
#                                             # 256, 4096 deployed to the end) and the test suite; ≤ 580 s,
#                                             # everything under $OUT (status.txt, one log per step)
#
# vtk (140 MB) is left behind: warpcoil imports it only to read .vtk/.vtp walls and necks and to write
# tube meshes and porous.vti, so the seed case runs without its tube mesh and the tests that need VTK
# fail there (listed in $OUT/pytest.log; collection goes on past them). Each step is cut off by its own
# timeout with SIGINT (pytest then prints its summary, a run ends "interrupted" with its outputs), so the
# report always comes back.
set -uo pipefail
cd "$(dirname "$0")/.."
PART_MIB=${PART_MIB:-56}
WHEELS=(warp-lang==1.19.0 trimesh usd-core dask distributed tblib tornado zict locket partd
        pytest-timeout pytest-xdist execnet)  # (the image's pytest has neither plugin the pytest step uses)

fetch() {
    grep -qx '/.whl/' .git/info/exclude 2>/dev/null || echo '/.whl/' >> .git/info/exclude
    rm -rf .whl && mkdir -p .whl/wheels
    python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
        --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 \
        --platform any -d .whl/wheels "${WHEELS[@]}" || return 1
    tar -cf - -C .whl wheels | split -b "${PART_MIB}m" -d - .whl/part_
    rm -rf .whl/wheels
    ls -l .whl
    echo "carry each .whl/part_NN in its own device run, back to back: 'receive' for all but the last, 'run' for it"
}

receive() {
    ls -l .whl/ 2>/dev/null || echo "no .whl/ here: carry [\".whl/part_NN\"]"
}

step() {  # step NAME TIMEOUT_S COMMAND…: its output in $OUT/NAME.log, its exit status in $OUT/status.txt
    local name=$1 limit=$2
    shift 2
    local start=$SECONDS
    timeout -s INT -k 15 "$limit" "$@" > "$OUT/$name.log" 2>&1
    echo "$name: exit $? in $((SECONDS - start)) s" | tee -a "$OUT/status.txt"
}

run() {
    : "${OUT:?OUT is the device tool's output folder}"
    cat .whl/part_* | tar -xf - -C /tmp || { echo "the parts do not join: carry every part first"; return 1; }
    python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site \
        /tmp/wheels/*.whl || return 1
    export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1 WARPCOIL_KERNEL_CACHE=$PWD/.warp_cache
    nvidia-smi -L > "$OUT/device.txt" 2>&1
    python3 -c "import warp as wp; wp.init(); print(wp.__version__, [str(d) for d in wp.get_devices()])" \
        >> "$OUT/device.txt" 2>&1
    step probe 30 python3 -m benchmarks.cuda_probe cuda:0  # graph conditionals and hash grids on this driver
    # every kernel module for the GPU and the CPU, eight at a time, before the tests share the cache
    step compile 150 bash -c "python3 -c 'from benchmarks.cuda_compile import KERNEL_MODULES as k; print(*k)' \
        | tr ' ' '\n' | xargs -P 8 -I{} python3 -c 'import importlib, warp as wp; wp.config.quiet = True; \
m = importlib.import_module(\"{}\"); [wp.load_module(m, device=d) for d in (\"cuda:0\", \"cpu\")]'"
    sed 's/^tube_mesh = true/tube_mesh = false/' scenes/seed_sphere.toml > /tmp/seed.toml  # (no VTK there)
    step seed 60 python3 -m warpcoil.cli run /tmp/seed.toml --device cuda:0 --no-usd -o /tmp/seed
    cp /tmp/seed/result.json "$OUT/seed_result.json" 2>/dev/null
    step ensemble 200 python3 -m warpcoil.cli bench ensemble --device cuda:0 -o /tmp/ensemble
    cp /tmp/ensemble/ensemble.md "$OUT/ensemble.md" 2>/dev/null  # (written after each size: kept if cut off)
    # the GPU-relevant modules first; Warp's default device there is cuda:0
    step pytest 140 python3 -m pytest -q -rfE --timeout 130 -n 8 -p no:cacheprovider --continue-on-collection-errors \
        tests/test_solver.py tests/test_implicit.py tests/test_contact.py tests/test_ensemble.py \
        tests/test_cheap_steps.py tests/test_friction.py tests/test_pair_once.py tests
}

case "${1:-}" in
    fetch) fetch ;;
    receive) receive ;;
    run) run ;;
    *) echo "usage: bash benchmarks/device_check.sh fetch|receive|run (see its header)" >&2; exit 2 ;;
esac
