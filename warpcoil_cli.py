"""The ``warpcoil`` command's entry point. Its start-up imports the package and, for the commands that
deploy, the libraries a run needs (Warp, USD, VTK, trimesh: ~3 s) with Ctrl-C and SIGTERM only noted,
then ends the command like a stop during a run would (exit 130, one line) where one came: raised inside
those imports, a KeyboardInterrupt can be swallowed by a library's own error handling (USD's plug-in
loading prints a warning and goes on), and the run then ignored the stop. Everything else is warpcoil.cli."""

import signal
import sys

EXIT_INTERRUPTED = 130  # = warpcoil.cli.EXIT_INTERRUPTED (tested)
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)  # = warpcoil.deploy.STOP_SIGNALS (tested)
DEPLOYING = ("run", "sweep", "plan", "validate", "bench")  # commands that import what a run needs at start


def main() -> int:
    stops: list[int] = []
    previous = {number: signal.signal(number, lambda number, _frame: stops.append(number))
                for number in STOP_SIGNALS}
    try:
        from warpcoil.cli import main as command
        if set(sys.argv[1:2]) & set(DEPLOYING):
            import warpcoil.deploy  # noqa: F401  (Warp's kernels, USD, VTK, trimesh)
            import warpcoil.recorder.outputs  # noqa: F401
    finally:
        for number, action in previous.items():
            signal.signal(number, action)
    if stops:
        print("warpcoil: interrupted while starting", file=sys.stderr)
        return EXIT_INTERRUPTED
    return command()
