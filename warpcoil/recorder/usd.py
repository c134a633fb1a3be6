"""Record a coil deployment as an animated USD stage (usdview, Omniverse, Blender).

Stage layout (all lengths in mm, ``metersPerUnit = 0.001``)::

    /World                    Xform, default prim, kind "component"
    /World/Wall               Mesh, static triangulated aneurysm/vessel wall
    /World/Coils              Xform
    /World/Coils/Coil_<k>     BasisCurves (linear), time-sampled points/extent
    /World/Stent              BasisCurves (linear), static struts (stent-assisted runs)
    /World/Balloon            BasisCurves (linear) along the balloon axis, per-vertex widths =
                              the balloon's diameter, time-sampled with its inflation

The stage is built in memory and exported in one go on :meth:`UsdRecorder.close`
through :func:`~warpcoil.recorder.atomic.atomic_path`, so an aborted run leaves
no file behind. The format follows the extension: ``.usdc``/``.usd`` crate,
``.usda`` text.
"""

from __future__ import annotations

from pathlib import Path
from types import TracebackType

import numpy as np
from pxr import Gf, Kind, Usd, UsdGeom, UsdValidation, Vt

from warpcoil.recorder.atomic import atomic_path

USD_SUFFIXES = (".usd", ".usda", ".usdc")
COIL_COLORS_RGB = (
    (0.85, 0.65, 0.13),  # gold
    (0.75, 0.75, 0.78),  # platinum
    (0.20, 0.55, 0.85),  # blue
    (0.85, 0.30, 0.25),  # red
    (0.35, 0.70, 0.35),  # green
    (0.60, 0.40, 0.75),  # purple
)
WALL_COLOR_RGB = (0.90, 0.55, 0.55)
WALL_OPACITY = 0.35


class UsdRecorder:
    """Write coil centrelines (and an optional static wall) to an animated USD file.

    Args:
        path: output file, ``.usdc``/``.usd`` (binary crate) or ``.usda`` (text).
        coil_node_counts: number of centreline nodes of each coil.
        coil_widths_mm: secondary (helix) diameter d of each coil in mm, used as
            the constant curve width.
        wall_vertices_mm: (V, 3) wall vertex positions in mm, or None for no wall.
        wall_faces: (F, 3) triangle vertex indices, required with the vertices.
        time_codes_per_second: USD time codes per simulated second; a frame at
            ``time_s`` is stored at code ``time_s * time_codes_per_second`` (:func:`time_code`:
            fractional where a frame is not a whole number of codes long, which viewers
            interpolate at their integer frames).
        frames_per_second: the playback rate viewers use (codes per wall-clock
            second); equal to ``time_codes_per_second`` (the default) plays in
            real time, a smaller value in slow motion.
        up_axis: stage up axis, "Y" or "Z".

    A frame at the same time as the previous one overwrites it; a frame whose code is
    lower than the previous frame's raises ``ValueError``.
    """

    def __init__(
        self,
        path: Path,
        coil_node_counts: list[int],
        coil_widths_mm: list[float],
        wall_vertices_mm: np.ndarray | None = None,
        wall_faces: np.ndarray | None = None,
        time_codes_per_second: float = 100.0,
        up_axis: str = "Z",
        frames_per_second: float | None = None,
    ) -> None:
        self.path = Path(path)
        if self.path.suffix not in USD_SUFFIXES:
            raise ValueError(f"USD output must end in one of {USD_SUFFIXES}: {self.path}")
        if len(coil_node_counts) != len(coil_widths_mm):
            raise ValueError("coil_node_counts and coil_widths_mm differ in length")
        if (wall_vertices_mm is None) != (wall_faces is None):
            raise ValueError("wall_vertices_mm and wall_faces must be given together")
        if up_axis not in ("Y", "Z"):
            raise ValueError(f"up_axis must be 'Y' or 'Z', got {up_axis!r}")
        if time_codes_per_second <= 0.0:
            raise ValueError("time_codes_per_second must be positive")

        self.coil_node_counts = [int(n) for n in coil_node_counts]
        self.coil_widths_mm = [float(d) for d in coil_widths_mm]
        self.time_codes_per_second = float(time_codes_per_second)
        self._time_codes: list[float] = []
        self._closed = False

        self._stage = Usd.Stage.CreateInMemory()
        UsdGeom.SetStageMetersPerUnit(self._stage, UsdGeom.LinearUnits.millimeters)
        UsdGeom.SetStageUpAxis(self._stage, up_axis)
        self._stage.SetTimeCodesPerSecond(self.time_codes_per_second)
        self._stage.SetFramesPerSecond(self.time_codes_per_second if frames_per_second is None
                                       else float(frames_per_second))

        world = UsdGeom.Xform.Define(self._stage, "/World")
        Usd.ModelAPI(world.GetPrim()).SetKind(Kind.Tokens.component)
        self._stage.SetDefaultPrim(world.GetPrim())
        if wall_vertices_mm is not None:
            self._define_wall(np.asarray(wall_vertices_mm), np.asarray(wall_faces))
        UsdGeom.Xform.Define(self._stage, "/World/Coils")
        self._coils = [self._define_coil(k) for k in range(len(self.coil_node_counts))]

    def _define_wall(self, vertices_mm: np.ndarray, faces: np.ndarray) -> None:
        """Static triangle mesh at /World/Wall, drawn flat and see-through."""
        if vertices_mm.ndim != 2 or vertices_mm.shape[1] != 3:
            raise ValueError(f"wall_vertices_mm must be (V, 3), got {vertices_mm.shape}")
        if faces.ndim != 2 or faces.shape[1] != 3:
            raise ValueError(f"wall_faces must be (F, 3) triangles, got {faces.shape}")
        if faces.size and (faces.min() < 0 or faces.max() >= len(vertices_mm)):
            raise ValueError("wall_faces index a vertex outside wall_vertices_mm")
        mesh = UsdGeom.Mesh.Define(self._stage, "/World/Wall")
        points = Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(vertices_mm, dtype=np.float32))
        mesh.CreatePointsAttr(points)
        counts = np.full(len(faces), 3, dtype=np.int32)
        mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(counts))
        mesh.CreateFaceVertexIndicesAttr(
            Vt.IntArray.FromNumpy(np.ascontiguousarray(faces.ravel(), dtype=np.int32))
        )
        mesh.CreateExtentAttr(UsdGeom.Mesh.ComputeExtent(points))
        mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        mesh.CreateDoubleSidedAttr(True)
        mesh.CreateDisplayColorPrimvar(UsdGeom.Tokens.constant).Set([Gf.Vec3f(*WALL_COLOR_RGB)])
        mesh.CreateDisplayOpacityPrimvar(UsdGeom.Tokens.constant).Set([WALL_OPACITY])

    def _define_coil(self, k: int) -> UsdGeom.BasisCurves:
        """Linear curve at /World/Coils/Coil_<k> with constant width d and colour."""
        curve = UsdGeom.BasisCurves.Define(self._stage, f"/World/Coils/Coil_{k}")
        curve.CreateTypeAttr(UsdGeom.Tokens.linear)
        curve.CreateCurveVertexCountsAttr([self.coil_node_counts[k]])
        curve.CreateWidthsAttr([self.coil_widths_mm[k]])
        curve.SetWidthsInterpolation(UsdGeom.Tokens.constant)
        color_rgb = COIL_COLORS_RGB[k % len(COIL_COLORS_RGB)]
        curve.CreateDisplayColorPrimvar(UsdGeom.Tokens.constant).Set([Gf.Vec3f(*color_rgb)])
        curve.CreatePointsAttr()
        curve.CreateExtentAttr()
        return curve

    def add_stent(self, starts_mm: np.ndarray, ends_mm: np.ndarray, strut_diameter_mm: float) -> None:
        """Static struts at /World/Stent, one two-point curve each."""
        curve = UsdGeom.BasisCurves.Define(self._stage, "/World/Stent")
        curve.CreateTypeAttr(UsdGeom.Tokens.linear)
        points = np.ascontiguousarray(np.stack([starts_mm, ends_mm], 1).reshape(-1, 3), dtype=np.float32)
        curve.CreateCurveVertexCountsAttr([2] * len(starts_mm))
        curve.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(points))
        curve.CreateWidthsAttr([float(strut_diameter_mm)])
        curve.SetWidthsInterpolation(UsdGeom.Tokens.constant)
        curve.CreateExtentAttr(Vt.Vec3fArray.FromNumpy(np.stack([points.min(0), points.max(0)])))
        curve.CreateDisplayColorPrimvar(UsdGeom.Tokens.constant).Set([Gf.Vec3f(0.55, 0.57, 0.6)])

    def add_balloon(self, axis_mm: np.ndarray, radii_mm: np.ndarray) -> None:
        """The balloon at /World/Balloon: its axis with the inflated diameter as widths."""
        curve = UsdGeom.BasisCurves.Define(self._stage, "/World/Balloon")
        curve.CreateTypeAttr(UsdGeom.Tokens.linear)
        points = np.ascontiguousarray(axis_mm, dtype=np.float32)
        curve.CreateCurveVertexCountsAttr([len(points)])
        curve.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(points))
        curve.SetWidthsInterpolation(UsdGeom.Tokens.vertex)
        curve.CreateWidthsAttr()
        reach = float(np.max(radii_mm))
        curve.CreateExtentAttr(Vt.Vec3fArray.FromNumpy(np.stack([points.min(0) - reach, points.max(0) + reach])))
        curve.CreateDisplayColorPrimvar(UsdGeom.Tokens.constant).Set([Gf.Vec3f(0.3, 0.6, 0.9)])
        curve.CreateDisplayOpacityPrimvar(UsdGeom.Tokens.constant).Set([0.4])
        self._balloon = (curve, 2.0 * np.asarray(radii_mm, dtype=np.float64))

    def set_balloon(self, time_s: float, inflation: float) -> None:
        """Time sample of the balloon's widths: diameter × inflation (0–1)."""
        curve, diameters = self._balloon
        widths = np.maximum(diameters * float(inflation), 1e-3).astype(np.float32)
        curve.GetWidthsAttr().Set(Vt.FloatArray.FromNumpy(widths), self.time_code(time_s))

    def add_frame(self, time_s: float, positions_mm: list[np.ndarray]) -> None:
        """Write one time sample of every coil's (n_nodes_k, 3) node positions in mm."""
        if self._closed:
            raise RuntimeError("UsdRecorder is closed")
        if len(positions_mm) != len(self._coils):
            raise ValueError(f"expected {len(self._coils)} coils, got {len(positions_mm)}")
        code = self.time_code(time_s)
        if self._time_codes and code < self._time_codes[-1]:
            raise ValueError(f"time {time_s} s (code {code}) precedes the previous frame")

        for k, (curve, pos_mm) in enumerate(zip(self._coils, positions_mm, strict=True)):
            pos_mm = np.ascontiguousarray(pos_mm, dtype=np.float32)
            if pos_mm.shape != (self.coil_node_counts[k], 3):
                raise ValueError(
                    f"coil {k}: expected shape ({self.coil_node_counts[k]}, 3), got {pos_mm.shape}"
                )
            half_width_mm = 0.5 * self.coil_widths_mm[k]
            extent = Vt.Vec3fArray.FromNumpy(
                np.stack([pos_mm.min(axis=0) - half_width_mm, pos_mm.max(axis=0) + half_width_mm])
            )
            curve.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy(pos_mm), code)
            curve.GetExtentAttr().Set(extent, code)

        if not self._time_codes or code != self._time_codes[-1]:
            self._time_codes.append(code)

    def time_code(self, time_s: float) -> float:
        """The code of simulated time ``time_s`` (s): time × codes per second, to 1e-6 of a code (so a
        frame of whole codes gets a whole code; distinct frames, at least a step apart, never share one).
        Not rounded to whole codes: frames last whole steps, not whole codes (a 10 ms frame of 22 steps of
        0.467 ms lasts 1.028 codes), and rounding put two frames on one code now and then, the later
        overwriting the earlier (C0091: 206 samples for 207 frames)."""
        return round(time_s * self.time_codes_per_second, 6)

    @property
    def time_codes(self) -> list[float]:
        """The distinct time codes written so far, increasing."""
        return list(self._time_codes)

    def close(self) -> None:
        """Set the playback range and atomically write the stage to ``path``."""
        if self._closed:
            return
        if self._time_codes:
            self._stage.SetStartTimeCode(self._time_codes[0])
            self._stage.SetEndTimeCode(self._time_codes[-1])
        with atomic_path(self.path) as tmp_path:
            if not self._stage.GetRootLayer().Export(str(tmp_path)):
                raise OSError(f"USD export to {tmp_path} failed")
        self._release()

    def _release(self) -> None:
        self._closed = True
        self._coils = []
        self._stage = None

    def __enter__(self) -> UsdRecorder:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if exc_type is None:
            self.close()
        else:
            self._release()


def validate_usd(path: Path) -> list[str]:
    """Run all registered usd-core validators on ``path``; return the error messages.

    Same validators as ``usdchecker``; warnings are ignored. An empty list means
    the stage is valid.
    """
    stage = Usd.Stage.Open(str(path))
    validators = UsdValidation.ValidationRegistry().GetOrLoadAllValidators()
    found = UsdValidation.ValidationContext(validators).Validate(stage)
    return [
        e.GetErrorAsString()
        for e in found
        if e.GetType() == UsdValidation.ValidationErrorType.Error
    ]
