"""Image programs of the workstation: ``circle_detector`` and ``corner_holes_detector``.

Both run on one overhead camera reading (:class:`~mks_sim.devices.camera.CameraFrame`, or any
object with ``rgb``, ``K`` and ``camera_to_world``) and report one row per object seen:

1. Segment: grey image, Gaussian blur, Otsu threshold; the foreground is the minority class
   (objects cover less of the image than the table) unless ``polarity`` says ``"dark"`` or
   ``"bright"``; a morphological opening removes speckle.
2. Contours with ``RETR_CCOMP``: top-level contours are objects, their children are holes.
   Objects touching the image border (seen only in part) and blobs smaller than
   ``min_area_px`` are dropped.
3. Every contour is back-projected through ``K`` and the camera pose onto the table plane
   ``z = plane_z_m`` (a sensor parameter, not ground truth), so positions and radii are metres
   in the world frame. Centroid and area come from the metric polygon (shoelace), the radius
   from the area (``sqrt(A / pi)``), which is unbiased by pixel digitisation.
4. A contour is a circle when its largest radial deviation from the centroid, relative to its
   radius, is at most ``circle_tolerance + circle_pixel_slack / r_px`` (the second term allows
   for digitisation at small sizes: a rendered 10 px disc deviates by ~0.14, a 14 px hexagon
   by ~0.2, a 5 px hole by up to ~0.3; defaults 0.04 and 1.5). Holes smaller than
   ``min_shape_px`` (8 px radius) count as circles: too small to tell, and drilled in practice. Corners: 0 for a circle (Table 4-3 of the paper gives discs 0 corners),
   else the vertex count of ``approxPolyDP`` with ``epsilon = poly_epsilon * perimeter``.

``circle_detector`` -> (x, y, radius): ``radius`` of the object if it is a circle, else of its
largest circular hole (a nut's bore), else 0 — the paper's Table 4-1 reports radius 0 for the
polygons and the hole radius (0.5) for the objects with holes. ``report_all = false`` keeps only
rows with a radius.

``corner_holes_detector`` -> (x, y, corners, holes).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any, Literal

import cv2
import numpy as np

from mks_sim.errors import DataError, SensorFailure
from mks_sim.sensing.registry import params_of, takes_params
from mks_sim.specs import param


@dataclass(frozen=True)
class VisionParams:
    """Params of ``circle_detector`` and ``corner_holes_detector`` (see the module doc)."""

    plane_z_m: float = 0.0
    polarity: Literal["auto", "bright", "dark"] = "auto"
    blur_px: int = param(3, low=0)
    open_px: int = param(3, low=0)
    min_area_px: float = param(30, low=0.0)
    min_hole_area_px: float = param(8, low=0.0)
    circle_tolerance: float = param(0.04, low=0.0)
    circle_pixel_slack: float = param(1.5, low=0.0)
    min_shape_px: float = param(8.0, low=0.0)
    poly_epsilon: float = param(0.03, low=0.0, low_open=True)
    ignore_border: bool = True
    report_all: bool = True


#: The defaults of :class:`VisionParams` as a dict (``find_blobs`` merges params over it).
DEFAULTS: dict[str, Any] = asdict(VisionParams())


@dataclass(frozen=True)
class Blob:
    """One segmented object, metres on the table plane (world frame)."""

    x: float
    y: float
    area_m2: float
    radius_m: float
    circular: bool
    corners: int
    hole_radii_m: tuple[float, ...]  # radius of each hole; NaN when the hole is not circular

    @property
    def holes(self) -> int:
        """Number of holes."""
        return len(self.hole_radii_m)


def _camera_input(inputs: Mapping[str, Any], program: str) -> Any:
    frames = [v for v in inputs.values() if hasattr(v, "rgb") and hasattr(v, "K")]
    if len(frames) != 1:
        raise SensorFailure(
            program,
            f"expected exactly one camera reading among inputs {sorted(inputs)}, got {len(frames)}",
        )
    return frames[0]


def backproject_to_plane(
    uv: np.ndarray, K: np.ndarray, camera_to_world: np.ndarray, plane_z: float
) -> np.ndarray:
    """Intersect the viewing rays of pixels ``uv`` (N, 2) with the plane ``z = plane_z``.

    Returns:
        (N, 3) world points; NaN rows for rays parallel to or pointing away from the plane.
    """
    uv = np.asarray(uv, dtype=float).reshape(-1, 2)
    rays_cam = np.linalg.solve(K, np.c_[uv, np.ones(len(uv))].T)  # (3, N)
    rays = (camera_to_world[:3, :3] @ rays_cam).T  # (N, 3)
    origin = camera_to_world[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (plane_z - origin[2]) / rays[:, 2]
    s = np.where(np.isfinite(s) & (s > 0), s, np.nan)
    return origin + s[:, None] * rays


def _polygon_stats(xy: np.ndarray) -> tuple[float, float, float]:
    """(area >= 0, cx, cy) of a closed polygon (N, 2) by the shoelace formula."""
    x, y = xy[:, 0], xy[:, 1]
    xn, yn = np.roll(x, -1), np.roll(y, -1)
    cross = x * yn - xn * y
    a = 0.5 * cross.sum()
    if abs(a) < 1e-15:
        return 0.0, float(x.mean()), float(y.mean())
    cx = ((x + xn) * cross).sum() / (6 * a)
    cy = ((y + yn) * cross).sum() / (6 * a)
    return abs(float(a)), float(cx), float(cy)


def segment(rgb: np.ndarray, params: Mapping[str, Any]) -> np.ndarray:
    """(H, W) uint8 foreground mask (255 = object) of an RGB image."""
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise DataError(f"expected an (H, W, 3) uint8 image, got {rgb.shape} {rgb.dtype}")
    grey = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY)
    b = int(params["blur_px"])
    if b > 1:
        grey = cv2.GaussianBlur(grey, (b | 1, b | 1), 0)
    _, mask = cv2.threshold(grey, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    polarity = params["polarity"]
    if polarity == "dark" or (polarity == "auto" and np.count_nonzero(mask) > mask.size / 2):
        mask = cv2.bitwise_not(mask)
    elif polarity not in ("auto", "bright", "dark"):
        raise DataError(f"polarity: expected 'auto', 'bright' or 'dark', got {polarity!r}")
    k = int(params["open_px"])
    if k > 1:
        mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, np.ones((k, k), np.uint8))
    return mask


def _contour_shape(
    contour: np.ndarray, frame: Any, params: Mapping[str, Any], hole: bool = False
) -> tuple[float, float, float, float, bool, int]:
    """(area_m2, cx, cy, radius_m, circular, corners) of one pixel contour.

    OpenCV traces the centres of the boundary's foreground pixels, so a hole's contour runs
    through the ring of object pixels around the hole, one pixel outside the hole's own
    boundary pixels: a hole's radius is reduced by one pixel (at the contour's scale), which
    makes hole and object radii agree within ~0.2 px on synthetic discs.
    """
    px = contour[:, 0, :].astype(float)
    world = backproject_to_plane(px, frame.K, frame.camera_to_world, float(params["plane_z_m"]))
    if not np.isfinite(world).all():
        raise SensorFailure("vision", "a contour's viewing rays miss the table plane")
    area, cx, cy = _polygon_stats(world[:, :2])
    area_px = max(cv2.contourArea(contour), 1e-9)
    pixel_m = np.sqrt(area / area_px)
    radius = float(np.sqrt(area / np.pi)) - (pixel_m if hole else 0.0)
    d = np.hypot(world[:, 0] - cx, world[:, 1] - cy)
    r_px = np.sqrt(area_px / np.pi) + 0.5
    # A hole below min_shape_px radius is too small to tell a circle from a polygon; holes in
    # the workstation's parts are drilled bores, so it counts as a circle.
    circular = bool(
        radius > 0
        and (
            (d.max() - d.min()) / radius
            <= params["circle_tolerance"] + params["circle_pixel_slack"] / r_px
            or (hole and r_px < params["min_shape_px"])
        )
    )
    if circular:
        corners = 0
    else:
        eps = float(params["poly_epsilon"]) * cv2.arcLength(contour, True)
        corners = len(cv2.approxPolyDP(contour, eps, True))
    return area, cx, cy, radius, circular, corners


def find_blobs(frame: Any, params: Mapping[str, Any] | None = None) -> list[Blob]:
    """Segment a camera frame into objects, metres on the table plane (see the module doc)."""
    p = {**DEFAULTS, **(params or {})}
    rgb = np.asarray(frame.rgb)
    mask = segment(rgb, p)
    h, w = mask.shape
    contours, hierarchy = cv2.findContours(mask, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)
    if hierarchy is None:
        return []
    hier = hierarchy[0]  # (n, 4): next, previous, first_child, parent
    blobs = []
    for i, c in enumerate(contours):
        if hier[i, 3] != -1 or cv2.contourArea(c) < p["min_area_px"]:
            continue
        x0, y0, bw, bh = cv2.boundingRect(c)
        if p["ignore_border"] and (x0 <= 0 or y0 <= 0 or x0 + bw >= w or y0 + bh >= h):
            continue
        area, cx, cy, radius, circular, corners = _contour_shape(c, frame, p)
        holes = []
        child = hier[i, 2]
        while child != -1:
            hc = contours[child]
            if cv2.contourArea(hc) >= p["min_hole_area_px"] and len(hc) >= 3:
                _, _, _, hr, hcirc, _ = _contour_shape(hc, frame, p, hole=True)
                holes.append(hr if hcirc else float("nan"))
            child = hier[child, 0]
        blobs.append(Blob(cx, cy, area, radius, circular, corners, tuple(holes)))
    return blobs


def _circle_radius(blob: Blob) -> float:
    if blob.circular:
        return blob.radius_m
    circular_holes = [r for r in blob.hole_radii_m if np.isfinite(r)]
    return max(circular_holes) if circular_holes else 0.0


@takes_params(VisionParams)
def circle_detector(inputs: Mapping[str, Any], params: Mapping[str, Any]) -> np.ndarray:
    """(N, 3) rows (x, y, radius), metres on the table plane; see the module doc."""
    frame = _camera_input(inputs, "circle_detector")
    p = asdict(params_of(VisionParams, params, "circle_detector"))
    rows = [(b.x, b.y, _circle_radius(b)) for b in find_blobs(frame, p)]
    if not p["report_all"]:
        rows = [r for r in rows if r[2] > 0]
    return np.asarray(rows, dtype=float).reshape(-1, 3)


@takes_params(VisionParams)
def corner_holes_detector(inputs: Mapping[str, Any], params: Mapping[str, Any]) -> np.ndarray:
    """(N, 4) rows (x, y, corners, holes), x, y metres on the table plane."""
    frame = _camera_input(inputs, "corner_holes_detector")
    p = asdict(params_of(VisionParams, params, "corner_holes_detector"))
    rows = [(b.x, b.y, b.corners, b.holes) for b in find_blobs(frame, p)]
    return np.asarray(rows, dtype=float).reshape(-1, 4)
