"""3-D point programs of the workstation (metres, world frame).

Point sources (alternates of one another for ``Range_Points``):

- ``range_points``: the range finder's hit points merged over its views.
- ``stereo_points``: OpenCV StereoSGBM on the stereo pair, disparity -> depth with the
  baseline and focal length, reprojected to world points (valid disparities only).
- ``depth_points``: the depth camera's pixels back-projected through ``K`` and its pose.

Every source takes the optional params ``crop_min`` / ``crop_max`` (world box, metres: the
work region the sensor reports on) and ``voxel_m`` (keep one point per voxel).

Descriptions over a point stream (input: a stream whose first three fields are x, y, z):

- ``surface_curvature``: (x, y, z, curvature) with the Table 4-5 code, +1 curved / -1 planar,
  from PCA normals on the SPG (``mks_sim.lowlevel.grouping``).
- ``vertex_detector``: (x, y, z) of vertexes: planar regions of each object, intersections of
  plane triples supported by the data, the table plane (a sensor parameter) as an extra face.
- ``control_point_detector``: (x, y, z) candidate control points of the industrial part: the
  vertexes where one upward face and two walls meet (``industrial_part_control_points``'s
  recipe, ``mks_sim/geometry/meshes.py``); the Hough matcher labels them.
- ``sphere_detector``: (x, y, z, radius) of sphere fits to curved regions.

Objects are separated before grouping (the paper separates the cube-sphere pair "by the
connectivity of the spatial proximity graph", section 4.1): the one low-level representation
(:class:`mks_sim.localization.representation.Representation`, built once per stream) fits the
table plane near ``z = table_z_m``, drops the points within its band (at least
``table_margin_m``) and splits the rest into SPG components with edges no longer than
``gap_m``.

``touch_contacts``: (x, y, z, pressure) of the taxels above ``min_pressure_pa`` of every touch
pad input — 3-D non-visual data for the same k-d tree and SPG as the visual points.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass, replace
from types import SimpleNamespace
from typing import Any

import cv2
import numpy as np

from mks_sim.errors import DataError, SensorFailure
from mks_sim.fields import Stream
from mks_sim.geometry.keypoints import first_in_each_cell
from mks_sim.sensing.registry import takes_params
from mks_sim.specs import param

logger = logging.getLogger(__name__)


# --- params (validated against the sensor files at load; programs read the mapping) -------

Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class SourceParams:
    """Params every point source takes: the work region and the voxel thinning."""

    crop_min: Vec3 | None = None
    crop_max: Vec3 | None = None
    voxel_m: float = param(0.0, low=0.0)


@dataclass(frozen=True)
class StereoParams(SourceParams):
    """``stereo_points``: StereoSGBM settings and the depth limit."""

    num_disparities: int = param(128, low=16)
    block_size: int = param(5, low=1)
    min_disparity: int = 0
    uniqueness: int = param(10, low=0)
    speckle_window: int = param(100, low=0)
    max_depth_m: float | None = param(None, low=0.0, low_open=True)

    def __post_init__(self) -> None:
        if self.num_disparities % 16:
            raise ValueError("num_disparities", "a multiple of 16", self.num_disparities)


@dataclass(frozen=True)
class DepthParams(SourceParams):
    """``depth_points``: keep every ``stride``-th pixel."""

    stride: int = param(1, low=1)


@dataclass(frozen=True)
class TableParams:
    """The table plane (a sensor parameter; None: found by the representation), the
    object separation of the representation (``_representation``) and its point budget: a
    larger cloud is first averaged on a voxel grid of edge 1.1 x spacing x
    sqrt(N / ``max_points``), when that edge is at most ``max_voxel_spacings`` spacings
    (:class:`~mks_sim.localization.representation.Representation`)."""

    table_z_m: float | None = None
    table_margin_m: float = param(0.003, low=0.0)
    gap_m: float = param(0.012, low=0.0, low_open=True)
    m: int = param(12, low=1)
    min_object_points: int = param(30, low=1)
    max_points: int = param(100000, low=10)
    max_voxel_spacings: float | None = param(None, low=1.0)


@dataclass(frozen=True)
class CurvatureParams(TableParams):
    """``surface_curvature`` (objects of the representation unless ``drop_table = false``)."""

    drop_table: bool = True
    curvature_threshold: float | None = param(None, low=0.0)


@dataclass(frozen=True)
class VertexParams(TableParams):
    """``vertex_detector``: vertexes of faces of at least ``min_points`` points."""

    min_points: int = param(20, low=1)
    min_angle_deg: float = param(30.0, low=0.0, high=90.0)


@dataclass(frozen=True)
class ControlPointParams(VertexParams):
    """``control_point_detector``."""

    up_tolerance_deg: float = param(20.0, low=0.0, high=90.0)
    outline_corners: bool = True
    merge_m: float = param(0.0, low=0.0)


@dataclass(frozen=True)
class SphereParams(TableParams):
    """``sphere_detector``."""

    min_radius_m: float = param(0.005, low=0.0)
    max_radius_m: float = param(0.2, low=0.0, low_open=True)
    max_rmse_ratio: float = param(0.1, low=0.0)


@dataclass(frozen=True)
class TouchParams:
    """``touch_contacts``."""

    min_pressure_pa: float = param(500.0, low=0.0)


# --- helpers ---------------------------------------------------------------------------------


def postprocess(points: np.ndarray, params: Mapping[str, Any]) -> np.ndarray:
    """Drop non-finite rows, crop to ``crop_min``/``crop_max``, thin to ``voxel_m``."""
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    # (per column, and a mask's rows by compress: several times faster than axis-1 and [mask])
    pts = np.compress(
        np.isfinite(pts[:, 0]) & np.isfinite(pts[:, 1]) & np.isfinite(pts[:, 2]), pts, axis=0
    )
    if "crop_min" in params or "crop_max" in params:
        lo = np.asarray(params.get("crop_min", [-np.inf] * 3), dtype=float)
        hi = np.asarray(params.get("crop_max", [np.inf] * 3), dtype=float)
        if lo.shape != (3,) or hi.shape != (3,):
            raise DataError(f"crop_min/crop_max: expected 3 numbers each, got {lo} and {hi}")
        inside = np.ones(len(pts), dtype=bool)
        for a in range(3):
            inside &= (pts[:, a] >= lo[a]) & (pts[:, a] <= hi[a])
        pts = np.compress(inside, pts, axis=0)
    voxel = float(params.get("voxel_m", 0.0))
    if voxel > 0 and len(pts):
        pts = pts[first_in_each_cell(np.floor(pts / voxel).astype(np.int64))]
    return pts


def _stream_points(inputs: Mapping[str, Any], program: str) -> np.ndarray:
    if len(inputs) != 1:
        raise SensorFailure(program, f"expected one point-stream input, got {sorted(inputs)}")
    value = next(iter(inputs.values()))
    data = value.data if isinstance(value, Stream) else np.asarray(value, dtype=float)
    if data.ndim != 2 or data.shape[1] < 3:
        raise SensorFailure(program, f"expected (N, >=3) points, got shape {data.shape}")
    pts = data[:, :3]
    return pts[np.isfinite(pts).all(axis=1)]


def representation_config(params: Mapping[str, Any]) -> Any:
    """The :class:`~mks_sim.localization.representation.RepresentationConfig` a description
    sensor's parameters ask for (:class:`TableParams`): sensors whose configs are equal share
    one representation of their input stream."""
    from mks_sim.localization.representation import RepresentationConfig

    return RepresentationConfig(
        table_z_m=_optional_float(params.get("table_z_m")),
        table_margin_m=float(params.get("table_margin_m", 0.003)),
        gap_m=float(params.get("gap_m", 0.012)),
        m=int(params.get("m", 12)),
        max_points=int(params.get("max_points", 100000)),
        max_voxel_spacings=_optional_float(params.get("max_voxel_spacings")),
    )


def _optional_float(value: Any) -> float | None:
    return None if value is None else float(value)


def _representation(inputs: Mapping[str, Any], params: Mapping[str, Any], program: str) -> Any:
    """The shared low-level representation of the input point stream, built at most once per
    stream (k-d tree, table, SPG, normals, segmentation: ``mks_sim.localization``)."""
    from mks_sim.localization.representation import representation_of

    if len(inputs) != 1:
        raise SensorFailure(program, f"expected one point-stream input, got {sorted(inputs)}")
    value = next(iter(inputs.values()))
    data = value.data if isinstance(value, Stream) else np.asarray(value, dtype=float)
    if data.ndim != 2 or data.shape[1] < 3 or len(data) < 10:
        raise SensorFailure(program, f"expected (N >= 10, >=3) points, got shape {data.shape}")
    try:
        return representation_of(data, representation_config(params))
    except DataError as exc:
        raise SensorFailure(program, str(exc)) from exc


def _object_clouds(pts: np.ndarray, params: Mapping[str, Any]) -> list[np.ndarray]:
    """Points above the table split into objects, largest first: the SPG components of the
    one low-level representation (the table plane fitted near ``table_z_m``)."""
    from mks_sim.localization.representation import Representation

    min_points = int(params.get("min_object_points", 30))
    if np.isfinite(np.asarray(pts, dtype=float)[:, :3]).all(axis=1).sum() < max(min_points, 10):
        return []
    config = replace(
        representation_config(params),
        table_margin_m=float(params.get("table_margin_m", 0.004)),
    )
    rep = Representation(pts, config)
    return [rep.objects[c] for c in rep.components(min_points)]


# --- point sources ---------------------------------------------------------------------------


@takes_params(SourceParams)
def range_points(inputs: Mapping[str, Any], params: Mapping[str, Any]) -> np.ndarray:
    """(N, 3) hit points of every range-finder view (``list[RangeScan]`` inputs)."""
    chunks = []
    for name, reading in inputs.items():
        scans = reading if isinstance(reading, list | tuple) else [reading]
        for s in scans:
            if not hasattr(s, "points_world") or not hasattr(s, "hit"):
                raise SensorFailure("range_points", f"input {name!r} is not a range scan")
            hit, world = np.asarray(s.hit, dtype=bool), np.asarray(s.points_world)
            if hit.shape != world.shape[:1]:
                raise SensorFailure(
                    "range_points",
                    f"input {name!r}: {hit.shape} hit flags for {world.shape} points",
                )
            chunks.append(np.compress(hit, world, axis=0))
    pts = postprocess(np.concatenate(chunks) if chunks else np.empty((0, 3)), params)
    if len(pts) == 0:
        raise SensorFailure("range_points", "no range returns")
    return pts


def _frames(inputs: Mapping[str, Any]) -> Any:
    """A stereo frame (anything with ``left``, ``right``, ``K``, ``left_to_world``,
    ``right_to_left``) from one stereo reading or two camera readings (duck-typed: the sensing
    layer does not import the devices)."""
    values = list(inputs.values())
    if len(values) == 1 and hasattr(values[0], "right_to_left"):
        return values[0]
    if len(values) != 2:
        raise SensorFailure(
            "stereo_points", f"expected a left and a right frame, got {sorted(inputs)}"
        )
    left = inputs.get("stereo_left", values[0])
    right = inputs.get("stereo_right", values[1])
    if left.rgb.shape != right.rgb.shape or not np.allclose(left.K, right.K, atol=1e-6):
        raise SensorFailure(
            "stereo_points",
            f"expected two cameras with equal image size and intrinsics, got {left.rgb.shape} "
            f"K={np.round(left.K, 3).tolist()} and {right.rgb.shape} K={np.round(right.K, 3).tolist()}",
        )
    right_to_left = np.linalg.inv(left.camera_to_world) @ right.camera_to_world
    if np.linalg.norm(right_to_left[:3, 3]) < 1e-9:
        raise SensorFailure("stereo_points", "the two cameras share one optical centre")
    return SimpleNamespace(
        left=left.rgb, right=right.rgb, K=left.K, left_to_world=left.camera_to_world,
        right_to_left=right_to_left,
    )  # fmt: skip


def stereo_to_points(sf: Any, params: Mapping[str, Any]) -> np.ndarray:
    """(N, 3) world points from a :class:`~mks_sim.devices.stereo.StereoFrame` (SGBM)."""
    h, w = sf.left.shape[:2]
    K = np.asarray(sf.K, dtype=float)
    left_to_right = np.linalg.inv(sf.right_to_left)
    R1, R2, P1, P2, Q, _, _ = cv2.stereoRectify(
        K, np.zeros(5), K, np.zeros(5), (w, h), left_to_right[:3, :3], left_to_right[:3, 3],
        flags=cv2.CALIB_ZERO_DISPARITY, alpha=0,
    )  # fmt: skip
    maps_l = cv2.initUndistortRectifyMap(K, np.zeros(5), R1, P1, (w, h), cv2.CV_32FC1)
    maps_r = cv2.initUndistortRectifyMap(K, np.zeros(5), R2, P2, (w, h), cv2.CV_32FC1)
    grey_l = cv2.remap(
        cv2.cvtColor(np.ascontiguousarray(sf.left), cv2.COLOR_RGB2GRAY), *maps_l, cv2.INTER_LINEAR
    )
    grey_r = cv2.remap(
        cv2.cvtColor(np.ascontiguousarray(sf.right), cv2.COLOR_RGB2GRAY), *maps_r, cv2.INTER_LINEAR
    )
    num = int(params.get("num_disparities", 128))
    num = max(16, 16 * ((num + 15) // 16))
    block = int(params.get("block_size", 5)) | 1
    min_d = int(params.get("min_disparity", 0))
    sgbm = cv2.StereoSGBM.create(
        minDisparity=min_d, numDisparities=num, blockSize=block,
        P1=8 * block * block, P2=32 * block * block, disp12MaxDiff=1,
        uniquenessRatio=int(params.get("uniqueness", 10)),
        speckleWindowSize=int(params.get("speckle_window", 100)), speckleRange=2,
        mode=cv2.STEREO_SGBM_MODE_SGBM,
    )  # fmt: skip
    disp = sgbm.compute(grey_l, grey_r).astype(np.float32) / 16.0
    valid = disp > max(min_d, 0) + 0.5
    # OpenCV ignores its rectified region's border: do not trust the leftmost num columns.
    valid[:, : min_d + num] = False
    xyz_rect = cv2.reprojectImageTo3D(disp, Q)[valid].astype(float)  # rectified left frame
    xyz_cam = xyz_rect @ R1  # R1 maps left camera -> rectified; R1^T back, row form
    T = np.asarray(sf.left_to_world, dtype=float)
    pts = xyz_cam @ T[:3, :3].T + T[:3, 3]
    max_depth = float(params.get("max_depth_m", np.inf))
    return pts[xyz_rect[:, 2] <= max_depth]


@takes_params(StereoParams)
def stereo_points(inputs: Mapping[str, Any], params: Mapping[str, Any]) -> np.ndarray:
    """(N, 3) world points from the stereo pair (two ``CameraFrame`` s or a ``StereoFrame``)."""
    pts = postprocess(stereo_to_points(_frames(inputs), params), params)
    if len(pts) == 0:
        raise SensorFailure("stereo_points", "no valid disparities")
    return pts


def depth_to_points(frame: Any, stride: int = 1) -> np.ndarray:
    """(N, 3) world points of a depth ``CameraFrame`` (every ``stride``-th pixel, finite depth)."""
    if frame.depth is None:
        raise SensorFailure("depth_points", f"camera {frame.name!r} gives no depth")
    depth = np.asarray(frame.depth, dtype=float)[::stride, ::stride]
    h, w = np.asarray(frame.depth).shape
    v, u = np.mgrid[0:h:stride, 0:w:stride]
    ok = np.isfinite(depth) & (depth > 0)
    K = np.asarray(frame.K, dtype=float)
    z = depth[ok]
    x = (u[ok] - K[0, 2]) * z / K[0, 0]
    y = (v[ok] - K[1, 2]) * z / K[1, 1]
    T = np.asarray(frame.camera_to_world, dtype=float)
    return np.c_[x, y, z] @ T[:3, :3].T + T[:3, 3]


@takes_params(DepthParams)
def depth_points(inputs: Mapping[str, Any], params: Mapping[str, Any]) -> np.ndarray:
    """(N, 3) world points from one depth camera reading."""
    frames = [v for v in inputs.values() if hasattr(v, "depth")]
    if len(frames) != 1:
        raise SensorFailure(
            "depth_points", f"expected one depth camera input, got {sorted(inputs)}"
        )
    pts = postprocess(depth_to_points(frames[0], int(params.get("stride", 1))), params)
    if len(pts) == 0:
        raise SensorFailure("depth_points", "no valid depth pixels")
    return pts


# --- descriptions ----------------------------------------------------------------------------


@takes_params(CurvatureParams)
def surface_curvature(inputs: Mapping[str, Any], params: Mapping[str, Any]) -> np.ndarray:
    """(N, 4) rows (x, y, z, curvature code +1 / -1) of the object points (table dropped)."""
    from mks_sim.lowlevel.grouping import curvature_code, estimate_normals

    kw = {"threshold": params["curvature_threshold"]} if "curvature_threshold" in params else {}
    if params.get("drop_table", True):
        rep = _representation(inputs, params, "surface_curvature")
        pts = rep.raw_objects  # at the sensor's resolution, whatever the budget averaged
        if len(pts) < 4:
            raise SensorFailure("surface_curvature", f"expected >= 4 object points, got {len(pts)}")
        curvature = rep.raw_curvature
    else:
        pts = _stream_points(inputs, "surface_curvature")
        if len(pts) < 4:
            raise SensorFailure("surface_curvature", f"expected >= 4 points, got {len(pts)}")
        curvature = estimate_normals(pts, m=int(params.get("m", 12))).curvature
    return np.c_[pts, curvature_code(curvature, **kw).astype(float)]


def object_vertexes(rep: Any, component: np.ndarray, params: Mapping[str, Any]) -> Any:
    """(Vertexes, planar regions) of one object component of a representation (faces of at
    least ``min_points`` points; the table as the face the object rests on)."""
    return rep.vertexes_of(
        component,
        min_points=int(params.get("min_points") or 20),
        min_angle_deg=float(params.get("min_angle_deg", 30.0)),
    )


@takes_params(VertexParams)
def vertex_detector(inputs: Mapping[str, Any], params: Mapping[str, Any]) -> np.ndarray:
    """(V, 3) vertexes of every object above the table."""
    rep = _representation(inputs, params, "vertex_detector")
    comps = rep.components(int(params.get("min_object_points", 30)))
    rows = [object_vertexes(rep, c, params)[0].points for c in comps]
    return np.concatenate(rows) if rows else np.empty((0, 3))


def outline_corners(
    points: np.ndarray, normal: np.ndarray, spacing: float, epsilon_cells: float = 2.0
) -> np.ndarray:
    """(k, 3) convex corners of the outline of a planar region's points.

    The points are projected onto their plane, rasterised at the sampling ``spacing`` (closed
    by one cell so that the sampling gaps do not split the region), the outer contour is
    simplified with ``approxPolyDP`` (``epsilon_cells`` cells) and its convex vertices are
    returned, on the region's mean plane. The outline runs through the outermost samples, so a
    corner lies up to about one spacing inside the true edge.
    """
    n = normal / np.linalg.norm(normal)
    e1 = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    c = points.mean(axis=0)
    uv = (points - c) @ np.stack([e1, e2]).T  # (n, 2)
    cell = max(spacing, 1e-6)
    lo = uv.min(axis=0) - 3 * cell
    ij = np.floor((uv - lo) / cell).astype(int)
    shape = ij.max(axis=0) + 4
    img = np.zeros((shape[1], shape[0]), np.uint8)
    img[ij[:, 1], ij[:, 0]] = 255
    img = cv2.morphologyEx(img, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))
    contours, _ = cv2.findContours(img, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not contours:
        return np.empty((0, 3))
    poly = cv2.approxPolyDP(max(contours, key=cv2.contourArea), epsilon_cells, True)[:, 0, :]
    if len(poly) < 3:
        return np.empty((0, 3))
    q = (poly + 0.5) * cell + lo  # cell centres back to plane coordinates
    prev, nxt = np.roll(q, 1, axis=0), np.roll(q, -1, axis=0)
    a, b = q - prev, nxt - q
    turn = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    area2 = np.sum(q[:, 0] * np.roll(q[:, 1], -1) - np.roll(q[:, 0], -1) * q[:, 1])
    convex = q[np.sign(turn) == np.sign(area2)]
    return c + convex[:, :1] * e1 + convex[:, 1:] * e2


@takes_params(ControlPointParams)
def control_point_detector(inputs: Mapping[str, Any], params: Mapping[str, Any]) -> np.ndarray:
    """(C, 3) candidate control points of the industrial part.

    First the vertexes where one upward face meets two walls (the recipe of
    ``industrial_part_control_points``; exact where both walls are seen). Walls facing away
    from the scanners are not seen, and the part's 8 mm walls are sparsely sampled, so with
    ``outline_corners = true`` (default) the convex corners of the upward faces' outlines
    (:func:`outline_corners`, within about one sampling spacing) are added where no vertex
    lies within ``merge_m`` (default 3 spacings). The Hough matcher labels the candidates.
    """
    rep = _representation(inputs, params, "control_point_detector")
    up_cos = np.cos(np.deg2rad(float(params.get("up_tolerance_deg", 20.0))))
    wall_sin = np.sin(np.deg2rad(float(params.get("up_tolerance_deg", 20.0))))
    rows: list[np.ndarray] = []
    comps = rep.components(int(params.get("min_object_points", 30)))
    # the outlines at the sensor's own resolution: an averaging budget's coarse cells would
    # round the corners off by about a cell
    spacing = max(rep.raw_spacing, 1e-6)
    for comp in comps:
        verts, planes = object_vertexes(rep, comp, params)
        n_regions = len(planes)
        found = []
        for v, faces, normals in zip(verts.points, verts.faces, verts.normals):
            if np.any(faces >= n_regions):  # on the table: a bottom corner
                continue
            nz = np.abs(normals[:, 2])
            if (nz >= up_cos).sum() == 1 and (nz <= wall_sin).sum() == 2:
                found.append(v)
        if params.get("outline_corners", True):
            merge = float(params.get("merge_m", 0.0)) or 3.0 * spacing
            for region in planes:
                if abs(region.normal[2]) < up_cos:
                    continue
                pts = rep.raw_of(region.indices)
                for corner in outline_corners(pts, region.normal, spacing):
                    if all(np.linalg.norm(corner - f) > merge for f in found):
                        found.append(corner)
        rows.extend(found)
    return np.asarray(rows, dtype=float).reshape(-1, 3)


@takes_params(SphereParams)
def sphere_detector(inputs: Mapping[str, Any], params: Mapping[str, Any]) -> np.ndarray:
    """(S, 4) rows (x, y, z, radius) of spheres fitted to curved regions of the objects."""
    rep = _representation(inputs, params, "sphere_detector")
    r_min = float(params.get("min_radius_m", 0.005))
    r_max = float(params.get("max_radius_m", 0.2))
    max_rmse = float(params.get("max_rmse_ratio", 0.1))
    rows = []
    if len(rep.components(int(params.get("min_object_points", 30)))):
        for region in rep.segmentation.curved:
            s = region.sphere
            if s is not None and r_min <= s.radius <= r_max and s.rmse <= max_rmse * s.radius:
                rows.append([*s.center, s.radius])
    return np.asarray(rows, dtype=float).reshape(-1, 4)


@takes_params(TouchParams)
def touch_contacts(inputs: Mapping[str, Any], params: Mapping[str, Any]) -> np.ndarray:
    """(N, 4) rows (x, y, z, pressure Pa) of taxels above ``min_pressure_pa`` (default 500)."""
    threshold = float(params.get("min_pressure_pa", 500.0))
    rows = []
    for name, reading in inputs.items():
        if not hasattr(reading, "pressure") or not hasattr(reading, "positions_world"):
            raise SensorFailure("touch_contacts", f"input {name!r} is not a touch reading")
        p = np.asarray(reading.pressure, dtype=float)
        pos = np.asarray(reading.positions_world, dtype=float)
        on = p > threshold
        rows.append(np.c_[pos[on], p[on]])
    return np.concatenate(rows) if rows else np.empty((0, 4))
