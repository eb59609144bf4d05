"""The scene-consistency check (mks_sim.localization.verify.consistency) against a brute-force
count: every sensed point near the posed model compared with every model sample."""

from __future__ import annotations

import numpy as np
import pytest

from mks_sim.geometry.meshes import box_mesh, sample_surface
from mks_sim.geometry.transforms import make_transform
from mks_sim.localization.verify import consistency
from mks_sim.lowlevel.regions import Plane


def _brute(T, pts, nrm, cloud, table, d):  # noqa: ANN001, ANN202
    """The check's definition, point by point (no trees, no caches)."""
    P = pts @ T[:3, :3].T + T[:3, 3]
    N = nrm @ T[:3, :3].T
    seen = N[:, 2] > -0.3
    centre = P.mean(axis=0)
    radius = np.max(np.linalg.norm(P - centre, axis=1))
    near = cloud[np.linalg.norm(cloud - centre, axis=1) <= radius + 2 * d]
    explained = inside = below = 0
    for q in near:
        dd = np.linalg.norm(P - q, axis=1)
        if np.min(dd[seen]) <= d:
            explained += 1
            continue
        j = int(np.argmin(dd))
        if dd[j] > d and (q - P[j]) @ N[j] < -d:
            inside += 1
            continue
        col = np.linalg.norm(P[:, :2] - q[:2], axis=1) <= 0.5 * d
        if np.count_nonzero(P[col, 2] > q[2] + 2 * d) >= 2:
            below += 1
    penetration = float(np.mean(table.distance(P) < -d))
    return explained, inside, below, penetration


@pytest.mark.parametrize("shift", [(0.0, 0.0, 0.0), (0.012, -0.004, 0.0), (0.0, 0.0, -0.006)])
def test_consistency_counts_match_brute_force(shift: tuple[float, float, float]) -> None:
    rng = np.random.default_rng(4)
    pts, nrm = sample_surface(box_mesh(0.05), 1500, rng=rng)
    T = make_transform(np.eye(3), [0.0, 0.0, 0.775])
    # the cube's top and sides as sensed, a noisy table around and under it, a few strays
    P = pts @ T[:3, :3].T + T[:3, 3]
    vis = (nrm[:, 2] > 0.5) | (nrm[:, 0] > 0.5) | (nrm[:, 1] < -0.5)
    g = rng.uniform(-0.06, 0.06, size=(4000, 2))
    table_pts = np.c_[g, 0.75 + rng.normal(0, 0.0005, len(g))]
    strays = rng.uniform([-0.03, -0.03, 0.74], [0.03, 0.03, 0.81], size=(200, 3))
    cloud = np.concatenate([P[vis] + rng.normal(0, 0.0005, (int(vis.sum()), 3)), table_pts, strays])
    table = Plane(np.array([0.0, 0.0, 1.0]), 0.75)
    Ts = make_transform(np.eye(3), np.add(T[:3, 3], shift))
    d = 0.003
    got = consistency(Ts, pts, nrm, cloud, table, d)
    exp_e, exp_i, exp_b, exp_p = _brute(Ts, pts, nrm, cloud, table, d)
    assert (got.explained, got.inside, got.below) == (exp_e, exp_i, exp_b)
    assert got.penetration == pytest.approx(exp_p)
    assert exp_b > 0 or exp_i > 0 or shift == (0.0, 0.0, 0.0)  # the shifted poses see some
    # a second call reuses the model's cached tree and gives the same counts
    again = consistency(Ts, pts, nrm, cloud, table, d)
    assert again.as_dict() == got.as_dict()
