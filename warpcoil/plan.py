"""`warpcoil plan SCENE`: deploy treatment options, each with perturbed catheter tips, and rank them.

The options come from the scene's ``[plan]`` table (``[[plan.option]]`` tables of scene
keys, ``device = "none" | "balloon" | "stent"``) or from ``--vary`` as in sweeps. Every
option is deployed ``perturbations`` times, the catheter axis tilted by
``perturbation_deg`` towards evenly spaced directions around its nominal axis (the
deployment is chaotic: a tiny change of the tip changes the coil's track), all as one
Dask sweep (:func:`warpcoil.sweep.run_members`). The options are ranked by
:mod:`warpcoil.plan_rank` and the plan is written as ``plan.md``, ``plan.csv`` and
``plan.png`` beside the members' folders. docs/PLAN.md.
"""

from __future__ import annotations

import csv
import io
import itertools
import math
import time
import tomllib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .plan_rank import CRITERIA, Ranked, Stats, active_criteria, rank
from .recorder import outputs
from .recorder.atomic import all_or_none, write_text_atomic
from .orientation import anatomy_normal, tip_axis
from .sac import neck_frame
from .scene import SceneError, load_scene
from .sweep import MAX_MEMBERS, SAME_SETTING, Member, check_varies, run_members, same_coil_setting
from .wall import load_wall

DEVICES = ("none", "balloon", "stent")
PLAN_KEYS = ("perturbations", "perturbation_deg", "top", "balloon", "stent", "option")
USABLE = ("completed", "jammed", "timeout")  # a failed (numerically unstable) run says nothing about the option


class PlanError(ValueError):
    """A bad ``[plan]`` table or ``--vary``: names the file, the key and the fix."""


@dataclass(frozen=True)
class Option:
    """One treatment option: its name, assist device, and the scene keys it sets."""

    name: str
    device: str
    keys: dict  # scene key (table.key, coil.N.key) -> value, the device's table included


@dataclass(frozen=True)
class Plan:
    options: tuple[Option, ...]
    perturbations: int = 3
    perturbation_deg: float = 1.0
    top: int = 3


def _error(source: Path, key: str, problem: str, fix: str) -> PlanError:
    return PlanError(f"{source}: {key}: {problem}; fix: {fix}")


def _flat(table: dict, prefix: str = "") -> dict:
    """``{"catheter": {"angle_deg": 5}}`` (TOML's dotted keys) -> ``{"catheter.angle_deg": 5}``."""
    flat = {}
    for key, value in table.items():
        if isinstance(value, dict) and not (prefix == "" and key in ("balloon", "stent")):
            flat |= _flat(value, f"{prefix}{key}.")
        else:
            flat[f"{prefix}{key}"] = value
    return flat


def _number(source: Path, key: str, value, low: float, integer: bool = False) -> float:
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value) and value >= low
    if not ok or (integer and value != int(value)):
        kind = "a whole number" if integer else "a number"
        raise _error(source, key, f"must be {kind} ≥ {low:g}, got {value!r}", f"write e.g. {key.split('.')[-1]} = "
                     f"{max(low, 3):g}")
    return int(value) if integer else float(value)


def read_plan(scene_path: Path, varies: list[tuple[str, list]] | None = None) -> Plan:
    """The plan of the scene at ``scene_path``: its ``[plan]`` table, the options from
    ``varies`` (``--vary``, their Cartesian product) when given. Every option's scene is
    checked here; raises :class:`PlanError` (or SceneError for the scene itself)."""
    source = Path(scene_path).expanduser().resolve()
    load_scene(source)  # the scene itself first: its own errors name its own keys
    with source.open("rb") as file:
        document = tomllib.load(file)
    table = document.get("plan", {})
    if not isinstance(table, dict):
        raise _error(source, "plan", f"must be a table, got {table!r}", "write it as a [plan] table")
    for key in table:
        if key not in PLAN_KEYS:
            raise _error(source, f"plan.{key}", "unknown key", f"use one of {', '.join(PLAN_KEYS)} (docs/PLAN.md)")
    perturbations = _number(source, "plan.perturbations", table.get("perturbations", 3), 2, integer=True)
    perturbation_deg = _number(source, "plan.perturbation_deg", table.get("perturbation_deg", 1.0), 0.0)
    if not 0.0 < perturbation_deg <= 10.0:
        raise _error(source, "plan.perturbation_deg", f"{perturbation_deg:g}° is not a small tilt in (0, 10]",
                     "write e.g. perturbation_deg = 1.0")
    top = _number(source, "plan.top", table.get("top", 3), 1, integer=True)
    devices = {name: table.get(name) for name in ("balloon", "stent")}
    for name, geometry in devices.items():
        if geometry is not None and not isinstance(geometry, dict):
            raise _error(source, f"plan.{name}", f"must be a table of [{name}] keys, got {geometry!r}",
                         f"write [plan.{name}] with axis = [[x, y, z], …] and diameter_mm (docs/SCENES.md)")
    check_varies(varies or [])
    if varies and table.get("option") is not None:
        raise _error(source, "plan.option", "given beside --vary, which would replace these options unseen",
                     "give the options one way: remove --vary, or the [[plan.option]] tables")
    if varies:
        raw = [dict(zip([k for k, _ in varies], combo)) for combo in itertools.product(*(v for _, v in varies))]
        where = ["--vary " + " ".join(f"{k}={v}" for k, v in r.items()) for r in raw]
    else:
        raw = table.get("option")
        if not isinstance(raw, list) or not raw or not all(isinstance(r, dict) for r in raw):
            raise _error(source, "plan.option", "the plan has no options",
                         "add [[plan.option]] tables (name, device, scene keys such as catheter.angle_deg), "
                         "or give --vary KEY=A,B (docs/PLAN.md)")
        where = [f"plan.option[{k}]" for k in range(len(raw))]
    options = [_option(source, document, devices, r, w, k) for k, (r, w) in enumerate(zip(raw, where))]
    names = [o.name for o in options]
    for k, name in enumerate(names):
        if names.index(name) != k:
            raise _error(source, _at(where[k], "name"), f"{name!r} names two options", "give each option its own name")
    treatments = [(o.device, o.keys) for o in options]  # (0 and 0.0 are one value)
    for k, treatment in enumerate(treatments):
        if treatments.index(treatment) != k:
            j = treatments.index(treatment)
            raise _error(source, where[k], f"({names[k]}) is the treatment of {where[j]} ({names[j]}): the same "
                         "device and scene keys, run twice to tie", "change one of them, or remove it")
    if len(options) < 2:
        raise _error(source, where[0], "a plan compares options, and there is one",
                     "add at least one more [[plan.option]] (or --vary value)")
    for option, place in zip(options, where):
        try:
            scene = load_scene(source, option.keys)
        except SceneError as error:
            raise PlanError(f"{place} ({option.name}): {error}") from None
        if scene.catheter.placement != "neck" and scene.catheter.centerline_mm is not None:
            raise _error(source, "catheter.centerline", "the plan tilts the catheter axis at the tip, and a "
                         "centerline fixes it", 'remove the centerline, or use placement = "neck"')
    return Plan(tuple(options), perturbations, perturbation_deg, top)


def _at(where: str, key: str) -> str:
    """An option's key as a message names it: plan.option[1].device, or --vary device=x (device)."""
    return f"{where} ({key})" if where.startswith("--vary") else f"{where}.{key}"


def _option(source: Path, document: dict, devices: dict, raw: dict, where: str, index: int) -> Option:
    """One option from its table (or --vary values): name, device, scene keys."""
    keys = _flat({k: v for k, v in raw.items() if k not in ("name", "device")})
    pair = same_coil_setting(keys)
    if pair:
        raise _error(source, where, f"sets {pair[0]} and {pair[1]}: {SAME_SETTING}", "keep one of them")
    device = raw.get("device", "none")
    if device not in DEVICES:
        raise _error(source, _at(where, "device"), f"{device!r} is not an assist device",
                     f"write device = one of {', '.join(repr(d) for d in DEVICES)}")
    for key in keys:
        if key.split(".")[0] in ("balloon", "stent"):
            raise _error(source, _at(where, key), "an option names its device, not the device's keys",
                         f'write device = "{key.split(".")[0]}" and put the geometry in [plan.{key.split(".")[0]}]')
    if device != "none" or "device" in raw:
        for table in ("balloon", "stent"):
            if table in document:
                raise _error(source, table, f"the scene's [{table}] would apply to every option, and "
                             f"{where} chooses its device", f"move [{table}] to [plan.{table}]")
    if device != "none":
        geometry = devices[device]
        if geometry is None:
            raise _error(source, f"plan.{device}", f"{where} uses a {device}, and the plan gives none",
                         f"add [plan.{device}] with the keys of a scene's [{device}] (axis, diameter_mm, …)")
        keys |= {f"{device}.{k}": v for k, v in geometry.items()}
    scene_device = next((table for table in ("balloon", "stent") if table in document), None)
    if device == "none" and scene_device is not None:
        device = f"{scene_device} (the scene's)"  # every option uses it: reported as theirs
    name = raw.get("name")
    if name is None:
        shown = {k: v for k, v in raw.items() if k != "name"}
        name = ", ".join(f"{k}={v:g}" if isinstance(v, float) else f"{k}={v}" for k, v in _flat(shown).items())
    if not isinstance(name, str) or not name.strip():
        raise _error(source, _at(where, "name"), f"must be a non-empty text, got {name!r}",
                     f'write name = "option {index + 1}"')
    return Option(name.strip(), device, keys)


def tilted(direction: np.ndarray, angle_deg: float, toward_deg: float,
           reference: np.ndarray | None = None) -> np.ndarray:
    """``direction`` (unit) tilted by ``angle_deg`` towards the azimuth ``toward_deg`` about it
    (measured from e1 of its :func:`~warpcoil.sac.neck_frame`: ``reference``, the direction the wall
    defines, so the perturbations turn with the scene; without it the coordinate axes')."""
    u, v, d = neck_frame(direction, reference)
    a, t = math.radians(angle_deg), math.radians(toward_deg)
    return math.cos(a) * d + math.sin(a) * (math.cos(t) * u + math.sin(t) * v)


def perturbed_keys(catheter, count: int, angle_deg: float, reference: np.ndarray | None = None) -> list[dict]:
    """``count`` catheter settings: the axis tilted by ``angle_deg`` towards evenly spaced
    azimuths about its nominal direction. ``placement = "neck"``: as angle_deg/azimuth_deg
    (the nominal axis in the neck frame (e1, e2, n) is (sin a cos φ, sin a sin φ, cos a), which
    turns with the wall); explicit: as the direction, the azimuths counted from ``reference`` (the
    direction the wall defines normal to it: orientation.anatomy_normal; None: the coordinate axes')."""
    towards = [360.0 * k / count for k in range(count)]
    if catheter.placement != "neck":
        return [{"catheter.direction": [round(float(x), 12)
                                        for x in tilted(catheter.direction, angle_deg, t, reference)]}
                for t in towards]
    a, phi = math.radians(catheter.angle_deg), math.radians(catheter.azimuth_deg)
    nominal = np.array([math.sin(a) * math.cos(phi), math.sin(a) * math.sin(phi), math.cos(a)])
    keys = []
    for t in towards:
        d = tilted(nominal, angle_deg, t)
        keys.append({"catheter.angle_deg": round(math.degrees(math.acos(min(1.0, d[2]))), 9),
                     "catheter.azimuth_deg": round(math.degrees(math.atan2(d[1], d[0])), 9)})
    return keys


def explicit_reference(scene) -> np.ndarray | None:
    """For an explicit catheter in a wall, the direction normal to its axis the wall defines
    (orientation.anatomy_normal), from which the perturbations' azimuths are counted; else None."""
    if scene.catheter.placement == "neck" or scene.wall is None:
        return None
    wall = load_wall(scene.wall)
    return anatomy_normal(tip_axis(scene.catheter), wall.vertices_mm, wall.faces, np.asarray(scene.catheter.tip_mm))


def plan_members(scene_path: Path, plan: Plan) -> tuple[list[Member], list[int]]:
    """The sweep's members (option × perturbation) and each member's option index (at most a
    sweep's MAX_MEMBERS, else PlanError)."""
    if len(plan.options) * plan.perturbations > MAX_MEMBERS:
        raise PlanError(f"{scene_path}: {len(plan.options):,} options × {plan.perturbations} catheter perturbations "
                        f"are more than a sweep's {MAX_MEMBERS:,} members; fix: fewer options (values of [plan] "
                        "keys or --vary) or fewer perturbations")
    todo, owner = [], []
    for k, option in enumerate(plan.options):
        scene = load_scene(scene_path, option.keys)
        for p, tip in enumerate(perturbed_keys(scene.catheter, plan.perturbations, plan.perturbation_deg,
                                               explicit_reference(scene))):
            todo.append(Member(len(todo), {**option.keys, **tip}, label=f"{option.name} (tip {p + 1})"))
            owner.append(k)
    return todo, owner


@dataclass
class PlanResult:
    plan: Plan
    ranked: list[Ranked]
    members: list[Member]
    owner: list[int]  # option index of each member
    occlusion_graded: bool
    wall_time_s: float


def run_plan(scene_path: Path, plan: Plan, out: Path, device: str | None = None,
             progress: Callable[[Member], None] | None = None, scheduler: str | None = None,
             workers: int | None = None, resume: bool = False, retries: int = 2,
             checked: Callable[[], None] | None = None) -> PlanResult:
    """Deploy every option × perturbation as one sweep, rank the options, write plan.md,
    plan.csv and plan.png into ``out``."""
    started = time.perf_counter()
    todo, owner = plan_members(scene_path, plan)
    run_members(scene_path, todo, out, device, progress, scheduler, workers, resume=resume, retries=retries,
                checked=checked,
                title="Plan", stale_names=outputs.PLAN_OUTPUTS)
    stats, usable = [], []
    for k in range(len(plan.options)):
        results = [m.result for m, o in zip(todo, owner) if o == k and m.result["status"] in USABLE]
        stats.append({c.key: Stats(tuple(c.read(r) for r in results)) for c in CRITERIA})
        usable.append(bool(results))
    ranked = rank(stats, usable)
    graded = any(s["modified_raymond_roy_class"].known for s in stats)
    result = PlanResult(plan, ranked, todo, owner, graded, time.perf_counter() - started)
    from .recorder.plan_figure import write_plan_png

    with all_or_none(*(out / name for name in outputs.SWEEP_OUTPUTS + outputs.PLAN_OUTPUTS)):  # (this plan's)
        write_plan_png(out / "plan.png", scene_path, result)
        write_text_atomic(out / "plan.csv", plan_csv(result))
        write_text_atomic(out / "plan.md", plan_markdown(scene_path, result))
    return result


def _statuses(result: PlanResult, k: int) -> str:
    statuses = [m.result["status"] for m, o in zip(result.members, result.owner) if o == k]
    return ", ".join(f"{statuses.count(s)} {s}" for s in dict.fromkeys(statuses))


def _chosen_keys(option: Option) -> dict:
    """The scene keys an option sets, less its device's geometry (the same for every option)."""
    return {k: v for k, v in option.keys.items() if k.split(".")[0] not in ("balloon", "stent")}


def _rank_text(r: Ranked) -> str:
    if r.rank == 0:
        return "–"
    return f"={r.rank}" if r.tied_with else str(r.rank)


def plan_csv(result: PlanResult) -> str:
    """One row per option in ranked order: rank, name, device, keys, runs, and per criterion
    the mean, standard deviation and the runs' values (``;``-separated, empty: not reported)."""
    buffer = io.StringIO()
    columns = ["rank", "option", "device", "keys", "runs", "statuses"]
    for c in CRITERIA:
        columns += [f"{c.key}_mean", f"{c.key}_sd", f"{c.key}_values"]
    columns += ["tied_with", "beaten_by", "decided_by"]
    writer = csv.DictWriter(buffer, fieldnames=columns, lineterminator="\n")
    writer.writeheader()
    options = result.plan.options
    for r in result.ranked:
        option = options[r.index]
        row = {"rank": _rank_text(r), "option": option.name, "device": option.device,
               "keys": "; ".join(f"{k}={v}" for k, v in _chosen_keys(option).items()),
               "runs": sum(1 for o in result.owner if o == r.index), "statuses": _statuses(result, r.index),
               "tied_with": "; ".join(options[j].name for j in r.tied_with),
               "beaten_by": options[r.beaten_by[0]].name if r.beaten_by else "",
               "decided_by": r.beaten_by[1] if r.beaten_by else ""}
        for c in CRITERIA:
            s = r.stats[c.key]
            row[f"{c.key}_mean"] = f"{s.mean:.6g}" if s.known else ""
            row[f"{c.key}_sd"] = f"{s.spread:.6g}" if s.known else ""
            row[f"{c.key}_values"] = ";".join("" if v is None else f"{v:.6g}" for v in s.values)
        writer.writerow(row)
    return buffer.getvalue()


def _cell(s: Stats, decimals: int) -> str:
    if not s.known:
        return "–"
    return f"{s.mean:.{decimals}f} ± {s.spread:.{decimals}f}"


def plan_markdown(scene_path: Path, result: PlanResult) -> str:
    """plan.md: the ranked table, the criteria, the tie rule, the ties, and the picture."""
    options, plan = result.plan.options, result.plan
    criteria = active_criteria([r.stats for r in result.ranked if r.rank])
    decimals = {"deployed_percent": 0, "herniated_length_mm": 1, "modified_raymond_roy_class": 1,
                "neck_coverage_percent": 0, "packing_density_percent": 1, "peak_push_force_mN": 2}
    header = ["rank", "option"] + [f"{c.label} ({c.unit})" if c.unit else c.label for c in criteria] + \
        ["runs", "below the rank above on"]
    lines = [f"# Treatment plan: {scene_path.name}", "",
             f"{len(options)} options × {plan.perturbations} catheter-tip perturbations (axis tilted "
             f"{plan.perturbation_deg:g}° towards {plan.perturbations} evenly spaced directions) = "
             f"{len(result.members)} deployments{_resumed(result)}, {result.wall_time_s:.0f} s wall time. Values: "
             "mean ± standard deviation over an option's runs.", "",
             "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for r in result.ranked:
        beaten = f"{r.beaten_by[1]} (vs {options[r.beaten_by[0]].name})" if r.beaten_by else ""
        if r.cycle:
            beaten = (beaten + "; " if beaten else "") + "placed by fewest defeats (a cycle)"
        cells = [_rank_text(r), options[r.index].name] + [_cell(r.stats[c.key], decimals[c.key]) for c in criteria]
        lines.append("| " + " | ".join(cells + [_statuses(result, r.index), beaten]) + " |")
    lines += ["", "## How the options are ranked", ""]
    lines += [f"{k}. **{c.label}**" + (f" ({c.unit})" if c.unit else "") +
              (", lower is better" if c.lower_is_better else ", higher is better") +
              f"; resolution {_resolution(c)}" for k, c in enumerate(CRITERIA, 1)]
    skipped = [c.label for c in CRITERIA if c not in criteria]
    lines += ["", "Tie rule: two options tie on a criterion when their means differ by no more than the larger of "
              "their two standard deviations, or than the criterion's resolution, whichever is larger. An option "
              "beats another when, at the first criterion (in the order above) on which they do not tie, its mean "
              "is better. Rank 1 is every option no other option beats; those are set aside and the next rank is "
              "found the same way, so options sharing a rank (`=`) tie on every criterion. A failed "
              "(numerically unstable) run is left out of its option's statistics; a jammed or timed-out one is "
              "counted, with the part of its coil it deployed (the first criterion)."]
    if not result.occlusion_graded:
        lines += ["", "**Occlusion grade not available**: no run reported `occlusion.raymond_roy_class` in its "
                  "result.json, so the options are ranked without it."]
    if skipped:
        lines += ["", "Criteria no run reported (skipped): " + ", ".join(skipped) + "."]
    groups = {}
    for r in result.ranked:
        if r.tied_with and r.rank:
            groups.setdefault(r.rank, []).append(options[r.index].name)
    if groups:
        lines += ["", "Ties: " + "; ".join(f"rank {k}: " + ", ".join(v) for k, v in groups.items()) + "."]
    lines += ["", "## Options", ""]
    for k, option in enumerate(options):
        keys = ", ".join(f"`{key} = {value}`" for key, value in _chosen_keys(option).items())
        lines.append(f"- **{option.name}**: device {option.device}" + (f"; {keys}" if keys else ""))
    lines += ["", f"![the top options, each tip perturbation]({'plan.png'})", "",
              "Member folders `member_NNN` hold each deployment's result.json, centerline.csv and timeseries.csv; "
              "plan.csv has each run's values."]
    return "\n".join(lines) + "\n"


def _resumed(result: PlanResult) -> str:
    kept = sum(m.resumed for m in result.members)
    return f" ({kept} kept from an earlier run by --resume)" if kept else ""


def _resolution(c) -> str:
    if c.relative:
        return f"{c.resolution:g} {c.unit} + {100 * c.relative:g} % of the larger mean"
    return f"{c.resolution:g} {c.unit}".strip() + (" class" if not c.unit else "")


__all__ = ["Option", "Plan", "PlanError", "PlanResult", "perturbed_keys", "plan_members", "read_plan", "run_plan",
           "tilted"]
