"""Hypothesis generators of the localization engine (polyhedral and sphere models):

- :func:`vertex_hypotheses` — each detected vertex (three face normals) matched to each model
  corner fixes a pose; votes counted over the other vertexes in arrays, one quick batch score
  per distinct placement; with three or more vertexes the rotation-invariant 3-D Hough
  (section 2.2.1) adds its maxima;
- :func:`plane_pair_hypotheses` — pairs of detected planes matched to pairs of model faces
  (for when no vertex is seen), face extents checked for every pairing at once;
- :func:`support_face_hypotheses` — each support face of a polyhedral model on the sensed
  table plane, yaws from the footprint's principal axes and 8 fixed ones; all starts of a
  segment pre-scored in one batch, the best refined by ICP;
- :func:`sphere_centre_hough` — centres voted by ``p - r n`` for a sphere of known radius;
  :func:`score_spheres` refines seeds with :func:`fit_fixed_sphere` (IRLS Gauss-Newton,
  soft-L1) and checks the cap coverage.
"""

from __future__ import annotations

import functools
import itertools
import logging
import time
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from mks_sim.errors import DataError, MksError
from mks_sim.geometry.keypoints import unique_cells
from mks_sim.geometry.points import fibonacci_sphere
from mks_sim.geometry.transforms import cross3, make_transform, rotation_from_covariance
from mks_sim.lowlevel import _gridknn
from mks_sim.lowlevel._gridknn import column_mean
from mks_sim.lowlevel.grouping import Vertexes
from mks_sim.lowlevel.regions import Plane
from mks_sim.models.pose import PoseHypothesis
from mks_sim.models.refine import _compiled_available, batch_inlier_fractions

__all__ = [
    "fit_fixed_sphere",
    "plane_pair_hypotheses",
    "principal_angle",
    "rotation_about",
    "rotation_between",
    "score_spheres",
    "sphere_centre_hough",
    "stable_hull_normals",
    "support_face_hypotheses",
    "vertex_hypotheses",
]

log = logging.getLogger(__name__)
FloatArray = NDArray[np.float64]


def principal_angle(xy: FloatArray) -> float:
    c = xy - xy.mean(axis=0)
    w, v = np.linalg.eigh(c.T @ c)
    major = v[:, int(np.argmax(w))]
    return float(np.arctan2(major[1], major[0]))


def footprint_rectangle(xy: FloatArray) -> tuple[FloatArray, float, FloatArray]:
    """The minimum-area rectangle around (N >= 3, 2) points (OpenCV's rotating calipers on
    their hull): ``(centre (2,), direction of its first side in radians, (2,) the lengths of
    its first and second sides)``.

    A square's principal axes are any pair of directions (equal eigenvalues); its
    minimum-area rectangle is the square itself, so this gives the yaw and the centre of a
    footprint that PCA and the mean do not: a cube seen by the stereo pair as its top face
    and part of one side (tuning seed 5: support-face starts from the points' mean and
    principal axis converged 20 mm and 9-13 deg off; the rectangle's centre is the cube's).
    """
    import cv2

    origin = xy.mean(axis=0)
    (cx, cy), (w, h), deg = cv2.minAreaRect((xy - origin).astype(np.float32))
    return origin + np.array([cx, cy]), float(np.radians(deg)), np.array([w, h], dtype=float)


def _on_table(
    R: FloatArray, tr: FloatArray, moved: FloatArray, table: Plane, up: FloatArray
) -> PoseHypothesis:
    """The pose (R, tr) lowered or raised along ``up`` until the model (``moved`` = its
    points rotated by R) rests on the table plane."""
    tr = tr + up * (table.offset - float(np.min(moved @ up)))
    T = make_transform(R, tr)
    return PoseHypothesis(T, T[:3, 3].copy(), votes=0)


def _rectangle_placements(
    rotated: FloatArray,
    R0: FloatArray,
    seg_rect: tuple[FloatArray, float, FloatArray],
    up: FloatArray,
    min_spare: float,
) -> list[tuple[FloatArray, FloatArray]]:
    """(R, xy translation) placements of a model on a support face (``rotated``: its points
    rotated by ``R0``, the face down) whose footprint rectangle lines up with the segment's
    (:func:`footprint_rectangle`): the four quarter-turn yaws that align their sides, each
    with the rectangles' centres together and, when the model's footprint is larger than the
    seen one by ``min_spare`` or more, with each corner together (the seen footprint of a
    partly hidden object shares a corner with its whole one: the cube under the sphere)."""
    seg_centre, side, seg_wh = seg_rect
    _, model_side, _ = footprint_rectangle(rotated[:, :2])
    u = np.array([np.cos(side), np.sin(side)])
    v = np.array([-u[1], u[0]])
    c_seg = np.array([seg_centre @ u, seg_centre @ v])  # (u, v) frame
    out = []
    for k in range(4):
        Rz = rotation_about(up, side - model_side + k * np.pi / 2)
        xy = (rotated @ Rz.T)[:, :2]
        lo = np.array([np.min(xy @ u), np.min(xy @ v)])
        hi = np.array([np.max(xy @ u), np.max(xy @ v)])
        spare = np.maximum(0.5 * (hi - lo) - 0.5 * seg_wh, 0.0)
        corners = [(0, 0)]
        if np.max(spare) >= min_spare:
            corners += [(1, 1), (1, -1), (-1, 1), (-1, -1)]
        for su, sv in corners:
            shift = c_seg + np.array([su, sv]) * spare - 0.5 * (lo + hi)
            out.append((Rz @ R0, shift[0] * u + shift[1] * v))
    return out


def support_face_hypotheses(
    model: Any,
    segments: list[Any],
    table: Plane,
    band: float,
    d: float,
    rng: np.random.Generator,
    timing: dict[str, float],
) -> list[PoseHypothesis]:
    """Poses with a support face of the model on the table plane: all starts of a segment
    pre-scored in one batch, the best refined by ICP."""
    from mks_sim.models.refine import verify_hypotheses

    t = time.perf_counter()
    surface = model.surface
    pts = np.asarray(surface.points, dtype=np.float64)
    up = table.normal / np.linalg.norm(table.normal)
    normals = support_normals(model)
    out: list[PoseHypothesis] = []
    for seg in segments:
        # off the table's noise band (stereo noise near the table joins the segment)
        height = table.distance(seg.points)
        above = height > band
        seg_pts = seg.points[above]
        if len(seg_pts) < 30:
            continue
        if float(height[above].min()) > surface.size:
            # higher over the table than the model reaches: not resting on it (held in the
            # hand: the L-bracket lifted 10 cm was put back on the table by its support faces
            # and the grasp judged a slip, tuning seeds 1006, 1011, 1020, 1031)
            continue
        xy = seg_pts[:, :2] - seg_pts[:, :2].mean(axis=0)
        if 2.0 * float(np.percentile(np.linalg.norm(xy, axis=1), 98)) > 1.3 * surface.size:
            continue  # larger than the model: not one object of it
        starts: list[PoseHypothesis] = []
        seg_angle = principal_angle(seg_pts[:, :2])
        rect = footprint_rectangle(seg_pts[:, :2])
        for n in normals:
            R0 = rotation_between(n, -up)
            rotated = pts @ R0.T
            model_angle = principal_angle(rotated[:, :2])
            # yaws from the footprints' principal axes and 8 fixed ones (the axes may
            # mislead), the points' means aligned; then the footprint rectangles' placements
            for yaw in [seg_angle - model_angle + k * np.pi / 2 for k in range(4)] + [
                k * np.pi / 4 for k in range(8)
            ]:
                R = rotation_about(up, yaw) @ R0
                moved = pts @ R.T
                tr = np.zeros(3)
                tr[:2] = seg_pts[:, :2].mean(axis=0) - moved[:, :2].mean(axis=0)
                starts.append(_on_table(R, tr, moved, table, up))
            for R, tr_xy in _rectangle_placements(rotated, R0, rect, up, 2 * d):
                moved = pts @ R.T
                starts.append(_on_table(R, np.r_[tr_xy, 0.0], moved, table, up))
        if not starts:
            continue
        t_hyp = time.perf_counter()
        timing["hypotheses"] = timing.get("hypotheses", 0.0) + (t_hyp - t)
        verified = verify_hypotheses(
            starts,
            surface,
            seg_pts,
            inlier_distance=d,
            icp_distance=max(4 * d, 0.15 * surface.size),
            symmetries=model.symmetries(),
            max_icp=len(starts),
            prescreen=24,
            full_refine=4,
            max_scene_points=800,
            rng=rng,
        )
        t = time.perf_counter()
        timing["verification"] = timing.get("verification", 0.0) + (t - t_hyp)
        out.extend(v.hypothesis for v in verified)
    out.sort(key=lambda h: -h.score)
    return out


def support_normals(model: Any) -> list[FloatArray]:
    """Outward normals (model frame) of the faces a model can rest on: its faces with no
    model point beyond them, and the hull's planes whose polygon holds the centroid's
    projection (:func:`stable_hull_normals`)."""
    surface = model.surface
    pts = np.asarray(surface.points, dtype=np.float64)
    # the model's exact corners make the hull's planes exact (samples miss edges)
    corners = np.asarray(getattr(model, "vertexes", np.empty((0, 3))), dtype=np.float64)
    rests = stable_hull_normals(np.vstack([corners.reshape(-1, 3), pts]), centre=pts.mean(axis=0))
    normals = [
        np.asarray(face.normal, dtype=np.float64)
        for face in getattr(model, "faces", ())
        if np.max(pts @ face.normal) <= face.offset + 0.02 * surface.size
    ]  # support faces: no model points beyond them
    normals += [n for n in rests if all(n @ m < 0.999 for m in normals)]
    return normals


def rested_pose(
    matrix: FloatArray,
    model: Any,
    table: Plane,
    normals: Sequence[FloatArray],
    max_tilt_deg: float,
    max_gap: float,
) -> tuple[FloatArray, FloatArray] | None:
    """A pose's nearest resting pose on the table plane: ``(pose, face normal in the model
    frame)``, or None when no support face is within ``max_tilt_deg`` of facing the table or
    the model's lowest point is more than ``max_gap`` from it.

    The support face whose outward normal points nearest the table is turned to face it
    exactly, about the model's centre, and the model is set down on the plane; what the
    pose says of yaw and of the position along the table is kept."""
    T = np.asarray(matrix, dtype=np.float64)
    pts = np.asarray(model.surface.points, dtype=np.float64)
    up = table.normal / np.linalg.norm(table.normal)
    world = pts @ T[:3, :3].T + T[:3, 3]
    if abs(float(np.min(world @ up)) - table.offset) > max_gap or not len(normals):
        return None
    down = np.array([-(T[:3, :3] @ n) @ up for n in normals])  # cosines to facing the table
    k = int(np.argmax(down))
    if down[k] < np.cos(np.radians(max_tilt_deg)):
        return None
    Q = rotation_between(T[:3, :3] @ normals[k], -up)
    centre = T[:3, :3] @ column_mean(pts) + T[:3, 3]
    R = Q @ T[:3, :3]
    moved = pts @ R.T
    tr = Q @ (T[:3, 3] - centre) + centre
    tr = tr + up * (table.offset - float(np.min((moved + tr) @ up)))
    return make_transform(R, tr), np.asarray(normals[k], dtype=np.float64)


def stable_hull_normals(
    points: FloatArray,
    centre: FloatArray | None = None,
    min_area: float = 0.02,
    tol: float = 1e-3,
) -> list[FloatArray]:
    """Outward normals of the convex hull's planes of ``points`` (a model's corners and
    surface samples) that the object can rest on: planes of at least ``min_area`` of the
    hull's area onto whose polygon ``centre`` (default the points' mean) projects. Rests
    that are no face of the model (an L-bracket on its two leg ends) come from these."""
    from scipy.spatial import ConvexHull, Delaunay, QhullError

    pts = np.asarray(points, dtype=np.float64)
    try:
        hull = ConvexHull(pts)
    except (QhullError, ValueError):
        return []
    tri = pts[hull.simplices]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    keys = np.round(hull.equations[:, :3] / tol).astype(np.int64)
    _, group = np.unique(keys, axis=0, return_inverse=True)
    group = group.ravel()
    group_area = np.bincount(group, weights=area)
    centre = column_mean(pts) if centre is None else np.asarray(centre, dtype=np.float64)
    out: list[FloatArray] = []
    for g in np.flatnonzero(group_area >= min_area * area.sum()):
        rows = np.flatnonzero(group == g)
        n = hull.equations[rows[0], :3] / np.linalg.norm(hull.equations[rows[0], :3])
        corners = pts[np.unique(hull.simplices[rows])]
        # the plane's polygon and the projected centre in 2-D plane coordinates
        u = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
        u /= np.linalg.norm(u)
        v = np.cross(n, u)
        flat = np.stack([corners @ u, corners @ v], axis=1)
        try:
            inside = Delaunay(flat).find_simplex(np.array([centre @ u, centre @ v])) >= 0
        except QhullError:  # a sliver of a plane: no rest
            continue
        if inside:
            out.append(n)
    return out


def rotation_between(a: FloatArray, b: FloatArray) -> FloatArray:
    """Rotation taking unit vector ``a`` to unit vector ``b``."""
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    v = np.cross(a, b)
    c = float(a @ b)
    if np.linalg.norm(v) < 1e-9:
        if c > 0:
            return np.eye(3)
        axis = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
        return rotation_about(axis / np.linalg.norm(axis), np.pi)
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx / (1.0 + c)


def rotation_about(axis: FloatArray, angle: float) -> FloatArray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(np.asarray(axis, dtype=float) * angle).as_matrix()


class BallQueries:
    """The two questions the sphere fits ask of the object points, without a tree (compiled
    passes over the points: :func:`~mks_sim.lowlevel._gridknn.ball_rows`,
    :func:`~mks_sim.lowlevel._gridknn.space_any`): the points within a radius of a centre
    (the tree's rule, ascending indices) and whether a point lies within a distance of each
    query (``tree.query(...)[0] <= r``). The workstation's 4,300 object points: no 1.2 ms
    tree build, the same answers; the points come in another order than the tree's, so the
    fits' sums round in their own order."""

    def __init__(self, points: FloatArray) -> None:
        self.points = np.ascontiguousarray(points, dtype=np.float64)

    def query_ball_point(self, c: FloatArray, r: float) -> NDArray[np.intp]:
        return _gridknn.ball_rows(self.points, np.asarray(c, dtype=np.float64), r)

    def within(self, queries: FloatArray, r: float) -> NDArray[np.bool_]:
        # strictly within the next float up: within r, as the tree's distance <= r
        return _gridknn.space_any(self.points, queries, float(np.nextafter(r, np.inf)))


def score_spheres(
    objects: FloatArray,
    seeds: list[FloatArray],
    radius: float,
    d: float,
    *,
    tree: cKDTree | None = None,
) -> list[tuple[float, PoseHypothesis, dict[str, Any]]]:
    """Refine sphere centre seeds (fixed radius) and check each: cap coverage, residual.
    ``tree``: the k-d tree of ``objects`` when the caller has it; default: :class:`BallQueries`
    when numba imports, else a tree built here."""
    out: list[tuple[float, PoseHypothesis, dict[str, Any]]] = []
    if len(objects) < 20:
        return out
    index: cKDTree | BallQueries
    if tree is not None:
        index = tree
    elif _gridknn.available():
        index = BallQueries(objects)
    else:
        index = cKDTree(objects)
    cap = _upper_cap()
    for c0 in seeds:
        fit = fit_fixed_sphere(objects, index, np.asarray(c0, dtype=float), radius, d)
        if fit is None:
            continue
        c, rmse, n_in = fit
        if isinstance(index, BallQueries):
            covered = index.within(c + radius * cap, d)
        else:
            covered = index.query(c + radius * cap)[0] <= d
        coverage = float(np.mean(covered))
        inside = len(index.query_ball_point(c, r=max(radius - 2 * d, 0.0)))
        check = {
            "coverage": coverage,
            "explained": n_in,
            "inside": inside,
            "rmse_m": rmse,
            # a third of the cap may be hidden (resting on the cube, stereo gaps); fits to
            # other curved surfaces leave larger residuals
            "ok": bool(
                coverage >= 0.4
                and rmse <= 0.05 * radius
                and inside <= 0.05 * max(n_in, 1)
                and n_in >= 30
            ),
        }
        T = np.eye(4)
        T[:3, 3] = c
        h = PoseHypothesis(T, c.copy(), votes=n_in, rmse=rmse, score=coverage)
        out.append((coverage, h, check))
    return out


@functools.cache
def _upper_cap() -> FloatArray:
    """The directions of a sphere's cap seen from above (400 Fibonacci directions, z > 0.3),
    read-only, computed once (0.1 ms a call)."""
    cap = fibonacci_sphere(400)
    cap = np.ascontiguousarray(cap[cap[:, 2] > 0.3])
    cap.setflags(write=False)
    return cap


#: A sphere-centre Hough cell with fewer votes than this fraction of the fullest cell's is
#: no seed. Scene 2 healthy (tuning seeds 0-5): the sphere's cell held 350-700 votes, every
#: other peak at most 84, and all of those failed the fit's check (~1 ms each); with the
#: stereo pair's noisier normals the peaks spread (212, 165, 143, 86, ...) and stay seeds.
SPHERE_MIN_VOTE_FRACTION = 0.25


def sphere_centre_hough(
    objects: FloatArray,
    radius: float,
    normals: FloatArray,
    peaks: int = 4,
    min_fraction: float = SPHERE_MIN_VOTE_FRACTION,
) -> list[FloatArray]:
    """Centres voted by ``p - r n`` (outward normals of the representation), the fullest
    cells (at least 10 votes and ``min_fraction`` of the fullest cell's)."""
    if len(objects) < 50:
        return []
    votes = objects - radius * normals
    cell = radius / 5.0
    # the cells in lexicographic order (ties among peaks as np.unique of the rows breaks them)
    _, inv, counts = unique_cells(np.floor(votes / cell).astype(np.int64), first=False)
    floor = max(10.0, min_fraction * float(counts.max())) if len(counts) else 10.0
    out: list[FloatArray] = []
    for k in np.argsort(-counts)[: peaks * 3]:
        if counts[k] < floor or len(out) >= peaks:
            break
        c = votes[inv == k].mean(axis=0)
        if all(np.linalg.norm(c - o) > radius / 2 for o in out):
            out.append(c)
    return out


_DIAG3 = np.diag_indices(3)


#: Shell points from which the sphere fit's iterations run compiled (numba).
SPHERE_COMPILED_MIN_POINTS = 32


def fit_fixed_sphere(
    objects: FloatArray,
    tree: cKDTree | BallQueries,
    c0: FloatArray,
    radius: float,
    d: float,
    *,
    compiled: bool | None = None,
) -> tuple[FloatArray, float, int] | None:
    """Centre of a sphere of known radius fitted robustly to the points near ``c0``'s shell.

    ``compiled``: the Gauss-Newton iterations of each shell in one numba call
    (:mod:`mks_sim.localization._hypotheses_kernels`, the same arithmetic summed in another
    order) or in numpy; None: compiled from :data:`SPHERE_COMPILED_MIN_POINTS` shell points
    when numba imports."""
    if compiled is None:
        compiled = _compiled_available()
    c = np.asarray(c0, dtype=np.float64).copy()
    band = max(3.0 * d, 0.15 * radius)
    f_scale = max(d / 3.0, 1e-4)
    for _ in range(4):
        idx = tree.query_ball_point(c, r=radius + band)
        if len(idx) < 20:
            return None
        pts = objects[idx]
        diff = pts - c
        shell = np.abs(np.sqrt(np.einsum("ij,ij->i", diff, diff)) - radius) < band
        pts = pts[shell]
        if len(pts) < 20:
            return None
        start = c.copy()
        # Gauss-Newton with soft-L1 (IRLS) weights on r_i = |p_i - c| - R; a micrometre step
        # ends it (fits to other surfaces oscillate below that and are rejected later)
        if compiled and len(pts) >= SPHERE_COMPILED_MIN_POINTS:
            from mks_sim.localization._hypotheses_kernels import sphere_gauss_newton

            c = sphere_gauss_newton(np.ascontiguousarray(pts), c, radius, f_scale, 20)
        else:
            for _ in range(20):
                diff = pts - c
                dist = np.maximum(np.sqrt(np.einsum("ij,ij->i", diff, diff)), 1e-12)
                u = diff / dist[:, None]
                r = dist - radius
                w = 1.0 / np.sqrt(1.0 + (r / f_scale) ** 2)
                wu = u * w[:, None]
                H = wu.T @ u
                H[_DIAG3] += 1e-12
                delta = np.linalg.solve(H, wu.T @ r)
                c = c + delta
                if float(np.sqrt(delta @ delta)) < 1e-6:
                    break
        step = float(np.linalg.norm(c - start))
        band = max(1.5 * d, 0.5 * band)
        if step < 1e-5:
            break
    q = objects[tree.query_ball_point(c, r=radius + d)] - c
    r = np.sqrt(np.einsum("ij,ij->i", q, q)) - radius
    inl = np.abs(r) <= d
    if inl.sum() < 20:
        return None
    return c, float(np.sqrt(np.mean(r[inl] ** 2))), int(inl.sum())


# ----------------------------------------------------- vertex, plane-pair, rotation-invariant


def vertex_hypotheses(
    model: Any,
    detected: Vertexes,
    scene_points: FloatArray,
    *,
    vote_distance: float,
    max_angle_deg: float = 20.0,
    keep: int = 100,
    rotinv: bool = True,
    corners: bool = True,
    compiled: bool = False,
) -> list[PoseHypothesis]:
    """Pose hypotheses from matching detected vertexes (with face normals) to model corners.

    Each (detected vertex, model corner, assignment of three of the corner's face normals to
    the vertex's three face normals) whose angles agree gives a rotation (normals aligned) and
    a translation (vertex onto corner). Votes: the detected vertexes that some transformed
    model corner lands within ``vote_distance`` of. With three or more detected vertexes the
    rotation-invariant Hough (section 2.2.1) adds its maxima when that matcher is available.

    Args:
        rotinv: add the rotation-invariant Hough's maxima (the workstation runs that matcher
            on its model's logical sensor instead).
        corners: the hypotheses of each vertex's face normals matched to the model's
            corners (False with ``rotinv``: the rotation-invariant Hough's alone).
        compiled: those corner hypotheses in one compiled pass when numba imports
            (:func:`mks_sim.models._refine_kernels.vertex_poses`: the same tests in the same
            order; the rotations' and the products' rounding may differ: ``localize_cloud``
            and the workstation ask for it).

    Returns:
        At most ``keep`` hypotheses, most voted first (ties: better quick inlier fraction).
    """
    if len(detected) == 0:
        return []
    cpts = model.vertexes
    out: list[tuple[int, FloatArray, NDArray[np.int64]]] = []
    c_point, c_normals = model.corner_triples  # (K, 3), (K, 3, 3): every ordered triple
    c_gram = np.einsum("kij,klj->kil", c_normals, c_normals)  # (K, 3, 3)
    cos_max = np.cos(np.radians(max_angle_deg))
    if corners and compiled and _gridknn.available():
        from mks_sim.models._refine_kernels import vertex_poses

        votes_c, mats_c, match_c = vertex_poses(
            np.ascontiguousarray(detected.points, dtype=np.float64),
            np.ascontiguousarray(detected.normals, dtype=np.float64),
            np.ascontiguousarray(c_point), np.ascontiguousarray(c_normals),
            np.ascontiguousarray(c_gram), np.ascontiguousarray(cpts, dtype=np.float64),
            float(cos_max), float(vote_distance),
        )  # fmt: skip
        if not rotinv:  # the corners' poses alone: ranked as arrays
            return _ranked_corner_poses(
                model, votes_c, mats_c, match_c, len(detected), scene_points, vote_distance, keep
            )
        out.extend(zip(votes_c.tolist(), mats_c, match_c, strict=True))
    elif corners:
        det_tree = cKDTree(detected.points)
        for di in range(len(detected)):
            Nd = detected.normals[di]
            sel = np.flatnonzero(np.abs(c_gram - Nd @ Nd.T).max(axis=(1, 2)) <= 0.35)
            if sel.size == 0:
                continue
            M = c_normals[sel]  # (K', 3, 3) rows = model normals
            # Batched Kabsch: R m_i ~ n_i.
            R = rotation_from_covariance(np.matmul(np.transpose(M, (0, 2, 1)), Nd))  # (K', 3, 3)
            # worst normal agreement: min over m of (R_k m_m) . n_m (matmul; einsum is slower)
            cos = (np.matmul(M, np.transpose(R, (0, 2, 1))) * Nd[None]).sum(axis=2).min(axis=1)
            good = cos >= cos_max
            R, kept = R[good], sel[good]
            t = detected.points[di] - np.matmul(R, c_point[kept][:, :, None])[:, :, 0]  # (K'', 3)
            moved = np.matmul(cpts[None], np.transpose(R, (0, 2, 1))) + t[:, None, :]  # (K'', V, 3)
            _, j = det_tree.query(moved.reshape(-1, 3), distance_upper_bound=vote_distance)
            j = j.reshape(len(R), -1)  # (K'', V) detected vertex of each model corner (n: none)
            # votes: distinct detected vertexes hit, per hypothesis (sorted rows, no loop)
            js = np.sort(j, axis=1)
            n_det = len(detected)
            votes = (js[:, 0] < n_det).astype(np.intp)
            votes += ((js[:, 1:] != js[:, :-1]) & (js[:, 1:] < n_det)).sum(axis=1)
            T = np.zeros((len(R), 4, 4))  # [[R, t], [0, 0, 0, 1]] for all of them at once
            T[:, :3, :3] = R
            T[:, :3, 3] = t
            T[:, 3, 3] = 1.0
            out.extend(zip(votes.tolist(), T, j, strict=True))
    if rotinv:
        out.extend(_rotinv_hypotheses(model, detected, vote_distance))
    if not out:
        return []
    # Rank by votes; break ties among the first ``keep`` by a quick inlier fraction.
    top = sorted(out, key=lambda o: -o[0])[:keep]
    rows = [k for k, o in enumerate(top) if o[2].ndim == 1]
    votes = np.array([o[0] for o in top], dtype=np.int64)
    mats = np.stack([o[1] for o in top])
    if len(rows) == len(top):  # every pose a corner's
        match = np.stack([o[2] for o in top])
        return _ranked_corner_poses(
            model, votes, mats, match, len(detected), scene_points, vote_distance, keep
        )
    order, refs = _quick_order(model, votes, mats, scene_points, vote_distance)
    corr: dict[int, NDArray[np.int64]] = {}
    if rows:
        found = _corner_correspondences(np.stack([top[k][2] for k in rows]), len(detected))
        corr = dict(zip(rows, found, strict=True))
    return PoseHypothesis.many(
        mats[order], refs[order], votes[order].tolist(),
        [corr.get(k, top[k][2]) for k in order.tolist()],
    )  # fmt: skip


def _quick_order(
    model: Any,
    votes: NDArray[np.int64],
    mats: FloatArray,
    scene_points: FloatArray,
    vote_distance: float,
) -> tuple[NDArray[np.intp], FloatArray]:
    """The order of K poses sorted by ``votes`` (most first) and, among equal votes, by a
    quick inlier fraction on about 100 of the scene points (a stable sort: full ties keep
    their order), and the (K, 3) model reference point under each pose."""
    sub = scene_points[:: max(1, len(scene_points) // 100)]
    # one quick score per distinct placement (poses equal up to a model symmetry share it)
    first, inverse = _distinct_placements(mats, model.symmetries(), vote_distance / 2)
    quick = batch_inlier_fractions(model.surface, sub, mats[first], vote_distance / 2)[inverse]
    order = np.lexsort((-quick, -votes))
    ref = model.vertexes.mean(axis=0)
    refs = np.einsum("kij,j->ki", mats[:, :3, :3], ref) + mats[:, :3, 3]  # (K, 3)
    return order, refs


def _ranked_corner_poses(
    model: Any,
    votes: NDArray[np.int64],
    mats: FloatArray,
    match: NDArray[np.int64],
    n_detected: int,
    scene_points: FloatArray,
    vote_distance: float,
    keep: int,
) -> list[PoseHypothesis]:
    """:func:`vertex_hypotheses`' ranking of corner poses on their arrays (``votes`` (H,),
    ``mats`` (H, 4, 4), ``match`` (H, V): the detected vertex each model corner landed on):
    the most voted ``keep`` (a stable sort) in :func:`_quick_order`, their corner pairs in
    one array (the hypotheses' correspondences are views of it). The compiled matcher's
    poses come here without a Python tuple, sort key or stack per pose (the cube's
    localization, three segments: 2.9 -> 2.3 ms)."""
    if len(votes) == 0:
        return []
    top = np.argsort(-votes, kind="stable")[:keep]
    votes, mats, match = votes[top], mats[top], match[top]
    order, refs = _quick_order(model, votes, mats, scene_points, vote_distance)
    pairs, counts = _corner_pairs(match, n_detected)
    starts = np.cumsum(counts) - counts
    counts = counts[order]
    take = np.repeat(starts[order] - (np.cumsum(counts) - counts), counts)
    take += np.arange(len(take))
    return PoseHypothesis.many(mats[order], refs[order], votes[order].tolist(), pairs[take], counts)


def _distinct_placements(
    matrices: FloatArray,
    symmetries: FloatArray | None,
    tolerance: float,
    compiled: bool | None = None,
) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Poses that are the same placement up to a model symmetry, grouped in arrays: each
    rotation is replaced by its symmetric image closest to a fixed generic rotation, then
    rotations (to 0.01) and translations (to ``tolerance``) are rounded and compared.

    ``compiled``: the symmetric images in one compiled pass
    (:func:`~mks_sim.localization._hypotheses_kernels.canonical_rotations`, the same values)
    or numpy's einsums; None: compiled when numba imports.

    Returns:
        (first index of each group, (K,) group of each pose); poses near a rounding boundary
        may stay apart (harmless: they are then scored twice).
    """
    R = matrices[:, :3, :3]
    if symmetries is not None and len(symmetries):
        S = np.concatenate([np.eye(3)[None], np.asarray(symmetries, dtype=np.float64)])
        if compiled is None:
            compiled = _gridknn.available()
        if compiled:  # (the same images, one compiled pass)
            from mks_sim.localization._hypotheses_kernels import canonical_rotations

            R = canonical_rotations(np.ascontiguousarray(R), S, _GENERIC_ROTATION)
        else:
            RS = np.einsum("kij,sjl->ksil", R, S)  # (K, S, 3, 3)
            best = np.einsum("ksij,ij->ks", RS, _GENERIC_ROTATION).argmax(axis=1)
            R = RS[np.arange(len(R)), best]
    key = np.concatenate(
        [np.round(R.reshape(len(R), 9) / 0.01), np.round(matrices[:, :3, 3] / tolerance)], axis=1
    ).astype(np.int64)  # whole numbers (and -0 is 0)
    # equal rows by a dict of their bytes (a hundred rows: np.unique(axis=0) sorts them as
    # records, ~10x slower); groups numbered in order of first appearance
    group: dict[bytes, int] = {}
    inverse = np.fromiter(
        (group.setdefault(row.tobytes(), len(group)) for row in key), dtype=np.intp, count=len(key)
    )
    first = np.full(len(group), len(key), dtype=np.intp)
    np.minimum.at(first, inverse, np.arange(len(key)))
    return first, inverse


#: A fixed rotation in general position (canonical symmetric images in _distinct_placements).
_GENERIC_ROTATION = np.array(
    [[0.36, 0.48, -0.80], [-0.80, 0.60, 0.00], [0.48, 0.64, 0.60]], dtype=np.float64
)


def _corner_correspondences(j: NDArray[np.intp], n_detected: int) -> list[NDArray[np.int64]]:
    """Per row of ``j`` (K, V) -- the detected vertex each model corner landed on
    (``n_detected``: none) -- the (C, 2) (detected vertex, model corner) pairs, the first
    corner per detected vertex, ordered by detected vertex (all rows in a few array calls)."""
    pairs, counts = _corner_pairs(j, n_detected)
    return np.split(pairs, np.cumsum(counts)[:-1])


def _corner_pairs(
    j: NDArray[np.intp], n_detected: int
) -> tuple[NDArray[np.int64], NDArray[np.intp]]:
    """:func:`_corner_correspondences`' pairs of all the rows one after another, and the
    (K,) count of each row's."""
    n_rows, n_corners = j.shape
    first = np.full((n_rows, n_detected + 1), n_corners, dtype=np.int64)
    rows = np.arange(n_rows)
    for v in range(n_corners - 1, -1, -1):  # the last write, the first corner, wins
        first[rows, np.minimum(j[:, v], n_detected)] = v
    r, dv = np.nonzero(first[:, :n_detected] < n_corners)
    pairs = np.column_stack([dv, first[r, dv]]).astype(np.int64)
    return pairs, np.bincount(r, minlength=n_rows)


def _frame(a: FloatArray, b: FloatArray) -> FloatArray:
    """(3, 3) orthonormal frame (columns) from two non-parallel directions."""
    e1 = a / np.linalg.norm(a)
    e3 = cross3(a, b)
    norm = np.linalg.norm(e3)
    if norm < 1e-9:  # callers filter near-parallel pairs; never divide by zero into NaN frames
        raise DataError(f"_frame: directions {a} and {b} are parallel")
    e3 /= norm
    return np.column_stack([e1, cross3(e3, e1), e3])


def plane_pair_hypotheses(
    model: Any,
    planes: Sequence[tuple[Plane, FloatArray | None]],
    scene_points: FloatArray,
    *,
    inlier_distance: float,
    max_angle_deg: float = 8.0,
    keep: int = 40,
    compiled: bool = False,
) -> list[PoseHypothesis]:
    """Pose hypotheses from pairs of detected planes matched to pairs of model faces.

    For when fewer than one vertex is visible (e.g. one wall and the top of a part on a
    table). Two non-parallel planes fix the rotation and two components of the translation;
    the third (along their intersection line) centres the first plane's observed extent on
    the model face's extent. Face extents must not be exceeded by the observed region.

    Args:
        model: the model (its large faces).
        planes: detected planes with their points ((n, 3)) or None for a plane not sampled by
            the data (the table: it is never the first of a pair).
        scene_points: (N, 3) segment points (for a quick inlier ranking).
        inlier_distance: ranking inlier distance.
        max_angle_deg: tolerance on the angle between the two normals.
        keep: hypotheses returned (best quick inlier fraction first).
        compiled: the poses in one compiled pass when numba imports
            (:func:`mks_sim.models._refine_kernels.plane_pair_poses`: the same tests, in the
            same order; the rounding of the products may differ: ``localize_cloud`` and the
            workstation ask for it).
    """
    sub = scene_points[:: max(1, len(scene_points) // 80)]
    extremes, offsets = model.face_extremes
    pa, pb, pcos, pframes = model.face_pairs
    cos_tol = np.sin(np.radians(max_angle_deg))
    slack = 4 * inlier_distance
    if compiled and planes and len(pa) and _gridknn.available():
        from mks_sim.models._refine_kernels import plane_pair_poses

        sampled = np.array([pts is not None for _, pts in planes], dtype=bool)
        chunks = [np.zeros((0, 3)) if p is None else np.asarray(p, np.float64) for _, p in planes]
        starts = np.zeros(len(planes) + 1, dtype=np.int64)
        np.cumsum([len(c) for c in chunks], out=starts[1:])
        Ts = plane_pair_poses(
            np.array([P.normal for P, _ in planes], dtype=np.float64),
            np.array([P.offset for P, _ in planes], dtype=np.float64),
            starts, sampled, np.ascontiguousarray(np.concatenate(chunks)),
            np.ascontiguousarray(extremes), offsets, np.asarray(pa, np.int64),
            np.asarray(pb, np.int64), np.asarray(pcos, np.float64),
            np.ascontiguousarray(pframes, dtype=np.float64), float(cos_tol), float(slack),
        )  # fmt: skip
        out = [(0.0, T) for T in Ts]
    else:
        poses = _plane_pair_poses(planes, extremes, offsets, model.face_pairs, cos_tol, slack)
        out = [(0.0, T) for T in poses]
    if out:
        quick = batch_inlier_fractions(
            model.surface, sub, np.stack([o[1] for o in out]), inlier_distance
        )
        out = [(float(q), o[1]) for q, o in zip(quick, out)]
    out.sort(key=lambda o: -o[0])
    ref = model.vertexes.mean(axis=0)
    top = [T for _, T in out[:keep]]
    if not top:
        return []
    refs = np.stack([T[:3, :3] @ ref + T[:3, 3] for T in top])  # (each as before)
    none = np.zeros((0, 2), dtype=np.int64)
    return PoseHypothesis.many(np.stack(top), refs, [0] * len(top), [none] * len(top))


def _plane_pair_poses(
    planes: Sequence[tuple[Plane, FloatArray | None]],
    extremes: FloatArray,
    offsets: FloatArray,
    face_pairs: tuple[NDArray[np.intp], NDArray[np.intp], FloatArray, FloatArray],
    cos_tol: float,
    slack: float,
) -> list[FloatArray]:
    """The poses of :func:`plane_pair_hypotheses` by numpy, pair by pair."""
    pa, pb, pcos, pframes = face_pairs
    out: list[FloatArray] = []
    for (P, p_pts), (Q, q_pts) in itertools.permutations(planes, 2):
        if p_pts is None:
            continue
        cpq = float(P.normal @ Q.normal)
        if abs(cpq) > 0.9:
            continue
        frame_s = _frame(P.normal, Q.normal)
        e, f_dir = frame_s[:, 2], frame_s[:, 1]
        pe, pf = p_pts @ e, p_pts @ f_dir
        sel = np.flatnonzero(np.abs(pcos - cpq) <= cos_tol)
        if sel.size == 0:
            continue
        Rs = np.einsum("ij,kjl->kil", frame_s, np.transpose(pframes[sel], (0, 2, 1)))
        # face extents along the scene directions, every candidate pairing at once
        A_ex, B_ex = extremes[pa[sel]], extremes[pb[sel]]  # (K, E, 3)
        ae = np.einsum("kpi,kji,j->kp", A_ex, Rs, e)  # A.points @ (R^T e)
        af = np.einsum("kpi,kji,j->kp", A_ex, Rs, f_dir)
        ok = (np.ptp(pe) <= np.ptp(ae, axis=1) + slack) & (np.ptp(pf) <= np.ptp(af, axis=1) + slack)
        if q_pts is not None:
            g = cross3(Q.normal, e)  # Q's in-plane direction across the shared edge
            qe, qg = q_pts @ e, q_pts @ g
            be = np.einsum("kpi,kji,j->kp", B_ex, Rs, e)
            bg = np.einsum("kpi,kji,j->kp", B_ex, Rs, g)
            ok &= (np.ptp(qe) <= np.ptp(be, axis=1) + slack) & (
                np.ptp(qg) <= np.ptp(bg, axis=1) + slack
            )
        if not ok.any():
            continue
        lhs = np.stack([P.normal, Q.normal, e])
        try:
            lhs_inv = np.linalg.inv(lhs)
        except np.linalg.LinAlgError:
            continue
        mid_s = (pe.max() + pe.min()) / 2
        mid_m = (ae.max(axis=1) + ae.min(axis=1)) / 2
        rhs = np.stack(
            [P.offset - offsets[pa[sel]], Q.offset - offsets[pb[sel]], mid_s - mid_m], axis=1
        )
        t = rhs @ lhs_inv.T  # (K, 3)
        ok &= np.all(np.isfinite(t), axis=1) & np.all(np.isfinite(Rs), axis=(1, 2))
        idx = np.flatnonzero(ok)
        Ts = np.zeros((len(idx), 4, 4))  # make_transform's matrices, all at once
        Ts[:, :3, :3] = Rs[idx]
        Ts[:, :3, 3] = t[idx]
        Ts[:, 3, 3] = 1.0
        out.extend(Ts)
    return out


def _rotinv_hypotheses(
    model: Any, detected: Vertexes, vote_distance: float, max_points: int = 6
) -> list[tuple[int, FloatArray, NDArray[np.int64]]]:
    """Maxima of the rotation-invariant 3-D Hough (section 2.2.1) over the detected vertexes
    (the ``max_points`` best supported: its cost grows with the cube of their number)."""
    if len(detected) < 3:
        return []
    try:
        from mks_sim.models.rotinv import RotationInvariantHough
    except ImportError:  # pragma: no cover - part of the package
        return []
    order = np.argsort(detected.support, kind="stable")[:max_points]
    try:
        hough = RotationInvariantHough(model.vertexes, tolerance=vote_distance / 2)
        found = hough.detect(detected.points[order])
    except MksError as exc:
        log.debug("rotation-invariant Hough gave nothing: %s", exc)
        return []
    out = []
    for h in found:
        corr = np.asarray(h.correspondences, dtype=np.int64).reshape(-1, 2).copy()
        corr[:, 0] = order[corr[:, 0]]  # back to indices into ``detected``
        out.append((int(h.votes), np.asarray(h.matrix, dtype=np.float64), corr))
    return out
