"""`warpcoil sweep`: one scene, some keys varied, every member deployed in
ensembles (one set of launches per group of compatible members) on Dask.

``--vary catheter.angle_deg=0:30:5`` (start:stop:step, stop included) or
``--vary simulation.push_speed_mm_s=50,100``; several ``--vary`` make the
Cartesian product. Each ensemble is one Dask task (warpcoil.sweep_task) on an
embedded LocalCluster or an existing scheduler; the client writes each member's
folder ``member_NNN`` (result.json, centerline.csv, timeseries.csv, the pictures /
tube meshes, deployment.usdc and deployment.gif its scene's [output] asks for) in one
rename, and the summary.csv / summary.md last (their presence means the sweep
is complete). docs/SWEEPS.md: clusters, resume, retries.
"""

from __future__ import annotations

import contextlib
import csv
import hashlib
import io
import itertools
import json
import logging
import math
import os
import re
import secrets
import shutil
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

from .deploy import (COMPLETED, FAILED, JAMMED, TIMEOUT, ensemble_groups, host_models, resolve_anatomies,
                     world_bounds, world_steps)
from .preflight import SetupError, check_wall_field, preflight
from .preshape import PreshapeError
from .progress import Progress
from .recorder.atomic import all_or_none, write_folder_atomic, write_text_atomic
from .recorder.outputs import ANIMATION_GIF, DEPLOYMENT_USD, RESULT_JSON
from .scene import INTEGRATOR_KEYS, SceneError, load_scene
from .settings import AUTO_INTEGRATOR, Scene, reference_reasons
from .solver import UnstableStepError, wall_field_extent
from .sweep_task import MemberOutput, make_task, named_files, run_task, wants_usd
from .wall import WallError

FINAL_STATUSES = (COMPLETED, FAILED, JAMMED, TIMEOUT)
NAMING_INTEGRATOR = tuple(f"simulation.{key}" for key in INTEGRATOR_KEYS)  # member keys that choose the integrator
WORKER_WAIT_S = 60.0  # how long a --scheduler sweep waits for its first worker


class SweepError(ValueError):
    """Bad sweep input: a --vary that cannot be read, an unreachable scheduler, a
    resumed folder that holds another sweep."""


class SweepIncomplete(RuntimeError):
    """Some ensembles failed after their retries; the other members are written."""


SCENE_ERRORS = (SceneError, WallError, PreshapeError, SetupError, UnstableStepError)  # a scene that cannot run
MAX_MEMBERS = 20_000  # a sweep's members (more is most likely a mistyped step: 10:30:0.0001 is 200 001)


def parse_vary(text: str) -> tuple[str, list]:
    """``key=start:stop:step`` or ``key=a,b,c`` → (key, values)."""
    key, sep, values = text.partition("=")
    key = key.strip()  # ("coil.length_mm = 6,8": the values are stripped each)
    fix = "write --vary key=start:stop:step or key=a,b,c, e.g. catheter.angle_deg=0:30:5"
    if not sep or not key or not values:
        raise SweepError(f"--vary {text!r}: {fix}")
    if ":" in values:
        bounds = values.split(":")
        if len(bounds) != 3:
            raise SweepError(f"--vary {text!r}: a range is three numbers, start:stop:step, and {values!r} has "
                             f"{len(bounds)}; {fix}")
        try:
            start, stop, step = (float(v) for v in bounds)
        except ValueError:
            start = stop = step = math.nan  # (a word that is no number: said as one below)
        if not all(math.isfinite(v) for v in (start, stop, step)):
            raise SweepError(f"--vary {text!r}: start, stop and step must be finite numbers; {fix}")
        if not step > 0.0 or stop < start:
            raise SweepError(f"--vary {text!r}: needs step > 0 and stop ≥ start; {fix}")
        count = int(math.floor((stop - start) / step + 1e-9)) + 1
        if count > MAX_MEMBERS:
            raise SweepError(f"--vary {text!r}: {count:,} values, more than a sweep's {MAX_MEMBERS:,} members; "
                             "fix: a coarser step (or run the range as several sweeps)")
        return key, [round(start + k * step, 12) for k in range(count)]
    return key, [_scalar(v) for v in values.split(",")]


def _scalar(text: str):
    text = text.strip()
    if text.lower() in ("true", "false"):
        return text.lower() == "true"
    try:
        return float(text)
    except ValueError:
        return text


@dataclass
class Member:
    index: int
    values: dict  # the varied keys and their values
    result: dict | None = None  # its result.json
    resumed: bool = False  # found complete in the output folder (--resume)
    label: str | None = None  # how progress names its values (default: key=value for each)

    @property
    def name(self) -> str:
        return f"member_{self.index:03d}"


SAME_SETTING = "the same key of one coil (coil.KEY sets every coil's, coil.N.KEY coil N's), one overriding the other"


def same_coil_setting(keys) -> tuple[str, str] | None:
    """The first two of ``keys`` that set the same key of one coil (``coil.K`` sets every coil's, so
    ``coil.N.K`` too; ``coil.0.K`` and ``coil.00.K``), else None."""
    seen: dict[str, tuple] = {}
    for key in keys:
        parts = key.split(".")
        if parts[0] != "coil" or not (len(parts) == 2 or len(parts) == 3 and parts[1].isdigit()):
            continue
        coil, name = (None, parts[1]) if len(parts) == 2 else (int(parts[1]), parts[2])
        for other, (other_coil, other_name) in seen.items():
            if name == other_name and (coil == other_coil or None in (coil, other_coil)):
                return other, key
        seen[key] = (coil, name)
    return None


def check_varies(varies: list[tuple[str, list]]) -> None:
    """SweepError for a key varied twice (the last --vary of it won, unseen), two keys that set one coil's
    same key (coil.K and coil.0.K: one overrides the other, unseen) or a value given twice for one key
    (two identical members)."""
    keys = [k for k, _ in varies]
    twice = sorted({k for k in keys if keys.count(k) > 1})
    if twice:
        raise SweepError(f"--vary {twice[0]}: given {keys.count(twice[0])} times; fix: one --vary per key, its values "
                         "in one list (key=a,b,c)")
    pair = same_coil_setting(keys)
    if pair:
        raise SweepError(f"--vary {pair[0]} and --vary {pair[1]}: both set {SAME_SETTING}; fix: vary one of them")
    for key, values in varies:
        seen = [v for k, v in enumerate(values) if v in values[:k]]
        if seen:
            raise SweepError(f"--vary {key}: the value {seen[0]!r} is given twice (two identical members); fix: "
                             "give each value once")


def members(varies: list[tuple[str, list]]) -> list[Member]:
    """The Cartesian product of ``varies`` (:func:`check_varies`), at most MAX_MEMBERS (else SweepError)."""
    check_varies(varies)
    keys = [k for k, _ in varies]
    count = math.prod(len(v) for _, v in varies)
    if count > MAX_MEMBERS:
        raise SweepError(f"--vary {' '.join(keys)}: {count:,} members, more than a sweep's "
                         f"{MAX_MEMBERS:,}; fix: coarser steps or fewer values (or run them as several sweeps)")
    return [Member(i, dict(zip(keys, combo))) for i, combo in enumerate(itertools.product(*(v for _, v in varies)))]


def complete_result(folder: Path) -> dict | None:
    """The result.json of a member folder that holds a complete result, else None.
    Complete: result.json reads as JSON, its status is final (completed, failed,
    jammed, timeout), and every file it lists under "files" (name → bytes) is in
    the folder with that size."""
    try:
        result = json.loads((folder / RESULT_JSON).read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(result, dict) or result.get("status") not in FINAL_STATUSES:
        return None
    files = result.get("files")
    if not isinstance(files, dict):
        return None
    for name, size in files.items():
        path = folder / name
        if not path.is_file() or path.stat().st_size != size:
            return None
    return result


def scene_fingerprint(scene: Scene, files: dict[Path, bytes] | None = None) -> str:
    """SHA-256 of a member's scene as the scene file and its values give it: every value (its repr) and
    the bytes of every file it names (``files``: a cache of those bytes by path), so --resume tells a
    member of an edited scene (or of a changed mesh) from one of this scene."""
    files = {} if files is None else files
    digest = hashlib.sha256(repr(scene).encode())
    for path in named_files(scene):
        if path not in files:
            files[path] = path.read_bytes() if path.is_file() else b"(missing)"
        digest.update(str(path).encode())
        digest.update(files[path])
    return digest.hexdigest()


def member_files(output: MemberOutput, member: Member, scene_path: Path, warnings: list[str],
                 fingerprint: str) -> dict[str, bytes]:
    """A member folder's files: the run's outputs and result.json, which adds the
    scene, the varied values, the scene's fingerprint (:func:`scene_fingerprint`), the member's
    warnings (as `warpcoil run` keeps them) and the list of files (for --resume)."""
    listed = {name: len(data) for name, data in output.files.items()}
    result = {**output.result, "scene": str(Path(scene_path).resolve()), "varied": member.values,
              "scene_sha256": fingerprint, "warnings": warnings, "files": listed}
    return {**output.files, RESULT_JSON: (json.dumps(result, indent=2) + "\n").encode()}


def _summary_row(member: Member) -> dict:
    r = member.result
    regions = r.get("regions") or {}
    row = {"member": member.name, **member.values}
    row |= {k: r.get(k) for k in ("status", "packing_density", "length_outside_sac_mm")}
    row["neck_coverage"] = regions.get("neck_coverage")
    row["raymond_roy_class"] = (r.get("occlusion") or {}).get("raymond_roy_class")
    row |= {k: r.get(k) for k in ("min_coil_gap_mm", "min_wall_gap_mm", "push_force_peak_uN", "steps", "wall_time_s")}
    return {k: ("" if v is None or (isinstance(v, float) and not math.isfinite(v)) else
                (f"{v:.6g}" if isinstance(v, float) else v)) for k, v in row.items()}


def write_summary(out: Path, all_members: list[Member], header: str) -> None:
    rows = [_summary_row(m) for m in all_members]
    columns = list(dict.fromkeys(key for row in rows for key in row))  # members may vary different keys (a plan)
    rows = [{c: row.get(c, "") for c in columns} for row in rows]
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=columns, lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    lines = [header, "", "| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(str(row[c]) for c in columns) + " |" for row in rows]
    with all_or_none(out / "summary.csv", out / "summary.md"):
        write_text_atomic(out / "summary.csv", buffer.getvalue())
        write_text_atomic(out / "summary.md", "\n".join(lines) + "\n")


def member_values(member: Member) -> str:
    """The member's values as a line names them (its label, or key=value for each varied key)."""
    return member.label if member.label is not None else \
        " ".join(f"{k}={v:g}" if isinstance(v, float) else f"{k}={v}" for k, v in member.values.items())


@contextlib.contextmanager
def naming_member(member: Member) -> Iterator[None]:
    """A member's scene, wall or set-up error prefixed with the member and its values: the key it names
    may hold a value the file does not (given by --vary or a plan option), or follow from one (a catheter
    outside a varied sphere)."""
    try:
        yield
    except SCENE_ERRORS as error:
        which = f'option "{member.label}"' if member.label is not None else f"{member.name} ({member_values(member)})"
        raise type(error)(f"{which}: {error}") from None


def member_line(member: Member) -> str:
    """One line on a finished member: its values, status, packing and time."""
    r = member.result
    values = member_values(member)
    packing = r.get("packing_density")
    facts = [r["status"], f"packing {100 * packing:.1f} %" if packing is not None else "no sac",
             f"{r.get('steps')} steps", f"{r.get('wall_time_s', 0.0):.1f} s"]
    return f"{member.name} {values}: " + ", ".join(facts) + (" (resumed: complete from an earlier run)"
                                                              if member.resumed else "")


class SweepProgress:
    """Progress over members by the rules of every command (warpcoil.progress: a
    bar on a terminal, a line every few seconds or 10 % in a log, nothing when
    quiet), the bar showing the count of each status so far, plus one line per
    finished member (:func:`member_line`; above the bar on a terminal)."""

    def __init__(self, quiet: bool = False, stream=None, command: str = "sweep"):
        self.quiet, self.stream, self.command = quiet, stream if stream is not None else sys.stderr, command
        self.progress: Progress | None = None
        self.statuses: dict[str, int] = {}

    def start(self, total: int) -> None:
        self.progress = Progress("sweep", "deployments", total=total, quiet=self.quiet, stream=self.stream, decimals=0)

    def __call__(self, member: Member) -> None:
        status = member.result["status"]
        self.statuses[status] = self.statuses.get(status, 0) + 1
        if not self.quiet:
            if self.progress.terminal:
                from tqdm import tqdm

                tqdm.write(member_line(member), file=self.stream)
            else:
                print(member_line(member), file=self.stream, flush=True)
        self.progress.update(sum(self.statuses.values()), ", ".join(f"{n} {s}" for s, n in self.statuses.items()))

    def warn(self, text: str) -> None:
        """A warning before the members run (as ``warpcoil run`` gives its own), quiet or not."""
        line = f"warpcoil {self.command}: warning: {text}"
        if self.progress is not None and self.progress.terminal:
            from tqdm import tqdm

            tqdm.write(line, file=self.stream)
        else:
            print(line, file=self.stream, flush=True)

    def close(self, failed: bool = False) -> None:
        """End the bar; ``failed`` (the sweep stopped on an error): no closing line in a log."""
        if self.progress is not None:
            if failed and not self.progress.terminal:
                self.progress.quiet = True
            self.progress.close()


def default_workers(device: str | None) -> int:
    """Local workers: one per GPU for a CUDA sweep (the default device where there
    are GPUs), one per core otherwise; one for an explicit cuda:N."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    if device == "cpu":
        return cores
    if device is not None and device.startswith("cuda:"):
        return 1
    import warp as wp

    from . import _warp  # noqa: F401

    gpus = wp.get_cuda_device_count()
    return gpus if gpus > 0 else cores


SCHEDULER_FIX = "fix: give the address `dask scheduler` prints, e.g. tcp://10.0.0.5:8786"


def check_scheduler(address: str | None) -> None:
    """Raise SweepError for a --scheduler address Dask cannot read (an empty one would silently run the
    local cluster), before anything runs: one line with the problem and the fix."""
    if address is None:
        return
    from distributed.comm.addressing import parse_address, parse_host_port
    from distributed.comm.registry import get_backend

    if not address.strip():
        raise SweepError(f"--scheduler '{address}': empty; {SCHEDULER_FIX}, or leave out --scheduler for a "
                         "local cluster (--workers)")
    try:
        scheme, location = parse_address(address)
        get_backend(scheme)
        if scheme in ("tcp", "tls", "ws", "wss"):  # (host:port; inproc and ucx name theirs otherwise)
            parse_host_port(location)
    except ValueError as error:
        problem = "the port is not a number" if "int()" in str(error) else str(error)
        raise SweepError(f"--scheduler '{address}': {problem}; {SCHEDULER_FIX}") from None


@contextlib.contextmanager
def dask_client(scheduler: str | None, workers: int | None, device: str | None, retries: int) -> Iterator:
    """A Dask client: of the scheduler at ``scheduler``, or of an embedded
    LocalCluster of ``workers`` processes with one thread each (closed on exit).
    ``retries``: a local scheduler reruns a task whose worker died this often."""
    import dask
    from distributed import Client, LocalCluster

    if scheduler:
        try:
            client = Client(scheduler)  # waits distributed.comm.timeouts.connect (30 s)
        except (OSError, TimeoutError) as error:
            raise SweepError(f"--scheduler {scheduler}: cannot connect ({error}); start one with `dask scheduler` "
                             "and give the address it prints, e.g. tcp://10.0.0.5:8786") from error
        try:
            try:
                client.wait_for_workers(1, timeout=WORKER_WAIT_S)
            except TimeoutError as error:
                raise SweepError(f"--scheduler {scheduler}: no worker connected within {WORKER_WAIT_S:.0f} s; "
                                 f"start some with `dask worker {scheduler}`") from error
            yield client
        finally:
            client.close()
        return
    preload = dask.config.get("distributed.worker.preload", None) or []  # (a user's: a list, or one name)
    preload = [preload] if isinstance(preload, str) else list(preload)
    preload.append("warpcoil.sweep_task")  # (its dask_setup)
    with dask.config.set({"distributed.scheduler.allowed-failures": retries, "distributed.worker.preload": preload}):
        cluster = LocalCluster(n_workers=workers or default_workers(device), threads_per_worker=1, processes=True,
                               dashboard_address=None, silence_logs=logging.CRITICAL,  # no dashboard; its health
                               scheduler_kwargs={"dashboard_address": "127.0.0.1:0"})  # routes on a free port
        # (CRITICAL: a worker busy compiling kernels misses a heartbeat, which distributed logs as an ERROR with
        # a traceback on the user's terminal though the sweep goes on; a member's own failure reaches the client)
    try:
        with Client(cluster) as client:
            yield client
    finally:
        cluster.close()


REPLACE_HINT = "give another -o folder, or add --overwrite (without --resume) to replace it"


def one_integrator(scene_path: Path, todo: list[Member], scenes: list[Scene]) -> tuple[list[Scene], list[str]]:
    """One integrator for a sweep's members that name none: where the scene reader's rule (wall
    friction, segments below d/2: settings.reference_reasons) puts some members on the reference and
    leaves others on the implicit default (a --vary of contact.friction_wall from 0), those that name
    no integrator of their own (none of NAMING_INTEGRATOR among their keys) run the reference too, so
    that they differ by what is varied and not by their integrator; (scenes, the notes saying so)."""
    by_rule = [s for s in scenes if any(note in s.notes for note in reference_reasons(s))]
    switch = [k for k, (m, s) in enumerate(zip(todo, scenes)) if s.simulation.integrator == "implicit"
              and not any(key in m.values and m.values[key] != AUTO_INTEGRATOR for key in NAMING_INTEGRATOR)]
    if not by_rule or not switch:
        return scenes, []
    scenes = list(scenes)
    for k in switch:
        scenes[k] = load_scene(scene_path, {**todo[k].values, "simulation.integrator": "symplectic"})
    others = f"the {len(switch)} other member{'s' if len(switch) > 1 else ''}"
    return scenes, [f"{len(by_rule)} of {len(todo)} members have wall friction or segments below d/2 and the scene "
                    f"names no integrator (simulation.integrator, implicit_scheme or dt_s): {others} run the "
                    "reference (symplectic) step too, so that the members differ by what is varied, not by their "
                    "integrator"]  # (the members the rule chose say why in their own preflight notes)


def run_sweep(scene_path: Path, varies: list[tuple[str, list]], out: Path, device: str | None = None,
              progress: Callable[[Member], None] | None = None, scheduler: str | None = None,
              workers: int | None = None, usd: bool | None = None, resume: bool = False, retries: int = 2,
              checked: Callable[[], None] | None = None) -> list[Member]:
    """Deploy every member of the Cartesian product of ``varies`` (:func:`run_members`)."""
    return run_members(scene_path, members(varies), out, device, progress, scheduler, workers, usd, resume, retries,
                       checked=checked)


def run_members(scene_path: Path, todo: list[Member], out: Path, device: str | None = None,
                progress: Callable[[Member], None] | None = None, scheduler: str | None = None,
                workers: int | None = None, usd: bool | None = None, resume: bool = False, retries: int = 2,
                title: str = "Sweep", stale_names: tuple[str, ...] = (),
                checked: Callable[[], None] | None = None) -> list[Member]:
    """Deploy every member (``todo``: indices 0…n−1, each with the scene keys it sets) on
    Dask; write their folders as they come back, then the summary (headed ``title`` of
    the scene; ``stale_names``: other files of ``out`` that only this run may leave, removed
    with the old summary once every member is checked). ``progress(member)`` after each
    finished (or resumed) member. ``checked()``: called once every member is checked, before
    anything is written (`--overwrite` clears the folder there: a bad input keeps it). ``usd``: every
    member's deployment.usdc written (True, `--usd`) or not (False, `--no-usd`); None: as its scene's
    [output] says, as for a single run.

    Members that can share an ensemble are grouped (deploy.ensemble_groups) and
    each group is split into one task per worker thread (a CPU launch runs on one
    core; a GPU worker still advances its share of members per launch). A task
    that raises, or whose worker dies, is rerun up to ``retries`` times; a member
    equals its single run wherever it runs. ``resume``: members whose folder holds
    a complete result (:func:`complete_result`) are not rerun. Raises
    SweepIncomplete (after writing every member that finished) when a task still
    fails."""
    scenes = []
    for member in todo:  # every member checked before anything is written
        with naming_member(member):
            scenes.append(load_scene(scene_path, member.values))
    named_files: dict[Path, bytes] = {}  # (each file the scenes name read once)
    fingerprints = [scene_fingerprint(scene, named_files) for scene in scenes]  # as the scene gives it (before the
    scenes, unified = one_integrator(scene_path, todo, scenes)  # integrator the sweep's members share)
    folders = [out / m.name for m in todo]
    if resume:
        for member, folder in zip(todo, folders):
            found = complete_result(folder)
            if found is not None and found.get("varied") != member.values:
                raise SweepError(f"--resume: {folder} holds {found.get('varied')}, not {member.values}: another "
                                 f"sweep's member; {REPLACE_HINT}")
            made_from = Path(str(found.get("scene", ""))) if found is not None else None
            if made_from is not None and made_from.is_absolute() and made_from != Path(scene_path).resolve():
                raise SweepError(f"--resume: {folder} was made from {made_from}, not {Path(scene_path).resolve()}: "
                                 f"another sweep's member; {REPLACE_HINT}")
            if found is not None and found.get("scene_sha256", fingerprints[member.index]) != fingerprints[member.index]:
                found = None  # made from another version of the scene (a value or a named file changed): run again
            if found is not None and found.get("scheme", {}).get("integrator") != scenes[member.index].simulation.integrator:
                found = None  # run on another integrator (an earlier release's rule): run again
            wanted = {DEPLOYMENT_USD: wants_usd(scenes[member.index], usd),
                      ANIMATION_GIF: scenes[member.index].output.animation}
            if found is not None and any(want and name not in found.get("files", {}) for name, want in wanted.items()):
                found = None  # made without a USD or GIF this sweep asks for (an earlier release's): run again
            member.result, member.resumed = found, found is not None
        ours = {folder.name for folder in folders}
        foreign = sorted(f.name for f in out.glob("member_*") if f.is_dir() and f.name not in ours
                         and re.fullmatch(r"member_\d+", f.name))
        if foreign:
            raise SweepError(f"--resume: {out} holds {', '.join(foreign[:3])}{', …' if len(foreign) > 3 else ''}, "
                             f"which this sweep of {len(todo)} members does not have: another sweep's; {REPLACE_HINT}")
    pending = [m.index for m in todo if m.result is None]
    # walls and necks checked before any worker starts, and each member's warnings as `warpcoil run` would give
    # them (a catheter outside the lumen: SetupError before any step); kept in its result.json, and said once each
    # before the members run and in the summary
    shared: dict[tuple, tuple] = {}  # (scenes with one wall share it)
    anatomies, models, member_warnings = [], [], {}
    for k in pending:
        with naming_member(todo[k]):
            anatomy = resolve_anatomies([scenes[k]], shared)[0]
            model = host_models([scenes[k]], [anatomy], "cpu")[0]  # step bounds and groups, host-side
            bounds = world_bounds(model)
            world_steps(model, [scenes[k]], bounds)  # (its frame against its step and time limit)
            check_wall_field(scenes[k], anatomy, wall_field_extent(model)[0])  # (built in the member's solver)
            member_warnings[k] = list(dict.fromkeys(unified + preflight(scenes[k], anatomy, "cpu", bounds[0].dt_s)))
        anatomies.append(anatomy)
        models.append(model)
    stored = [w for m in todo if m.resumed for w in m.result.get("warnings", [])]
    warnings = list(dict.fromkeys(unified + [w for k in pending for w in member_warnings[k]] + stored))
    if isinstance(progress, SweepProgress):
        for warning in warnings:
            progress.warn(warning)
    if checked is not None:
        checked()
    out.mkdir(parents=True, exist_ok=True)
    for stale in ("summary.csv", "summary.md", *stale_names):  # a summary is only ever of this sweep
        (out / stale).unlink(missing_ok=True)
    for partial in out.glob(".member_*.tmp-*"):  # a member folder being written when a sweep was killed
        shutil.rmtree(partial, ignore_errors=True)
    started = time.perf_counter()
    for member in todo:
        if member.resumed and progress:
            progress(member)
    batches, slots, failures = [], 0, []
    if pending:
        groups = ensemble_groups([scenes[k] for k in pending], "cpu", anatomies, models)
        with dask_client(scheduler, workers, device, retries) as client:
            from distributed import as_completed

            slots = sum(client.nthreads().values())
            batches = [part for group in groups for part in ([pending[i] for i in group[j::slots]]
                                                             for j in range(slots)) if part]
            token = secrets.token_hex(4)
            futures = {client.submit(run_task, make_task(batch, [scenes[k] for k in batch], usd, device),
                                     retries=retries, pure=False, key=f"warpcoil-ensemble-{token}-{n}"): batch
                       for n, batch in enumerate(batches)}
            for future in as_completed(futures):
                if future.status != "finished":  # erred after its retries, or cancelled
                    failures.append((futures[future], future.exception() if future.status == "error" else
                                     future.status))
                    continue
                for output in future.result():
                    member = todo[output.index]
                    files = member_files(output, member, scene_path, member_warnings[output.index],
                                         fingerprints[output.index])
                    write_folder_atomic(folders[output.index], files)
                    member.result = json.loads((folders[output.index] / RESULT_JSON).read_text())
                    if progress:
                        progress(member)
                future.release()
    if failures:
        missing = sorted(k for batch, _ in failures for k in batch)
        why = failures[0][1]
        if type(why).__name__ == "KilledWorker":  # (its own text names only the task; the worker's log is silenced)
            why = (f"a Dask worker process died running it {retries + 1} time(s) (out of memory, or a crash in native "
                   "code; fewer --workers leave each more memory)")
        raise SweepIncomplete(f"{len(missing)} member(s) not run ({', '.join(todo[k].name for k in missing)}): "
                              f"{why}; the others are written; rerun with --resume to finish")
    elapsed = time.perf_counter() - started
    statuses = [m.result["status"] for m in todo]
    resumed = sum(m.resumed for m in todo)
    rate = f" ({60.0 * len(pending) / elapsed:.3g} deployments/min)" if pending else ""
    write_summary(out, todo, f"# {title} of {scene_path.name}\n\n{len(todo)} members ({resumed} resumed) in "
                  f"{len(batches)} ensemble task(s) on {slots} Dask worker thread(s), {elapsed:.1f} s wall time"
                  f"{rate}; " + ", ".join(f"{statuses.count(s)} {s}" for s in dict.fromkeys(statuses)) + "."
                  + "".join(f"\n\nWarning: {w}" for w in warnings))
    return todo


__all__ = ["Member", "SCENE_ERRORS", "SweepError", "SweepIncomplete", "SweepProgress", "complete_result", "parse_vary", "run_members",
           "run_sweep"]
