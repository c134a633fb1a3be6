"""Read a scene TOML file (schema: docs/SCENES.md) into a :class:`Scene`.

Every problem raises :class:`SceneError` with one message naming the file,
the dotted key (``coil[1].length_mm``), what is wrong and how to fix it.
Paths in the file are relative to the scene file's folder.
"""

from __future__ import annotations

import difflib
import math
import tomllib
from dataclasses import MISSING, fields, replace
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from .catalog import CatalogueError, find_line
from .coil import SHAPES, CoilSpec
from .settings import (
    CatheterSpec,
    BalloonSpec,
    StentSpec,
    ContactSettings,
    NeckSpec,
    OutputSettings,
    RegionSettings,
    Scene,
    SimulationSettings,
    WallSpec,
    AUTO_INTEGRATOR,
    resolve_integrator,
)

Vec3 = tuple[float, float, float]
# [simulation] keys that choose the integrator (a step dt_s is chosen for one): a scene with none of them
# and wall friction or segments below d/2 runs the reference (settings.resolve_integrator)
INTEGRATOR_KEYS = ("integrator", "implicit_scheme", "dt_s")


class SceneError(ValueError):
    """A scene file that cannot be read; the message says where and how to fix it."""


class _Invalid(Exception):
    """A bad value; the reader adds the file and the key."""

    def __init__(self, problem: str, fix: str) -> None:
        super().__init__(problem)
        self.problem, self.fix = problem, fix


# --- value checks: (TOML value, scene folder) -> converted value ----------------
Check = Callable[[Any, Path], Any]


def _is_number(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _positive(value: object, base: Path) -> float:
    if not _is_number(value):
        raise _Invalid(f"must be a number, got {value!r}", "write a number without quotes, e.g. 1.0")
    if not (math.isfinite(value) and value > 0.0):
        raise _Invalid(f"must be a finite number > 0, got {value!r}", "give a positive value")
    return float(value)


def _finite(value: object, base: Path) -> float:
    if not (_is_number(value) and math.isfinite(value)):
        raise _Invalid(f"must be a finite number, got {value!r}", "write a number without quotes, e.g. 0.0")
    return float(value)


def _nonnegative(value: object, base: Path) -> float:
    number = _finite(value, base)
    if number < 0.0:
        raise _Invalid(f"must be ≥ 0, got {value!r}", "give 0 (none) or a positive value")
    return number


def _fraction(value: object, base: Path) -> float:
    number = _positive(value, base)
    if number > 1.0:
        raise _Invalid(f"must be in (0, 1], got {value!r}", "give a value such as 0.5")
    return number


def _bool(value: object, base: Path) -> bool:
    if not isinstance(value, bool):
        raise _Invalid(f"must be true or false, got {value!r}", "write true or false without quotes")
    return value


def _text(value: object, base: Path, example: str = "framing") -> str:
    if not isinstance(value, str):
        raise _Invalid(f"must be a string, got {value!r}", f'write it in quotes, e.g. "{example}"')
    return value


def _text_like(example: str) -> Check:
    """A string key whose fix shows ``example``."""
    return lambda value, base: _text(value, base, example)


def _choice(*options: str) -> Check:
    def check(value: object, base: Path) -> str:
        if _text(value, base) not in options:
            raise _Invalid(f"must be one of {', '.join(map(repr, options))}, got {value!r}", f"use one of {options}")
        return value

    return check


def _vec3(value: object, base: Path) -> Vec3:
    if not (isinstance(value, list) and len(value) == 3 and all(_is_number(v) and math.isfinite(v) for v in value)):
        raise _Invalid(f"must be a list of 3 finite numbers [x, y, z], got {value!r}", "write e.g. [0.0, 0.0, 1.0]")
    return tuple(float(v) for v in value)


def _direction(value: object, base: Path) -> Vec3:
    vector = _vec3(value, base)
    norm = math.hypot(*vector)
    if norm == 0.0:
        raise _Invalid("must not be the zero vector", "give a direction, e.g. [0.0, 0.0, 1.0]")
    return tuple(v / norm for v in vector)


def _polyline(value: object, base: Path) -> tuple[Vec3, ...]:
    if not (isinstance(value, list) and len(value) >= 2):
        raise _Invalid(
            f"must be a list of at least 2 points [[x, y, z], ...], got {value!r}",
            "list the points from the proximal end to the tip",
        )
    return tuple(_vec3(point, base) for point in value)


def _existing_file(value: object, base: Path) -> Path:
    path = (base / _text(value, base, "sac.stl")).resolve()
    if path.is_dir():
        raise _Invalid(f"{path} is a folder, not a file", f"give the path of a file in it (relative to {base})")
    if not path.is_file():
        raise _Invalid(f"file {path} does not exist", f"check the path; it is relative to {base}")
    return path


MAX_COIL_SEGMENTS = 20_000  # a coil with more (5.8 m at d 0.2921 mm) is a unit mistake; setup cost grows as its square
CENTERLINE_DIRECTION_TOLERANCE_DEG = 1.0  # a direction given beside a centerline agrees with its last segment

# --- schema ---------------------------------------------------------------------
class _Key(NamedTuple):
    check: Check
    field: str | None = None  # dataclass field, if named differently
    required: bool = False
    shape: str | None = None  # coil key only meaningful for this shape


_WALL = {
    "mesh": _Key(_existing_file),
    "units": _Key(_choice("mm", "m")),
    "repair": _Key(_bool),
    "sphere_diameter_mm": _Key(_positive),
    "center_mm": _Key(_vec3),
}
_WALL_SOURCES = ("mesh", "sphere_diameter_mm")  # exactly one is given
_WALL_ONLY_WITH = {"units": "mesh", "repair": "mesh", "center_mm": "sphere_diameter_mm"}
_CATHETER = {
    "tip": _Key(_vec3, "tip_mm"),
    "direction": _Key(_direction),
    "centerline": _Key(_polyline, "centerline_mm"),
    "placement": _Key(_choice("explicit", "neck")),
    "depth_mm": _Key(_finite),
    "angle_deg": _Key(_finite),
    "azimuth_deg": _Key(_finite),
    "roll_deg": _Key(_finite),
}
_NECK = {
    "contour": _Key(_existing_file),
    "plane_point_mm": _Key(_vec3),
    "plane_normal": _Key(_direction),
    "sac_point_mm": _Key(_vec3),
}
_REGIONS = {"voxel_mm": _Key(_positive), "neck_band_mm": _Key(_positive), "boundary_mm": _Key(_positive),
            "occlusion_threshold": _Key(_fraction)}
_COIL = {
    "name": _Key(_text),
    "shape": _Key(_choice(*SHAPES)),
    "file": _Key(_existing_file, "preshape_file", shape="file"),
    "wire_diameter_mm": _Key(_positive, required=True),
    "loop_diameter_mm": _Key(_positive, required=True),
    "length_mm": _Key(_positive, required=True),
    "pitch_mm": _Key(_positive, shape="helix"),
    "shrink": _Key(_fraction, shape="spherical"),
    "segment_length_mm": _Key(_positive),
    "primary_wire_diameter_mm": _Key(_positive),
    "bending_stiffness_uN_mm2": _Key(_positive),
    "twist_stiffness_uN_mm2": _Key(_positive),
    "linear_density_g_mm": _Key(_positive),
    "axial_stiffness_uN": _Key(_positive),
    "stretch_resistant": _Key(_bool),
}
_PRODUCT = {"product": _Key(_text_like("Axium Prime 3D")),  # a catalogue coil: warpcoil/catalog.py
            "size": _Key(_text_like("3 x 6"))}  # loop mm x length cm
_PRODUCT_COIL = {**{key: spec._replace(required=False) for key, spec in _COIL.items()}, **_PRODUCT}
_CONTACT = {"P0_uN": _Key(_positive), "c0_mm": _Key(_positive), "friction_wall": _Key(_nonnegative),
            "friction_coil": _Key(_nonnegative), "friction_catheter": _Key(_nonnegative),
            "friction_speed_mm_s": _Key(_positive), "wall_query": _Key(_choice("sdf", "bvh")),
            "wall_voxel_mm": _Key(_positive)}
_SIMULATION = {
    "push_speed_mm_s": _Key(_positive),
    "damping_uN_per_mm": _Key(_positive),
    "damping_speed_mm_s": _Key(_positive),
    "integrator": _Key(_choice("auto", "symplectic", "implicit")),
    "implicit_scheme": _Key(_choice("euler", "gated_chord", "bdf2")),  # = implicit.IMPLICIT_SCHEMES (tested)
    "dt_s": _Key(_positive),
    "dt_safety": _Key(_fraction),
    "allow_unstable_dt": _Key(_bool),
    "mass_scale": _Key(_positive),
    "jam_force_uN": _Key(_positive),
    "stall_force_ratio": _Key(_positive),
    "stall_force_uN": _Key(_positive),
    "stall_window_s": _Key(_positive),
    "stall_packing": _Key(_fraction),
    "rest_kinetic_energy_nJ": _Key(_positive),
    "max_time_s": _Key(_positive),
    "frame_interval_s": _Key(_positive),
}
_OUTPUT = {"usd": _Key(_bool), "png": _Key(_bool), "tube_mesh": _Key(_bool), "animation": _Key(_bool),
           "porous": _Key(_bool), "porous_voxel_mm": _Key(_positive)}
_BALLOON = {"axis": _Key(_polyline, "axis_mm", required=True), "diameter_mm": _Key(_positive),
            "deflate_at_s": _Key(_positive), "deflation_time_s": _Key(_positive)}
_STENT = {"axis": _Key(_polyline, "axis_mm", required=True), "diameter_mm": _Key(_positive),
          "cell_size_mm": _Key(_positive), "strut_diameter_mm": _Key(_positive)}
_TABLES = ("wall", "neck", "catheter", "coil", "contact", "simulation", "output", "regions", "balloon", "stent",
           "plan")  # [plan]: options of `warpcoil plan`, read by warpcoil.plan (ignored by a run)


def _unknown(key: str, known: Sequence[str]) -> str:
    close = difflib.get_close_matches(key, known, n=1)
    return f"did you mean {close[0]!r}?" if close else f"remove it; known: {', '.join(known)}"


class _Reader:
    def __init__(self, source: Path) -> None:
        self.source, self.base = source, source.parent

    def error(self, key: str | None, problem: str, fix: str) -> SceneError:
        where = f"{self.source}: {key}" if key else str(self.source)
        return SceneError(f"{where}: {problem}; fix: {fix}")

    def table(self, value: object, schema: dict[str, _Key], where: str) -> dict[str, Any]:
        """Checked values of one table, keyed by dataclass field."""
        if not isinstance(value, dict):
            raise self.error(where, f"must be a table, got {value!r}", f"write it as a [{where}] table")
        for key in value:
            if key not in schema:
                raise self.error(f"{where}.{key}", "unknown key", _unknown(key, list(schema)))
        for key, spec in schema.items():
            if spec.required and key not in value:
                raise self.error(f"{where}.{key}", "required key is missing", f"add {key} = ... to [{where}]")
        values = {}
        for key, item in value.items():
            try:
                values[schema[key].field or key] = schema[key].check(item, self.base)
            except _Invalid as bad:
                raise self.error(f"{where}.{key}", bad.problem, bad.fix) from None
        return values

    def build(self, cls: type, values: dict[str, Any], where: str) -> Any:
        """``cls(**values)``, its ValueErrors turned into SceneErrors about ``where``."""
        try:
            return cls(**values)
        except ValueError as exc:
            raise self.error(where, str(exc), "correct the values of this table") from exc

    def section(self, document: dict[str, Any], name: str, schema: dict[str, _Key], cls: type) -> Any:
        return self.build(cls, self.table(document.get(name, {}), schema, name), name)

    def coil(self, value: object, index: int) -> CoilSpec:
        where = f"coil[{index}]"
        if isinstance(value, dict) and any(key in value for key in _PRODUCT):
            return self.product_coil(value, index)
        values = self.table(value, _COIL, where)
        self.check_primary(values, value, where, values.get("wire_diameter_mm"))
        spec = self.build(CoilSpec, {"name": f"coil_{index}", **self.shaped(value, values, where)}, where)
        return self.checked_coil(spec, value, where)

    def check_primary(self, values: dict[str, Any], value: dict[str, Any], where: str, d_mm: float | None) -> None:
        """Refuse a primary wire no thinner than the coil's wire diameter ``d_mm`` (it is wound into the coil)."""
        primary = values.get("primary_wire_diameter_mm", CoilSpec.primary_wire_diameter_mm)
        if d_mm is not None and primary >= d_mm:
            key = "primary_wire_diameter_mm" if "primary_wire_diameter_mm" in value else "wire_diameter_mm"
            raise self.error(f"{where}.{key}", f"the primary wire ({primary:g} mm) is not thinner than the coil's wire "
                             f"diameter d = {d_mm:g} mm it is wound into", f"give primary_wire_diameter_mm below "
                             f"{d_mm:g} mm (the default is {CoilSpec.primary_wire_diameter_mm:g}), or check "
                             "wire_diameter_mm")

    def checked_coil(self, spec: CoilSpec, value: dict[str, Any], where: str) -> CoilSpec:
        """``spec``, refused when its loops are no wider than its wire (it cannot wind) or its length
        holds fewer than two segments or more than MAX_COIL_SEGMENTS (n = round(L / l0))."""
        if spec.shape != "file" and spec.loop_diameter_mm <= spec.wire_diameter_mm:
            key = "loop_diameter_mm" if "loop_diameter_mm" in value else "wire_diameter_mm"
            raise self.error(f"{where}.{key}", f"a loop of {spec.loop_diameter_mm:g} mm is not wider than the coil's "
                             f"wire diameter d = {spec.wire_diameter_mm:g} mm: the coil cannot wind into it",
                             "give a loop_diameter_mm larger than wire_diameter_mm")
        segments = round(spec.length_mm / spec.l0)
        key = "segment_length_mm" if "segment_length_mm" in value else "length_mm"
        if segments > MAX_COIL_SEGMENTS:
            raise self.error(f"{where}.{key}", f"length {spec.length_mm:g} mm holds {segments} segments of "
                             f"{spec.l0:g} mm, more than {MAX_COIL_SEGMENTS} (the catalogue's longest coil, 500 mm, holds "
                             "~1 700 at d; setting up a coil grows with the square of its nodes)",
                             "give length_mm and segment_length_mm in mm, or a longer segment_length_mm")
        if segments >= 2:
            return spec
        given = "segment_length_mm" if "segment_length_mm" in value else "segment_length_mm, by default d"
        raise self.error(f"{where}.{key}", f"length {spec.length_mm:g} mm holds fewer than two segments of "
                         f"{spec.l0:g} mm ({given})", "use a longer coil (length_mm) or a shorter segment_length_mm")

    def shaped(self, value: dict[str, Any], values: dict[str, Any], where: str,
               shape: str | None = None) -> dict[str, Any]:
        """``values`` after checking the keys that belong to one pre-shape only."""
        shape = shape or values.get("shape", CoilSpec.shape)
        for key, spec in _COIL.items():
            if spec.shape is not None and spec.shape != shape and key in value:
                raise self.error(f"{where}.{key}", f"is only for shape = {spec.shape!r}, not {shape!r}", "remove it")
        if shape == "file" and "file" not in value:
            fix = 'add file = "preshape.txt" (x y z per line, mm)'
            raise self.error(f"{where}.file", "is required for shape = 'file'", fix)
        return values

    def product_coil(self, value: dict[str, Any], index: int) -> CoilSpec:
        """A coil named by catalogue ``product`` and ``size``: the line's geometry and
        material; keys it publishes are refused, keys it derives may be overridden."""
        where = f"coil[{index}]"
        values = self.table(value, _PRODUCT_COIL, where)
        for key, example in (("product", '"Axium Prime 3D"'), ("size", '"6 x 20" (loop mm x length cm)')):
            if key not in value:
                raise self.error(f"{where}.{key}", "product and size go together; this one is missing",
                                 f"add {key} = a catalogue line's (`warpcoil coils` lists them), e.g. {example}, "
                                 "or describe the coil by its own keys (loop_diameter_mm, length_mm) without "
                                 f"{'size' if key == 'product' else 'product'}")
        try:
            line = find_line(values.pop("product"))
        except CatalogueError as bad:
            raise self.error(f"{where}.product", bad.problem, bad.fix) from None
        for key in value:
            if key in line.published_keys:
                raise self.error(f"{where}.{key}", f"is set by product = {line.family!r} from its source ({line.source})",
                                 "remove it, or describe the coil by its keys without product and size")
        values = self.shaped(value, values, where, shape=line.model_shape)
        self.check_primary(values, value, where, values.get("wire_diameter_mm", line.d_mm))
        try:
            spec, note = line.spec(values.pop("size"), **values)
        except CatalogueError as bad:
            raise self.error(f"{where}.size", bad.problem, bad.fix) from None
        except ValueError as exc:
            raise self.error(where, str(exc), "correct the values of this table") from exc
        notes = [note] if note else []
        if "wire_diameter_mm" not in value and line.d_basis == "model default":
            notes.append(f"{line.family}: no public source gives its secondary diameter; the model default "
                         f"d = {line.d_mm:g} mm is used (set wire_diameter_mm from the instructions for use)")
        name = values.get("name", f"coil_{index}")
        return self.checked_coil(spec.with_(name=name, notes=tuple(notes)), value, where)

    def catheter(self, document: dict[str, Any]) -> CatheterSpec:
        catheter = self.section(document, "catheter", _CATHETER, CatheterSpec)
        if catheter.placement == "neck":
            if "neck" not in document:
                raise self.error("catheter.placement", "'neck' needs a [neck] table",
                                 'add [neck] contour = "neck.vtk" (or plane_point_mm and plane_normal)')
            for key in ("tip", "direction", "centerline"):
                if key in document.get("catheter", {}):
                    raise self.error(f"catheter.{key}", "is set by placement = 'neck'",
                                     "remove it, or use placement = 'explicit'")
        else:  # an explicit tip and direction: the neck placement's keys would be ignored
            for key in ("depth_mm", "angle_deg", "azimuth_deg"):
                if key in document.get("catheter", {}):
                    raise self.error(f"catheter.{key}", "applies only with placement = 'neck' (this catheter has "
                                     "an explicit tip and direction, which it would not change)",
                                     "use placement = 'neck' with a [neck] table, or set (or vary) catheter.tip "
                                     "and catheter.direction")
        line = catheter.centerline_mm
        if line is None:
            return catheter
        if math.dist(line[-1], catheter.tip_mm) > 1e-6:
            raise self.error(
                "catheter.centerline",
                f"last point {list(line[-1])} is not the tip {list(catheter.tip_mm)}",
                "end the centerline at catheter.tip",
            )
        last = [b - a for a, b in zip(line[-2], line[-1])]
        length = math.hypot(*last)
        if length <= 1e-6:
            raise self.error("catheter.centerline", "its last two points coincide: the tip has no direction",
                             "drop the repeated point")
        axis = tuple(c / length for c in last)  # the coil leaves along the last segment
        if "direction" in document.get("catheter", {}):
            off_deg = math.degrees(math.acos(max(-1.0, min(1.0, sum(a * b for a, b in zip(axis, catheter.direction))))))
            if off_deg > CENTERLINE_DIRECTION_TOLERANCE_DEG:
                raise self.error("catheter.direction",
                                 f"{[round(c, 4) for c in catheter.direction]} is {off_deg:.1f}° off the centerline's "
                                 f"last segment {[round(c, 4) for c in axis]}, along which the coil leaves the tip",
                                 "remove direction (the centerline sets it), or make the two agree")
        return replace(catheter, direction=axis)

    def neck(self, document: dict[str, Any]) -> NeckSpec:
        if "wall" not in document:
            raise self.error("neck", "a neck needs a [wall]", "add a [wall] table, or remove [neck]")
        value = document["neck"]
        neck = self.section(document, "neck", _NECK, NeckSpec)
        plane = ("plane_point_mm" in value, "plane_normal" in value)
        if (neck.contour is not None) == all(plane) or any(plane) != all(plane):
            raise self.error("neck.contour / neck.plane_point_mm", "give either a contour or a plane",
                             'contour = "neck.vtk", or both plane_point_mm = [x, y, z] and plane_normal = [x, y, z]')
        return neck

    def wall(self, document: dict[str, Any]) -> WallSpec:
        value = document["wall"]
        values = self.table(value, _WALL, "wall")
        given = [source for source in _WALL_SOURCES if source in value]
        if len(given) != 1:
            problem = "both are given" if given else "one of them is required, both are missing"
            fix = 'give either mesh = "sac.stl" (a file) or sphere_diameter_mm = 6.0 (a generated sphere)'
            raise self.error("wall.mesh / wall.sphere_diameter_mm", problem, fix)
        for key, source in _WALL_ONLY_WITH.items():
            if key in value and source not in value:
                raise self.error(f"wall.{key}", f"is only for wall.{source}, not wall.{given[0]}", "remove it")
        return self.build(WallSpec, values, "wall")

    def simulation(self, document: dict[str, Any]) -> SimulationSettings:
        """The [simulation] table; an ``implicit_scheme`` or ``dt_s`` without ``integrator`` names the
        implicit step (a step or scheme chosen for it: not switched by settings.resolve_integrator)."""
        simulation = self.section(document, "simulation", _SIMULATION, SimulationSettings)
        if "implicit_scheme" in document.get("simulation", {}) and simulation.integrator == "symplectic":
            raise self.error("simulation.implicit_scheme", f"applies only to integrator = 'implicit' (this scene's is "
                             f"{simulation.integrator!r}, which it would not change)",
                             'add integrator = "implicit", or remove implicit_scheme')
        if simulation.integrator == AUTO_INTEGRATOR and any(key in document.get("simulation", {})
                                                            for key in ("implicit_scheme", "dt_s")):
            simulation = replace(simulation, integrator="implicit")
        return simulation

    def output(self, document: dict[str, Any]) -> OutputSettings:
        output = self.section(document, "output", _OUTPUT, OutputSettings)
        if output.porous and "wall" not in document:
            raise self.error("output.porous", "the porous field fills the sac, and there is no [wall]",
                             "add a [wall] table (and a [neck] to cut the sac), or set porous = false")
        return output

    def scene(self, document: dict[str, Any]) -> Scene:
        for key in document:
            if key not in _TABLES:
                raise self.error(key, "unknown top-level table or key", _unknown(key, _TABLES))
        if "balloon" in document and "stent" in document:
            raise self.error("balloon / stent", "both devices are given", "keep one of [balloon] and [stent]")
        coils = document.get("coil")
        if not isinstance(coils, list) or not coils:
            raise self.error("coil", f"needs one or more [[coil]] tables, got {coils!r}", "add a [[coil]] table")
        scene = Scene(
            coils=tuple(self.coil(coil, index) for index, coil in enumerate(coils)),
            catheter=self.catheter(document),
            wall=self.wall(document) if "wall" in document else None,
            contact=self.section(document, "contact", _CONTACT, ContactSettings),
            simulation=self.simulation(document),  # checked as written (a table, its keys) before the rule reads it
            output=self.output(document),
            neck=self.neck(document) if "neck" in document else None,
            regions=self.section(document, "regions", _REGIONS, RegionSettings),
            balloon=self.section(document, "balloon", _BALLOON, BalloonSpec) if "balloon" in document else None,
            stent=self.section(document, "stent", _STENT, StentSpec) if "stent" in document else None,
            source=self.source,
        )
        if "regions" in document and "neck" not in document:  # (its settings, checked, would change nothing)
            raise self.error("regions", "the regional densities are measured from the neck, and there is no [neck]",
                             "add a [neck] table (docs/SCENES.md), or remove [regions]")
        return resolve_integrator(scene)


def _override(reader: _Reader, document: dict[str, Any], key: str, value: Any) -> None:
    """Set ``table.key`` (or ``coil.key`` for every coil, ``coil.N.key`` for coil N) in the document."""
    parts = key.split(".")
    fix = 'name a scene key as table.key, e.g. catheter.angle_deg, coil.length_mm or coil.0.length_mm'
    if parts[0] == "plan":  # read by `warpcoil plan` from the file alone: varied, it would change nothing
        raise reader.error(key, "is a setting of the plan, not of a deployment, and would change nothing here",
                           "set it in the scene's [plan] table; vary scene keys such as catheter.angle_deg")
    if len(parts) == 3 and parts[0] == "coil" and parts[1].isdigit():
        coils = document.get("coil", [])
        if int(parts[1]) >= len(coils):
            raise reader.error(key, f"there is no coil {parts[1]} (the scene has {len(coils)})", fix)
        targets = [coils[int(parts[1])]]
    elif len(parts) == 2 and parts[0] == "coil":
        targets = document.get("coil", [])
    elif len(parts) == 2:
        targets = [document.setdefault(parts[0], {})]
    else:
        raise reader.error(key, "is not a scene key", fix)
    for table in targets:
        if not isinstance(table, dict):
            raise reader.error(key, f"{parts[0]} is not a table", fix)
        table[parts[-1]] = value


BUILT_IN_PYTHON = Path("<Scene built in Python>")  # where check_built_scene's errors say the scene is from
_SECTIONS = (("catheter", _CATHETER), ("wall", _WALL), ("neck", _NECK), ("contact", _CONTACT),
             ("simulation", _SIMULATION), ("output", _OUTPUT), ("regions", _REGIONS), ("balloon", _BALLOON),
             ("stent", _STENT))  # Scene field = [table], its keys


def _toml_value(value: Any) -> Any:
    """A dataclass field's value as TOML gives it (tuples as lists, paths as strings)."""
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, np.ndarray | np.generic):  # numpy arrays and scalars, as the model takes them
        return _toml_value(value.tolist())
    if isinstance(value, tuple | list):
        return [_toml_value(v) for v in value]
    return value


def _table_of(spec: Any, schema: dict[str, _Key]) -> dict[str, Any]:
    """The TOML table that gives the dataclass ``spec``: its required keys and every field that differs
    from its default (a default written out would trip the reader's "only with" rules; a catheter's
    default direction beside a centerline is the TOML catheter without one: the centerline sets it)."""
    defaults = {f.name: _toml_value(f.default) if f.default is not MISSING else
                _toml_value(f.default_factory()) if f.default_factory is not MISSING else MISSING
                for f in fields(spec)}
    table = {}
    for key, item in schema.items():
        name = item.field or key
        value = _toml_value(getattr(spec, name, None))
        if value is not None and (item.required or value != defaults.get(name, MISSING)):
            table[key] = value
    return table


def check_built_scene(scene: Scene) -> None:
    """Raise SceneError where the scene reader would refuse the same scene written as TOML: each
    value's range and type, and the rules between keys (a mesh and a sphere, a neck placement
    without a neck, a centerline off the direction, ...), named by table and key as in a file
    (``BUILT_IN_PYTHON`` for the file). For a Scene built in Python (deploy.Ensemble calls it)."""
    document: dict[str, Any] = {"coil": [_table_of(c, _COIL) for c in scene.coils]}
    for name, schema in _SECTIONS:
        spec = getattr(scene, name)
        if spec is not None and not (name == "regions" and spec == RegionSettings()):  # (as a file without one)
            document[name] = _table_of(spec, schema)
    _Reader(BUILT_IN_PYTHON).scene(document)


def load_scene(path: str | Path, overrides: dict[str, Any] | None = None) -> Scene:
    """Read the scene TOML file at ``path``, with ``overrides`` (``{"catheter.angle_deg":
    10.0}``: see :func:`_override`) set before it is checked; raise :class:`SceneError`
    on any problem."""
    source = Path(path).expanduser().resolve()
    reader = _Reader(source)
    try:
        with source.open("rb") as file:
            document = tomllib.load(file)
    except OSError as exc:
        raise reader.error(None, f"cannot be read ({exc.strerror or exc})", "check the path and permissions") from exc
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise reader.error(None, f"is not valid TOML: {exc}", "correct the syntax there") from exc
    for key, value in (overrides or {}).items():
        _override(reader, document, key, value)
    return reader.scene(document)
