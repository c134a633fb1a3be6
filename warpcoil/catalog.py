"""The coil catalogue: detachable coil lines as their makers publish them.

Data: ``warpcoil/data/coils.csv`` (sources and method: docs/COILS.md). One row per
line (family); a field no public source gives is left empty and the model's value
is used instead, labelled by its *basis*:

* secondary diameter d: ``published`` (``d_in``), else ``system 10 nominal``
  (a 10-system coil is named for its 0.010 in secondary diameter), else
  ``model default`` (:class:`CoilSpec`'s 0.2921 mm, the MODEL.md reference coil);
* primary wire: ``published`` (``primary_wire_in``), else ``model default`` (0.05 mm);
* material (EI, GJ, EA, linear density): always ``derived`` by :class:`CoilSpec`
  from d and the primary wire (close-wound Pt–W spring, Wahl).

A size is ``"loop x length"`` in mm × cm (``"6 x 20"``). It is accepted when the
line lists it, or when the line publishes only its cleared range and the size lies
inside it (then with a note: the maker's grid is not public, check the IFU).
Units: mm, cm only in the catalogue's size text; inches only in the CSV's ``_in`` columns.
"""

from __future__ import annotations

import csv
import difflib
import re
from dataclasses import dataclass
from functools import cache
from importlib.resources import files

from .coil import CoilSpec

INCH_MM = 25.4
SYSTEM_NOMINAL_IN = {"10": 0.010}  # secondary diameter a coil system is named for, in
MODEL_SHAPE = {"3D framing": "spherical", "helical filling": "helix", "soft finishing": "helix"}
_SIZE = re.compile(r"^\s*(\d+(?:\.\d+)?)\s*[x×X*]\s*(\d+(?:\.\d+)?)\s*$")


class CatalogueError(ValueError):
    """An unknown family or size: ``problem``, and a ``fix`` naming the nearest matches."""

    def __init__(self, problem: str, fix: str) -> None:
        super().__init__(f"{problem}; fix: {fix}")
        self.problem, self.fix = problem, fix


def parse_size(text: str) -> tuple[float, float]:
    """``"6 x 20"`` -> (loop diameter mm, length cm)."""
    match = _SIZE.match(text) if isinstance(text, str) else None
    if match is None:
        raise CatalogueError(f'size {text!r} is not "LOOP x LENGTH" (loop diameter in mm, length in cm)',
                             'write e.g. size = "6 x 20"')
    return float(match[1]), float(match[2])


def _size_text(loop_mm: float, length_cm: float) -> str:
    return f"{loop_mm:g} x {length_cm:g}"


def _number(text: str) -> float | None:
    return float(text) if text.strip() else None


@dataclass(frozen=True)
class CoilLine:
    """One coil line (family) of the catalogue, as its source gives it."""

    family: str
    maker: str
    shape_class: str  # 3D framing, helical filling, soft finishing
    system: str  # "10", "18" or "" (not published)
    d_in: float | None  # published secondary diameter, in
    loop_range_mm: tuple[float, float]
    length_range_cm: tuple[float, float]
    sizes: tuple[tuple[float, float], ...]  # published (loop mm, length cm) pairs
    primary_wire_in: float | None
    softness: str
    stretch_resistant: bool | None
    source: str
    source_url: str
    source_note: str

    @property
    def model_shape(self) -> str:
        return MODEL_SHAPE[self.shape_class]

    @property
    def d_mm(self) -> float:
        """Secondary diameter used by the model, mm (see :attr:`d_basis`)."""
        if self.d_in is not None:
            return self.d_in * INCH_MM
        if self.system in SYSTEM_NOMINAL_IN:
            return SYSTEM_NOMINAL_IN[self.system] * INCH_MM
        return CoilSpec.wire_diameter_mm

    @property
    def d_basis(self) -> str:
        if self.d_in is not None:
            return "published"
        if self.system in SYSTEM_NOMINAL_IN:
            return f"system {self.system} nominal ({SYSTEM_NOMINAL_IN[self.system]:.3f} in)"
        return "model default"

    @property
    def primary_wire_mm(self) -> float:
        return self.primary_wire_in * INCH_MM if self.primary_wire_in is not None else CoilSpec.primary_wire_diameter_mm

    @property
    def primary_wire_basis(self) -> str:
        return "published" if self.primary_wire_in is not None else "model default"

    @property
    def published_keys(self) -> frozenset[str]:
        """Scene keys the catalogue fills from a published figure (refused beside ``product``)."""
        keys = {"shape", "loop_diameter_mm", "length_mm"}
        if self.d_basis == "published":
            keys.add("wire_diameter_mm")
        if self.primary_wire_in is not None:
            keys.add("primary_wire_diameter_mm")
        if self.stretch_resistant is not None:
            keys.add("stretch_resistant")
        return frozenset(keys)

    def size_note(self, loop_mm: float, length_cm: float) -> str | None:
        """None for a listed size; a note for one inside the cleared range; raises
        :class:`CatalogueError` (with the nearest sizes) for one outside it."""
        if (loop_mm, length_cm) in self.sizes:
            return None
        (loop_lo, loop_hi), (len_lo, len_hi) = self.loop_range_mm, self.length_range_cm
        if loop_lo <= loop_mm <= loop_hi and len_lo <= length_cm <= len_hi:
            return (f"{self.family} {_size_text(loop_mm, length_cm)}: inside the cleared range "
                    f"{loop_lo:g}–{loop_hi:g} mm × {len_lo:g}–{len_hi:g} cm of {self.source}, but the maker's size "
                    "grid is not public: check in the instructions for use that this size exists")
        clamped = (min(max(loop_mm, loop_lo), loop_hi), min(max(length_cm, len_lo), len_hi))
        near = sorted({clamped, *self.sizes}, key=lambda s: abs(s[0] - loop_mm) / loop_hi + abs(s[1] - length_cm) / len_hi)
        raise CatalogueError(
            f"{self.family} has no size {_size_text(loop_mm, length_cm)} (its range is {loop_lo:g}–{loop_hi:g} mm × "
            f"{len_lo:g}–{len_hi:g} cm, {self.source})",
            "nearest: " + ", ".join(f'"{_size_text(*s)}"' for s in near[:3]) + " (warpcoil coils lists the sizes)")

    def spec(self, size: str, **overrides) -> tuple[CoilSpec, str | None]:
        """The :class:`CoilSpec` of this line at ``size`` (``"6 x 20"``), with ``overrides``
        (other CoilSpec fields), and the size note (None for a listed size)."""
        loop_mm, length_cm = parse_size(size)
        note = self.size_note(loop_mm, length_cm)
        values = {"wire_diameter_mm": self.d_mm, "primary_wire_diameter_mm": self.primary_wire_mm,
                  "shape": self.model_shape, "loop_diameter_mm": loop_mm, "length_mm": 10.0 * length_cm,
                  "product": self.family, "size": size}
        if self.stretch_resistant is not None:
            values["stretch_resistant"] = self.stretch_resistant
        return CoilSpec(**{**values, **overrides}), note


def _line(row: dict[str, str]) -> CoilLine:
    sizes = tuple(parse_size(s) for s in row["sizes"].split(";") if s.strip())
    sr = {"yes": True, "no": False, "": None}[row["stretch_resistant"].strip()]
    if row["shape_class"] not in MODEL_SHAPE:
        raise ValueError(f"coils.csv: {row['family']}: shape_class {row['shape_class']!r} is not one of {list(MODEL_SHAPE)}")
    return CoilLine(
        family=row["family"], maker=row["maker"], shape_class=row["shape_class"], system=row["system"].strip(),
        d_in=_number(row["d_in"]),
        loop_range_mm=(float(row["loop_min_mm"]), float(row["loop_max_mm"])),
        length_range_cm=(float(row["length_min_cm"]), float(row["length_max_cm"])),
        sizes=sizes, primary_wire_in=_number(row["primary_wire_in"]), softness=row["softness"],
        stretch_resistant=sr, source=row["source"], source_url=row["source_url"], source_note=row["source_note"])


@cache
def catalogue() -> dict[str, CoilLine]:
    """Every line of the shipped catalogue, by family name."""
    text = (files("warpcoil") / "data" / "coils.csv").read_text(encoding="utf-8")
    return {line.family: line for line in map(_line, csv.DictReader(text.splitlines()))}


def nearest_families(name: str, n: int = 3) -> list[str]:
    """The catalogue's families closest to ``name`` (difflib, case-insensitive; substring matches first)."""
    families = list(catalogue())
    lower = {f.lower(): f for f in families}
    contained = [f for f in families if name.lower() and name.lower() in f.lower()]
    close = [lower[m] for m in difflib.get_close_matches(name.lower(), list(lower), n=n, cutoff=0.3)]
    return list(dict.fromkeys(contained + close))[:n] or families[:n]


def find_line(family: str) -> CoilLine:
    """The line named ``family`` (exact, then case-insensitive); :class:`CatalogueError` otherwise."""
    lines = catalogue()
    if family in lines:
        return lines[family]
    for name, line in lines.items():
        if name.lower() == family.strip().lower():
            return line
    raise CatalogueError(f"unknown coil family {family!r}",
                         "did you mean " + " or ".join(repr(f) for f in nearest_families(family))
                         + "? (warpcoil coils lists the catalogue)")


def select(family: str | None = None) -> list[CoilLine]:
    """The lines whose family contains ``family`` (case-insensitive; all for None);
    :class:`CatalogueError` with the nearest families when none does."""
    lines = list(catalogue().values())
    if family is None:
        return lines
    chosen = [line for line in lines if family.strip().lower() in line.family.lower()]
    if not chosen:
        raise CatalogueError(f"no coil family matches {family!r}",
                             "try " + " or ".join(repr(f) for f in nearest_families(family)))
    return chosen


def listing(lines: list[CoilLine]) -> str:
    """The lines as a text table (units in the header) and their sources."""
    header = ("family", "maker", "shape", "system", "d mm (basis)", "loop mm", "length cm", "sizes listed",
              "primary wire mm (basis)", "EI µN·mm² (derived)", "mass g/mm (derived)", "softness", "source")
    rows = []
    for line in lines:
        spec = CoilSpec(wire_diameter_mm=line.d_mm, primary_wire_diameter_mm=line.primary_wire_mm)
        rows.append((line.family, line.maker, line.shape_class, line.system or "–",
                     f"{line.d_mm:.4g} ({line.d_basis})",
                     "{:g}–{:g}".format(*line.loop_range_mm), "{:g}–{:g}".format(*line.length_range_cm),
                     ", ".join(_size_text(*s) for s in line.sizes) or "– (range only)",
                     f"{line.primary_wire_mm:.4g} ({line.primary_wire_basis})",
                     f"{spec.EI:.3g}", f"{spec.rho:.3g}", line.softness or "–", line.source))
    widths = [max(len(str(r[i])) for r in (header, *rows)) for i in range(len(header))]
    text = ["  ".join(str(c).ljust(w) for c, w in zip(r, widths)).rstrip() for r in (header, *rows)]
    text.insert(1, "  ".join("-" * w for w in widths))
    text += ["", "sources (docs/COILS.md says what each gives and what is derived):"]
    text += [f"  {line.family}: {line.source} — {line.source_url}" for line in lines]
    return "\n".join(text) + "\n"
