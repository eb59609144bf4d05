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
        min_clearance_m: lowest pinch-point height above the table for this object (the
            fingertips reach ~1 cm below the pinch point when closed), metres.
    """

    kind: str
    half_extents_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    radius_m: float = 0.0
    features: dict[str, GraspFeature] = field(default_factory=dict)
    min_clearance_m: float = 0.018

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

    The hand descends pre-shaped to ``width_m`` plus ``PRESHAPE_MARGIN_M``
    (:attr:`preshape_q`).
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
    def preshape_q(self) -> float:
        """Finger angle (rad) to descend with."""
        return preshape_q(self.width_m)

    @property
    def lifted_world(self) -> np.ndarray:
        """(3,) the pinch point after lifting."""
        return np.asarray(self.grasp_point_world) + np.array([0.0, 0.0, self.lift_height_m])


def wrap_angle(angle: float) -> float:
    """``angle`` wrapped to [-pi, pi)."""
    return (angle + math.pi) % (2 * math.pi) - math.pi


# Finger joint angle (rad) -> distance between the pad of finger 1 and the pads of fingers
# 2 + 3 along the closing axis (m), measured on the pads of mks_sim.sim.robot (same q on all
# three fingers). Descending with the hand pre-shaped to the object's width plus a margin
# keeps the fingertips off the table and off neighbouring objects.
FINGER_Q = np.array([0.15, 0.3, 0.45, 0.6, 0.75, 0.9, 1.05, 1.2, 1.35])
PAD_APERTURE_M = np.array([0.159, 0.143, 0.126, 0.107, 0.087, 0.066, 0.045, 0.024, 0.004])
PRESHAPE_MARGIN_M = 0.035
# Fingertips across the closing axis in the pinch-site frame (y, m): finger 1, 2, 3.
FINGERTIPS_Y = np.array([-0.016, -0.044, 0.014])
FINGER_CLEARANCE_M = 0.022


def preshape_q(width_m: float, margin_m: float = PRESHAPE_MARGIN_M) -> float:
    """Finger angle (rad) whose pad aperture is ``width_m + margin_m`` (clamped to the range)."""
    aperture = float(np.clip(width_m + margin_m, PAD_APERTURE_M[-1], PAD_APERTURE_M[0]))
    return float(np.interp(aperture, PAD_APERTURE_M[::-1], FINGER_Q[::-1]))


def fingertips_xy(aperture_m: float) -> np.ndarray:
    """(3, 2) fingertip positions in the pinch-site frame for a pad aperture (m)."""
    half = aperture_m / 2
    return np.stack([np.array([half, -half, -half]), FINGERTIPS_Y], axis=1)


# Kept for plots: the fingertips of the fully open hand.
FINGERTIPS_XY = fingertips_xy(float(PAD_APERTURE_M[0]))


def finger_collisions(
    point: np.ndarray, yaw: float, obstacles_world: np.ndarray | None, aperture_m: float = 0.16
) -> int:
    """Obstacle points a top-down descent to ``point`` at ``yaw`` would put a fingertip on,
    the hand pre-shaped to ``aperture_m``."""
    if obstacles_world is None or len(obstacles_world) == 0:
        return 0
    c, s = math.cos(yaw), math.sin(yaw)
    tips = fingertips_xy(aperture_m) @ np.array([[c, s], [-s, c]]) + point[:2]  # (3, 2) world xy
    obs = np.asarray(obstacles_world, dtype=float)
    obs = obs[obs[:, 2] < point[2] + 0.10]
    d = np.linalg.norm(obs[None, :, :2] - tips[:, None, :], axis=2)  # (3, N)
    return int(np.count_nonzero(d.min(axis=0) < FINGER_CLEARANCE_M))


def _ranked(
    candidates: list[tuple[float, float]],
    point: np.ndarray,
    preferred_yaw: float,
    obstacles_world: np.ndarray | None,
) -> list[tuple[float, float]]:
    """Candidates by fewest finger collisions, then least wrist turn (yaw near preferred)."""

    def key(c: tuple[float, float]) -> tuple[int, float]:
        turn = abs(wrap_angle(c[0] - preferred_yaw))
        return finger_collisions(point, c[0], obstacles_world, c[1] + PRESHAPE_MARGIN_M), turn

    return [
        (preferred_yaw + wrap_angle(y - preferred_yaw), w) for y, w in sorted(candidates, key=key)
    ]


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
    min_clearance_m: float | None = None,
    obstacles_world: np.ndarray | None = None,
) -> GraspPlan:
    """The best grasp of :func:`rank_grasps` (same arguments)."""
    return rank_grasps(object_to_world, action, geometry, preferred_yaw, table_z,
                       min_clearance_m, obstacles_world)[0]  # fmt: skip


def rank_grasps(
    object_to_world: np.ndarray,
    action: GraspAction,
    geometry: ObjectGeometry,
    preferred_yaw: float = 0.0,
    table_z: float = 0.0,
    min_clearance_m: float | None = None,
    obstacles_world: np.ndarray | None = None,
) -> list[GraspPlan]:
    """Top-down grasps for an object at ``object_to_world``, best first.

    Args:
        object_to_world: (4, 4) estimated pose of the object (never ground truth).
        action: the task's grasp parameters.
        geometry: the model's shape.
        preferred_yaw: yaw (rad) the hand would rather keep (its current one).
        table_z: height of the table top, metres.
        min_clearance_m: the pinch point stays at least this high above the table so the
            fingertips do not dig into it (default ``geometry.min_clearance_m``).
        obstacles_world: (N, 3) sensed points of everything but the object and the table
            (world frame, metres), or None. Candidate yaws whose open fingertips would come
            down on such points are avoided; among the free ones the hand turns least.

    Raises:
        DataError: the pose is not a finite 4x4 matrix.
        NotFound: a ``feature`` grasp names a feature the geometry does not have.
        SpecError: the grasp type does not fit the geometry.
    """
    T = _check_pose(object_to_world)
    R, centre = T[:3, :3], T[:3, 3]
    gt = action.grasp_type
    candidates: list[tuple[float, float]] = []  # (yaw, width)
    if gt == "opposite_faces":
        if geometry.kind not in ("box", "part"):
            raise SpecError(f"grasp_type 'opposite_faces' needs a box model, got {geometry.kind!r}")
        tilt = np.abs(R[2, :])  # |z component| of each face normal pair
        for i in np.flatnonzero(tilt <= tilt.min() + 0.05):
            yaw_i = math.atan2(R[1, i], R[0, i])
            candidates += [
                (yaw_i + k * math.pi, 2.0 * geometry.half_extents_m[i]) for k in range(2)
            ]
        point = centre + np.array([0.0, 0.0, -action.grasp_depth_m])
    elif gt == "through_centre":
        candidates = [(preferred_yaw + k * math.pi / 6, 2.0 * geometry.radius_m) for k in range(12)]
        point = centre + np.array([0.0, 0.0, -action.grasp_depth_m])
    elif gt == "feature":
        feat = geometry.features.get(action.feature)
        if feat is None:
            raise NotFound(
                f"grasp feature {action.feature!r} not in the model; known: {sorted(geometry.features)}"
            )
        point = (
            R @ np.asarray(feat.point_object) + centre - np.array([0.0, 0.0, action.grasp_depth_m])
        )
        axis = R @ np.asarray(feat.axis_object)
        yaw_f = math.atan2(axis[1], axis[0])
        candidates = [(yaw_f + k * math.pi, feat.width_m) for k in range(2)]
    else:  # pragma: no cover - the spec loader rejects other types
        raise SpecError(f"unknown grasp_type {gt!r}")
    clearance = geometry.min_clearance_m if min_clearance_m is None else min_clearance_m
    point[2] = max(point[2], table_z + clearance)
    return [
        GraspPlan(
            grasp_point_world=(float(point[0]), float(point[1]), float(point[2])),
            yaw_rad=float(yaw),
            width_m=float(width),
            approach_height_m=action.approach_height_m,
            lift_height_m=action.lift_height_m,
        )
        for yaw, width in _ranked(candidates, point, preferred_yaw, obstacles_world)
    ]
