"""Synthetic scans: ray casting checked against analytic ray-box and ray-sphere intersection."""

from __future__ import annotations

import numpy as np
import pytest

from mks_sim.errors import DataError
from mks_sim.geometry.meshes import box_mesh, icosphere, industrial_part_mesh
from mks_sim.geometry.scan import camera_rays, scan_scene, synthetic_scan, synthetic_scan_organized


def _pose(rng: np.random.Generator, t: np.ndarray) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] *= -1
    tf = np.eye(4)
    tf[:3, :3] = q
    tf[:3, 3] = t
    return tf


def _slab_hits(eye, dirs, tf, half):
    """Analytic ray / oriented-box intersection: nearest t per ray (inf if none)."""
    r = tf[:3, :3]
    o = (eye - tf[:3, 3]) @ r
    d = dirs.reshape(-1, 3) @ r
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (-half - o) / d
        t2 = (half - o) / d
    tmin = np.nanmax(np.minimum(t1, t2), axis=1)
    tmax = np.nanmin(np.maximum(t1, t2), axis=1)
    hit = (tmax >= tmin) & (tmax > 0)
    return np.where(hit, tmin, np.inf).reshape(dirs.shape[:2])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_box_scan_matches_slab_method(seed: int) -> None:
    rng = np.random.default_rng(seed)
    size = np.array([0.08, 0.05, 0.03])
    tf = _pose(rng, rng.uniform(-0.02, 0.02, 3))
    eye = np.array([0.15, -0.1, 0.25])
    res = scan_scene(box_mesh(size), tf, eye, [0, 0, 0], width=64, height=48, fov_deg=40)
    dirs, _, _ = camera_rays(eye, [0, 0, 0], 64, 48, 40)
    t_ref = _slab_hits(eye, dirs, tf, size / 2)
    hit_ref = np.isfinite(t_ref)
    hit = res.mesh_index >= 0
    # Pixels exactly on a silhouette edge may go either way.
    assert np.mean(hit != hit_ref) < 0.005
    both = hit & hit_ref
    np.testing.assert_allclose(res.range_m[both], t_ref[both], atol=1e-9)
    assert np.all(np.isnan(res.organized[~hit]))


def test_sphere_scan_on_surface_and_silhouette() -> None:
    radius = 0.05
    eye = np.array([0.0, 0.0, 0.4])
    pts = synthetic_scan(icosphere(radius, 4), np.eye(4), eye, [0, 0, 0], 100, 100, 30)
    d = np.linalg.norm(pts, axis=1)
    assert np.all(d <= radius + 1e-12) and np.all(d > radius * 0.995)
    # Visible cap only: every point faces the camera.
    assert np.all(np.einsum("ij,ij->i", pts, eye - pts) > -1e-9)
    # Pixel count = the analytic silhouette (a disk of angular radius asin(r / 0.4)).
    dirs, _, _ = camera_rays(eye, [0, 0, 0], 100, 100, 30)
    ang = np.arccos(np.clip(-dirs[..., 2], -1, 1))
    expected = np.sum(ang < np.arcsin(radius / 0.4))
    assert len(pts) == pytest.approx(expected, rel=0.03)


def test_clutter_occludes_and_labels() -> None:
    part = industrial_part_mesh()
    table = box_mesh((1.0, 1.0, 0.02))
    table_tf = np.eye(4)
    table_tf[2, 3] = -0.01
    blocker_tf = np.eye(4)
    blocker_tf[:3, 3] = [0.0, 0.0, 0.15]  # a plate between camera and part
    eye = [0.0, 0.0, 0.5]
    res = scan_scene(
        part,
        np.eye(4),
        eye,
        [0, 0, 0],
        width=80,
        height=60,
        extra=[(table, table_tf), (box_mesh((0.03, 0.2, 0.005)), blocker_tf)],
    )
    labels = res.labels
    assert set(np.unique(labels)) == {0, 1, 2}
    part_pts = res.points[labels == 0]
    assert np.all(part_pts[:, 2] > -1e-9) and np.all(part_pts[:, 2] < 0.03 + 1e-9)
    # Nothing of the part is seen through the blocker's shadow strip |x| < 0.015 * 0.5/0.35.
    assert not np.any(np.abs(part_pts[:, 0]) < 0.015 * (0.5 - 0.03) / (0.5 - 0.1525) - 1e-3)
    assert np.all(res.points[labels == 1][:, 2] == pytest.approx(0.0, abs=1e-9))


def test_noise_and_organized_shape() -> None:
    eye = [0.0, 0.0, 0.3]
    clean = synthetic_scan_organized(box_mesh(0.1), np.eye(4), eye, [0, 0, 0], 40, 30, 30)
    noisy = synthetic_scan_organized(
        box_mesh(0.1), np.eye(4), eye, [0, 0, 0], 40, 30, 30, 0.001, np.random.default_rng(0)
    )
    assert clean.shape == (30, 40, 3)
    ok = ~np.isnan(clean[..., 0])
    dev = np.linalg.norm(noisy[ok] - clean[ok], axis=1)
    assert dev.std() == pytest.approx(0.001 * np.sqrt(1 - 2 / np.pi), rel=0.15)


def test_bad_arguments() -> None:
    with pytest.raises(DataError, match="coincide"):
        synthetic_scan(box_mesh(1), np.eye(4), [0, 0, 0], [0, 0, 0])
    with pytest.raises(DataError, match=r"\(4, 4\)"):
        synthetic_scan(box_mesh(1), np.eye(3), [0, 0, 1], [0, 0, 0])
