"""Views fused into one point set: the range finder and the wrist camera at several arm poses.

Active sensing (issue 13) takes more than one look at a scene: the range finder's scan, then
the wrist camera moved by the arm to a viewpoint that sees what the first view missed. The
logical sensor ``Fused_Points`` (``sensors/views.toml``) merges every view it is given into
one world-frame cloud, so the ``Representation`` (and the localization on it) is built on the
fused set:

- a *view* is one reading of one input device: a range finder reading (its mounts' scans
  together: the scanner's one look) or one depth ``CameraFrame``;
- an input may hold several readings taken at different arm poses: :class:`Views` (a tuple
  of readings), served by a :class:`HeldViews` device that returns what was captured;
- views are merged in order: each later view, thinned to one point per cube of the first
  view's spacing (at most ``merge_m``), adds only its points farther than ``merge_m`` from
  every point kept before, so where two views see the same surface the density does not
  double and a close view is no denser than the first, and one view alone passes through
  unchanged (``Fused_Points`` of the range finder alone equals ``Range_Points``);
- the stream's ``source`` names each row's view (``range_finder#0``, ``wrist_camera#1``), so
  the provenance of every point is kept.

The next-view parameters of the same sensor (``rescan_below``, ``min_pad_points``,
``pad_radius_m``, ``viewpoints``) are data for the caller that moves the arm
(``mks_sim.tasks.bin``): this program does not read them.

Like every program, nothing here imports the devices (duck-typed readings).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from mks_sim.errors import SensorFailure
from mks_sim.fields import Field, OutputVector, Stream
from mks_sim.geometry.keypoints import first_in_each_cell
from mks_sim.sensing.programs.points import SourceParams, depth_to_points, postprocess
from mks_sim.sensing.registry import params_of, takes_params
from mks_sim.specs import param

__all__ = ["FuseParams", "HeldViews", "Views", "fuse_views", "view_points"]

Vec3 = tuple[float, float, float]


class Views(tuple[Any, ...]):
    """Readings of one device taken at several poses (oldest first): one view each."""

    __slots__ = ()


class HeldViews:
    """A device-like holder of captured readings: ``read()`` returns them as :class:`Views`.

    The snapshot reads devices once; the views of active sensing are captured one by one as
    the arm moves, held here, and fused in one snapshot.

    Args:
        name: the device name the readings came from.
        readings: the captured readings, oldest first.
    """

    def __init__(self, name: str, readings: Sequence[Any] = ()) -> None:
        self.name = name
        self.readings: list[Any] = list(readings)

    def read(self) -> Views:
        """Every held reading (one view each)."""
        return Views(self.readings)


@dataclass(frozen=True)
class FuseParams(SourceParams):
    """``fuse_views``: the merge distance and depth-pixel stride; the next-view data.

    Attributes:
        merge_m: a later view's point within this distance of a kept one is dropped.
        stride: keep every ``stride``-th depth pixel of a camera view.
        rescan_below: take another view when the best instance scores below this.
        min_pad_points: ... or when fewer sensed points than this lie near a planned pad
            contact (the grasp side is occluded).
        pad_radius_m: "near a pad contact".
        viewpoints: candidate pinch-site positions (world, metres) of the wrist views.
        max_views: views at most (the first one included).
    """

    merge_m: float = param(0.0025, low=0.0)
    stride: int = param(1, low=1)
    rescan_below: float = param(0.6, low=0.0, high=1.0)
    min_pad_points: int = param(10, low=0)
    pad_radius_m: float = param(0.006, low=0.0, low_open=True)
    viewpoints: tuple[Vec3, ...] = ()
    max_views: int = param(2, low=1)


_XYZ = OutputVector(
    (
        Field("x", -1.0, 1.0, "m"),
        Field("y", -1.0, 1.0, "m"),
        Field("z", 0.5, 1.5, "m"),
    )
)


def view_points(reading: Any, stride: int = 1) -> np.ndarray:
    """(N, 3) world points of one view: a range finder reading (scans with ``points_world``
    and ``hit``) or a depth camera frame.

    Raises:
        SensorFailure: a reading of neither kind.
    """
    if hasattr(reading, "depth") and hasattr(reading, "K"):
        return depth_to_points(reading, stride)
    scans = reading if isinstance(reading, list | tuple) else [reading]
    chunks = []
    for s in scans:
        if not (hasattr(s, "points_world") and hasattr(s, "hit")):
            raise SensorFailure(
                "fuse_views",
                f"expected range scans or a depth frame, got {type(s).__name__}",
            )
        chunks.append(np.asarray(s.points_world)[np.asarray(s.hit)])
    return np.concatenate(chunks) if chunks else np.empty((0, 3))


def merge_views(clouds: Sequence[np.ndarray], merge_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Merge views in order: ((M, 3) points, (M,) index of the view of each point).

    A later view's point within ``merge_m`` of a point kept from an earlier view is dropped,
    and a later view is first thinned to one point per cube of the first view's spacing
    (median nearest-neighbour distance), at most ``merge_m``: the wrist camera's close views
    are ~2-3x denser than the range finder's scan, and the instance score counts explained
    points at the first view's spacing, so unthinned they lifted every instance they saw to
    1 (issue 13; tuning seed 4000: all six scored 1.0). The first view passes unchanged.
    """
    kept: list[np.ndarray] = []
    which: list[np.ndarray] = []
    cube = merge_m
    for k, pts in enumerate(clouds):
        pts = np.asarray(pts, dtype=np.float64).reshape(-1, 3)
        if not kept and len(pts) >= 2:
            sample = pts[:: max(1, len(pts) // 2000)]
            spacing = float(np.median(cKDTree(pts).query(sample, k=2)[0][:, 1]))
            cube = min(merge_m, spacing) if spacing > 0 else merge_m
        if kept and merge_m > 0 and len(pts):
            pts = pts[first_in_each_cell(np.floor(pts / cube).astype(np.int64))]
            d = cKDTree(np.concatenate(kept)).query(pts, distance_upper_bound=merge_m)[0]
            pts = pts[~np.isfinite(d)]
        kept.append(pts)
        which.append(np.full(len(pts), k, dtype=np.int64))
    if not kept:
        return np.empty((0, 3)), np.empty(0, dtype=np.int64)
    return np.concatenate(kept), np.concatenate(which)


@takes_params(FuseParams)
def fuse_views(inputs: Mapping[str, Any], params: Mapping[str, Any]) -> Stream:
    """(N, 3) world points of every view of every input, merged (module docstring); the
    stream's ``source`` names each point's view (``<device>#<k>``)."""
    p = params_of(FuseParams, params, "fuse_views")
    names: list[str] = []
    clouds: list[np.ndarray] = []
    for device, reading in inputs.items():
        # an input holding no view yet (the wrist camera before the arm moved) adds none
        readings = list(reading) if isinstance(reading, Views) else [reading]
        for k, r in enumerate(readings):
            clouds.append(postprocess(view_points(r, p.stride), params))
            names.append(f"{device}#{k}")
    pts, which = merge_views(clouds, p.merge_m)
    if len(pts) == 0:
        raise SensorFailure("fuse_views", f"no points in {len(names)} view(s)")
    source = np.asarray(names, dtype=np.str_)[which]
    return Stream(pts, _XYZ, "fuse_views", source=source)
