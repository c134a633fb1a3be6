"""One sweep task: an ensemble of members, shipped to a Dask worker and back.

No filesystem is shared between the client and the workers. The task carries
its members' scenes and the bytes of every file they name (wall mesh, neck
contour, pre-shape files); the worker writes those to a temporary folder,
points the scenes at them, runs the ensemble, writes each member's outputs
with the same writer as a single run (so the files are byte for byte a single
run's), and returns their bytes. The client writes the member folders.
"""

from __future__ import annotations

import json
import signal
import tempfile
import threading
from dataclasses import dataclass, fields, is_dataclass, replace
from pathlib import Path

from .settings import Scene


def wants_usd(scene: Scene, usd: bool | None) -> bool:
    """Whether a member of ``scene`` writes its deployment.usdc: ``usd`` (`--usd` True, `--no-usd` False), or
    where that is None as the scene's [output] says (as for a single run)."""
    return scene.output.usd if usd is None else usd


@dataclass(frozen=True)
class EnsembleTask:
    """Members (their sweep indices and checked scenes) that run as one Ensemble;
    ``files``: bytes of each file the scenes name, keyed by the client's path."""

    indices: tuple[int, ...]
    scenes: tuple[Scene, ...]
    files: dict[str, bytes]
    usd: bool | None = None  # every member's deployment.usdc written (True) or not (False); None: as its scene says
    device: str | None = None

    def wants_usd(self, scene: Scene) -> bool:
        return wants_usd(scene, self.usd)


@dataclass(frozen=True)
class MemberOutput:
    """What comes back for one member: its result.json content and its other files."""

    index: int
    result: dict
    files: dict[str, bytes]  # file name in the member folder → bytes


def _with_paths(value, change):
    """``value`` (a dataclass, tuple or list, nested) with each Path ``p`` in it
    replaced by ``change(p)``; every other value kept."""
    if isinstance(value, Path):
        return change(value)
    if is_dataclass(value) and not isinstance(value, type):
        return replace(value, **{f.name: _with_paths(getattr(value, f.name), change)
                                 for f in fields(value) if f.init})
    if isinstance(value, (tuple, list)):
        return type(value)(_with_paths(v, change) for v in value)
    return value


def named_files(scene: Scene) -> list[Path]:
    """The files a scene reads: every path in its settings (wall mesh, neck contour,
    pre-shape files, and any file key added later), not the TOML file itself."""
    found: list[Path] = []
    _with_paths(replace(scene, source=None), lambda path: found.append(path) or path)
    return list(dict.fromkeys(found))


def make_task(indices: list[int], scenes: list[Scene], usd: bool | None, device: str | None) -> EnsembleTask:
    """Read the files the scenes name into the task."""
    files = {str(path): path.read_bytes() for scene in scenes for path in named_files(scene)}
    return EnsembleTask(tuple(indices), tuple(scenes), files, usd, device)


def _relocated(scene: Scene, moved: dict[str, Path]) -> Scene:
    """The scene with every file it names replaced by its copy on this machine."""
    source = scene.source
    return replace(_with_paths(replace(scene, source=None), lambda path: moved[str(path)]), source=source)


def worker_device(device: str | None, worker_name, cuda_count: int) -> str | None:
    """The Warp device a worker runs on: ``device`` as given, except that "cuda"
    (or no device, where there are GPUs) means GPU ``worker_name % cuda_count`` for
    the numbered workers of a local cluster (one worker per GPU)."""
    if cuda_count > 0 and device in (None, "cuda") and isinstance(worker_name, int):
        return f"cuda:{worker_name % cuda_count}"
    return device


def _this_worker_device(device: str | None) -> str | None:
    import warp as wp

    from . import _warp  # noqa: F401  (kernel cache, init)

    try:
        from distributed import get_worker

        name = get_worker().name
    except ValueError:  # not on a Dask worker
        name = None
    return worker_device(device, name, wp.get_cuda_device_count())


def _frame_recorders(member, folder: Path, usd: bool) -> list:
    """A member's recorders of its frames, as `warpcoil run` has them: its deployment.usdc (``usd``), with
    its balloon or stent, and its deployment.gif where its scene's [output] asks for the animation."""
    from .recorder.animation import AnimationFrames
    from .recorder.outputs import ANIMATION_GIF, DEPLOYMENT_USD, UsdFrames

    wall, catheter, interval_s = member.anatomy.wall, member.anatomy.catheter, member.scene.simulation.frame_interval_s
    vertices, faces = (wall.vertices_mm, wall.faces) if wall is not None else (None, None)
    widths = [c.d for c in member.scene.coils]
    recorders = []
    if usd:
        recorders.append(UsdFrames(folder / DEPLOYMENT_USD, member.coil_nodes, widths, vertices, faces, interval_s,
                                   member.withdrawn_from))
        recorders[-1].add_device(member.anatomy.balloon, member.anatomy.stent)
    if member.scene.output.animation:
        recorders.append(AnimationFrames(folder / ANIMATION_GIF, member.coil_nodes, widths, vertices, faces,
                                         (catheter.tip_mm, catheter.direction, catheter.centerline_mm), interval_s))
    return recorders


def run_task(task: EnsembleTask) -> list[MemberOutput]:
    """Deploy the task's members as one ensemble (on a worker); their outputs."""
    from .deploy import Ensemble
    from .recorder.outputs import RESULT_JSON, write_run

    with tempfile.TemporaryDirectory(prefix="warpcoil-task-") as tmp:
        root = Path(tmp)
        moved = {}
        for k, (original, data) in enumerate(task.files.items()):
            copy = root / "inputs" / str(k) / Path(original).name
            copy.parent.mkdir(parents=True)
            copy.write_bytes(data)
            moved[original] = copy
        scenes = [_relocated(scene, moved) for scene in task.scenes]
        folders = [root / f"member_{k}" for k in range(len(scenes))]
        for folder in folders:
            folder.mkdir()
        ensemble = Ensemble(scenes, _this_worker_device(task.device))
        recorders: dict[int, list] = {}
        last_time_s: dict[int, float] = {}

        def record(member, frame, state):
            k = member.index
            if k not in recorders or frame.time_s <= last_time_s[k]:  # a member rerun alone starts again
                recorders[k] = _frame_recorders(member, folders[k], task.wants_usd(member.scene))
            last_time_s[k] = frame.time_s
            for recorder in recorders[k]:
                recorder(frame, state)

        recorded = any(task.wants_usd(s) or s.output.animation for s in scenes)
        results = ensemble.run(record if recorded else None)
        for recorder in (r for kept in recorders.values() for r in kept):
            recorder.close()
        outputs = []
        for k, (scene, anatomy, result) in enumerate(zip(scenes, ensemble.anatomies, results)):
            write_run(folders[k], scene, anatomy.wall, result, sac=anatomy.sac)
            files = {p.name: p.read_bytes() for p in sorted(folders[k].iterdir()) if p.name != RESULT_JSON}
            outputs.append(MemberOutput(task.indices[k], json.loads((folders[k] / RESULT_JSON).read_text()), files))
        return outputs


def dask_setup(worker) -> None:
    """Dask worker preload of the sweep's own local cluster (sweep.dask_client): its worker processes
    ignore Ctrl-C (SIGINT), which a terminal sends to the whole process group; the sweep ends them
    itself when it is interrupted, so a Ctrl-C prints one line, not each worker's traceback."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)
