"""Ranking the options of a treatment plan by clinical criteria, ties made explicit.

Each option is deployed several times with the catheter tip slightly perturbed (the
deployment is chaotic), so every criterion has a mean and a spread (the sample
standard deviation over the option's runs). Criteria, in order of priority:

0. coil deployed (% of its length, higher is better): a run that jammed (its coil withdrawn)
   or timed out before the coil was in has not delivered the treatment, whatever its herniation;
1. herniated length (mm, lower is better): coil outside the sac (in the parent vessel);
2. occlusion grade (Raymond–Roy class I = 1, II = 2, III / IIIa = 3, IIIb = 4; lower is
   better), from ``result.json["occlusion"]["modified_raymond_roy_class"]`` (else
   ``raymond_roy_class``) where the run gives it;
3. neck coverage (% of the ostium, higher is better);
4. packing density of the coil inside the sac (%, higher is better);
5. peak push force (mN, lower is better): the largest frame-mean push force
   (``push_force_mean_max_uN``), what the hand feels; the single-step peak is contact
   ringing.

**Tie rule.** Two options tie on a criterion when their means differ by no more than
the larger of their two spreads, or than the criterion's resolution (:data:`CRITERIA`),
whichever is larger. Option A *beats* B when, at the first criterion on which they do
not tie, A's mean is better. Rank 1 is every option no other option beats; they are
removed and the next rank is found the same way. Options of one rank tie on every
criterion with each other. A criterion no option reports is skipped; an option without
a value for a criterion ties with every other on it.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

RAYMOND_ROY = {"I": 1.0, "II": 2.0, "III": 3.0, "IIIA": 3.0, "IIIB": 4.0}


def raymond_roy_number(value) -> float | None:
    """Class I, II, III (IIIa), IIIb (or 1, 2, 3) as the ordinal 1, 2, 3, 4; None if absent."""
    if value is None:
        return None
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return float(value)
    text = str(value).strip().upper().removeprefix("CLASS").strip()
    if text not in RAYMOND_ROY:
        raise ValueError(f"occlusion.raymond_roy_class {value!r} is not one of I, II, III, IIIa, IIIb")
    return RAYMOND_ROY[text]


def _occlusion(result: dict) -> float | None:
    """The modified class (IIIa before IIIb) where the run gives it, else the class."""
    occlusion = result.get("occlusion")
    if not isinstance(occlusion, dict):
        return None
    return raymond_roy_number(occlusion.get("modified_raymond_roy_class", occlusion.get("raymond_roy_class")))


def _neck_coverage(result: dict) -> float | None:
    value = (result.get("regions") or {}).get("neck_coverage")
    return None if value is None else 100.0 * value


def _packing(result: dict) -> float | None:
    value = result.get("packing_density_in_sac", result.get("packing_density"))
    return None if value is None else 100.0 * value


def _push_force(result: dict) -> float | None:
    value = result.get("push_force_mean_max_uN")
    return None if value is None else value / 1e3


def _herniated(result: dict) -> float | None:
    return result.get("length_outside_sac_mm")


def _deployed(result: dict) -> float | None:
    deployed, total = result.get("deployed_length_mm"), result.get("coil_length_mm")
    return None if deployed is None or not total else 100.0 * deployed / total


# push forces closer than this fixed threshold (mN) tie: the implicit default reads the push force within
# 0.25 F0 of the finest reference on the seed case (F0 = the stored energy per mm, 0.9–2 mN for the shipped
# coils; stiffer coils read worse, SCENES.md), so differences of tens of µN (an option deploying into free
# space against one barely touching) are no finding; 0.25 mN is 0.12–0.28 F0 of the shipped coils
PUSH_FORCE_RESOLUTION_MN = 0.25


@dataclass(frozen=True)
class Criterion:
    """One ranking criterion: how to read it from a result.json, which way is better,
    and its resolution (differences below ``resolution`` + ``relative`` × the larger
    magnitude are ties whatever the spread)."""

    key: str  # column stem in plan.csv
    label: str  # in plan.md
    unit: str
    lower_is_better: bool
    resolution: float
    read: Callable[[dict], float | None]
    relative: float = 0.0

    def tolerance(self, a: "Stats", b: "Stats") -> float:
        scale = max(abs(a.mean), abs(b.mean))
        return max(a.spread, b.spread, self.resolution + self.relative * scale)


CRITERIA = (
    Criterion("deployed_percent", "coil deployed", "%", False, 1.0, _deployed),
    Criterion("herniated_length_mm", "herniated length", "mm", True, 0.5, _herniated),
    Criterion("modified_raymond_roy_class", "occlusion (Raymond–Roy: 1 = I, 2 = II, 3 = IIIa, 4 = IIIb)", "", True,
              0.5, _occlusion),
    Criterion("neck_coverage_percent", "neck coverage", "%", False, 2.0, _neck_coverage),
    Criterion("packing_density_percent", "packing density in the sac", "%", False, 1.0, _packing),
    Criterion("peak_push_force_mN", "peak push force (largest frame mean)", "mN", True, PUSH_FORCE_RESOLUTION_MN,
              _push_force, relative=0.1),
)


@dataclass(frozen=True)
class Stats:
    """A criterion over an option's runs: mean, spread (sample standard deviation; 0 for
    one run) and the values (None where a run does not report it)."""

    values: tuple[float | None, ...]

    @property
    def known(self) -> list[float]:
        return [v for v in self.values if v is not None and math.isfinite(v)]

    @property
    def mean(self) -> float:
        known = self.known
        return sum(known) / len(known) if known else math.nan

    @property
    def spread(self) -> float:
        known = self.known
        if len(known) < 2:
            return 0.0
        mean = self.mean
        return math.sqrt(sum((v - mean) ** 2 for v in known) / (len(known) - 1))


@dataclass
class Ranked:
    """An option's place: ``rank`` (shared by the options it ties with), the options that
    tie with it on every criterion, and what put it below the rank above."""

    index: int  # the option's position in the plan
    stats: dict[str, Stats]  # criterion key -> Stats
    rank: int = 0
    tied_with: tuple[int, ...] = ()
    beaten_by: tuple[int, str] | None = None  # (option index, criterion label) of one option above it
    cycle: bool = False  # placed by fewest defeats (the pairwise comparisons had a cycle)


def active_criteria(options: Sequence[dict[str, Stats]]) -> list[Criterion]:
    """The criteria at least one option reports."""
    return [c for c in CRITERIA if any(o[c.key].known for o in options)]


def compare(a: dict[str, Stats], b: dict[str, Stats], criteria: Sequence[Criterion]) -> tuple[int, str | None]:
    """(+1 a beats b, −1 b beats a, 0 tie on every criterion), and the deciding criterion's label."""
    for criterion in criteria:
        sa, sb = a[criterion.key], b[criterion.key]
        if not sa.known or not sb.known:
            continue
        difference = sa.mean - sb.mean
        if abs(difference) <= criterion.tolerance(sa, sb):
            continue
        a_better = difference < 0.0 if criterion.lower_is_better else difference > 0.0
        return (1 if a_better else -1), criterion.label
    return 0, None


def rank(options: Sequence[dict[str, Stats]], usable: Sequence[bool] | None = None) -> list[Ranked]:
    """The options in ranked order (best first). ``usable[k]`` False (no run gave a result)
    puts option k after every ranked one, unranked (rank 0)."""
    usable = list(usable) if usable is not None else [True] * len(options)
    criteria = active_criteria([o for o, ok in zip(options, usable) if ok])
    n = len(options)
    outcome = [[compare(options[i], options[j], criteria) if i != j else (0, None) for j in range(n)]
               for i in range(n)]
    remaining = [k for k in range(n) if usable[k]]
    ordered: list[Ranked] = []
    place = 1
    while remaining:
        losses = {k: [j for j in remaining if outcome[j][k][0] > 0] for k in remaining}
        group = [k for k in remaining if not losses[k]]
        cycle = not group
        if cycle:  # a beats b beats c beats a: the fewest defeats go first
            fewest = min(len(v) for v in losses.values())
            group = [k for k in remaining if len(losses[k]) == fewest]
        group.sort(key=lambda k: tuple(_sort_value(options[k][c.key], c) for c in criteria) + (k,))
        for k in group:
            above = [j for r in ordered for j in [r.index] if outcome[j][k][0] > 0]
            beaten = (above[-1], outcome[above[-1]][k][1]) if above else None  # the nearest above
            ordered.append(Ranked(k, dict(options[k]), place, tuple(j for j in group if j != k), beaten, cycle))
        place += len(group)
        remaining = [k for k in remaining if k not in group]
    ordered += [Ranked(k, dict(options[k])) for k in range(n) if not usable[k]]
    return ordered


def _sort_value(stats: Stats, criterion: Criterion) -> float:
    """Order inside a group of tied options (display only): by the means, criterion by criterion."""
    mean = stats.mean
    if math.isnan(mean):
        return math.inf
    return mean if criterion.lower_is_better else -mean


__all__ = ["CRITERIA", "Criterion", "Ranked", "Stats", "active_criteria", "compare", "rank", "raymond_roy_number"]
