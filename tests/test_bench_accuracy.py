"""`warpcoil bench accuracy`'s Pareto check (no runs: rows made up): the reference's default and, on a
deployment, the implicit default (the scene default) are each judged against the settings that are candidates."""

from warpcoil.bench.accuracy import IMPLICIT_DEFAULT_ROW, Row, pareto_check

CASE = "seed deployment"


def row(setting: str, time_s: float, error: float, default: bool = False, not_default: str = "") -> Row:
    return Row(CASE, setting, default, 100, time_s, error, not_default=not_default, floor=0.15)


def test_the_implicit_default_is_judged_beside_the_default():
    rows = [row("symplectic default", 18.0, 0.03, default=True),
            row(IMPLICIT_DEFAULT_ROW + "gated_chord: θ 0.65 gated, chord)", 2.0, 0.05),
            row("implicit BDF2", 1.4, 0.06, not_default="push force off by 0.53 F0 (> 0.25 F0)"),
            row("implicit θ 0.7, 1.2 c0", 1.0, 0.06),
            row("implicit θ 0.7, 2.4 c0", 1.9, 0.20)]  # above the chaotic spread: not equal
    symplectic, implicit = pareto_check(rows).splitlines()
    assert symplectic.startswith(f"- {CASE}: reference default 18 s") and "dominated by" in symplectic
    assert implicit.startswith(f"- {CASE}: default (implicit) 2 s")
    assert "dominated by implicit θ 0.7, 1.2 c0 (1 s" in implicit and "2.4 c0" not in implicit
    assert "faster but not default candidates: implicit BDF2: push force off by 0.53 F0" in implicit


def test_a_case_without_an_implicit_default_row_has_one_line():
    rows = [row("symplectic default", 18.0, 0.03, default=True), row("dt 0.5 bound", 30.0, 0.02)]
    assert pareto_check(rows) == (f"- {CASE}: reference default 18 s, error 3.00e-02 (errors below the chaotic spread "
                                  "1.50e-01 count as equal) — on the front (within 10 %)")
