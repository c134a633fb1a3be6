"""Command line: ``warpcoil run SCENE.toml``, ``warpcoil sweep``, ``warpcoil plan``, ``warpcoil validate``,
``warpcoil bench``, ``warpcoil coils``.

Exit codes: 0 completed (or validation passed), 1 failed (unstable run, or a
validation case out of tolerance), 2 bad input, 3 jammed or timed out,
4 the outputs could not be written (a full disk: none is left half-written),
130 interrupted (Ctrl-C, or SIGTERM from a batch scheduler).
"""

from __future__ import annotations

import argparse
import errno
import math
import sys
from contextlib import nullcontext
from pathlib import Path

EXIT_FOR_STATUS = {"completed": 0, "failed": 1, "jammed": 3, "timeout": 3, "interrupted": 130}
EXIT_INTERRUPTED = 130  # 128 + SIGINT, as a shell reports a Ctrl-C
EXIT_NOT_WRITTEN = 4  # an output could not be written (OSError: a full disk, a file-size limit)
WRITE_ERRORS = {errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EIO, errno.EROFS}  # the storage failed us


def _not_written(command: str, out: Path, error: OSError, kept: str) -> int:
    """One line for outputs that could not be written into ``out`` (``kept``: what is left there); exit 4.
    An OSError other than the storage's (WRITE_ERRORS) is raised again: it is no full disk."""
    if error.errno not in WRITE_ERRORS:
        raise error
    name = errno.errorcode[error.errno]
    print(f"warpcoil {command}: {out}: writing the outputs failed ({error.strerror}, {name}); {kept}; fix: free "
          "space on that disk (or raise the file-size limit, or choose another output folder) and run again",
          file=sys.stderr)
    return EXIT_NOT_WRITTEN


def _positive_seconds(text: str) -> float:
    """argparse type: a finite number of seconds > 0."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0.0):
        raise argparse.ArgumentTypeError(f"{text!r} is not a finite number of seconds > 0; give e.g. 0.01")
    return value


def _device(name: str | None):
    """The Warp device asked for (None: Warp's default); a CUDA device on a machine
    without a CUDA driver is refused here, once, in plain words."""
    if name is None:
        return None
    import warp as wp

    from .preflight import SetupError

    if name.startswith("cuda") and not wp.is_cuda_available():
        raise SetupError(f"--device {name}: no NVIDIA CUDA driver was found on this machine, so Warp can only run on "
                         "the CPU here; fix: use --device cpu (or leave --device out), or run on a machine with an "
                         "NVIDIA GPU and driver")
    try:
        return wp.get_device(name)
    except (RuntimeError, ValueError) as error:
        raise SetupError(f"--device {name}: {error}; fix: give cpu or cuda:N") from None


def _force_text(frame) -> str:
    """The frame's push force for the progress display, named as in timeseries.csv (mN)."""
    mN = lambda uN: round(uN / 1e3, 6) + 0.0  # noqa: E731  (no -2e-18 for a zero)
    return (f"push mean {mN(frame.push_force_mean_uN):.3g} mN, peak {mN(frame.push_force_peak_uN):.3g} mN, "
            f"t = {frame.time_s:.2f} s")


def _run(args: argparse.Namespace) -> int:
    from .deploy import Deployment
    from .preflight import SetupError, preflight
    from .preshape import PreshapeError
    from .recorder import outputs
    from .recorder.folder import OutputFolderError, check_output_path, claimed_folder, resumed_folder
    from .scene import SceneError, load_scene
    from .solver import UnstableStepError
    from .wall import WallError

    out = Path(args.output) if args.output else Path("out") / Path(args.scene).stem
    try:
        check_output_path(out)
        device = _device(args.device)
        scene = load_scene(args.scene, {} if args.frame_interval is None else
                           {"simulation.frame_interval_s": args.frame_interval})
        try:
            deployment = Deployment(scene, device)
        except UnstableStepError as error:
            raise SceneError(f"{scene.source}: simulation.dt_s: {error}") from None
        warnings = preflight(scene, deployment.anatomy, device, deployment.members[0].step_bound_s)
    except (SceneError, WallError, PreshapeError, SetupError, OutputFolderError) as error:
        given = args.frame_interval is not None and str(error).startswith(  # the flag's value, not the file's
            f"{Path(args.scene).expanduser().resolve()}: simulation.frame_interval_s")
        print(f"warpcoil run: {f'--frame-interval {args.frame_interval:g}: ' if given else ''}{error}", file=sys.stderr)
        return 2
    wall = deployment.anatomy.wall
    for note in (wall.notes if wall is not None else ()):
        print(f"warpcoil run: wall {wall.source}: {note}", file=sys.stderr)
    for warning in warnings:
        print(f"warpcoil run: warning: {warning}", file=sys.stderr)
    try:
        with claimed_folder(out, outputs.ALL_OUTPUTS, args.overwrite,
                            folder_pattern=outputs.MEMBER_FOLDERS):  # (a sweep's or plan's folder is no run's)
            return _deploy_into(out, scene, deployment, args, warnings)
    except OutputFolderError as error:
        print(f"warpcoil run: {error}", file=sys.stderr)
        return 2
    except OSError as error:
        return _not_written("run", out, error, "none of this run's outputs were left there")


def _deploy_into(out: Path, scene, deployment, args: argparse.Namespace, warnings: list[str]) -> int:
    """The run itself, into the claimed folder ``out``: frames to the USD and the
    animation as they come, then the outputs, all in a hidden folder moved into ``out``
    at the end (recorder.folder.staged_outputs: a killed run leaves none); the exit code
    of its status."""
    from .deploy import INTERRUPTED, stop_between_frames
    from .progress import Progress
    from .recorder import outputs
    from .recorder.folder import staged_outputs

    with staged_outputs(out, last=outputs.RESULT_JSON) as stage:
        recorders = []
        if scene.output.usd and not args.no_usd:
            recorders.append(outputs.UsdFrames.for_model(stage / outputs.DEPLOYMENT_USD, deployment.model,
                                                         scene.simulation.frame_interval_s,
                                                         deployment.members[0].withdrawn_from))
        if scene.output.animation:
            from .recorder.animation import AnimationFrames

            recorders.append(AnimationFrames.for_model(stage / outputs.ANIMATION_GIF, deployment.model,
                                                       deployment.anatomy.catheter, scene.simulation.frame_interval_s))
        progress = Progress("deployed", "mm", total=round(float(deployment.coil_lengths_mm.sum()), 1),
                            quiet=args.quiet)

        def on_frame(frame, state):
            for recorder in recorders:
                recorder(frame, state)
            progress.update(frame.deployed_length_mm, _force_text(frame))

        result = deployment.run(on_frame)
        # the run has ended: a first Ctrl-C waits for its outputs (after one that ended the run, the next stops at once)
        with stop_between_frames() if result.status != INTERRUPTED else nullcontext([False]) as late:
            progress.close()
            for recorder in recorders:
                recorder.close()
            outputs.write_run(stage, scene, deployment.anatomy.wall, result,
                              {"scene": str(scene.source), "warnings": warnings}, sac=deployment.anatomy.sac)
    if late[0]:
        print("warpcoil run: interrupted after the last frame: the outputs were written first", file=sys.stderr)
    print(f"{result.status}: {result.reason}")
    density = (f"in sac {100 * result.packing_density_in_sac:.1f} % (all deployed coil "
               f"{100 * result.packing_density:.1f} %)" if result.packing_density_in_sac is not None
               else "n/a (no wall)")
    print(f"deployed {result.deployed_length_mm:.1f} of {result.coil_length_mm:.1f} mm, packing density {density}, "
          f"{result.steps} {result.scheme['integrator']} steps of {result.dt_s:.3g} s"
          f"{f' (then {result.settle_dt_s:.3g} s)' if result.settle_dt_s else ''} in {result.wall_time_s:.1f} s wall time -> {out}")
    return EXIT_INTERRUPTED if late[0] else EXIT_FOR_STATUS[result.status]


def _coils(args: argparse.Namespace) -> int:
    from .catalog import CatalogueError, listing, select

    try:
        lines = select(args.family)
    except CatalogueError as error:
        print(f"warpcoil coils: --family: {error}", file=sys.stderr)
        return 2
    sys.stdout.write(listing(lines))
    return 0


def _sweep(args: argparse.Namespace) -> int:
    from .model import EnsembleError
    from .recorder import outputs
    from .recorder.folder import OutputFolderError, check_output_path, claimed_folder, clear_outputs, resumed_folder
    from .sweep import SCENE_ERRORS, SweepError, SweepIncomplete, SweepProgress, members, parse_vary, run_sweep

    out = Path(args.output) if args.output else Path("out") / f"{Path(args.scene).stem}_sweep"
    progress = SweepProgress(quiet=args.quiet)
    try:
        if args.jobs is not None:
            raise SweepError(f"--jobs {args.jobs}: removed; sweeps run on Dask: give --workers {args.jobs} (local "
                             "worker processes) or --scheduler ADDRESS (an existing cluster)")
        if args.workers is not None and (args.workers < 1 or args.scheduler):
            raise SweepError(f"--workers {args.workers}: give 1 or more local worker processes, and no --scheduler "
                             "(a cluster's size is set where its workers start)")
        _check_options(args)
        check_output_path(out)
        if not args.scheduler:  # a cluster's workers may have devices this machine lacks
            _device(args.device)
        varies = [parse_vary(v) for v in args.vary]
        progress.start(len(members(varies)))
        if args.resume:  # keeps the member folders (the complete ones are not rerun) and, until the resumed
            claim = resumed_folder(out)  # sweep is checked, the summary (sweep.run_members)
        else:  # (--overwrite clears the earlier outputs once every member is checked: a bad input keeps them)
            claim = claimed_folder(out, outputs.ALL_OUTPUTS, args.overwrite,
                                   folder_pattern=outputs.MEMBER_FOLDERS, clear=False)
        with claim:
            todo = run_sweep(Path(args.scene), varies, out, args.device, progress, args.scheduler, args.workers,
                             args.usd, args.resume, args.retries, checked=None if args.resume else lambda:
                             clear_outputs(out, outputs.ALL_OUTPUTS, outputs.MEMBER_FOLDERS))
    except (SweepError, *SCENE_ERRORS, EnsembleError, OutputFolderError) as error:
        progress.close(failed=True)
        print(f"warpcoil sweep: {error}", file=sys.stderr)
        return 2
    except SweepIncomplete as error:
        progress.close(failed=True)
        print(f"warpcoil sweep: {error}", file=sys.stderr)
        return 1
    except OSError as error:
        progress.close(failed=True)
        return _not_written("sweep", out, error, "the member folders written before are complete, no summary was "
                            "written; rerun with --resume to finish")
    progress.close()
    print((out / "summary.md").read_text())
    codes = {EXIT_FOR_STATUS[m.result["status"]] for m in todo}
    return 1 if 1 in codes else max(codes)


def _add_retries(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--retries", type=int, default=2, metavar="N",
                        help="rerun a task that raised or whose worker died up to N times (default 2)")


def _check_options(args: argparse.Namespace) -> None:
    """The options of sweep and plan that no value or pair of them allows: a --scheduler address Dask
    cannot read, --retries below 0, and --resume with --overwrite (keep the complete members, or replace
    them all: --resume won, unseen)."""
    from .sweep import SweepError, check_scheduler

    check_scheduler(args.scheduler)
    if args.retries < 0:
        raise SweepError(f"--retries {args.retries}: give 0 or more")
    if args.resume and args.overwrite:
        raise SweepError("--resume and --overwrite: --resume keeps the complete members, --overwrite replaces "
                         "them all; fix: give one of them")


def _plan(args: argparse.Namespace) -> int:
    from .model import EnsembleError
    from .plan import PlanError, read_plan, run_plan
    from .recorder import outputs
    from .recorder.folder import OutputFolderError, check_output_path, claimed_folder, clear_outputs, resumed_folder
    from .sweep import SCENE_ERRORS, SweepError, SweepIncomplete, SweepProgress, parse_vary

    out = Path(args.output) if args.output else Path("out") / f"{Path(args.scene).stem}_plan"
    progress = SweepProgress(quiet=args.quiet, command="plan")
    try:
        if args.workers is not None and (args.workers < 1 or args.scheduler):
            raise SweepError(f"--workers {args.workers}: give 1 or more local worker processes, and no --scheduler")
        _check_options(args)
        check_output_path(out)
        if not args.scheduler:
            _device(args.device)
        plan = read_plan(Path(args.scene), [parse_vary(v) for v in args.vary or []])
        progress.start(len(plan.options) * plan.perturbations)
        claim = resumed_folder(out) if args.resume else claimed_folder(  # (cleared once every run is checked)
            out, outputs.ALL_OUTPUTS, args.overwrite, folder_pattern=outputs.MEMBER_FOLDERS, clear=False)
        with claim:
            result = run_plan(Path(args.scene), plan, out, args.device, progress, args.scheduler, args.workers,
                              args.resume, args.retries, checked=None if args.resume else lambda:
                              clear_outputs(out, outputs.ALL_OUTPUTS, outputs.MEMBER_FOLDERS))
    except (PlanError, SweepError, *SCENE_ERRORS, EnsembleError, OutputFolderError) as error:
        progress.close(failed=True)
        print(f"warpcoil plan: {error}", file=sys.stderr)
        return 2
    except SweepIncomplete as error:
        progress.close(failed=True)
        print(f"warpcoil plan: {error}", file=sys.stderr)
        return 1
    except OSError as error:
        progress.close(failed=True)
        return _not_written("plan", out, error, "the member folders written before are complete, no summary was "
                            "written; rerun with --resume to finish")
    progress.close()
    print((out / "plan.md").read_text())
    return 1 if any(r.rank == 0 for r in result.ranked) else 0  # an option none of whose runs gave a result


def _validate(args: argparse.Namespace) -> int:
    from . import validation

    unknown = [name for name in args.cases if validation.case_name(name) not in validation.CASES]
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
    from .preflight import SetupError
    from .recorder.folder import OutputFolderError, claimed_folder

    ensemble = args.kind == "ensemble"
    refused = None
    if args.device is not None and not ensemble:
        refused = (f"--device applies to `bench ensemble` only ({args.kind} runs on Warp's default device); "
                   "fix: leave --device out")
    elif args.repeats is not None and ensemble:
        refused = "--repeats does not apply to `bench ensemble` (it times each size once); fix: leave --repeats out"
    elif args.repeats is not None and args.repeats < 1:
        refused = f"--repeats {args.repeats}: the timing runs per setting (median reported); fix: give 1 or more"
    try:
        device = _device(args.device)
    except SetupError as error:
        refused = str(error)
    if refused:
        print(f"warpcoil bench: {refused}", file=sys.stderr)
        return 2
    try:  # (a report replaces the same benchmark's last one in the folder)
        with claimed_folder(Path(args.output), (), overwrite=True) as out:
            return _bench_into(out, args, device)
    except OutputFolderError as error:
        print(f"warpcoil bench: {error}", file=sys.stderr)
        return 2


def _bench_into(out: Path, args: argparse.Namespace, device) -> int:
    """The benchmark ``args.kind`` into the claimed folder ``out``; its exit code."""
    if args.kind == "ensemble":
        from .bench.ensemble import main as ensemble_main

        return ensemble_main(out, quick=args.quick, repeats=1, device=device)
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


class _Parser(argparse.ArgumentParser):
    """argparse, but a usage error is one line (what is wrong, where to look) and exit 2."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: {message}; see {self.prog} --help\n")


RUN_EXITS = ("exit codes: 0 completed; 1 failed (went unstable); 2 bad input (nothing run); 3 jammed or timed "
             "out; 4 the outputs could not be written (a full disk; none left); 130 interrupted")
SWEEP_EXITS = ("exit codes: 0 every member completed; 1 a member failed (went unstable), or members were not run "
               "(their task still raised after --retries: rerun with --resume); 2 bad input (nothing run); 3 no "
               "member failed but one jammed or timed out; 4 the outputs could not be written (a full disk); 130 "
               "interrupted (Ctrl-C, SIGTERM)")
PLAN_EXITS = ("exit codes: 0 ranked, every option with a usable run (completed, jammed or timed out); 1 an option "
              "none of whose runs gave a result (all failed), or runs were not done (rerun with --resume); 2 bad "
              "input (nothing run); 4 the outputs could not be written (a full disk); 130 interrupted")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="warpcoil", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    from .validation import CASES

    validate = sub.add_parser("validate", help="run the validation cases and print a table; exit 1 on a failure")
    validate.add_argument("cases", nargs="*", metavar="CASE",
                          help=f"subset of: {', '.join(CASES)} (default: all)")
    validate.set_defaults(func=_validate)

    bench = sub.add_parser("bench", help="benchmarks: accuracy (run time against error), stress (hard cases), peers "
                                         "(against PyElastica and the NumPy twin), ensemble (batched deployments), "
                                         "steps (per-step cost, change by change)")
    bench.add_argument("kind", choices=["accuracy", "stress", "peers", "ensemble", "steps"],
                       help="accuracy: run time against error; stress: hard set-ups; peers: against PyElastica and "
                            "the NumPy twin; ensemble: deployments per minute of batched sweeps; steps: the seed "
                            "case's per-step cost with each cheap-step change and a per-launch profile")
    bench.add_argument("--device", help="Warp device for `ensemble` (cpu, cuda:0; default Warp's)")
    bench.add_argument("--quick", action="store_true", help="the short variant (< 3 min on 2 CPU cores)")
    bench.add_argument("-o", "--output", default="out/bench", help="folder for the report, table and plot")
    bench.add_argument("--repeats", type=int, help="timing runs per setting, median reported (default 3)")
    bench.set_defaults(func=_bench)

    sweep = sub.add_parser("sweep", help="deploy variants of a scene in batched ensembles; one result each + summary",
                           epilog=SWEEP_EXITS)
    sweep.add_argument("scene", help="scene TOML file")
    sweep.add_argument("--vary", action="append", required=True, metavar="KEY=START:STOP:STEP|A,B,C",
                       help="a scene key to vary, e.g. catheter.angle_deg=0:30:5 or coil.length_mm=40,50 (repeat "
                            "for a product)")
    sweep.add_argument("-o", "--output", help="output folder (default out/<scene name>_sweep)")
    sweep.add_argument("--device", help="Warp device, e.g. cpu or cuda:0 (default Warp's)")
    sweep.add_argument("--workers", type=int, metavar="N",
                       help="processes of the embedded Dask cluster (default: one per core, or one per GPU)")
    sweep.add_argument("--scheduler", metavar="ADDRESS",
                       help="run on an existing Dask cluster, e.g. tcp://10.0.0.5:8786 (docs/SWEEPS.md)")
    sweep.add_argument("--resume", action="store_true",
                       help="keep members whose folder holds a complete result; run the others")
    _add_retries(sweep)
    sweep.add_argument("-j", "--jobs", type=int, help=argparse.SUPPRESS)  # removed: says to use --workers
    usd = sweep.add_mutually_exclusive_group()
    usd.add_argument("--usd", action="store_const", const=True, dest="usd",
                     help="write each member's deployment.usdc, even where the scene's [output] says usd = false")
    usd.add_argument("--no-usd", action="store_const", const=False, dest="usd",
                     help="skip each member's deployment.usdc (default: as the scene's [output] usd says, as for run)")
    sweep.add_argument("--overwrite", action="store_true",
                       help="replace the outputs of an earlier sweep in the output folder (default: refuse)")
    sweep.add_argument("-q", "--quiet", action="store_true",
                       help="no progress (otherwise a bar on a terminal, a line every few seconds in a log)")
    sweep.set_defaults(func=_sweep)
    plan = sub.add_parser("plan", help="deploy treatment options (the scene's [plan] or --vary), each with "
                                       "perturbed catheter tips, and rank them: plan.md, plan.csv, plan.png",
                          epilog=PLAN_EXITS)
    plan.add_argument("scene", help="scene TOML file (with a [plan] table, docs/PLAN.md)")
    plan.add_argument("--vary", action="append", metavar="KEY=A,B,C",
                      help="options instead of [[plan.option]]: a scene key or device=none,balloon,stent (repeat "
                           "for a product)")
    plan.add_argument("-o", "--output", help="output folder (default out/<scene name>_plan)")
    plan.add_argument("--device", help="Warp device, e.g. cpu or cuda:0 (default Warp's)")
    plan.add_argument("--workers", type=int, metavar="N",
                      help="processes of the embedded Dask cluster (default: one per core, or one per GPU)")
    plan.add_argument("--scheduler", metavar="ADDRESS", help="run on an existing Dask cluster (docs/SWEEPS.md)")
    plan.add_argument("--resume", action="store_true", help="keep deployments already complete; run the others")
    _add_retries(plan)
    plan.add_argument("--overwrite", action="store_true",
                      help="replace the outputs of an earlier plan or sweep in the output folder (default: refuse)")
    plan.add_argument("-q", "--quiet", action="store_true", help="no progress")
    plan.set_defaults(func=_plan)
    coils = sub.add_parser("coils", help="list the coil catalogue (families, shapes, sizes, sources) for product = ...")
    coils.add_argument("--family", help="only the families whose name contains this text (case-insensitive)")
    coils.set_defaults(func=_coils)
    run = sub.add_parser("run", help="deploy the coils of a scene and write result.json, CSVs and USD",
                         epilog=RUN_EXITS)
    run.add_argument("scene", help="scene TOML file")
    run.add_argument("-o", "--output", help="output folder (default out/<scene name>)")
    run.add_argument("--no-usd", action="store_true", help="skip deployment.usdc")
    run.add_argument("--frame-interval", type=_positive_seconds,
                     help="seconds of simulated time between recorded frames (> 0)")
    run.add_argument("--device", help="Warp device, e.g. cpu or cuda:0 (default Warp's: a GPU if there is one)")
    run.add_argument("--overwrite", action="store_true",
                     help="replace the outputs of an earlier run in the output folder (default: refuse)")
    run.add_argument("-q", "--quiet", action="store_true",
                     help="no progress (otherwise a bar on a terminal, a line every few seconds in a log)")
    run.set_defaults(func=_run)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        if args.command in ("validate", "bench"):  # many runs: a stop ends the command, not the run that steps
            from .deploy import stop_at_once

            with stop_at_once():
                return args.func(args)
        if args.command in ("sweep", "plan"):  # runs on Dask: SIGTERM as Ctrl-C
            from .deploy import interrupt_on_stop

            with interrupt_on_stop():
                return args.func(args)
        return args.func(args)
    except KeyboardInterrupt:  # a second Ctrl-C, or one outside the stepping (a run's first ends it cleanly)
        print(f"warpcoil {args.command}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


if __name__ == "__main__":
    sys.exit(main())
