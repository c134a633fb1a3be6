"""UsdRecorder round trip through pxr, USD validation, and the atomic-write helpers."""

from pathlib import Path

import numpy as np
import pytest
import trimesh
from pxr import Usd, UsdGeom

from warpcoil.recorder import UsdRecorder, atomic_path, validate_usd, write_text_atomic

NODE_COUNTS = [11, 7]
WIDTHS_MM = [0.2921, 0.254]
TIME_CODES_PER_SECOND = 100.0
FRAME_TIMES_S = [0.0, 0.01, 0.02, 0.03, 0.04]


def coil_positions_mm(frame: int) -> list[np.ndarray]:
    """Straight coils along x, advancing and rising with the frame index."""
    return [
        np.column_stack(
            [np.linspace(0.0, 1.0, n) + 0.1 * frame, np.full(n, k), np.full(n, 0.05 * frame)]
        )
        for k, n in enumerate(NODE_COUNTS)
    ]


@pytest.fixture(scope="module")
def wall() -> trimesh.Trimesh:
    return trimesh.creation.icosphere(subdivisions=2, radius=1.75)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory, wall: trimesh.Trimesh) -> Path:
    path = tmp_path_factory.mktemp("usd") / "deployment.usdc"
    with UsdRecorder(
        path, NODE_COUNTS, WIDTHS_MM, wall.vertices, wall.faces, TIME_CODES_PER_SECOND
    ) as rec:
        for frame, time_s in enumerate(FRAME_TIMES_S):
            rec.add_frame(time_s, coil_positions_mm(frame))
    return path


def test_stage_metadata(recorded: Path) -> None:
    stage = Usd.Stage.Open(str(recorded))
    assert UsdGeom.GetStageMetersPerUnit(stage) == pytest.approx(0.001)
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z
    assert stage.GetTimeCodesPerSecond() == TIME_CODES_PER_SECOND
    assert stage.GetStartTimeCode() == 0
    assert stage.GetEndTimeCode() == 4
    assert stage.GetDefaultPrim().GetPath() == "/World"
    assert stage.GetDefaultPrim().IsA(UsdGeom.Xform)
    assert sorted(p.name for p in recorded.parent.iterdir()) == ["deployment.usdc"]


def test_coils(recorded: Path) -> None:
    stage = Usd.Stage.Open(str(recorded))
    for k, (n_nodes, width_mm) in enumerate(zip(NODE_COUNTS, WIDTHS_MM, strict=True)):
        prim = stage.GetPrimAtPath(f"/World/Coils/Coil_{k}")
        assert prim.IsA(UsdGeom.BasisCurves)
        curve = UsdGeom.BasisCurves(prim)
        assert curve.GetTypeAttr().Get() == UsdGeom.Tokens.linear
        assert list(curve.GetCurveVertexCountsAttr().Get()) == [n_nodes]
        assert curve.GetWidthsInterpolation() == UsdGeom.Tokens.constant
        np.testing.assert_allclose(curve.GetWidthsAttr().Get(), [width_mm], rtol=1e-6)
        assert curve.GetPointsAttr().GetTimeSamples() == [0, 1, 2, 3, 4]
        assert curve.GetExtentAttr().GetTimeSamples() == [0, 1, 2, 3, 4]
        for frame in (0, 3):
            points_mm = np.array(curve.GetPointsAttr().Get(frame))
            np.testing.assert_allclose(points_mm, coil_positions_mm(frame)[k], atol=1e-6)
            extent_mm = np.array(curve.GetExtentAttr().Get(frame))
            computed = UsdGeom.Boundable.ComputeExtentFromPlugins(curve, frame)
            np.testing.assert_allclose(extent_mm, np.array(computed), atol=1e-6)


def test_wall(recorded: Path, wall: trimesh.Trimesh) -> None:
    stage = Usd.Stage.Open(str(recorded))
    prim = stage.GetPrimAtPath("/World/Wall")
    assert prim.IsA(UsdGeom.Mesh)
    mesh = UsdGeom.Mesh(prim)
    assert len(mesh.GetPointsAttr().Get()) == len(wall.vertices)
    assert len(mesh.GetFaceVertexCountsAttr().Get()) == len(wall.faces)
    np.testing.assert_array_equal(mesh.GetFaceVertexIndicesAttr().Get(), wall.faces.ravel())
    assert mesh.GetSubdivisionSchemeAttr().Get() == UsdGeom.Tokens.none
    assert mesh.GetDoubleSidedAttr().Get()
    np.testing.assert_allclose(mesh.GetExtentAttr().Get(), wall.bounds, atol=1e-6)


def test_recorded_stage_is_valid(recorded: Path) -> None:
    assert validate_usd(recorded) == []


def test_validate_usd_reports_missing_metadata(tmp_path: Path) -> None:
    path = tmp_path / "bare.usda"
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.Xform.Define(stage, "/World")
    stage.Save()
    errors = validate_usd(path)
    assert any("metersPerUnit" in e for e in errors)
    assert any("defaultPrim" in e for e in errors)


def test_usda_output_is_text(tmp_path: Path) -> None:
    path = tmp_path / "deployment.usda"
    with UsdRecorder(path, NODE_COUNTS, WIDTHS_MM, up_axis="Y") as rec:
        rec.add_frame(0.5, coil_positions_mm(0))
    assert path.read_text().startswith("#usda")
    stage = Usd.Stage.Open(str(path))
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y
    assert stage.GetStartTimeCode() == stage.GetEndTimeCode() == 50
    assert not stage.GetPrimAtPath("/World/Wall")


def test_each_frame_keeps_its_own_time_a_repeated_time_the_later(tmp_path: Path) -> None:
    """Frames 2 ms apart at 100 codes/s get codes 1.0 and 1.2 (rounding put both on 1, losing one);
    a frame at the same time again replaces it."""
    path = tmp_path / "deployment.usdc"
    with UsdRecorder(path, NODE_COUNTS, WIDTHS_MM) as rec:
        rec.add_frame(0.010, coil_positions_mm(0))
        rec.add_frame(0.012, coil_positions_mm(1))
        rec.add_frame(0.012, coil_positions_mm(2))
        assert rec.time_codes == [1.0, 1.2]
        with pytest.raises(ValueError, match="precedes"):
            rec.add_frame(0.0, coil_positions_mm(3))
    stage = Usd.Stage.Open(str(path))  # keep a reference: prims die with their stage
    points = UsdGeom.BasisCurves.Get(stage, "/World/Coils/Coil_0").GetPointsAttr()
    assert points.GetTimeSamples() == [1.0, 1.2]
    np.testing.assert_allclose(np.array(points.Get(1.0)), coil_positions_mm(0)[0], atol=1e-6)
    np.testing.assert_allclose(np.array(points.Get(1.2)), coil_positions_mm(2)[0], atol=1e-6)


def test_wrong_shape_is_rejected(tmp_path: Path) -> None:
    rec = UsdRecorder(tmp_path / "x.usdc", NODE_COUNTS, WIDTHS_MM)
    with pytest.raises(ValueError, match="coil 1"):
        rec.add_frame(0.0, [np.zeros((11, 3)), np.zeros((6, 3))])


def test_exception_leaves_no_file(tmp_path: Path, wall: trimesh.Trimesh) -> None:
    path = tmp_path / "deployment.usdc"
    with pytest.raises(RuntimeError, match="boom"):
        with UsdRecorder(path, NODE_COUNTS, WIDTHS_MM, wall.vertices, wall.faces) as rec:
            rec.add_frame(0.0, coil_positions_mm(0))
            raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []


def test_write_text_atomic(tmp_path: Path) -> None:
    path = tmp_path / "summary.json"
    write_text_atomic(path, "{}")
    write_text_atomic(path, '{"a": 1}')
    assert path.read_text() == '{"a": 1}'
    assert list(tmp_path.iterdir()) == [path]


def test_atomic_path_keeps_suffix_and_replaces(tmp_path: Path) -> None:
    path = tmp_path / "out.usdc"
    path.write_text("old")
    with atomic_path(path) as tmp:
        assert tmp.parent == tmp_path
        assert tmp.suffix == ".usdc"
        assert tmp != path
        tmp.write_text("new")
        assert path.read_text() == "old"
    assert path.read_text() == "new"
    assert list(tmp_path.iterdir()) == [path]


def test_atomic_path_cleans_up_on_error(tmp_path: Path) -> None:
    path = tmp_path / "out.txt"
    path.write_text("old")
    with pytest.raises(KeyError):
        with atomic_path(path) as tmp:
            tmp.write_text("partial")
            raise KeyError("fail")
    assert path.read_text() == "old"
    assert list(tmp_path.iterdir()) == [path]


def test_frames_kept_until_close_write_the_same_file(tmp_path: Path, wall: trimesh.Trimesh) -> None:
    """UsdFrames keeps each frame's positions (copies: the state changes after the call)
    and writes the samples on close: byte for byte the file of a recorder fed frame by frame."""
    from types import SimpleNamespace

    from warpcoil.recorder.outputs import UsdFrames

    frame_s = 1.0 / TIME_CODES_PER_SECOND
    slices = [slice(3, 3 + NODE_COUNTS[0]), slice(3 + NODE_COUNTS[0], 3 + sum(NODE_COUNTS))]  # a member's nodes
    direct = tmp_path / "direct.usdc"
    with UsdRecorder(direct, NODE_COUNTS, WIDTHS_MM, wall.vertices, wall.faces, TIME_CODES_PER_SECOND,
                     frames_per_second=TIME_CODES_PER_SECOND) as rec:
        for frame, time_s in enumerate(FRAME_TIMES_S):
            rec.add_frame(time_s, coil_positions_mm(frame))
    kept = UsdFrames(tmp_path / "kept.usdc", slices, WIDTHS_MM, wall.vertices, wall.faces, frame_s)
    x = np.zeros((3 + sum(NODE_COUNTS) + 2, 3))
    state = SimpleNamespace(x=SimpleNamespace(numpy=lambda: x))
    for frame, time_s in enumerate(FRAME_TIMES_S):
        x[slices[0]], x[slices[1]] = coil_positions_mm(frame)
        kept(SimpleNamespace(time_s=time_s, balloon_inflation=None), state)
        x[:] = np.nan  # the state moves on
    kept.close()
    assert (tmp_path / "kept.usdc").read_bytes() == direct.read_bytes()
