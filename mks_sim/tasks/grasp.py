"""Choosing a grasp from a localized model (pure geometry, no simulator).

The Jaco hand closes finger 1 against fingers 2 and 3 along the x axis of its pinch site; the
hand approaches from above, so a grasp is a pinch point in the world, a yaw of that closing
axis about the world's vertical, and the width the fingers should stop at.

* ``opposite_faces`` (a box): the face pair whose normal is most horizontal; among the yaws
  that close on it (the normal direction, or the other horizontal pair when the box sits flat)
  the one nearest the hand's preferred yaw, so the wrist turns least.
* ``through_centre`` (a sphere): the pinch point is the centre, the yaw the preferred one.
* ``feature``: a named graspable feature of the model, given in the object frame as a point
  and a closing axis (``ObjectGeometry.features``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from mks_sim.errors import DataError, NotFound, SpecError
from mks_sim.tasks.spec import GraspAction


@dataclass(frozen=True)
class GraspFeature:
    """A graspable feature in the object frame.

    Attributes:
        point_object: (3,) pinch point, metres, object frame.
        axis_object: (3,) closing direction (unit), object frame.
        width_m: the feature's width along the axis, metres.
    """

    point_object: tuple[float, float, float]
    axis_object: tuple[float, float, float]
    width_m: float


@dataclass(frozen=True)
class ObjectGeometry:
    """What the planner needs to know about a model's shape.

    Attributes:
        kind: ``box`` | ``sphere`` | ``part``.
        half_extents_m: (3,) box half sizes (``box``; bounding box for ``part``), metres.
        radius_m: sphere radius (``sphere``), metres.
        features: named graspable features (``part``).
    """

    kind: str
    half_extents_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    radius_m: float = 0.0
    features: dict[str, GraspFeature] = field(default_factory=dict)

    @property
    def height_m(self) -> float:
        """Half height used for the clearance check (metres)."""
        if self.kind == "sphere":
            return self.radius_m
        return float(max(self.half_extents_m))


@dataclass(frozen=True)
class GraspPlan:
    """A top-down grasp.

    Attributes:
        grasp_point_world: (3,) where the pinch point closes, metres, world frame.
        yaw_rad: yaw of the closing axis (the pinch site's x axis) about world z, radians.
        width_m: the object's width between the fingers, metres.
        approach_height_m: pre-grasp height above the grasp point, metres.
        lift_height_m: how far to lift, metres.
    """

    grasp_point_world: tuple[float, float, float]
    yaw_rad: float
    width_m: float
    approach_height_m: float
    lift_height_m: float

    @property
    def pregrasp_world(self) -> np.ndarray:
        """(3,) the pre-grasp pinch point, straight above the grasp point."""
        return np.asarray(self.grasp_point_world) + np.array([0.0, 0.0, self.approach_height_m])

    @property
    def lifted_world(self) -> np.ndarray:
        """(3,) the pinch point after lifting."""
        return np.asarray(self.grasp_point_world) + np.array([0.0, 0.0, self.lift_height_m])


def wrap_angle(angle: float) -> float:
    """``angle`` wrapped to [-pi, pi)."""
    return (angle + math.pi) % (2 * math.pi) - math.pi


def _nearest_yaw(candidates: list[float], preferred: float, period: float) -> float:
    """The candidate (mod ``period``) nearest ``preferred``, returned near ``preferred``."""
    best, best_d = preferred, math.inf
    for yaw in candidates:
        d = (yaw - preferred + period / 2) % period - period / 2
        if abs(d) < best_d:
            best, best_d = preferred + d, abs(d)
    return best


def _check_pose(object_to_world: np.ndarray) -> np.ndarray:
    T = np.asarray(object_to_world, dtype=float)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise DataError(f"object_to_world: expected a finite 4x4 matrix, got shape {T.shape}")
    return T


def plan_grasp(
    object_to_world: np.ndarray,
    action: GraspAction,
    geometry: ObjectGeometry,
    preferred_yaw: float = 0.0,
    table_z: float = 0.0,
    min_clearance_m: float = 0.018,
) -> GraspPlan:
    """Choose a top-down grasp for an object at ``object_to_world``.

    Args:
        object_to_world: (4, 4) estimated pose of the object (never ground truth).
        action: the task's grasp parameters.
        geometry: the model's shape.
        preferred_yaw: yaw (rad) the hand would rather keep (its current one).
        table_z: height of the table top, metres.
        min_clearance_m: the pinch point stays at least this high above the table so the
            fingertips do not dig into it.

    Raises:
        DataError: the pose is not a finite 4x4 matrix.
        NotFound: a ``feature`` grasp names a feature the geometry does not have.
        SpecError: the grasp type does not fit the geometry.
    """
    T = _check_pose(object_to_world)
    R, centre = T[:3, :3], T[:3, 3]
    gt = action.grasp_type
    if gt == "opposite_faces":
        if geometry.kind not in ("box", "part"):
            raise SpecError(f"grasp_type 'opposite_faces' needs a box model, got {geometry.kind!r}")
        tilt = np.abs(R[2, :])  # |z component| of each face normal pair
        horizontal = np.flatnonzero(tilt <= tilt.min() + 0.05)
        candidates = []
        for i in horizontal:
            n = R[:, i]
            candidates.append(math.atan2(n[1], n[0]))
        yaw = _nearest_yaw(candidates, preferred_yaw, math.pi)
        axis_index = int(horizontal[0])
        for i in horizontal:
            n = R[:, i]
            d = abs(wrap_angle(2 * (math.atan2(n[1], n[0]) - yaw))) / 2
            if d < 1e-6:
                axis_index = int(i)
        width = 2.0 * geometry.half_extents_m[axis_index]
        point = centre + np.array([0.0, 0.0, -action.grasp_depth_m])
        point[2] = max(point[2], table_z + min_clearance_m)
    elif gt == "through_centre":
        yaw = preferred_yaw
        width = 2.0 * geometry.radius_m
        point = centre.copy()
        point[2] = max(point[2] - action.grasp_depth_m, table_z + min_clearance_m)
    elif gt == "feature":
        feat = geometry.features.get(action.feature)
        if feat is None:
            raise NotFound(
                f"grasp feature {action.feature!r} not in the model; known: {sorted(geometry.features)}"
            )
        point = R @ np.asarray(feat.point_object) + centre
        axis = R @ np.asarray(feat.axis_object)
        yaw = _nearest_yaw([math.atan2(axis[1], axis[0])], preferred_yaw, math.pi)
        width = feat.width_m
        point[2] = max(point[2] - action.grasp_depth_m, table_z + min_clearance_m)
    else:  # pragma: no cover - the spec loader rejects other types
        raise SpecError(f"unknown grasp_type {gt!r}")
    return GraspPlan(
        grasp_point_world=(float(point[0]), float(point[1]), float(point[2])),
        yaw_rad=float(yaw),
        width_m=float(width),
        approach_height_m=action.approach_height_m,
        lift_height_m=action.lift_height_m,
    )
