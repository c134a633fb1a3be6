"""The coil catalogue (issue 15, deliverable 1): every line names its source, a scene's
``product``/``size`` gives the catalogue's d, D and L, and unknown families or sizes are
input errors listing the nearest matches — checked through the API and as a user runs
``warpcoil`` (subprocess, output in files)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from warpcoil.catalog import INCH_MM, CatalogueError, catalogue, find_line, parse_size
from warpcoil.coil import CoilSpec
from warpcoil.scene import SceneError, load_scene

ROOT = Path(__file__).resolve().parents[1]

SCENE = """
[catheter]
tip = [0.0, 0.0, 0.0]
direction = [0.0, 0.0, 1.0]

[[coil]]
{coil}
"""


def write(tmp_path: Path, coil: str) -> Path:
    path = tmp_path / "product.toml"
    path.write_text(SCENE.format(coil=coil))
    return path


def cli(tmp_path: Path, *args: str) -> tuple[int, str, str]:
    """``warpcoil ARGS`` as a user runs it, stdout and stderr in files; (exit code, stdout, stderr)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    env.setdefault("WARPCOIL_KERNEL_CACHE", str(ROOT / ".warp_cache"))
    out, err = tmp_path / "stdout.txt", tmp_path / "stderr.txt"
    with out.open("w") as stdout, err.open("w") as stderr:
        code = subprocess.run([sys.executable, "-m", "warpcoil.cli", *args], stdout=stdout, stderr=stderr,
                              env=env, cwd=tmp_path, timeout=120).returncode
    return code, out.read_text(), err.read_text()


def test_every_line_names_a_source_and_a_consistent_range():
    lines = catalogue()
    assert len(lines) >= 4
    for line in lines.values():
        assert line.source.startswith("510(k) K") and line.source_url.startswith("https://"), line.family
        assert line.source_note, line.family
        (loop_lo, loop_hi), (len_lo, len_hi) = line.loop_range_mm, line.length_range_cm
        assert 0 < loop_lo <= loop_hi and 0 < len_lo <= len_hi, line.family
        for loop, length in line.sizes:  # every listed size lies in the line's published range
            assert loop_lo <= loop <= loop_hi and len_lo <= length <= len_hi, (line.family, loop, length)
        assert line.primary_wire_mm < line.d_mm, line.family


def test_inch_figures_convert_to_mm():
    soft, standard = find_line("Micrus SR MicroCoil Soft"), find_line("micrus sr microcoil standard")
    assert soft.primary_wire_mm == pytest.approx(0.0015 * 25.4) == pytest.approx(0.0381)
    assert standard.primary_wire_mm == pytest.approx(0.04445)
    assert soft.d_mm == pytest.approx(0.010 * INCH_MM) and soft.d_basis.startswith("system 10 nominal")
    # the softer line is the one with the thinner primary wind: EI ∝ d_w⁵ / D_m (Wahl, p = d_w)
    ratio = standard.spec("4 x 10")[0].EI / soft.spec("4 x 10")[0].EI
    dm = lambda line: line.d_mm - line.primary_wire_mm  # noqa: E731
    assert ratio == pytest.approx((0.04445 / 0.0381) ** 5 * dm(soft) / dm(standard), rel=1e-12)


def test_scene_product_gives_the_catalogue_geometry(tmp_path):
    scene = load_scene(write(tmp_path, 'product = "Axium Prime 3D"\nsize = "6 x 20"'))
    coil = scene.coils[0]
    line = find_line("Axium Prime 3D")
    assert (coil.wire_diameter_mm, coil.loop_diameter_mm, coil.length_mm) == (line.d_mm, 6.0, 200.0)
    assert coil.shape == "spherical"
    # material derived by CoilSpec from the same d and primary wire (nothing invented in between)
    reference = CoilSpec(wire_diameter_mm=line.d_mm, primary_wire_diameter_mm=line.primary_wire_mm)
    assert (coil.EI, coil.rho, coil.GJ) == (reference.EI, reference.rho, reference.GJ)
    assert any("grid is not public" in note for note in coil.notes)  # 6 x 20 is inside the range, not listed
    assert any("secondary diameter" in note for note in coil.notes)  # d is the model default: said so

    helix = load_scene(write(tmp_path, 'product = "Micrus SR MicroCoil Soft"\nsize = "4 x 10"\npitch_mm = 0.6'))
    coil = helix.coils[0]
    assert coil.shape == "helix" and coil.helix_pitch_mm == 0.6
    assert coil.wire_diameter_mm == pytest.approx(0.254) and coil.primary_wire_diameter_mm == pytest.approx(0.0381)
    assert coil.length_mm == pytest.approx(100.0) and coil.stretch_resistant


def test_listed_size_has_no_note_and_derived_keys_override(tmp_path):
    coil = load_scene(write(tmp_path, 'product = "Axium Prime 3D"\nsize = "3x6"\nwire_diameter_mm = 0.3\n'
                                      'bending_stiffness_uN_mm2 = 1500.0')).coils[0]
    assert coil.notes == () and coil.wire_diameter_mm == 0.3 and coil.EI == 1500.0


@pytest.mark.parametrize("coil, key, words", [
    ('product = "Axium Prme 3D"\nsize = "6 x 20"', "coil[0].product", ["'Axium Prime 3D'"]),
    ('product = "Axium Prime 3D"\nsize = "30 x 20"', "coil[0].size", ['"25 x 20"', "3–25 mm"]),
    ('product = "Axium Prime 3D"\nsize = "six by 20"', "coil[0].size", ['"6 x 20"']),
    ('product = "Axium Prime 3D"', "coil[0].size", ["add size"]),
    ('product = "Axium Prime 3D"\nsize = 3', "coil[0].size", ["must be a string", 'e.g. "3 x 6"']),
    ('product = "Axium Prime 3D"\nsize = "6 x 20"\nloop_diameter_mm = 5.0', "coil[0].loop_diameter_mm", ["K162704"]),
    ('product = "Micrus SR MicroCoil Soft"\nsize = "4 x 10"\nprimary_wire_diameter_mm = 0.05',
     "coil[0].primary_wire_diameter_mm", ["remove it"]),
    ('product = "Axium Prime 3D"\nsize = "6 x 20"\npitch_mm = 0.6', "coil[0].pitch_mm", ["only for shape"]),
])
def test_bad_product_is_an_input_error_naming_the_key(tmp_path, coil, key, words):
    with pytest.raises(SceneError) as error:
        load_scene(write(tmp_path, coil))
    message = str(error.value)
    assert f"product.toml: {key}:" in message and "fix:" in message, message
    for word in words:
        assert word in message, message


def test_parse_size():
    assert parse_size("6 x 20") == (6.0, 20.0) and parse_size("1.5×1") == (1.5, 1.0)
    with pytest.raises(CatalogueError):
        parse_size("6 mm x 20 cm")


def test_cli_unknown_family_exits_2_with_suggestions(tmp_path):
    path = write(tmp_path, 'product = "Axium Prime"\nsize = "6 x 20"')
    code, out, err = cli(tmp_path, "run", str(path), "-o", str(tmp_path / "out"))
    assert code == 2 and out == ""
    assert f"{path}: coil[0].product: unknown coil family 'Axium Prime'" in err
    assert "'Axium Prime 3D'" in err and "warpcoil coils" in err
    assert not (tmp_path / "out").exists()


def test_cli_coils_lists_the_families(tmp_path):
    code, out, err = cli(tmp_path, "coils")
    assert code == 0 and err == ""
    for line in catalogue().values():
        assert line.family in out and line.source_url in out
    code, out, err = cli(tmp_path, "coils", "--family", "micrus")
    assert code == 0 and "Micrus SR MicroCoil Soft" in out and "Axium" not in out
    code, out, err = cli(tmp_path, "coils", "--family", "Galaxy")
    assert code == 2 and out == "" and "--family: no coil family matches 'Galaxy'" in err


def test_cli_runs_a_product_scene(tmp_path):
    """A scene naming a product runs to completion with the catalogue's coil (issue 15: scenes
    using product = run); the model-default diameter is reported as a warning."""
    path = tmp_path / "product.toml"
    path.write_text('[wall]\nsphere_diameter_mm = 3.5\n\n[catheter]\ntip = [0.0, 0.0, -1.45]\n'
                    'direction = [0.0, 0.0, 1.0]\n\n[[coil]]\nproduct = "Axium Helix"\nsize = "1.5 x 1"\n\n'
                    '[simulation]\npush_speed_mm_s = 200.0\nframe_interval_s = 0.01\n\n[output]\nusd = false\n')
    code, out, err = cli(tmp_path, "run", str(path), "-o", str(tmp_path / "out"), "--quiet")
    assert code == 0, err
    result = json.loads((tmp_path / "out" / "result.json").read_text())
    line = find_line("Axium Helix")
    assert result["status"] == "completed"
    assert result["coils"][0]["wire_diameter_mm"] == line.d_mm
    assert result["coil_length_mm"] == pytest.approx(10.0, abs=line.d_mm)  # n = round(L / l0) segments
    assert (result["coils"][0]["product"], result["coils"][0]["size"]) == ("Axium Helix", "1.5 x 1")
    assert any("secondary diameter" in warning for warning in result["warnings"])
    assert "coil[0]: Axium Helix: no public source gives its secondary diameter" in err


def test_sweep_members_keep_the_coil_notes_a_run_warns_of(tmp_path):
    """A sweep of a product scene: the coil note `warpcoil run` warns of (a model-default
    diameter) is said once on stderr and kept in every member's result.json."""
    path = tmp_path / "product.toml"
    path.write_text('[wall]\nsphere_diameter_mm = 3.5\n\n[catheter]\ntip = [0.0, 0.0, -1.45]\n'
                    'direction = [0.0, 0.0, 1.0]\n\n[[coil]]\nproduct = "Axium Helix"\nsize = "1.5 x 1"\n\n'
                    '[simulation]\npush_speed_mm_s = 200.0\nframe_interval_s = 0.01\n\n[output]\nusd = false\n')
    code, out, err = cli(tmp_path, "sweep", str(path), "--vary", "simulation.push_speed_mm_s=150,200", "-o",
                         str(tmp_path / "sweep"))
    assert code == 0, err
    assert err.count("no public source gives its secondary diameter") == 1
    for member in ("member_000", "member_001"):
        result = json.loads((tmp_path / "sweep" / member / "result.json").read_text())
        assert result["status"] == "completed"
        notes = [w for w in result["warnings"] if "secondary diameter" in w]
        assert len(notes) == 1 and notes[0].startswith(f"{path}: coil[0]: Axium Helix: ")


def test_sweep_override_varies_the_size(tmp_path):
    path = write(tmp_path, 'product = "Micrus MicroCoil Spherical 10"\nsize = "4 x 10"')
    coil = load_scene(path, overrides={"coil.size": "3 x 6"}).coils[0]
    assert (coil.loop_diameter_mm, coil.length_mm, coil.shape) == (3.0, 60.0, "spherical")
    with pytest.raises(SceneError, match=r"coil\[0\]\.length_mm: is set by product"):
        load_scene(path, overrides={"coil.length_mm": 50.0})
