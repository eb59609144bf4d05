"""Grasps synthesised from the object's mesh (pure geometry, no simulator).

The Jaco hand closes finger 1 against fingers 2 and 3 along the x axis of its pinch site and
approaches from above, so a grasp is a pinch point in the world, a yaw of that closing axis
about the world's vertical, and the width the fingers should stop at.

:func:`synthesize_grasps` finds them from the model database's mesh (issue 10 section 4):

1. **Antipodal pairs.** Points sampled on the surface (seeded ``rng``) are paired when they
   lie at the same height, their horizontal distance fits the hand's opening
   (:data:`MIN_WIDTH_M` .. :data:`MAX_WIDTH_M`), and both inward normals lie inside the
   friction cone (half angle ``atan(mu)``, ``mu`` the object's sliding friction) around the
   closing axis.
2. **Pad support.** A pad centred on each contact (the pinch point closes on the line of the
   contacts, as the hand-written grasps did) must lie on the surface, and the surface must
   reach the pad's top edge: a pad that overhangs an edge catches it (the part's 22 mm step
   has to be pinched low for this reason; measured, docs/grasp.md).
3. **The approach.** Top-down: the pinch point keeps ``min_clearance_m`` above the table
   (model hint, default :data:`MIN_CLEARANCE_M`), and the open fingertips, pre-shaped to the
   width plus :data:`PRESHAPE_MARGIN_M`, must come down clear of the object's own surface and
   of the sensed points of other objects.
4. **Ranking.** By the distance from the centre of mass to the line of the pads, plus a
   penalty for contacts off the closing axis; candidates within :data:`COST_TOLERANCE_M` of
   the best are ordered by the wrist turn from ``preferred_yaw``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy.spatial import cKDTree

from mks_sim.errors import DataError, SpecError
from mks_sim.geometry.meshes import Mesh, sample_surface

if TYPE_CHECKING:
    from mks_sim.models.objects import ObjectModel
    from mks_sim.tasks.spec import GraspAction

__all__ = [
    "FINGERTIPS_XY",
    "GraspCandidate",
    "GraspPlan",
    "MAX_TILT_DEG",
    "down_rotation",
    "finger_collisions",
    "fingertips_xy",
    "hand_rotation",
    "plan_grasp",
    "preshape_q",
    "synthesize_grasps",
    "wrap_angle",
]


Rotation3 = tuple[tuple[float, float, float], tuple[float, float, float], tuple[float, float, float]]


def down_rotation(yaw: float) -> np.ndarray:
    """(3, 3) pinch-site rotation of a top-down hand: z (approach) = -world z, the closing
    (x) axis at ``yaw`` about world z (the rotation of ``controller.quat_down(yaw)``)."""
    x = np.array([math.cos(yaw), math.sin(yaw), 0.0])
    z = np.array([0.0, 0.0, -1.0])
    return np.stack([x, np.cross(z, x), z], axis=1)


def hand_rotation(yaw: float, rotation: Rotation3 | None) -> np.ndarray:
    """(3, 3) the hand's rotation: ``rotation`` when given, else top-down at ``yaw``."""
    return down_rotation(yaw) if rotation is None else np.asarray(rotation, dtype=float)


@dataclass(frozen=True)
class GraspPlan:
    """A grasp the controller executes: top-down at a yaw, or tilted (a full rotation).

    Attributes:
        grasp_point_world: (3,) where the pinch point closes, metres, world frame.
        yaw_rad: yaw of the closing axis (the pinch site's x axis) about world z, radians
            (of its horizontal projection for a tilted grasp).
        width_m: the object's width between the fingers, metres.
        approach_height_m: pre-grasp distance back along the approach, metres.
        lift_height_m: how far to lift (straight up), metres.
        rotation_world: (3, 3) row-major pinch-site rotation for a tilted grasp (columns:
            closing axis, across, approach); None for a top-down grasp (:func:`down_rotation`
            of ``yaw_rad``).

    The hand descends pre-shaped to ``width_m`` plus ``PRESHAPE_MARGIN_M``
    (:attr:`preshape_q`).
    """

    grasp_point_world: tuple[float, float, float]
    yaw_rad: float
    width_m: float
    approach_height_m: float
    lift_height_m: float
    rotation_world: Rotation3 | None = None

    @property
    def tilted(self) -> bool:
        """The approach is not straight down (the plan carries a full hand rotation)."""
        return self.rotation_world is not None

    @property
    def hand_rotation(self) -> np.ndarray:
        """(3, 3) pinch-site rotation in the world (columns: closing axis, across, approach)."""
        return hand_rotation(self.yaw_rad, self.rotation_world)

    @property
    def target_rotation(self) -> np.ndarray | None:
        """The rotation to pass the controller's moves (``rotation=``): the hand rotation of
        a tilted grasp, None for a top-down one (the moves then follow ``yaw_rad``)."""
        return None if self.rotation_world is None else self.hand_rotation

    @property
    def approach_world(self) -> np.ndarray:
        """(3,) unit direction the hand descends along ((0, 0, -1) for a top-down grasp)."""
        return self.hand_rotation[:, 2]

    @property
    def pregrasp_world(self) -> np.ndarray:
        """(3,) the pre-grasp pinch point, ``approach_height_m`` back along the approach
        (straight above the grasp point for a top-down grasp)."""
        if self.rotation_world is None:
            return np.asarray(self.grasp_point_world) + np.array([0.0, 0.0, self.approach_height_m])
        return np.asarray(self.grasp_point_world) - self.approach_height_m * self.approach_world

    @property
    def preshape_q(self) -> float:
        """Finger angle (rad) to descend with."""
        return preshape_q(self.width_m)

    @property
    def lifted_world(self) -> np.ndarray:
        """(3,) the pinch point after lifting."""
        return np.asarray(self.grasp_point_world) + np.array([0.0, 0.0, self.lift_height_m])


@dataclass(frozen=True)
class GraspCandidate:
    """One synthesised grasp, world frame.

    Attributes:
        pinch_world: (3,) pinch-site position at closing, metres.
        yaw_rad: yaw of the closing axis about world z, radians (finger 1 on the +axis side).
        width_m: horizontal distance between the two contacts, metres.
        contacts_world: (2, 3) contact of fingers 2/3, then of finger 1, metres.
        normals_world: (2, 3) outward surface normals at the contacts.
        antipodal: min over both contacts of cos(inward normal, closing direction); 1 is a
            perfect antipodal pair, ``cos(atan(mu))`` the edge of the friction cone.
        com_distance_m: distance from the centre of mass to the line of the contacts.
        cost: ranking cost (metres; lower is better).
        rotation_world: (3, 3) row-major pinch-site rotation of a tilted grasp (the closing
            axis not horizontal or the approach not vertical); None: top-down at ``yaw_rad``.
    """

    pinch_world: tuple[float, float, float]
    yaw_rad: float
    width_m: float
    contacts_world: tuple[tuple[float, float, float], tuple[float, float, float]]
    normals_world: tuple[tuple[float, float, float], tuple[float, float, float]]
    antipodal: float
    com_distance_m: float
    cost: float
    rotation_world: Rotation3 | None = None

    @property
    def hand_rotation(self) -> np.ndarray:
        """(3, 3) pinch-site rotation in the world (columns: closing axis, across, approach)."""
        return hand_rotation(self.yaw_rad, self.rotation_world)

    @property
    def axis_world(self) -> np.ndarray:
        """(3,) the closing direction (from fingers 2/3 toward finger 1), unit; horizontal
        for a top-down grasp."""
        if self.rotation_world is None:
            return np.array([math.cos(self.yaw_rad), math.sin(self.yaw_rad), 0.0])
        return self.hand_rotation[:, 0]

    @property
    def tilt_deg(self) -> float:
        """Angle between the approach and straight down, degrees."""
        return float(np.degrees(np.arccos(np.clip(-self.hand_rotation[2, 2], -1.0, 1.0))))

    def plan(self, action: GraspAction) -> GraspPlan:
        """The executable plan with the task's approach and lift heights."""
        return GraspPlan(
            grasp_point_world=self.pinch_world,
            yaw_rad=self.yaw_rad,
            width_m=self.width_m,
            approach_height_m=action.approach_height_m,
            lift_height_m=action.lift_height_m,
            rotation_world=self.rotation_world,
        )


def wrap_angle(angle: float) -> float:
    """``angle`` wrapped to [-pi, pi)."""
    return (angle + math.pi) % (2 * math.pi) - math.pi


# --- the hand (measured on the pads of mks_sim.sim.robot) -------------------------------------
# Finger joint angle (rad) -> distance between the pad of finger 1 and the pads of fingers
# 2 + 3 along the closing axis (m) (same q on all three fingers). Descending with the hand
# pre-shaped to the object's width plus a margin keeps the fingertips off the table and off
# neighbouring objects.
FINGER_Q = np.array([0.15, 0.3, 0.45, 0.6, 0.75, 0.9, 1.05, 1.2, 1.35])
PAD_APERTURE_M = np.array([0.159, 0.143, 0.126, 0.107, 0.087, 0.066, 0.045, 0.024, 0.004])
PRESHAPE_MARGIN_M = 0.035
# Fingertips across the closing axis in the pinch-site frame (y, m): finger 1, 2, 3 (open).
FINGERTIPS_Y = np.array([-0.016, -0.044, 0.014])
# Sensed points of other objects closer than this to an open fingertip block the descent.
FINGER_CLEARANCE_M = 0.022
# The pads span 0..15 mm below the pinch site; contact is taken at their centre, and the
# surface must reach their top edge.
PAD_CENTRE_BELOW_M = 0.008
PAD_TOP_ABOVE_CENTRE_M = 0.007
# The top probe sits this much higher still, so a pad within the probe tolerance of an edge
# does not pass for one on the face.
PAD_TOP_MARGIN_M = 0.002
# How far above a pad's centre the surface must reach by default: the whole pad on the face.
PAD_COVER_M = PAD_TOP_ABOVE_CENTRE_M + PAD_TOP_MARGIN_M
# Half the pad's width across the closing axis that must lie on the face (pads are ~13 mm).
PAD_HALF_WIDTH_M = 0.0065
# Where along the closing direction (m, + = further in) a pad may meet the surface: a curved
# or leaning face is met before or after the line of the contacts.
PAD_DEPTHS_M = np.array([-0.006, -0.003, 0.0, 0.003, 0.006, 0.009])
# Open fingertips reach this far below the pinch site (their lowest pad row).
FINGERTIP_DROP_M = 0.015
# The object's own surface closer than this to an open fingertip's axis blocks the descent
# (the fingertip's half thickness plus a little).
SELF_CLEARANCE_M = 0.008
# A top-down hand's palm (measured on the meshes of mks_sim.sim.robot, pinch-site frame: x the
# closing axis, y across): its lowest point PALM_ABOVE_M above the pinch site, over PALM_XY_M.
# A part standing on end (100 mm tall) pinched low had its top under the palm: the descent
# stopped 6-14 mm short, three candidates in a row (tuning bin 1, docs/bin.md). The knuckles
# (27-38 mm above the pinch site just inside the fingertips) are not modelled: a box for them
# dropped grasps that held (tuning bins 7, 8: 5 and 4 parts -> 4 and 2).
PALM_ABOVE_M = 0.072
PALM_XY_M = np.array([[-0.054, -0.062], [0.053, 0.032]])  # (min, max) x, y
# The object's own surface at most this close below the palm.
PALM_CLEARANCE_M = 0.004
# Widths the pads close on: the closed hand's pads are 4 mm apart, and a 10 mm wall with a
# 25 mm face (the L-bracket's) is held (tuning seeds 1000-1011: 9/12 at 8 mm, 0/12 at the
# former 20 mm, chosen when the part's 13 mm boss never gave contact on both pads, see
# docs/grasp.md; its boss stays out on the pad check). The widest is the open hand minus
# the pre-shape margin. The bin passes 20 mm (its empty-hand test reads the finger angle).
MIN_WIDTH_M = 0.008
# A contact face leaning more than this from the vertical is not pinched from the side (the
# friction cone alone allows 45 deg at mu = 1): the horizontal squeeze pushes the part along
# a leaning face, and the bracket on its leg ends (walls leaning 31 deg) slipped out of
# such pinches (tuning seeds 1006, 1008, 1010, 1011 at 45 deg); at 25 deg 1008 and 1010 hold.
MAX_FACE_LEAN_DEG = 25.0
MAX_WIDTH_M = float(PAD_APERTURE_M[0]) - PRESHAPE_MARGIN_M
# Pinch point above the table (fingertips reach ~15 mm below it); a model's grasp hint
# ``min_clearance_m`` overrides it.
MIN_CLEARANCE_M = 0.018
COST_TOLERANCE_M = 0.004  # candidates this close to the best are ordered by wrist turn
ANTIPODAL_WEIGHT_M = 0.05  # cost of a contact at the edge of the cone vs a perfect pair
PAIR_DZ_M = 0.0025  # the two contacts of a pair differ at most this much in height
SAMPLE_SPACING_M = 0.0012  # the dense surface sample the pad probes query
PROBE_TOL_M = 0.002
PROBE_NORMAL_COS = math.cos(math.radians(35.0))
# Tilted grasps (a part on its side or upside down has no horizontal antipodal pair): the
# approach at most this far from straight down (the bin's walls are 40 mm high, the hand
# comes from above them), ranked behind the top-down ones.
MAX_TILT_DEG = 45.0
MAX_TILTED = 12
TILT_WEIGHT_M = 0.02  # ranking cost of a grasp tilted by MAX_TILT_DEG
TILT_ROLLS_DEG = (0.0, -20.0, 20.0, -40.0, 40.0)  # approaches rolled about the closing axis
TILT_TIP_ABOVE_TABLE_M = 0.002  # a tilted hand's lowest open fingertip above the table
SWEEP_BACK_M = 0.16  # the sweep starts this far back along the approach (pre-grasp 12 cm)
PALM_START_M = 0.05  # the palm begins this far back from the pinch point
PALM_RADIUS_M = 0.035
TILT_SAMPLES = 240  # surface points drawn for the tilted pairs
TILT_PAIRS = 1500  # contact pairs (the cheapest) expanded into tilted candidates
TILT_CHECKED = 480  # the costly checks run on at most this many distinct tilted candidates


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


def _tips_world(pinch: np.ndarray, yaw: np.ndarray, aperture: np.ndarray) -> np.ndarray:
    """(K, 3, 2) open fingertip xy, world frame, for K pinch points / yaws / apertures."""
    half = aperture / 2
    lx = np.stack([half, -half, -half], axis=1)  # (K, 3) along the closing axis
    ly = np.broadcast_to(FINGERTIPS_Y, lx.shape)  # (K, 3) across it
    c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    # pinch-site y axis in the world is (sin yaw, -cos yaw) (z down, x at yaw)
    x = pinch[:, None, 0] + lx * c + ly * s
    y = pinch[:, None, 1] + lx * s - ly * c
    return np.stack([x, y], axis=2)


def _tip_hits(
    tips: np.ndarray, pinch_z: np.ndarray, points: np.ndarray, radius: float
) -> np.ndarray:
    """(K,) number of ``points`` (M, 3) a top-down descent to pinch heights ``pinch_z`` (K,)
    would put one of the fingertips ``tips`` (K, 3, 2) on (within ``radius`` in xy)."""
    K = len(tips)
    if len(points) == 0 or K == 0:
        return np.zeros(K, dtype=int)
    pairs = cKDTree(tips.reshape(-1, 2)).sparse_distance_matrix(
        cKDTree(points[:, :2]), radius, output_type="ndarray"
    )
    cand, pt = pairs["i"] // tips.shape[1], pairs["j"]
    low = points[pt, 2] > pinch_z[cand] - FINGERTIP_DROP_M
    key = np.unique(cand[low] * len(points) + pt[low])  # each point once per candidate
    return np.bincount(key // len(points), minlength=K)


def _under_palm(pinch: np.ndarray, yaw: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(K,) number of ``points`` (M, 3) within :data:`PALM_CLEARANCE_M` below (or above) a
    top-down hand's palm at pinch points ``pinch`` (K, 3), yaws ``yaw`` (K,)."""
    K = len(pinch)
    if K:  # only points as high as the lowest palm can be under one (most grasps: none)
        points = points[points[:, 2] > pinch[:, 2].min() + PALM_ABOVE_M - PALM_CLEARANCE_M]
    if len(points) == 0 or K == 0:
        return np.zeros(K, dtype=int)
    rel = points[None, :, :] - pinch[:, None, :]  # (K, M, 3)
    c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    x = rel[:, :, 0] * c + rel[:, :, 1] * s  # along the closing axis
    y = rel[:, :, 0] * s - rel[:, :, 1] * c  # pinch-site y: (sin yaw, -cos yaw)
    (x0, y0), (x1, y1) = PALM_XY_M
    under = (x >= x0) & (x <= x1) & (y >= y0) & (y <= y1)
    return np.count_nonzero(under & (rel[:, :, 2] > PALM_ABOVE_M - PALM_CLEARANCE_M), axis=1)


def finger_collisions(
    point: np.ndarray, yaw: float, obstacles_world: np.ndarray | None, aperture_m: float = 0.16
) -> int:
    """Obstacle points a top-down descent to ``point`` at ``yaw`` would put a fingertip on,
    the hand pre-shaped to ``aperture_m``."""
    if obstacles_world is None or len(obstacles_world) == 0:
        return 0
    p = np.asarray(point, dtype=float).reshape(1, 3)
    tips = _tips_world(p, np.array([yaw]), np.array([aperture_m]))
    obs = np.asarray(obstacles_world, dtype=float)
    obs = obs[obs[:, 2] < p[0, 2] + 0.10]
    return int(_tip_hits(tips, p[:, 2] + FINGERTIP_DROP_M, obs, FINGER_CLEARANCE_M)[0])


def _check_pose(object_to_world: np.ndarray) -> np.ndarray:
    T = np.asarray(object_to_world, dtype=float)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise DataError(f"object_to_world: expected a finite 4x4 matrix, got shape {T.shape}")
    return T


def _dense_surface(mesh: Mesh) -> tuple[np.ndarray, np.ndarray, cKDTree]:
    """Dense surface sample of ``mesh`` (body frame) and its k-d tree, cached on the mesh."""
    key = "grasp_dense_surface"
    if key not in mesh._cache:
        n = int(np.clip(mesh.area / SAMPLE_SPACING_M**2, 500, 40000))
        pts, nrm = sample_surface(mesh, n, rng=np.random.default_rng(0))
        mesh._cache[key] = (pts, nrm, cKDTree(pts))
    return mesh._cache[key]  # type: ignore[no-any-return]


def _supported(probes_body: np.ndarray, normals_body: np.ndarray, mesh: Mesh) -> np.ndarray:
    """(P,) True where a probe lies on the surface with a normal like ``normals_body``."""
    pts, nrm, tree = _dense_surface(mesh)
    _, idx = tree.query(probes_body, k=4, distance_upper_bound=PROBE_TOL_M)
    valid = idx < len(pts)  # missing neighbours are indicated with len(pts)
    same = np.einsum("pkj,pj->pk", nrm[np.minimum(idx, len(pts) - 1)], normals_body)
    return np.any(valid & (same >= PROBE_NORMAL_COS), axis=1)


def _hint(obj: Any, key: str, default: float) -> float:
    hints = getattr(obj, "grasp", None) or {}
    value = hints.get(key, default)
    if not isinstance(value, (int, float)) or not math.isfinite(value):
        raise SpecError(
            f"object {obj.name!r}: grasp hint {key!r}: expected a number, got {value!r}"
        )
    return float(value)


def synthesize_grasps(
    obj: ObjectModel,
    object_to_world: np.ndarray,
    *,
    table_z: float,
    obstacles: np.ndarray | None = None,
    rng: np.random.Generator | None = None,
    preferred_yaw: float = 0.0,
    n_samples: int = 300,
    max_candidates: int = 24,
    max_tilt_deg: float = MAX_TILT_DEG,
    max_tilted: int = MAX_TILTED,
    finger_clearance_m: float = FINGER_CLEARANCE_M,
    min_width_m: float = MIN_WIDTH_M,
    max_face_lean_deg: float = MAX_FACE_LEAN_DEG,
    pad_cover_m: float = PAD_COVER_M,
) -> list[GraspCandidate]:
    """Antipodal grasps of ``obj`` at ``object_to_world``: top-down first, then tilted.

    Args:
        obj: the model-database object (its ``mesh`` in metres, body frame; ``friction[0]``
            the sliding friction; hint ``grasp.min_clearance_m``).
        object_to_world: (4, 4) estimated pose of the object (never ground truth).
        table_z: height of the table top, metres.
        obstacles: (N, 3) sensed points of everything but the object and the table (world
            frame, metres), or None. Candidates whose open fingertips would come down within
            :data:`FINGER_CLEARANCE_M` of such a point are removed.
        rng: surface sampling (default seeded 0: deterministic).
        preferred_yaw: yaw (rad) the hand would rather keep (its current one); yaws are
            returned unwrapped to the nearest turn of it.
        n_samples: surface points drawn for pairing.
        max_candidates: at most this many top-down candidates (distinct contact pairs, each
            in both closing directions).
        max_tilt_deg: tilted grasps approach at most this far from straight down (0: top-down
            only); their closing axis may leave the horizontal (:func:`_tilted_grasps`).
        max_tilted: at most this many tilted candidates.
        finger_clearance_m: obstacle points closer than this to an open fingertip's descent
            block it (default :data:`FINGER_CLEARANCE_M`; a rigid fixture such as a bin wall
            may be passed closer).
        min_width_m: narrowest pinch (default :data:`MIN_WIDTH_M`).
        max_face_lean_deg: a top-down pinch's contact faces lean at most this far from the
            vertical (default :data:`MAX_FACE_LEAN_DEG`).
        pad_cover_m: the surface must reach this far above each pad's centre, toward the
            palm (default :data:`PAD_COVER_M`: the whole pad on the face). Less lets a pad
            reach over the face's top edge: a flange thinner than the pad can be pinched.

    Returns:
        Candidates: the top-down ones best first, then the tilted ones best first (a
        candidate with ``rotation_world`` set); empty when no pair passes the filters.

    Raises:
        DataError: the pose is not a finite 4x4 matrix.
        SpecError: a malformed grasp hint.
    """
    T = _check_pose(object_to_world)
    rng = np.random.default_rng(0) if rng is None else rng
    R, t = T[:3, :3], T[:3, 3]
    mesh = obj.mesh
    mu = float(obj.friction[0])
    cos_cone = math.cos(math.atan(mu))
    clearance = _hint(obj, "min_clearance_m", MIN_CLEARANCE_M)

    dense, dense_n, _ = _dense_surface(mesh)
    p_world = dense @ R.T + t  # (n, 3)
    n_world = dense_n @ R.T
    # A contact's inward normal must fit in a cone around a horizontal closing axis, and
    # its height keep the pinch point above the table's clearance.
    keep = np.flatnonzero(
        (np.abs(n_world[:, 2]) <= math.sin(min(math.atan(mu), math.radians(max_face_lean_deg))))
        & (p_world[:, 2] + PAD_CENTRE_BELOW_M >= table_z + clearance)
    )
    keep = rng.choice(keep, size=min(n_samples, len(keep)), replace=False)
    p_world, n_world = p_world[keep], n_world[keep]
    # Cheap pre-check per point (the full pad check runs per candidate below): the surface
    # reaches the pad's top edge above the contact.
    top = _reaches_top(mesh, R, t, p_world, n_world, pad_cover_m)
    p_world, n_world = p_world[top], n_world[top]

    # Pairs (i, j): i = fingers 2/3 side, j = finger 1 side, closing axis d from i to j;
    # the height test first, as it leaves few of the m^2 pairs.
    ii, jj = np.nonzero(np.abs(p_world[None, :, 2] - p_world[:, None, 2]) <= PAIR_DZ_M)
    D = p_world[jj, :2] - p_world[ii, :2]  # (P, 2)
    w = np.hypot(D[:, 0], D[:, 1])
    d = D / np.maximum(w, 1e-12)[:, None]  # horizontal unit
    a_i = -np.einsum("pk,pk->p", d, n_world[ii, :2])  # inward normal at i along +d
    a_j = np.einsum("pk,pk->p", d, n_world[jj, :2])  # inward normal at j along -d
    ok = (w >= min_width_m) & (w <= MAX_WIDTH_M) & (a_i >= cos_cone) & (a_j >= cos_cone)
    ii, jj, d, a_i, a_j, pair_width = ii[ok], jj[ok], d[ok], a_i[ok], a_j[ok], w[ok]
    obs = np.zeros((0, 3))
    if obstacles is not None and len(obstacles):
        obs = np.asarray(obstacles, dtype=float).reshape(-1, 3)
        obs = obs[np.all(np.isfinite(obs), axis=1)]
    own = dense[:: max(1, len(dense) // 2000)] @ R.T + t  # (<= 4000, 3)
    own = own[own[:, 2] > table_z + 0.002]
    tilted: list[GraspCandidate] = []
    if max_tilt_deg > 0 and max_tilted > 0:
        tilted = _tilted_grasps(
            obj, R, t, table_z=table_z, own=own, obs=obs, cos_cone=cos_cone,
            max_tilt=math.radians(max_tilt_deg), n_samples=n_samples,
            preferred_yaw=preferred_yaw, limit=max_tilted, finger_clearance=finger_clearance_m,
            min_width_m=min_width_m, pad_cover_m=pad_cover_m,
        )  # fmt: skip
    if len(ii) == 0:
        return tilted
    antipodal = np.minimum(a_i, a_j)
    mid = 0.5 * (p_world[ii] + p_world[jj])  # pad-centre line midpoint
    axis = np.column_stack([d, np.zeros(len(ii))])
    com = R @ mesh.centroid + t
    rel = com - mid
    com_dist = np.linalg.norm(rel - np.sum(rel * axis, axis=1)[:, None] * axis, axis=1)
    cost = com_dist + ANTIPODAL_WEIGHT_M * (1.0 - antipodal) / (1.0 - cos_cone + 1e-12)
    # Both closing directions of each pair: finger 1 on j (yaw of d) or on i (yaw + pi).
    K = len(ii)
    yaw = np.arctan2(axis[:, 1], axis[:, 0])
    yaw = np.concatenate([yaw, yaw + math.pi])  # (2K,)
    src = np.concatenate([np.arange(K), np.arange(K)])
    f1 = np.concatenate([jj, ii])  # finger 1's contact
    f23 = np.concatenate([ii, jj])  # fingers 2/3's contact
    pinch = mid[src] + np.array([0.0, 0.0, PAD_CENTRE_BELOW_M])
    aperture = pair_width[src] + PRESHAPE_MARGIN_M
    # The costly checks run on distinct candidates, cheapest first, a batch at a time.
    order = _distinct(np.arange(2 * K), pinch, yaw, cost[src], 2 * K)
    kept: list[int] = []
    start, batch = 0, 2 * max_candidates
    while start < len(order) and len(kept) < max_candidates:
        b = order[start : start + batch]
        start, batch = start + batch, 2 * batch  # few batches when most candidates fail
        tips = _tips_world(pinch[b], yaw[b], aperture[b])
        ok = _tip_hits(tips, pinch[b, 2], own, SELF_CLEARANCE_M) == 0
        ok &= _under_palm(pinch[b], yaw[b], own) == 0
        ok &= _tip_hits(tips, pinch[b, 2], obs, finger_clearance_m) == 0
        b = b[ok]
        ok = _pads_supported(
            mesh, R, t, p_world, n_world, f1[b], f23[b], yaw[b], cover_m=pad_cover_m
        )
        kept.extend(int(k) for k in b[ok])
    sel = kept[:max_candidates]
    out = [
        GraspCandidate(
            pinch_world=tuple(float(v) for v in pinch[k]),  # type: ignore[arg-type]
            yaw_rad=float(preferred_yaw + wrap_angle(yaw[k] - preferred_yaw)),
            width_m=float(pair_width[src[k]]),
            contacts_world=(tuple(map(float, p_world[f23[k]])), tuple(map(float, p_world[f1[k]]))),  # type: ignore[arg-type]
            normals_world=(tuple(map(float, n_world[f23[k]])), tuple(map(float, n_world[f1[k]]))),  # type: ignore[arg-type]
            antipodal=float(antipodal[src[k]]),
            com_distance_m=float(com_dist[src[k]]),
            cost=float(cost[src[k]]),
        )
        for k in sel
    ]
    return _by_wrist_turn(out, preferred_yaw) + tilted


def _tilted_grasps(
    obj: ObjectModel,
    R: np.ndarray,
    t: np.ndarray,
    *,
    table_z: float,
    own: np.ndarray,
    obs: np.ndarray,
    cos_cone: float,
    max_tilt: float,
    n_samples: int,
    preferred_yaw: float,
    limit: int,
    finger_clearance: float = FINGER_CLEARANCE_M,
    min_width_m: float = MIN_WIDTH_M,
    pad_cover_m: float = PAD_COVER_M,
) -> list[GraspCandidate]:
    """Grasps whose approach leaves the vertical (at most ``max_tilt`` rad), best first.

    Contact pairs at any height difference whose closing axis rises at most ``max_tilt``
    (both inward normals in the friction cone around it, in 3-D); the hand approaches
    perpendicular to the closing axis, as near to straight down as it can
    (:data:`TILT_ROLLS_DEG`: also rolled about the closing axis). The fingertips must stay
    :data:`TILT_TIP_ABOVE_TABLE_M` above the table and sweep clear of the object's own
    surface and of the obstacles along the approach; the palm (:data:`PALM_START_M` back
    along the approach) clear of the obstacles; both pads supported (their top edge toward
    the palm). Ranked by the top-down cost plus :data:`TILT_WEIGHT_M` per ``max_tilt`` of
    tilt. Pairs at the same height approached straight down are the top-down path's.
    """
    mesh = obj.mesh
    dense, dense_n, _ = _dense_surface(mesh)
    p_all = dense @ R.T + t
    n_all = dense_n @ R.T
    sin_n = math.sin(min(max_tilt + math.acos(cos_cone), math.pi / 2))
    keep = np.flatnonzero((np.abs(n_all[:, 2]) <= sin_n + 1e-12) & (p_all[:, 2] > table_z + 0.003))
    if len(keep) < 2:
        return []
    # a fixed stream: the caller's rng draws the same for the top-down grasps as before
    size = min(n_samples, TILT_SAMPLES, len(keep))
    keep = np.random.default_rng(1).choice(keep, size=size, replace=False)
    p_w, n_w = p_all[keep], n_all[keep]
    ii, jj = np.triu_indices(len(p_w), k=1)
    D = p_w[jj] - p_w[ii]
    w = np.linalg.norm(D, axis=1)
    d = D / np.maximum(w, 1e-12)[:, None]
    a_i = -np.einsum("pk,pk->p", d, n_w[ii])
    a_j = np.einsum("pk,pk->p", d, n_w[jj])
    ok = (w >= min_width_m) & (w <= MAX_WIDTH_M) & (a_i >= cos_cone) & (a_j >= cos_cone)
    ok &= np.abs(d[:, 2]) <= math.sin(max_tilt)
    ok = np.flatnonzero(ok)
    if len(ok) == 0:
        return []
    dz = D[ok, 2]
    ii, jj, d, w, anti = ii[ok], jj[ok], d[ok], w[ok], np.minimum(a_i, a_j)[ok]
    down = np.array([0.0, 0.0, -1.0])
    a0 = down - (d @ down)[:, None] * d
    a0 /= np.linalg.norm(a0, axis=1, keepdims=True)
    b0 = np.cross(d, a0)
    mid = 0.5 * (p_w[ii] + p_w[jj])
    com = R @ mesh.centroid + t
    rel = com - mid
    com_dist = np.linalg.norm(rel - np.sum(rel * d, axis=1)[:, None] * d, axis=1)
    base = com_dist + ANTIPODAL_WEIGHT_M * (1.0 - anti) / (1.0 - cos_cone + 1e-12)
    if len(base) > TILT_PAIRS:  # a round object pairs almost everything: the best suffice
        best = np.argpartition(base, TILT_PAIRS)[:TILT_PAIRS]
        ii, jj, d, w, anti, dz = ii[best], jj[best], d[best], w[best], anti[best], dz[best]
        a0, b0, mid = a0[best], b0[best], mid[best]
        com_dist, base = com_dist[best], base[best]
    flat = np.abs(dz) <= PAIR_DZ_M  # the top-down path's pairs
    # every (pair, roll, closing direction)
    src, xs, zs = [], [], []
    for roll in np.radians(TILT_ROLLS_DEG):
        a = math.cos(roll) * a0 + math.sin(roll) * b0
        tilt = np.arccos(np.clip(-a[:, 2], -1.0, 1.0))
        k = np.flatnonzero((tilt <= max_tilt + 1e-9) & ~(flat & (abs(roll) < 1e-9)))
        for sign in (1.0, -1.0):
            src.append(k)
            xs.append(sign * d[k])
            zs.append(a[k])
    if not sum(len(k) for k in src):
        return []
    sidx = np.concatenate(src)
    x = np.concatenate(xs)
    z = np.concatenate(zs)
    hand = np.stack([x, np.cross(z, x), z], axis=2)  # (C, 3, 3) columns x, y, z
    tilt = np.arccos(np.clip(-z[:, 2], -1.0, 1.0))
    cost = base[sidx] + TILT_WEIGHT_M * tilt / max_tilt
    pinch = mid[sidx] - PAD_CENTRE_BELOW_M * z
    forward = np.einsum("ck,ck->c", x, d[sidx]) > 0  # finger 1 on j
    f1 = np.where(forward, jj[sidx], ii[sidx])
    f23 = np.where(forward, ii[sidx], jj[sidx])
    aperture = w[sidx] + PRESHAPE_MARGIN_M
    yaw = np.arctan2(x[:, 1], x[:, 0])
    # the open fingertips stay above the table (cheap: first, on every candidate)
    tips_w = pinch[:, None] + np.einsum("kij,ktj->kti", hand, _tips_hand(aperture))
    low_ok = np.flatnonzero(tips_w[:, :, 2].min(axis=1) >= table_z + TILT_TIP_ABOVE_TABLE_M)
    if len(low_ok) == 0:
        return []
    order = _distinct(low_ok, pinch, yaw, cost, TILT_CHECKED)
    own_tree = cKDTree(own) if len(own) else None
    obs_tree = cKDTree(obs) if len(obs) else None
    kept: list[int] = []
    start, batch = 0, 2 * limit
    while start < len(order) and len(kept) < limit:
        b = order[start : start + batch]
        start, batch = start + batch, 2 * batch
        b = b[_pads_supported(mesh, R, t, p_w, n_w, f1[b], f23[b], yaw[b], hand[b], pad_cover_m)]
        tips = _tips_hand(aperture[b])  # (k, 3, 3) hand frame
        ok = ~_sweep_hits(hand[b], pinch[b], tips, own_tree, SELF_CLEARANCE_M)
        ok &= ~_sweep_hits(hand[b], pinch[b], tips, obs_tree, finger_clearance)
        ok &= ~_palm_hits(hand[b], pinch[b], obs_tree)
        kept.extend(int(k) for k in b[ok])
    return [
        GraspCandidate(
            pinch_world=tuple(float(v) for v in pinch[k]),  # type: ignore[arg-type]
            yaw_rad=float(preferred_yaw + wrap_angle(yaw[k] - preferred_yaw)),
            width_m=float(w[sidx[k]]),
            contacts_world=(tuple(map(float, p_w[f23[k]])), tuple(map(float, p_w[f1[k]]))),  # type: ignore[arg-type]
            normals_world=(tuple(map(float, n_w[f23[k]])), tuple(map(float, n_w[f1[k]]))),  # type: ignore[arg-type]
            antipodal=float(anti[sidx[k]]),
            com_distance_m=float(com_dist[sidx[k]]),
            cost=float(cost[k]),
            rotation_world=tuple(tuple(float(v) for v in row) for row in hand[k]),  # type: ignore[arg-type]
        )
        for k in kept[:limit]
    ]


def _tips_hand(aperture: np.ndarray) -> np.ndarray:
    """(K, 3, 3) the open fingertips' lowest points in the pinch-site frame (z = approach)."""
    half = aperture / 2
    lx = np.stack([half, -half, -half], axis=1)
    ly = np.broadcast_to(FINGERTIPS_Y, lx.shape)
    return np.stack([lx, ly, np.full(lx.shape, FINGERTIP_DROP_M)], axis=2)


def _chain_hits(
    starts: np.ndarray, direction: np.ndarray, lengths: tuple[float, float], tree: cKDTree | None,
    radius: float, spacing: float = 0.005,
) -> np.ndarray:
    """(K,) some point of ``tree`` lies within ``radius`` of one of the segments
    ``starts[k, l] + s * direction[k]``, ``s`` in ``lengths`` (K, L, 3 starts; balls every
    ``spacing`` along them, their radius grown to cover the cylinder between them)."""
    K = len(starts)
    if tree is None or K == 0:
        return np.zeros(K, dtype=bool)
    s = np.arange(lengths[0], lengths[1] + 1e-9, spacing)
    q = starts[:, :, None, :] + s[None, None, :, None] * direction[:, None, None, :]
    d, _ = tree.query(q.reshape(-1, 3), distance_upper_bound=math.hypot(radius, spacing / 2))
    return np.any(np.isfinite(d).reshape(K, -1), axis=1)


def _sweep_hits(
    hand: np.ndarray, pinch: np.ndarray, tips: np.ndarray, tree: cKDTree | None, radius: float
) -> np.ndarray:
    """(K,) a descent along each hand's approach would put a fingertip on a point of
    ``tree``: within ``radius`` of a fingertip's line, not beyond its lowest reach and at most
    :data:`SWEEP_BACK_M` back (the general form of the top-down ``_tip_hits``)."""
    tips_w = pinch[:, None] + np.einsum("kij,ktj->kti", hand, tips)  # lowest points
    back = -hand[:, :, 2]  # toward the palm
    return _chain_hits(tips_w, back, (0.0, SWEEP_BACK_M + FINGERTIP_DROP_M), tree, radius)


def _palm_hits(hand: np.ndarray, pinch: np.ndarray, tree: cKDTree | None) -> np.ndarray:
    """(K,) a point of ``tree`` within :data:`PALM_RADIUS_M` of the palm's axis (from
    :data:`PALM_START_M` to :data:`SWEEP_BACK_M` back along the approach): a tilted hand
    swings its palm over what lies beside the object."""
    back = -hand[:, :, 2]
    return _chain_hits(pinch[:, None], back, (PALM_START_M, SWEEP_BACK_M), tree, PALM_RADIUS_M,
                       spacing=0.01)  # fmt: skip


def _pads_supported(
    mesh: Mesh,
    R: np.ndarray,
    t: np.ndarray,
    p_world: np.ndarray,
    n_world: np.ndarray,
    f1: np.ndarray,
    f23: np.ndarray,
    yaw: np.ndarray,
    hand: np.ndarray | None = None,
    cover_m: float = PAD_COVER_M,
) -> np.ndarray:
    """(K,) both contacts carry a pad: the contact, the pad's sides across the closing axis
    and the same three points ``cover_m`` toward the palm (its top edge) lie on the surface, each
    where the pad is or shifted along the closing direction by one of :data:`PAD_DEPTHS_M`
    (a curved or leaning face). ``hand`` (K, 3, 3): the hand's rotations (tilted grasps);
    None: top-down at ``yaw``."""
    if hand is None:
        across = np.column_stack([np.sin(yaw), -np.cos(yaw), np.zeros(len(yaw))])  # site y
        axis = np.column_stack([np.cos(yaw), np.sin(yaw), np.zeros(len(yaw))])  # site x
        up: np.ndarray = np.array([0.0, 0.0, cover_m])
    else:
        axis, across = hand[:, :, 0], hand[:, :, 1]
        up = -cover_m * hand[:, :, 2]  # toward the palm
    side = PAD_HALF_WIDTH_M * across  # (K, 3)
    # The pad's six points, the most discriminating first (its top edge); each is tested
    # only for the candidates that passed the ones before.
    offsets = [up + 0.0 * side, up - side, up + side, 0.0 * side, -side, side]
    alive = np.ones(len(yaw), dtype=bool)
    for contact, inward in ((f1, -axis), (f23, axis)):
        for offset in offsets:
            k = np.flatnonzero(alive)
            if len(k) == 0:
                return alive
            probe = p_world[contact[k]] + offset[k]  # (k, 3)
            probes = probe[None] + PAD_DEPTHS_M[:, None, None] * inward[k][None]  # (D, k, 3)
            normals = np.broadcast_to(n_world[contact[k]], probes.shape)
            hit = _supported((probes.reshape(-1, 3) - t) @ R, normals.reshape(-1, 3) @ R, mesh)
            alive[k] = np.any(hit.reshape(probes.shape[:2]), axis=0)
    return alive


def _reaches_top(
    mesh: Mesh,
    R: np.ndarray,
    t: np.ndarray,
    p_world: np.ndarray,
    n_world: np.ndarray,
    cover_m: float = PAD_COVER_M,
) -> np.ndarray:
    """(n,) the surface is found ``cover_m`` above each contact (the pad's top edge; or up
    to :data:`PAD_DEPTHS_M` along the inward normal)."""
    up = np.array([0.0, 0.0, cover_m])
    probes = p_world[None] + up - PAD_DEPTHS_M[:, None, None] * n_world[None]  # (D, n, 3)
    normals = np.broadcast_to(n_world, probes.shape)
    hit = _supported((probes.reshape(-1, 3) - t) @ R, normals.reshape(-1, 3) @ R, mesh)
    return np.any(hit.reshape(probes.shape[:2]), axis=0)


def _distinct(
    idx: np.ndarray, pinch: np.ndarray, yaw: np.ndarray, cost: np.ndarray, limit: int
) -> np.ndarray:
    """The cheapest of ``idx`` per cell of 6 mm (pinch point) x 15 degrees (yaw), at most
    ``limit``, cheapest first (a vectorised non-maximum suppression)."""
    idx = idx[np.argsort(cost[idx], kind="stable")]
    cell = np.floor(pinch[idx] / 0.006).astype(np.int64)  # (k, 3)
    cell -= cell.min(axis=0)
    span = cell.max(axis=0) + 1
    turn = np.floor((yaw[idx] % (2 * math.pi)) / math.radians(15.0)).astype(np.int64)  # 0..23
    key = ((cell[:, 0] * span[1] + cell[:, 1]) * span[2] + cell[:, 2]) * 24 + turn
    _, first = np.unique(key, return_index=True)
    return idx[np.sort(first)][:limit]


def _by_wrist_turn(cands: list[GraspCandidate], preferred_yaw: float) -> list[GraspCandidate]:
    """Near-best candidates (within :data:`COST_TOLERANCE_M`) first, by least wrist turn."""
    if not cands:
        return cands
    best = min(c.cost for c in cands)

    def key(c: GraspCandidate) -> tuple[bool, float, float]:
        near = c.cost <= best + COST_TOLERANCE_M
        turn = abs(c.yaw_rad - preferred_yaw)
        return (not near, turn if near else c.cost, c.cost)

    return sorted(cands, key=key)


def plan_grasp(
    obj: ObjectModel,
    object_to_world: np.ndarray,
    action: GraspAction,
    *,
    table_z: float,
    preferred_yaw: float = 0.0,
    obstacles_world: np.ndarray | None = None,
    rng: np.random.Generator | None = None,
) -> GraspPlan | None:
    """The best synthesised grasp as an executable plan, or None when there is none."""
    cands = synthesize_grasps(obj, object_to_world, table_z=table_z, obstacles=obstacles_world,
                              rng=rng, preferred_yaw=preferred_yaw)  # fmt: skip
    return cands[0].plan(action) if cands else None
