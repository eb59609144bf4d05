"""Hypothesis generators of the workstation flow beyond the vertex and plane-pair votes of
:mod:`mks_sim.localize` (``vertex_hypotheses``, ``plane_pair_hypotheses``) and the
rotation-invariant Hough of the models' logical sensors:

- :func:`support_face_hypotheses` — each support face of a polyhedral model on the sensed
  table plane, yaws from the footprint's principal axes and 8 fixed ones; all starts of a
  segment pre-scored in one batch, the best refined by ICP;
- :func:`sphere_centre_hough` — centres voted by ``p - r n`` for a sphere of known radius;
  :func:`score_spheres` refines seeds with :func:`fit_fixed_sphere` (IRLS Gauss-Newton,
  soft-L1) and checks the cap coverage.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from mks_sim.geometry.points import fibonacci_sphere
from mks_sim.lowlevel.regions import Plane
from mks_sim.models.pose import PoseHypothesis

__all__ = [
    "fit_fixed_sphere",
    "principal_angle",
    "rotation_about",
    "rotation_between",
    "score_spheres",
    "sphere_centre_hough",
    "support_face_hypotheses",
]

FloatArray = NDArray[np.float64]


def principal_angle(xy: FloatArray) -> float:
    c = xy - xy.mean(axis=0)
    w, v = np.linalg.eigh(c.T @ c)
    major = v[:, int(np.argmax(w))]
    return float(np.arctan2(major[1], major[0]))


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
    from mks_sim.geometry.transforms import make_transform
    from mks_sim.models.refine import verify_hypotheses

    t = time.perf_counter()
    faces = getattr(model, "faces", ())
    surface = model.surface
    pts = np.asarray(surface.points, dtype=np.float64)
    up = table.normal / np.linalg.norm(table.normal)
    out: list[PoseHypothesis] = []
    for seg in segments:
        # off the table's noise band (stereo noise near the table joins the segment)
        seg_pts = seg.points[table.distance(seg.points) > band]
        if len(seg_pts) < 30:
            continue
        xy = seg_pts[:, :2] - seg_pts[:, :2].mean(axis=0)
        if 2.0 * float(np.percentile(np.linalg.norm(xy, axis=1), 98)) > 1.3 * surface.size:
            continue  # larger than the model: not one object of it
        starts: list[PoseHypothesis] = []
        seg_angle = principal_angle(seg_pts[:, :2])
        for face in faces:
            n = np.asarray(face.normal, dtype=np.float64)
            if np.max(pts @ n) > face.offset + 0.02 * surface.size:
                continue  # not a support face (model points beyond it)
            R0 = rotation_between(n, -up)
            rotated = pts @ R0.T
            model_angle = principal_angle(rotated[:, :2])
            yaws = [seg_angle - model_angle + k * np.pi / 2 for k in range(4)]
            yaws += [k * np.pi / 4 for k in range(8)]  # the footprint axis may mislead
            for yaw in yaws:
                R = rotation_about(up, yaw) @ R0
                moved = pts @ R.T
                tr = np.zeros(3)
                tr[:2] = seg_pts[:, :2].mean(axis=0) - moved[:, :2].mean(axis=0)
                # the support face on the table plane
                tr += up * (table.offset - float(np.min(moved @ up)))
                T = make_transform(R, tr)
                starts.append(PoseHypothesis(T, T[:3, 3].copy(), votes=0))
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


def score_spheres(
    objects: FloatArray, seeds: list[FloatArray], radius: float, d: float
) -> list[tuple[float, PoseHypothesis, dict[str, Any]]]:
    """Refine sphere centre seeds (fixed radius) and check each: cap coverage, residual."""
    out: list[tuple[float, PoseHypothesis, dict[str, Any]]] = []
    if len(objects) < 20:
        return out
    tree = cKDTree(objects)
    cap = fibonacci_sphere(400)
    cap = cap[cap[:, 2] > 0.3]
    for c0 in seeds:
        fit = fit_fixed_sphere(objects, tree, np.asarray(c0, dtype=float), radius, d)
        if fit is None:
            continue
        c, rmse, n_in = fit
        near_d = tree.query(c + radius * cap)[0]
        coverage = float(np.mean(near_d <= d))
        inside = len(tree.query_ball_point(c, r=max(radius - 2 * d, 0.0)))
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


def sphere_centre_hough(
    objects: FloatArray, radius: float, normals: FloatArray, peaks: int = 4
) -> list[FloatArray]:
    """Centres voted by ``p - r n`` (outward normals of the representation), the fullest
    cells."""
    if len(objects) < 50:
        return []
    votes = objects - radius * normals
    cell = radius / 5.0
    keys = np.floor(votes / cell).astype(np.int64)
    uniq, inv, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    inv = inv.reshape(-1)
    out: list[FloatArray] = []
    for k in np.argsort(-counts)[: peaks * 3]:
        if counts[k] < 10 or len(out) >= peaks:
            break
        c = votes[inv == k].mean(axis=0)
        if all(np.linalg.norm(c - o) > radius / 2 for o in out):
            out.append(c)
    return out


_DIAG3 = np.diag_indices(3)


def fit_fixed_sphere(
    objects: FloatArray, tree: cKDTree, c0: FloatArray, radius: float, d: float
) -> tuple[FloatArray, float, int] | None:
    """Centre of a sphere of known radius fitted robustly to the points near ``c0``'s shell."""
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
