"""Command line: ``warpcoil run SCENE.toml``, ``warpcoil sweep``, ``warpcoil validate``, ``warpcoil bench``.

Exit codes: 0 completed (or validation passed), 1 failed (unstable run, or a
validation case out of tolerance), 2 bad input, 3 jammed or timed out.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

EXIT_FOR_STATUS = {"completed": 0, "failed": 1, "jammed": 3, "timeout": 3}


def _run(args: argparse.Namespace) -> int:
    from .deploy import Deployment
    from .preshape import PreshapeError
    from .recorder import outputs
    from .scene import SceneError, load_scene
    from .solver import UnstableStepError
    from .wall import WallError

    try:
        scene = load_scene(args.scene)
        if args.frame_interval is not None:
            scene = replace(scene, simulation=replace(scene.simulation, frame_interval_s=args.frame_interval))
        deployment = Deployment(scene)
    except (SceneError, WallError, PreshapeError, UnstableStepError) as error:
        print(f"warpcoil run: {error}", file=sys.stderr)
        return 2
    out = Path(args.output) if args.output else Path("out") / Path(args.scene).stem
    out.mkdir(parents=True, exist_ok=True)
    usd = None
    if scene.output.usd and not args.no_usd:
        usd = outputs.UsdFrames.for_model(out / outputs.DEPLOYMENT_USD, deployment.model,
                                          scene.simulation.frame_interval_s)
    progress = _progress(deployment, quiet=args.quiet)

    def on_frame(frame, state):
        if usd is not None:
            usd(frame, state)
        progress(frame)

    result = deployment.run(on_frame)
    progress(None)
    if usd is not None:
        usd.close()
    outputs.write_run(out, scene, deployment.anatomy.wall, result, {"scene": str(scene.source)})
    print(f"{result.status}: {result.reason}")
    density = f"{100 * result.packing_density:.1f} %" if result.packing_density is not None else "n/a (no wall)"
    print(f"deployed {result.deployed_length_mm:.1f} of {result.coil_length_mm:.1f} mm, packing density {density}, "
          f"{result.steps} steps of {result.dt_s:.3g} s in {result.wall_time_s:.1f} s wall time -> {out}")
    return EXIT_FOR_STATUS[result.status]


def _progress(deployment, quiet: bool):
    """A tqdm bar over the deployed length (mm), with push force; silent when quiet."""
    if quiet:
        return lambda frame: None
    from tqdm import tqdm

    bar = tqdm(total=round(float(deployment.coil_lengths_mm.sum()), 1), unit="mm", desc="deployed",
               bar_format="{desc} {n:.1f}/{total} mm |{bar}| {elapsed} {postfix}")

    def update(frame):
        if frame is None:
            bar.close()
            return
        bar.n = round(frame.deployed_length_mm, 1)
        bar.set_postfix_str(f"push {frame.push_force_uN:8.1f} µN, t = {frame.time_s:.3f} s", refresh=True)

    return update


def _sweep(args: argparse.Namespace) -> int:
    from .model import EnsembleError
    from .preshape import PreshapeError
    from .scene import SceneError
    from .solver import UnstableStepError
    from .sweep import SweepError, parse_vary, run_sweep
    from .wall import WallError

    out = Path(args.output) if args.output else Path("out") / f"{Path(args.scene).stem}_sweep"
    try:
        varies = [parse_vary(v) for v in args.vary]
        if args.jobs < 1:
            raise SweepError(f"--jobs {args.jobs}: give 1 or more worker processes")
        bar = None
        if not args.quiet:
            from tqdm import tqdm
            bar = tqdm(unit="deployment", desc="sweep")

        def progress(done, total):
            bar.total = total
            bar.update(done - bar.n)

        todo = run_sweep(Path(args.scene), varies, out, args.device, progress if bar else None, args.jobs, args.usd)
        if bar:
            bar.close()
    except (SweepError, SceneError, WallError, PreshapeError, UnstableStepError, EnsembleError) as error:
        print(f"warpcoil sweep: {error}", file=sys.stderr)
        return 2
    print((out / "summary.md").read_text())
    codes = {EXIT_FOR_STATUS[m.result.status] for m in todo}
    return 1 if 1 in codes else max(codes)


def _validate(args: argparse.Namespace) -> int:
    from . import validation

    unknown = sorted(set(args.cases) - set(validation.CASES))
    if unknown:
        print(f"warpcoil validate: unknown case(s) {', '.join(unknown)}; choose from {', '.join(validation.CASES)}",
              file=sys.stderr)
        return 2
    rows = validation.run(args.cases or None)
    print(validation.format_table(rows))
    failed = [r for r in rows if not r.passed]
    print(f"\n{len(rows) - len(failed)} passed, {len(failed)} failed")
    return 1 if failed else 0


def _bench(args: argparse.Namespace) -> int:
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    if args.kind == "ensemble":
        from .bench.ensemble import main as ensemble_main

        return ensemble_main(out, quick=args.quick, repeats=1, device=args.device)
    if args.kind == "accuracy":
        from .bench.accuracy import main as bench_main
    elif args.kind == "peers":
        from .bench.peers import main as bench_main
    elif args.kind == "steps":
        from .bench.steps import main as bench_main
    else:
        from .bench.stress import main as bench_main
    repeats = args.repeats if args.repeats is not None else 3
    return bench_main(out, quick=args.quick, repeats=repeats)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="warpcoil", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    from .validation import CASES

    validate = sub.add_parser("validate", help="run the validation cases and print a table; exit 1 on a failure")
    validate.add_argument("cases", nargs="*", metavar="CASE",
                          help=f"subset of: {', '.join(CASES)} (default: all)")
    validate.set_defaults(func=_validate)

    bench = sub.add_parser("bench", help="benchmarks: run time against error, stress sweep")
    bench.add_argument("kind", choices=["accuracy", "stress", "peers", "ensemble", "steps"])
    bench.add_argument("--device", help="Warp device for `ensemble` (cpu, cuda:0; default Warp's)")
    bench.add_argument("--quick", action="store_true", help="the short variant (< 3 min on 2 CPU cores)")
    bench.add_argument("-o", "--output", default="out/bench", help="folder for the report, table and plot")
    bench.add_argument("--repeats", type=int, help="timing runs per setting, median reported (default 3)")
    bench.set_defaults(func=_bench)

    sweep = sub.add_parser("sweep", help="deploy variants of a scene in batched ensembles; one result each + summary")
    sweep.add_argument("scene", help="scene TOML file")
    sweep.add_argument("--vary", action="append", required=True, metavar="KEY=START:STOP:STEP|A,B,C",
                       help="a scene key to vary, e.g. catheter.angle_deg=0:30:5 or coil.length_mm=40,50 (repeat "
                            "for a product)")
    sweep.add_argument("-o", "--output", help="output folder (default out/<scene name>_sweep)")
    sweep.add_argument("--device", help="Warp device, e.g. cpu or cuda:0 (default Warp's)")
    sweep.add_argument("-j", "--jobs", type=int, default=1,
                       help="worker processes, each running a share of the members (on the CPU a launch uses one "
                            "core: give the number of cores; default 1)")
    sweep.add_argument("--usd", action="store_true", help="also write each member's deployment.usdc")
    sweep.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    sweep.set_defaults(func=_sweep)
    run = sub.add_parser("run", help="deploy the coils of a scene and write result.json, CSVs and USD")
    run.add_argument("scene", help="scene TOML file")
    run.add_argument("-o", "--output", help="output folder (default out/<scene name>)")
    run.add_argument("--no-usd", action="store_true", help="skip deployment.usdc")
    run.add_argument("--frame-interval", type=float, help="seconds of simulated time between recorded frames")
    run.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    run.set_defaults(func=_run)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
